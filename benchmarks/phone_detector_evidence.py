"""Does the detector see the phone itself? YOLOX-Nano's COCO "cell phone" score on crops around a
person's hands and face, against the phone labels (issue 35, item 5).

On whole frames the person detector never boxes a held phone (a few pixels there). Here each
phone-labelled person (true or false) of the labelled sets is fitted by the detector path
(``MediaPipePoseBackend``, default settings, one frame at a time) and matched to the label (IoU >=
0.5); squares around the person's head and hands are cut from the frame, enlarged (bicubic) to the
network's 416 px input and run through the same YOLOX-Nano (``PersonDetector.class_scores``); a
person's phone score is the largest "cell phone" score (objectness x class score, COCO class 67)
over the square's anchors. The squares (h: the person's box height):

- *head*: 0.4 h on the mean of the nose and ears seen (confidence >= 0.3): a phone at the ear or the mouth;
- *wrists*: 0.3 h on each wrist the pose model places (confidence >= 0.1): a phone in the hand;
- *head or wrists*: the larger of the two;
- *hands and face*: one square over the nose, ears, elbows and wrists seen (>= 0.3), 0.12 h of margin,
  at least 0.35 h, the score taken only at anchors within 0.15 h of a seen wrist.

Printed per person height: the AUC of each score (the chance that a phone user scores above a
non-user; 0.5 = no evidence; in brackets users + others) beside today's single-frame posture cue
(``PoseGeometryPhoneClassifier``) on the same people; every set, the real sets (walk_a, phone_a,
street) and the rendered ones apart; then the real people's scores one by one. ``--resolution``
also shrinks the street images so that each labelled person is T px tall (INTER_AREA; keypoints
scaled from the full-size fit) and prints, per T, each phone user's "head or wrists" score beside
the largest of the non-users': the person height from which a phone the detector sees stands out.
``--placements 9``: each square's score is the mean over 9 placements 4 % of the height apart.

    python benchmarks/phone_detector_evidence.py                       # the real sets
    python benchmarks/phone_detector_evidence.py --rendered /tmp/te    # also the rendered sets, from
                                                                       # trust_eval.py --keep /tmp/te
    python benchmarks/phone_detector_evidence.py --resolution          # also the street images shrunk
    python benchmarks/phone_detector_evidence.py --placements 9        # each square's mean over 9 placements
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # trust_eval, beside this file

REAL = ("walk_a", "phone_a", "street")  # camera footage; the rest are rendered
SCHEMES = ("head", "wrists", "head or wrists", "hands and face")
HEAD, WRIST, FACE_WRIST = (0, 3, 4), (9, 10), (0, 3, 4, 7, 8, 9, 10)
SHRUNK_HEIGHTS = (380, 300, 240, 180, 120)


def regions(keypoints: np.ndarray, confidences: np.ndarray, height: float) -> dict[str, list[tuple[float, ...]]]:
    """The squares (centre x, centre y, side) in frame pixels of each scheme but "head or wrists"
    (module docstring); a scheme with nothing seen has none."""
    kp, c = np.asarray(keypoints, float), np.asarray(confidences, float)
    seen = np.isfinite(kp).all(axis=1)
    out: dict[str, list[tuple[float, ...]]] = {"head": [], "wrists": [], "hands and face": []}
    head = [i for i in HEAD if seen[i] and c[i] >= 0.3]
    if head:
        x, y = kp[head].mean(axis=0)
        out["head"].append((float(x), float(y), 0.4 * height))
    out["wrists"] = [(float(kp[i, 0]), float(kp[i, 1]), 0.3 * height) for i in WRIST if seen[i] and c[i] >= 0.1]
    pts = kp[[i for i in FACE_WRIST if seen[i] and c[i] >= 0.3]]
    if len(pts):
        lo, hi = pts.min(axis=0) - 0.12 * height, pts.max(axis=0) + 0.12 * height
        side = max(float((hi - lo).max()), 0.35 * height)
        out["hands and face"].append((float(lo[0] + hi[0]) / 2, float(lo[1] + hi[1]) / 2, side))
    return out


def phone_scores(
    detector: object, frame: np.ndarray, kp: np.ndarray, c: np.ndarray, height: float, placements: int = 1
) -> dict:
    """A person's phone score under each scheme (NaN where it has no square) and ``runs``, the
    network runs it took; ``kp``, ``c``: COCO keypoints and confidences, ``height``: the box's (px).
    ``placements`` 9: each square's score is the mean over it moved by -1, 0, +1 x 4 % of ``height``
    each way (one placement's score moves with the crop), else 1: the square as placed."""
    out: dict[str, float] = {}
    runs = 0
    steps = [(0, 0)] if placements == 1 else [(i, j) for i in (-1, 0, 1) for j in (-1, 0, 1)]
    for name, squares in regions(kp, c, height).items():
        best = np.nan
        for x, y, side in squares:
            values = []
            for i, j in steps:
                centres, scores = detector.class_scores(frame, (x + i * 0.04 * height, y + j * 0.04 * height, side))
                runs += 1
                if name == "hands and face":
                    wrists = [kp[k] for k in WRIST if c[k] >= 0.3 and np.isfinite(kp[k]).all()]
                    near = np.zeros(len(scores), bool)
                    for w in wrists:
                        near |= np.hypot(*(centres - w).T) < 0.15 * height
                    values.append(float(scores[near].max()) if near.any() else 0.0)
                else:
                    values.append(float(scores.max()))
            value = float(np.mean(values))
            best = value if not np.isfinite(best) else max(best, value)
        out[name] = best
    finite = [v for v in (out["head"], out["wrists"]) if np.isfinite(v)]
    out["head or wrists"] = max(finite) if finite else np.nan
    out["runs"] = runs
    return out


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(
        prog="phone_detector_evidence.py",
        description=__doc__.splitlines()[0],
    )
    ap.add_argument("--rendered", type=Path, help="folder holding rendered/ and rendered_heldout/ frames")
    ap.add_argument("--resolution", action="store_true", help="also the street images shrunk (module docstring)")
    ap.add_argument(
        "--placements",
        type=int,
        choices=(1, 9),
        default=1,
        help="1: each square as placed; 9: the mean over it moved by 4 %% of the person's height each way",
    )
    args = ap.parse_args(argv)
    if args.rendered is not None:
        missing = [n for n in ("rendered", "rendered_heldout") if not (args.rendered / n).is_dir()]
        if missing:
            ap.error(f"--rendered {args.rendered}: no {' or '.join(missing)}/ folder in it (trust_eval.py --keep DIR)")
    return args


def main(argv: Sequence[str] | None = None) -> None:
    args = parse_args(argv)
    import cv2

    import trust_eval as te
    from trustnav.perception.detector import PersonDetector
    from trustnav.perception.mediapipe_backend import MediaPipePoseBackend
    from trustnav.perception.phone import PoseGeometryPhoneClassifier

    warnings.filterwarnings("ignore", message="SymbolDatabase.GetPrototype")
    sets = te.evidence_sets(args.rendered)
    detector, geometry = PersonDetector(), PoseGeometryPhoneClassifier()
    rows, seconds, runs = [], 0.0, 0
    with MediaPipePoseBackend(video=False) as backend:
        for name, frame_name, frame, label, person in te.labelled_people(sets, backend, "phone"):
            height = float(person.bbox[3] - person.bbox[1])
            t0 = time.perf_counter()
            s = phone_scores(detector, frame, person.keypoints, person.confidences, height, args.placements)
            seconds += time.perf_counter() - t0
            runs += s.pop("runs")
            s["posture"] = float(geometry(frame, person))
            rows.append({"set": name, "frame": frame_name, "id": label["id"], "phone": bool(label["phone"]),
                         "height": height, "path": sets[name] / frame_name, "person": person, **s})  # fmt: skip
    names = ("posture", *SCHEMES)
    print(f"{len(rows)} people, {runs} network runs, {1000 * seconds / max(runs, 1):.0f} ms a run "
          f"(load {os.getloadavg()[0]:.1f})\n")  # fmt: skip
    print("AUC, phone users against the others (people measured: users + others)")
    print("| people | person height | " + " | ".join(names) + " |")
    print("|---|---|" + "---|" * len(names))
    groups = (
        ("all", lambda r: True),
        ("real", lambda r: r["set"] in REAL),
        ("rendered", lambda r: r["set"] not in REAL),
    )
    for title, keep in groups:
        chosen = [r for r in rows if keep(r)]
        if not chosen:
            continue
        for lo, hi in (*te.HEIGHT_BANDS, (0, te.HEIGHT_BANDS[-1][1])):
            r = [x for x in chosen if lo <= x["height"] < hi]
            band = "all" if (lo, hi) == (0, te.HEIGHT_BANDS[-1][1]) else te.band_name(lo, hi)
            print(f"| {title} | {band} | " + " | ".join(te.auc([(x["phone"], x[n]) for x in r]) for n in names) + " |")
    print("\nThe real people (phone label, height px, posture cue, phone score per scheme)")
    print("| set | frame | person | phone | height | " + " | ".join(names) + " |")
    print("|---|---|---|---|---|" + "---|" * len(names))
    for r in rows:
        if r["set"] in REAL:
            print(f"| {r['set']} | {r['frame']} | {r['id']} | {r['phone']} | {r['height']:.0f} | "
                  + " | ".join(f"{r[n]:.3f}" for n in names) + " |")  # fmt: skip
    if args.resolution:
        street = [r for r in rows if r["set"] == "street"]
        users = [r for r in street if r["phone"]]
        print("\nThe street images shrunk so that each person is T px tall: 'head or wrists' phone score")
        print("| T (px) | " + " | ".join(r["id"] for r in users) + " | the largest of the others (who) | others |")
        print("|---|" + "---|" * (len(users) + 2))
        cache: dict[tuple[Path, float], np.ndarray] = {}
        for target in SHRUNK_HEIGHTS:
            got: list[tuple[bool, float, str]] = []
            for r in street:
                k = target / r["height"]
                if k > 1.0:
                    continue
                key = (r["path"], round(k, 4))
                if key not in cache:
                    cache.clear()
                    full = cv2.imread(str(r["path"]))[:, :, ::-1]
                    cache[key] = np.ascontiguousarray(cv2.resize(full, None, fx=k, fy=k, interpolation=cv2.INTER_AREA))
                p = r["person"]
                s = phone_scores(detector, cache[key], p.keypoints * k, p.confidences, r["height"] * k, args.placements)
                got.append((r["phone"], s["head or wrists"], r["id"]))
            by_user = {i: v for y, v, i in got if y}
            others = [(v, i) for y, v, i in got if not y]
            top = max(others) if others else (np.nan, "-")
            cells = [f"{by_user[r['id']]:.3f}" if r["id"] in by_user else "-" for r in users]
            print(f"| {target} | " + " | ".join(cells) + f" | {top[0]:.3f} ({top[1]}) | {len(others)} |")


if __name__ == "__main__":
    main()
