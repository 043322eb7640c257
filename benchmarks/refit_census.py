"""How often the detector path's refit acts, and on whom, over the labelled sets.

The refit (issue 35): a detector box whose landmark fits are all rejected gets one more fit on the
region the first rejected fit suggests for the next frame (``MediaPipePoseBackend._confirm`` with
``refit=True``, offline only; ``extra["refit"]``). Each set runs through ``trustnav estimate`` as in
``trust_eval.py``; every refitted person is looked up in the output and, on a labelled frame, in
the labels: a labelled person (IoU >= 0.5), an ignore region, or nothing (a false box)::

    python benchmarks/refit_census.py            # all labelled sets
    python benchmarks/refit_census.py --set street
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import trust_eval as te
import trustnav.perception.mediapipe_backend as mb


def _what(box: list[float], frame: dict[str, Any] | None) -> str:
    """Whom a box lies on in a labelled frame (None: the frame is not labelled)."""
    if frame is None:
        return "kept, on an unlabelled frame"
    best = max(frame["people"], key=lambda p: te.iou(box, p["bbox"]), default=None)
    if best is not None and te.iou(box, best["bbox"]) >= te.MATCH_IOU:
        return f"labelled person: {best['id']}"
    if any(te.inside_fraction(box, r) >= te.IGNORE_INSIDE for r in frame.get("ignore", [])):
        return "ignore region"
    return "no labelled person (a false box)"


def census(name: str, cache: Path) -> list[tuple[list[float], str]]:
    """(box, what it lies on) for every person the refit confirmed in set ``name``."""
    labels = te.load_labels(name)
    refits: list[list[float]] = []
    confirm = mb.MediaPipePoseBackend._confirm

    def spy(self: Any, *args: Any, **kwargs: Any) -> Any:
        out = confirm(self, *args, **kwargs)
        if out is not None and out[3].extra.get("refit"):
            refits.append([float(v) for v in out[3].bbox])
        return out

    mb.MediaPipePoseBackend._confirm = spy  # type: ignore[method-assign]
    try:
        with tempfile.TemporaryDirectory() as tmp:
            records = te.run_estimate(te.inputs_of(name, labels, cache), Path(tmp) / name)
    finally:
        mb.MediaPipePoseBackend._confirm = confirm  # type: ignore[method-assign]

    def what(box: list[float]) -> str:
        for r in records:
            if np.allclose(r["bbox"], box, atol=0.6):
                return _what(box, labels["frames"].get(r["frame"]))
        return "not in the output (a duplicate of another box, or gated)"

    return [(np.round(b).tolist(), what(b)) for b in refits]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--set", action="append", help="a labelled set (default: all)")
    args = parser.parse_args(argv)
    known = sorted(p.stem for p in te.LABELS.glob("*.json"))
    names = args.set or known
    unknown = [n for n in names if n not in known]
    if unknown:
        parser.error(f"--set {unknown[0]!r}: expected one of the labelled sets {known}")
    print(f"load {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory() as cache:
        for name in names:
            found = census(name, Path(cache))
            print(f"{name}: {len(found)} boxes confirmed by the refit")
            for box, what in found:
                print(f"  {box}: {what}")


if __name__ == "__main__":
    main()
