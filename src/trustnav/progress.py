"""One progress report for every long loop of trustnav (the CLI's commands, campaigns, drives).

:class:`Progress` draws a tqdm bar when its stream is a terminal and, when it is not (a log file, a
pipe, a CI job), writes one plain line every ``every`` seconds (``trustnav: case-1 (render):
12.3/40 s sim (31 %), 0:42 elapsed``) and a last line when it closes, so that a run logged to a
file shows how far it got while it runs. A run that stops early (an exception inside ``with``, or
``close(finished=False)``) is reported where it stopped, never at 100 %; a run that finishes before
its planned total (a drive that reaches its goal early) is shown complete.

:func:`step_reporter` and :func:`labelled_reporter` turn bars into the ``progress(t, duration)`` and
``progress(label, t, duration)`` callbacks that :func:`trustnav.sim.driving.drive` and
:func:`trustnav.sim.driving.compare.compare_trust` call after each control step.

Imports nothing of trustnav: every layer may use it.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import TracebackType
from typing import Any, TextIO

__all__ = ["Progress", "labelled_reporter", "step_reporter"]

#: seconds between two log lines when the stream is not a terminal
LOG_EVERY = 5.0


def _clock(seconds: float) -> str:
    s = int(seconds)
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


class Progress:
    """How far a loop has come, for a person watching: a tqdm bar on a terminal, else a log line
    every ``every`` seconds.

    Parameters
    ----------
    total : planned amount (frames, episodes, seconds of simulated time); None if unknown.
    desc : what runs (the bar's and each line's prefix).
    unit : the unit of ``total`` ("frame", "ep", "s sim").
    decimals : decimals of the amounts shown (1 for simulated seconds).
    enabled : False: nothing is written (``--quiet``).
    stream : where to write (default ``sys.stderr``); a terminal when ``stream.isatty()``.
    every : seconds between log lines off a terminal.
    leave : keep the terminal bar on screen when it closes.
    clock : monotonic clock in seconds (tests pass their own).
    """

    def __init__(
        self,
        total: float | None,
        desc: str = "",
        unit: str = "it",
        *,
        decimals: int = 0,
        enabled: bool = True,
        stream: TextIO | None = None,
        every: float = LOG_EVERY,
        leave: bool = True,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if total is not None and total < 0:
            raise ValueError(f"progress total must be >= 0 or None, got {total}")
        if every <= 0:
            raise ValueError(f"progress 'every' must be > 0 seconds, got {every}")
        self.total = total
        self.desc = desc
        self.unit = unit
        self.n: float = 0
        self.closed = False
        self.finished: bool | None = None  # set by close(): True done, False stopped early
        self._decimals = decimals
        self._stream = stream if stream is not None else sys.stderr
        self._every = every
        self._clock = clock
        self._t0 = clock()
        self._last_line = self._t0
        self._note: dict[str, Any] = {}
        self._bar: Any = None
        self._enabled = enabled
        if enabled and _is_terminal(self._stream):
            from tqdm import tqdm

            amount = f"{{n:.{decimals}f}}/{{total:.0f}}" if total is not None else f"{{n:.{decimals}f}}"
            self._bar = tqdm(
                total=total,
                desc=desc,
                unit=unit,
                file=self._stream,
                leave=leave,
                dynamic_ncols=True,
                bar_format=("{l_bar}{bar}| " if total is not None else "{desc}: ")
                + f"{amount} {unit} [{{elapsed}}{{postfix}}]",
            )

    # -- reporting
    def update(self, n: float = 1) -> None:
        """``n`` more done."""
        self.set(self.n + n)

    def set(self, value: float) -> None:
        """``value`` done in all (e.g. the simulated time reached)."""
        if self.closed:
            return
        self.n = value
        if self._bar is not None:
            self._bar.update(value - self._bar.n)
        elif self._enabled and self._clock() - self._last_line >= self._every:
            self._line()

    def note(self, **fields: Any) -> None:
        """Figures shown beside the amount (``failed=2``)."""
        self._note.update(fields)
        if self._bar is not None:
            self._bar.set_postfix(self._note, refresh=False)

    def describe(self, desc: str) -> None:
        """A new description (e.g. the sequence now read)."""
        self.desc = desc
        if self._bar is not None:
            self._bar.set_description(desc)

    def write(self, message: str) -> None:
        """A message line (a skipped frame) that does not break the bar."""
        if self._bar is not None:
            self._bar.write(message, file=self._stream)
        else:
            print(message, file=self._stream, flush=True)

    def close(self, finished: bool = True) -> None:
        """End the report: ``finished`` True shows the work complete (the total becomes the amount
        done when the work ended before its plan); False shows where it stopped, never 100 %."""
        if self.closed:
            return
        self.closed = True
        self.finished = finished
        if self._bar is not None:
            if not finished:
                self._bar.set_description(f"{self.desc} (interrupted)" if self.desc else "interrupted")
            if finished and self.total is not None and self.n < self.total:
                self._bar.total = self.n
            self._bar.refresh()
            self._bar.close()
        elif self._enabled:
            self._line(last=True)

    # -- context manager: an exception inside closes the report as stopped early
    def __enter__(self) -> Progress:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self.close(finished=kind is None)

    # -- the log line off a terminal
    def _line(self, last: bool = False) -> None:
        now = self._clock()
        self._last_line = now
        d = self._decimals
        total = self.total
        if last and self.finished and total is not None and self.n < total:
            total = self.n  # ended before its plan (a goal reached early): complete
        amount = f"{self.n:.{d}f}" + ("" if total is None else f"/{total:.{d}f}") + f" {self.unit}"
        if total:  # rounded down: short of the total never reads 100 %
            amount += f" ({100 if self.n >= total else int(100.0 * self.n / total)} %)"
        state = ("done" if self.finished else "interrupted") if last else ""
        notes = ", ".join(f"{k}={v}" for k, v in self._note.items())
        parts = [amount, f"{_clock(now - self._t0)} elapsed"] + ([notes] if notes else [])
        head = f"trustnav: {self.desc}: " if self.desc else "trustnav: "
        print(head + (f"{state}: " if state else "") + ", ".join(parts), file=self._stream, flush=True)


def _is_terminal(stream: TextIO) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # a closed or odd stream
        return False


@contextmanager
def step_reporter(desc: str, duration: float, **options: Any) -> Iterator[Callable[[float, float], None]]:
    """A ``progress(t, duration)`` callback for one drive, drawn as simulated seconds; the bar
    opens at the first report (after the world has opened) and closes with the ``with`` block,
    as stopped early if it raised."""
    bars: list[Progress] = []

    def report(t: float, _duration: float) -> None:
        if not bars:
            bars.append(Progress(duration, desc, "s sim", decimals=1, **options))
        bars[0].set(t)

    try:
        yield report
    except BaseException:
        for b in bars:
            b.close(finished=False)
        raise
    for b in bars:
        b.close()


@contextmanager
def labelled_reporter(desc: str, **options: Any) -> Iterator[Callable[[str, float, float], None]]:
    """A ``progress(label, t, duration)`` callback for several drives in turn (a comparison): one
    bar per label, the previous one closed as finished when the next label starts."""
    bars: dict[str, Progress] = {}

    def report(label: str, t: float, duration: float) -> None:
        if label not in bars:
            for b in bars.values():
                b.close()
            bars[label] = Progress(duration, f"{desc} {label}".strip(), "s sim", decimals=1, **options)
        bars[label].set(t)

    try:
        yield report
    except BaseException:
        for b in bars.values():
            b.close(finished=False)
        raise
    for b in bars.values():
        b.close()
