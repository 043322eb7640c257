"""Live input for `trustnav estimate`: a camera index or a stream URL, read through OpenCV (issue 20).

:class:`LiveSource` opens the capture with a bounded wait (a camera that does not exist or a URL
that does not answer fails in seconds, naming the input), then a grabber thread reads frames as
fast as the source gives them and keeps only the newest: the perception loop always works on the
latest frame, and frames it had no time for are counted as dropped. Each frame carries its
capture time: the stream's own clock (``CAP_PROP_POS_MSEC``) while that increases, else the wall
clock since the source opened.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
from numpy.typing import NDArray

from trustnav.perception.frames import FrameItem, is_live_source, quiet_stderr

__all__ = ["LiveSource", "frames_due", "is_live_source"]


def frames_due(t: float, t_first: float, fps: float, written: int, most: int) -> int:
    """How many times to write the frame captured at ``t`` into a video of ``fps`` frames/s that
    started at ``t_first`` and holds ``written`` frames, so that it plays in real time at the rate
    perception achieved (each frame held until the next one): at least 1, at most ``most``."""
    if not (math.isfinite(t) and math.isfinite(t_first)) or fps <= 0:
        return 1
    return max(1, min(most, round((t - t_first) * fps) + 1 - written))


def _open_cv(source: int | str, timeout_s: float) -> Any:
    import cv2

    ms = int(timeout_s * 1000)
    params = [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, ms, cv2.CAP_PROP_READ_TIMEOUT_MSEC, ms]
    with quiet_stderr():  # OpenCV's own warnings on a source it cannot open: the error says it
        return cv2.VideoCapture(source, cv2.CAP_ANY, params)


class LiveSource:
    """A live capture whose newest frame is always the one handed out (module docstring).

    source: a camera index as text (``"0"``) or a URL; open_timeout / read_timeout: seconds to wait
    for the source to open and for a next frame; capture_factory: ``(source, timeout_s) -> capture``
    with OpenCV's ``isOpened``, ``read``, ``get`` and ``release`` (tests give a fake one); pace:
    hand frames out no faster than their stream clock (default: for ``file://`` URLs, so that a
    recorded video plays as the live stream it was; cameras and network streams pace themselves).
    """

    def __init__(
        self,
        source: str,
        *,
        open_timeout: float = 5.0,
        read_timeout: float = 5.0,
        capture_factory: Callable[[int | str, float], Any] | None = None,
        pace: bool | None = None,
    ) -> None:
        if not is_live_source(source):
            raise ValueError(f"live input must be a camera index or a URL, got {source!r}")
        for name, v in (("open_timeout", open_timeout), ("read_timeout", read_timeout)):
            if not 0 < v <= 600:
                raise ValueError(f"{name} must be in (0, 600] s, got {v!r}")
        self.source = source
        self.read_timeout = read_timeout
        self.pace = source.lower().startswith("file://") if pace is None else pace
        factory = capture_factory or _open_cv
        target: int | str = int(source) if source.isdigit() else source
        box: dict[str, Any] = {}

        def opener() -> None:
            try:
                box["cap"] = factory(target, open_timeout)
            except Exception as exc:  # reported below
                box["error"] = exc

        t = threading.Thread(target=opener, name="trustnav-live-open", daemon=True)
        t.start()
        t.join(open_timeout + 1.0)
        cap = box.get("cap")
        what = f"camera {source}" if source.isdigit() else source
        if t.is_alive():
            raise ValueError(f"live input {what} did not open within {open_timeout:g} s")
        if cap is None or not cap.isOpened():
            why = f" ({box['error']})" if "error" in box else ""
            raise ValueError(f"cannot open live input {what}{why}: no such camera, or the stream does not answer")
        self._cap = cap
        fps = float(cap.get(5) or 0.0)  # cv2.CAP_PROP_FPS
        self.fps: float | None = fps if 0 < fps < 1000 else None
        self._cond = threading.Condition()
        self._newest: tuple[int, float, NDArray[np.uint8]] | None = None
        self._taken = -1
        self._grabbed = 0
        self.dropped = 0
        self._eof = False
        self._stop = False
        self._opened = time.monotonic()
        self._thread = threading.Thread(target=self._grab, name="trustnav-live-grab", daemon=True)

    def _start(self) -> None:
        """Start reading (at the first call of :meth:`frames`: a source opened early, to fail fast,
        is not read while the caller still loads its models)."""
        if not self._thread.is_alive() and not self._eof and self._grabbed == 0:
            self._opened = time.monotonic()
            self._thread.start()

    def _grab(self) -> None:
        last_t = -math.inf
        use_stream_clock = True
        wall_offset = 0.0
        while not self._stop:
            ok, bgr = self._cap.read()
            now = time.monotonic() - self._opened
            if not ok or bgr is None:
                with self._cond:
                    self._eof = True
                    self._cond.notify_all()
                return
            pos = float(self._cap.get(0) or 0.0) / 1000.0  # cv2.CAP_PROP_POS_MSEC
            if use_stream_clock and not (math.isfinite(pos) and pos >= 0 and pos > last_t):
                use_stream_clock = False  # the stream has no usable clock: the wall clock from here on
                wall_offset = (last_t if math.isfinite(last_t) else 0.0) - now
            t = pos if use_stream_clock else max(now + wall_offset, last_t + 1e-6)
            last_t = t
            if self.pace and use_stream_clock:
                time.sleep(max(0.0, t - (time.monotonic() - self._opened)))
            rgb = np.ascontiguousarray(bgr[..., ::-1])
            with self._cond:
                if self._newest is not None and self._newest[0] != self._taken:
                    self.dropped += 1  # the loop never took the previous one
                self._newest = (self._grabbed, t, rgb)
                self._grabbed += 1
                self._cond.notify_all()

    def frames(self, max_frames: int | None = None, max_seconds: float | None = None) -> Iterator[FrameItem]:
        """The newest frame each time one is asked for, until the stream ends, ``max_frames`` were
        handed out or ``max_seconds`` of wall time passed. Names are ``SOURCE#k`` (k: the frame's
        number in the stream, so gaps show the drops)."""
        self._start()
        handed = 0
        start = time.monotonic()
        while (max_frames is None or handed < max_frames) and (
            max_seconds is None or time.monotonic() - start < max_seconds
        ):
            with self._cond:
                deadline = time.monotonic() + self.read_timeout
                while (self._newest is None or self._newest[0] == self._taken) and not self._eof:
                    left = deadline - time.monotonic()
                    if left <= 0:
                        raise TimeoutError(f"live input {self.source}: no frame for {self.read_timeout:g} s")
                    self._cond.wait(left)
                if self._newest is None or self._newest[0] == self._taken:
                    return  # the stream ended
                k, t, rgb = self._newest
                self._taken = k
            yield FrameItem(f"{self.source}#{k}", handed, rgb, time=t)
            handed += 1

    def close(self) -> None:
        """Stop the grabber and release the capture."""
        if self._stop:
            return  # closed already
        self._stop = True
        if self._thread.is_alive():
            self._thread.join(timeout=self.read_timeout + 1.0)
        self._cap.release()

    def __enter__(self) -> LiveSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
