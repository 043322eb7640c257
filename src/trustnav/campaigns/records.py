"""Episode records on disk: one JSON object per line, appended as episodes complete.

A campaign directory holds ``records.jsonl``; a record's ``key`` (sweep : point id : seed)
identifies its episode across runs, so a rerun skips every key already there (a later record of
the same key replaces an earlier one, e.g. a retried failure). A line cut short by an interrupted
write is dropped when the file is opened again.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

__all__ = ["RecordStore"]


class RecordStore:
    """Append-only JSON Lines file of episode records, keyed by ``key``."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._fh: IO[str] | None = None

    def _repair(self) -> None:
        """Cut a trailing partial line (the write an interruption stopped)."""
        if not self.path.exists() or self.path.stat().st_size == 0:
            return
        with open(self.path, "rb+") as fh:
            fh.seek(-1, os.SEEK_END)
            if fh.read(1) == b"\n":
                return
            fh.seek(0)
            keep = fh.read().rfind(b"\n") + 1
            fh.truncate(keep)

    def __iter__(self) -> Iterator[dict[str, Any]]:
        if not self.path.exists():
            return
        with open(self.path, encoding="utf-8") as fh:
            for line in fh:
                line = line.strip()
                if not line:
                    continue
                try:
                    rec = json.loads(line)
                except json.JSONDecodeError:
                    continue  # a line cut short: the episode counts as not done
                if isinstance(rec, dict) and "key" in rec:
                    yield rec

    def latest(self) -> dict[str, dict[str, Any]]:
        """The last record of each key."""
        return {r["key"]: r for r in self}

    def open(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._repair()
        self._fh = open(self.path, "a", encoding="utf-8")

    def append(self, record: dict[str, Any]) -> None:
        """Write one record and flush it (an interruption loses at most the line being written)."""
        if self._fh is None:
            raise RuntimeError("RecordStore.append before open()")
        self._fh.write(json.dumps(record, separators=(",", ":"), allow_nan=False) + "\n")
        self._fh.flush()

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None

    def __enter__(self) -> RecordStore:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
