"""Does the hand landmark model see a held phone on the detector's people? (issue 35, item 5)

For every phone-labelled person (true or false) of the labelled sets, the person detector path
(``MediaPipePoseBackend``, default settings, one frame at a time) is fitted and matched to the label
(IoU >= 0.5); on a square of 0.3 x the person's height around each wrist the pose model sees
(confidence >= 0.3), upscaled to 256 px, MediaPipe's hand landmark model (``mediapipe.solutions.hands``,
static images, detection >= 0.3; in the pinned wheel) looks for a hand. Printed per person height:
people, people with a hand found on a wrist, among phone users and among the others, and people whose
hand has its fingers curled round something (mean fingertip distance from the palm centre < the palm's
length), phone users against the others.

    python benchmarks/phone_image_evidence.py                       # the real sets
    python benchmarks/phone_image_evidence.py --rendered /tmp/te    # also the rendered sets, from
                                                                    # trust_eval.py --keep /tmp/te
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # trust_eval, beside this file

BINS = ((0, 100), (100, 150), (150, 250), (250, 100000))
WRIST_COCO = (9, 10)


def curled(landmarks: np.ndarray) -> bool:
    """Fingers closed round something: mean fingertip (8, 12, 16, 20) distance from the palm's centre
    (0, 5, 9, 13, 17) below the palm's length (wrist 0 to middle knuckle 9)."""
    palm = landmarks[[0, 5, 9, 13, 17]].mean(axis=0)
    span = float(np.linalg.norm(landmarks[9] - landmarks[0])) + 1e-6
    return float(np.mean([np.linalg.norm(landmarks[t] - palm) for t in (8, 12, 16, 20)])) / span < 1.0


def main() -> None:
    import cv2
    import mediapipe as mp

    import trust_eval as te
    from trustnav.perception.mediapipe_backend import MediaPipePoseBackend
    from trustnav.perception.types import box_iou

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rendered", type=Path, help="folder holding rendered/ and rendered_heldout/ frames")
    args = ap.parse_args()
    warnings.filterwarnings("ignore", message="SymbolDatabase.GetPrototype")
    seq = te.SHARED / "data" / "sequences"
    sets = {"walk_a": seq / "walk_a", "phone_a": seq / "phone_a", "street": te.SHARED / "data" / "street_images"}
    if args.rendered:
        sets |= {name: args.rendered / name for name in ("rendered", "rendered_heldout")}
    rows = []
    with (
        MediaPipePoseBackend(video=False) as backend,
        mp.solutions.hands.Hands(static_image_mode=True, max_num_hands=2, min_detection_confidence=0.3) as hands,
    ):
        for name, folder in sets.items():
            for frame_name, labelled in te.load_labels(name)["frames"].items():
                image = cv2.imread(str(folder / frame_name))
                if image is None:
                    raise SystemExit(f"cannot read {folder / frame_name}")
                frame = np.ascontiguousarray(image[:, :, ::-1])
                people = backend(frame)
                for label in labelled["people"]:
                    if label.get("phone") is None or not people:
                        continue
                    person = max(people, key=lambda q: box_iou(q.bbox, label["bbox"]))
                    if box_iou(person.bbox, label["bbox"]) < 0.5:
                        continue
                    height = float(person.bbox[3] - person.bbox[1])
                    found = held = False
                    for k in WRIST_COCO:
                        if person.confidences[k] < 0.3:
                            continue
                        x, y = person.keypoints[k]
                        half = max(0.3 * height, 24.0) / 2
                        x0, y0 = int(max(0.0, x - half)), int(max(0.0, y - half))
                        crop = frame[y0 : int(y + half), x0 : int(x + half)]
                        if crop.size == 0:
                            continue
                        result = hands.process(cv2.resize(crop, (256, 256), interpolation=cv2.INTER_CUBIC))
                        if result.multi_hand_landmarks:
                            found = True
                            lm = np.array([(p.x, p.y) for p in result.multi_hand_landmarks[0].landmark])
                            held = held or curled(lm)
                    rows.append((bool(label["phone"]), height, found, held))
    print("| person height | people | a hand found | phone users: found | others: found | fingers curled |")
    print("|---|---|---|---|---|---|")
    for lo, hi in BINS:
        r = [x for x in rows if lo <= x[1] < hi]
        ph, no = [x for x in r if x[0]], [x for x in r if not x[0]]
        span = f"< {hi} px" if lo == 0 else f">= {lo} px" if hi == BINS[-1][1] else f"{lo}-{hi} px"
        curl = f"{sum(x[3] for x in ph)}/{len(ph)} vs {sum(x[3] for x in no)}/{len(no)}"
        print(f"| {span} | {len(r)} | {sum(x[2] for x in r)} | {sum(x[2] for x in ph)}/{len(ph)} | "
              f"{sum(x[2] for x in no)}/{len(no)} | {curl} |")  # fmt: skip


if __name__ == "__main__":
    main()
