"""How far a one-pixel shift of the frame moves each person's keypoints and LOOKING's reading: one
landmark fit against the median of fits on moved crops (``trustnav estimate --crop-fits N``,
:mod:`trustnav.perception.crop_ensemble`).

Every 5th frame of walk_a, every frame of phone_a and the three labelled street photos are read as
they are and moved by (1, 0) and (0, 1) px (edges repeated); each person found on both (IoU >= 0.7
after undoing the move) gives the median distance of their keypoints seen on both (confidence > 0.3)
from where the move puts them, in % of the person's height, and the change of LOOKING's probability
on the two fits. Both backends run in the same process, one after the other; the load is printed.

    python benchmarks/crop_jitter.py            # 1 fit against 5 (~3 min on 2 quiet cores)
    python benchmarks/crop_jitter.py --fits 7
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
SHIFTS = ((1, 0), (0, 1))


def frames() -> list[Path]:
    seq = SHARED / "data" / "sequences"
    street = SHARED / "data" / "street_images"
    return [
        *sorted((seq / "walk_a").glob("*.png"))[::5],
        *sorted((seq / "phone_a").glob("*.png")),
        *(street / f for f in ("crossing.jpg", "street_1.png", "street_2.png")),
    ]


def read(path: Path, dx: int = 0, dy: int = 0) -> np.ndarray:
    import cv2

    img = cv2.imread(str(path))
    if img is None:
        raise SystemExit(f"cannot read {path}")
    h, w = img.shape[:2]
    moved = cv2.warpAffine(img, np.float32([[1, 0, dx], [0, 1, dy]]), (w, h), borderMode=cv2.BORDER_REPLICATE)
    return moved[:, :, ::-1].copy()


def sensitivity(backend, eye, paths: Sequence[Path]) -> tuple[list[float], list[float]]:
    """Per person and shift: keypoint move (% of height) and |change| of LOOKING's probability."""
    from trustnav.perception.looking import normalise_keypoints
    from trustnav.perception.types import box_iou

    moves, looks = [], []
    for path in paths:
        frame = read(path)
        width = frame.shape[1]
        people = backend(frame)
        for dx, dy in SHIFTS:
            others = backend(read(path, dx, dy))
            back = np.array([dx, dy, dx, dy], dtype=float)
            for p in people:
                q = max(others, key=lambda o: box_iou(o.bbox - back, p.bbox), default=None)
                if q is None or box_iou(q.bbox - back, p.bbox) < 0.7:
                    continue
                seen = (p.confidences > 0.3) & (q.confidences > 0.3)
                if not seen.any():
                    continue
                move = np.linalg.norm(q.keypoints - [dx, dy] - p.keypoints, axis=1)[seen]
                moves.append(100 * float(np.median(move)) / float(p.bbox[3] - p.bbox[1]))
                inputs = np.stack([normalise_keypoints(o.keypoints, o.confidences, width) for o in (p, q)])
                pa, pb = eye.predict(inputs)
                looks.append(abs(float(pa) - float(pb)))
    return moves, looks


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="crop_jitter.py", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("--fits", type=int, default=5, help="fits of the ensemble (2-7, default 5)")
    args = parser.parse_args(argv)
    if not 2 <= args.fits <= 7:
        raise SystemExit(f"--fits must be 2-7, got {args.fits}")
    if not SHARED.is_dir():
        raise SystemExit(f"needs the shared data at {SHARED}")
    from trustnav.perception.crop_ensemble import CropEnsembleBackend
    from trustnav.perception.looking import LookingModel
    from trustnav.perception.mediapipe_backend import MediaPipePoseBackend

    eye = LookingModel.from_file(SHARED / "models" / "looking" / "LookingModel_LOOK+PIE.p")
    paths = frames()
    print(f"{len(paths)} frames, shifts {SHIFTS} px")
    print(
        "| landmark fits | person-shift pairs | keypoint move, median / p90 (% height) | LOOKING change, mean / p90 |"
    )
    print("|---|---|---|---|")
    for label, backend in (("1", MediaPipePoseBackend()), (str(args.fits), CropEnsembleBackend(fits=args.fits))):
        with backend:
            moves, looks = sensitivity(backend, eye, paths)
        print(f"| {label} | {len(moves)} | {np.median(moves):.2f} / {np.percentile(moves, 90):.2f} | "
              f"{np.mean(looks):.3f} / {np.percentile(looks, 90):.3f} |", flush=True)  # fmt: skip
    print(f"load (1 min) {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
