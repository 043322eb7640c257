"""Streaming perception: frames in with their time stamps, results out without blocking (issue 20).

:class:`StreamingPerceiver` runs a perception step (a :class:`~trustnav.perception.pipeline.
PerceptionPipeline`, or any callable ``(frame, time) -> people``) on a worker thread:

- ``mode="realtime"``: the worker always takes the **newest** frame. A frame submitted while another
  is still waiting replaces it and is counted as dropped, so the latency of a result is bounded by
  about two processing times, however far the camera runs ahead. With ``max_latency`` = S, frames
  wait instead while they are younger than S seconds (oldest first; older ones are dropped, the
  newest never): a stream that falls behind for a moment (the first frame's full search, a burst
  of people) catches up without losing frames, at the price of up to S seconds more latency;
- ``mode="offline"``: every frame is processed in order (evaluation, recorded video); ``submit``
  waits when ``max_queue`` frames are waiting.

Each :class:`StreamResult` carries the frame's capture time, the wall-clock latency from its
submission to its result, and the frames dropped so far. One frame on which the step fails gives a
result with ``error`` set; the stream goes on.
"""

from __future__ import annotations

import collections
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["MODES", "StreamResult", "StreamingPerceiver"]

MODES = ("realtime", "offline")


@dataclass(frozen=True)
class StreamResult:
    """The perception of one frame of a stream.

    index: the frame's position in submission order (dropped frames keep theirs, so gaps show);
    capture_time: its time stamp (s); people: what the step returned; latency: wall seconds from
    ``submit`` to the result; dropped: frames dropped before this result; error: why the step failed.
    """

    index: int
    capture_time: float
    people: list[Any] = field(default_factory=list)
    latency: float = math.nan
    dropped: int = 0
    error: str | None = None


class StreamingPerceiver:
    """Runs ``step(frame, time)`` on a worker thread over a stream of frames (module docstring)."""

    def __init__(
        self,
        step: Callable[..., list[Any]],
        *,
        mode: str = "realtime",
        max_queue: int = 8,
        max_latency: float | None = None,
        clock: Callable[[], float] = time.perf_counter,
    ) -> None:
        if not callable(step):
            raise ValueError(f"step must be callable as step(frame, time=...), got {type(step).__name__}")
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        if not isinstance(max_queue, int) or max_queue < 1:
            raise ValueError(f"max_queue must be an integer >= 1, got {max_queue!r}")
        if max_latency is not None:
            try:
                ok = mode == "realtime" and 0.0 < float(max_latency) <= 10.0
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise ValueError(
                    f"max_latency must be a number of seconds in (0, 10] with mode='realtime', got {max_latency!r}"
                )
        self.max_latency = None if max_latency is None else float(max_latency)
        self.step = step
        self.mode = mode
        self.max_queue = max_queue if mode == "offline" else 1
        self._clock = clock
        self._cond = threading.Condition()
        self._waiting: collections.deque[tuple[int, float, NDArray[np.uint8], float]] = collections.deque()
        self._results: list[StreamResult] = []
        self._submitted = 0
        self._dropped = 0
        self._working = False
        self._closed = False
        self._last_time = -math.inf
        self._latencies: list[float] = []
        self._thread = threading.Thread(target=self._run, name="trustnav-perceiver", daemon=True)
        self._thread.start()

    # -- producer side -------------------------------------------------------------------------

    def submit(self, frame: NDArray[np.uint8], capture_time: float) -> int:
        """Hand over a frame captured at ``capture_time`` (s, increasing); returns its index.

        Real time: never waits; a frame still waiting is replaced (dropped). Offline: waits while
        ``max_queue`` frames are waiting."""
        t = float(capture_time)
        if not math.isfinite(t):
            raise ValueError(f"capture_time must be a finite number of seconds, got {capture_time!r}")
        with self._cond:
            if self._closed:
                raise RuntimeError("the StreamingPerceiver is closed")
            if t < self._last_time:
                raise ValueError(f"capture_time must not decrease: {t} after {self._last_time}")
            self._last_time = t
            if self.mode == "realtime" and self.max_latency is None:
                self._dropped += len(self._waiting)
                self._waiting.clear()
            elif self.mode == "realtime":
                self._drop_stale()
            else:
                while len(self._waiting) >= self.max_queue and not self._closed:
                    self._cond.wait()
            index = self._submitted
            self._submitted += 1
            self._waiting.append((index, t, frame, self._clock()))
            self._cond.notify_all()
        return index

    # -- consumer side -------------------------------------------------------------------------

    def poll(self) -> list[StreamResult]:
        """The results finished since the last call, in order (never waits)."""
        with self._cond:
            out, self._results = self._results, []
        return out

    def drain(self, timeout: float | None = None) -> list[StreamResult]:
        """Wait until every submitted frame is processed or dropped (or ``timeout`` s), then poll."""
        deadline = None if timeout is None else self._clock() + timeout
        with self._cond:
            while self._waiting or self._working:
                left = None if deadline is None else deadline - self._clock()
                if left is not None and left <= 0:
                    break
                self._cond.wait(left)
        return self.poll()

    @property
    def stats(self) -> dict[str, float]:
        """Frames submitted, processed and dropped; latency median and p95 (s)."""
        with self._cond:
            lat = list(self._latencies)
            return {
                "submitted": self._submitted,
                "processed": len(lat),
                "dropped": self._dropped,
                "latency_median_s": float(np.median(lat)) if lat else math.nan,
                "latency_p95_s": float(np.percentile(lat, 95)) if lat else math.nan,
            }

    def close(self) -> None:
        """Stop the worker after the frame it is on (frames still waiting are dropped)."""
        with self._cond:
            self._closed = True
            self._dropped += len(self._waiting)
            self._waiting.clear()
            self._cond.notify_all()
        self._thread.join(timeout=30.0)

    def __enter__(self) -> StreamingPerceiver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _drop_stale(self) -> None:
        """Drop the waiting frames older than ``max_latency`` (caller holds the lock); the newest
        frame waiting stays."""
        now = self._clock()
        while len(self._waiting) > 1 and now - self._waiting[0][3] > self.max_latency:
            self._waiting.popleft()
            self._dropped += 1

    # -- the worker ----------------------------------------------------------------------------

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._waiting and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return
                if self.max_latency is not None:
                    self._drop_stale()
                index, t, frame, submitted = self._waiting.popleft()
                self._working = True
                self._cond.notify_all()
            people: list[Any] = []
            error = None
            try:
                people = list(self.step(frame, time=t))
            except Exception as exc:  # one bad frame never stops the stream
                error = f"perception failed on frame {index} (t = {t:.3f} s): {type(exc).__name__}: {exc}"
            latency = self._clock() - submitted
            with self._cond:
                self._working = False
                self._latencies.append(latency)
                self._results.append(StreamResult(index, t, people, latency, self._dropped, error))
                self._cond.notify_all()
