"""Output folders written whole or not at all, and the tables written frame by frame.

A bottom layer (like :mod:`trustnav.progress`) that imports nothing of trustnav's: any command or
campaign may use it. :class:`OutputFolder`: a command writes into a temporary sibling of its folder
and the outputs are moved into place only when the run is done, so an interruption (Ctrl-C,
SIGTERM) or a failure leaves the earlier outputs as they were and nothing that blocks a rerun.
:class:`TrackTable`: ``tracks.csv`` flushed frame by frame, ``tracks.json`` on close.
"""

from __future__ import annotations

import contextlib
import csv
import glob
import json
import os
import secrets
import shutil
import signal
import threading
from collections.abc import Iterator
from pathlib import Path

__all__ = ["OutputFolder", "TrackTable", "no_interrupts"]

_PARTIAL = ".trustnav-{pid}-{token}.partial"


@contextlib.contextmanager
def no_interrupts() -> Iterator[None]:
    """Ctrl-C and SIGTERM wait (are ignored) while files are moved into place: a move is never cut short."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.signal(s, signal.SIG_IGN) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        path.unlink()


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True
    return True


class OutputFolder:
    """An output folder written whole or not at all.

    Refuses (ValueError, before anything is written) an ``out`` that is a file, or a folder that holds
    files unless ``overwrite``. The command writes into :attr:`path`, a temporary sibling of ``out``
    (``.<name>.trustnav-<pid>-<token>.partial``); :meth:`commit` moves the finished outputs into ``out``
    (trustnav's earlier ``outputs`` there, glob patterns, are replaced; files of other names are left
    alone), :meth:`discard` removes them. As a context manager it commits on a normal exit and discards
    on any exception (Ctrl-C included): an interrupted or failed run leaves ``out`` as it was and
    nothing that blocks a rerun. Temporary folders left by a killed run (its process gone) are removed
    the next time the same ``out`` is written.
    """

    def __init__(self, out: str | Path, overwrite: bool, outputs: tuple[str, ...]) -> None:
        self.out = Path(out)
        if self.out.exists() and not self.out.is_dir():
            raise ValueError(f"--out {self.out} is a file, expected a folder (new or empty) for the outputs")
        if self.out.is_dir() and any(self.out.iterdir()) and not overwrite:
            raise ValueError(
                f"--out {self.out} is not empty (outputs of an earlier run?): pass --overwrite to replace "
                "trustnav's outputs there, or choose a new folder"
            )
        self.outputs = outputs
        self._path: Path | None = None
        self.state = "new"  # -> open -> committed | discarded | kept aside

    @property
    def path(self) -> Path:
        """Where the command writes (the temporary folder, until :meth:`commit`)."""
        if self._path is None:
            raise RuntimeError("OutputFolder.path before open()")
        return self._path

    def has_earlier_outputs(self) -> bool:
        """Whether ``out`` holds outputs of an earlier run (what :meth:`commit` would replace)."""
        return self.out.is_dir() and any(any(self.out.glob(p)) for p in self.outputs)

    def final(self, path: Path) -> Path:
        """Where ``path`` (under :attr:`path`) will be once committed."""
        return self.out / Path(path).relative_to(self.path)

    def open(self) -> Path:
        real = self.out.resolve()
        real.parent.mkdir(parents=True, exist_ok=True)
        for stale in real.parent.glob(f".{glob.escape(real.name)}{_PARTIAL.format(pid='*', token='*')}"):
            pid = stale.name[len(real.name) + 1 :].split("-")[1]
            if pid.isdigit() and not _pid_alive(int(pid)):
                shutil.rmtree(stale, ignore_errors=True)
        self._path = real.parent / f".{real.name}{_PARTIAL.format(pid=os.getpid(), token=secrets.token_hex(4))}"
        self._path.mkdir()
        self.state = "open"
        return self._path

    def commit(self) -> Path:
        """Move the outputs into ``out`` (Ctrl-C waits until they are all there); returns ``out``."""
        tmp = self.path
        with no_interrupts():
            if not self.out.exists():
                tmp.rename(self.out.resolve())
            else:
                for pattern in self.outputs:
                    for old in self.out.glob(pattern):
                        _remove(old)
                for entry in sorted(tmp.iterdir()):
                    target = self.out / entry.name
                    if target.exists() or target.is_symlink():
                        _remove(target)
                    shutil.move(entry, target)
                tmp.rmdir()
        self.state = "committed"
        return self.out

    def discard(self) -> None:
        """Remove what the run wrote; ``out`` stays as it was."""
        if self._path is not None:
            with no_interrupts():
                shutil.rmtree(self._path, ignore_errors=True)
        self.state = "discarded"

    def keep_aside(self, suffix: str = "interrupted") -> Path:
        """Keep what the run wrote beside ``out`` (``<out>.interrupted``, ``-2``... if taken), leaving
        ``out`` as it was; returns that folder."""
        real = self.out.resolve()
        where, k = real.with_name(f"{real.name}.{suffix}"), 2
        while where.exists():
            where, k = real.with_name(f"{real.name}.{suffix}-{k}"), k + 1
        with no_interrupts():
            self.path.rename(where)
        self.state = "kept aside"
        return self.out.with_name(where.name)

    def keep(self, earlier: bool) -> tuple[Path, str]:
        """Keep what an interrupted run wrote: committed into ``out`` when it held no ``earlier``
        outputs, else kept aside (:meth:`keep_aside`); returns the folder and a note for the user."""
        if earlier:
            return self.keep_aside(), f" ({self.out} keeps the earlier outputs)"
        return self.commit(), ""

    def __enter__(self) -> OutputFolder:
        self.open()
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        if self.state == "open":
            if exc_type is None:
                self.commit()
            else:
                self.discard()


class TrackTable:
    """tracks.csv written and flushed frame by frame; tracks.json written on close (also after an
    interruption), so an interrupted run keeps every record it produced."""

    FIELDS = ("frame", "track_id", "bbox", "eye_contact", "phone", "fluctuation", "smartphone_trait", "eye_trait",
              "pose_trait", "score", "trust", "sequence")  # fmt: skip

    def __init__(self, out: Path, extra: tuple[str, ...] = ()) -> None:
        self.out = out
        self.rows: list[dict] = []
        self._fh = open(out / "tracks.csv", "w", newline="")  # closed in close()
        self._csv = csv.DictWriter(self._fh, fieldnames=(*self.FIELDS, *extra))
        self._csv.writeheader()
        self._fh.flush()

    def add(self, records: list[dict]) -> None:
        self.rows.extend(records)
        self._csv.writerows({**r, "bbox": " ".join(f"{v:g}" for v in r["bbox"])} for r in records)
        self._fh.flush()

    def close(self) -> None:
        self._fh.close()
        tmp = self.out / "tracks.json.part"
        tmp.write_text(json.dumps(self.rows, indent=1))
        tmp.replace(self.out / "tracks.json")
