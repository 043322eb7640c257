"""Does the hand landmark model see a held phone on the detector's people? (issue 35, item 5)

For every phone-labelled person (true or false) of the labelled sets, the person detector path
(``MediaPipePoseBackend``, default settings, one frame at a time) is fitted and matched to the label
(IoU >= 0.5); on a square of 0.3 x the person's height around each wrist the pose model sees
(confidence >= 0.3), upscaled to 256 px, MediaPipe's hand landmark model (``mediapipe.solutions.hands``,
static images, detection >= 0.3; in the pinned wheel) looks for a hand. Printed per person height:
people, people with a hand found on a wrist, among phone users and among the others, and people whose
hand has its fingers curled round something (mean fingertip distance from the palm centre < the palm's
length), phone users against the others.

Then the evidence issue 35 listed as not tried, each as the AUC of one number per person (the chance
that a phone user scores above a non-user: 0.5 = no evidence, 1 = separates them; in brackets the
people it could be measured on), per person height, beside the AUC of today's single-frame posture
cue (``PoseGeometryPhoneClassifier``) on the same people:

- *head bowed*: minus the face mesh's pitch (``FaceEyeContact``, default settings: faces under 20 px
  fitted on 5 shifted crops), people >= 100 px on whom a face was fitted;
- *face lit from below*: the mean grey of the lower half of the face square over its upper half (a
  screen's light on the chin; the face square is 0.6 of the head square ``face.head_box`` gives);
- *forearms raised*: the mean elevation (deg above the horizontal, image up) of the forearms (elbow to
  wrist, both seen >= 0.3): a phone held to be read raises the forearms toward the horizontal;
- *wrists together*: minus the wrists' distance in torso lengths (shoulders' to hips' midpoint).

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
REAL = ("walk_a", "phone_a", "street")  # camera footage; the rest are rendered


def curled(landmarks: np.ndarray) -> bool:
    """Fingers closed round something: mean fingertip (8, 12, 16, 20) distance from the palm's centre
    (0, 5, 9, 13, 17) below the palm's length (wrist 0 to middle knuckle 9)."""
    palm = landmarks[[0, 5, 9, 13, 17]].mean(axis=0)
    span = float(np.linalg.norm(landmarks[9] - landmarks[0])) + 1e-6
    return float(np.mean([np.linalg.norm(landmarks[t] - palm) for t in (8, 12, 16, 20)])) / span < 1.0


def evidence(frame: np.ndarray, person: object, face: object, geometry: object) -> dict[str, float]:
    """The per-person numbers of the second table (NaN where not measurable)."""
    from trustnav.perception.face import head_box

    kp, conf = person.keypoints, person.confidences
    out = {"posture": float(geometry(frame, person))}
    res = face.analyse(frame, person)
    out["head bowed"] = -res.pitch if np.isfinite(res.pitch) else np.nan
    head = head_box(person)
    out["lit from below"] = np.nan
    if head is not None:
        cx, cy, side = head
        half = 0.3 * side
        x0, x1 = int(max(cx - half, 0)), int(max(cx + half, 0))
        y0, y1 = int(max(cy - half, 0)), int(max(cy + half, 0))
        grey = frame[y0:y1, x0:x1].astype(float).mean(axis=2) if y1 - y0 >= 4 and x1 - x0 >= 2 else None
        if grey is not None and grey.size:
            mid = grey.shape[0] // 2
            out["lit from below"] = float(grey[mid:].mean() / max(grey[:mid].mean(), 1.0))
    arms = [(7, 9), (8, 10)]  # COCO elbow -> wrist, left and right
    if all(conf[i] >= 0.3 and conf[j] >= 0.3 for i, j in arms):
        rises = [np.degrees(np.arctan2(kp[i][1] - kp[j][1], abs(kp[j][0] - kp[i][0]))) for i, j in arms]
        out["forearms raised"] = float(np.mean(rises))
    else:
        out["forearms raised"] = np.nan
    torso = float(np.linalg.norm((kp[5] + kp[6]) / 2 - (kp[11] + kp[12]) / 2))
    ok = conf[9] >= 0.3 and conf[10] >= 0.3 and torso > 1.0
    out["wrists together"] = -float(np.linalg.norm(kp[9] - kp[10])) / torso if ok else np.nan
    return out


def main() -> None:
    import cv2
    import mediapipe as mp

    import trust_eval as te
    from trustnav.perception.face import FaceEyeContact
    from trustnav.perception.mediapipe_backend import MediaPipePoseBackend
    from trustnav.perception.phone import PoseGeometryPhoneClassifier

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rendered", type=Path, help="folder holding rendered/ and rendered_heldout/ frames")
    args = ap.parse_args()
    warnings.filterwarnings("ignore", message="SymbolDatabase.GetPrototype")
    sets = te.evidence_sets(args.rendered)
    rows = []
    face, geometry = FaceEyeContact(), PoseGeometryPhoneClassifier()
    with (
        MediaPipePoseBackend(video=False) as backend,
        mp.solutions.hands.Hands(static_image_mode=True, max_num_hands=2, min_detection_confidence=0.3) as hands,
    ):
        for name, _, frame, label, person in te.labelled_people(sets, backend, "phone"):
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
            more = evidence(frame, person, face, geometry)
            rows.append((bool(label["phone"]), height, found, held, more, name in REAL))
    print("| person height | people | a hand found | phone users: found | others: found | fingers curled |")
    print("|---|---|---|---|---|---|")
    for lo, hi in BINS:
        r = [x for x in rows if lo <= x[1] < hi]
        ph, no = [x for x in r if x[0]], [x for x in r if not x[0]]
        span = f"< {hi} px" if lo == 0 else f">= {lo} px" if hi == BINS[-1][1] else f"{lo}-{hi} px"
        curl = f"{sum(x[3] for x in ph)}/{len(ph)} vs {sum(x[3] for x in no)}/{len(no)}"
        print(f"| {span} | {len(r)} | {sum(x[2] for x in r)} | {sum(x[2] for x in ph)}/{len(ph)} | "
              f"{sum(x[2] for x in no)}/{len(no)} | {curl} |")  # fmt: skip
    names = list(rows[0][4]) if rows else []
    print()
    print("AUC, phone users against the others (people measured: users + others)")
    print("| person height | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    for lo, hi in (*BINS, (0, BINS[-1][1])):
        r = [x for x in rows if lo <= x[1] < hi]
        span = (
            "all"
            if (lo, hi) == (0, BINS[-1][1])
            else f"< {hi} px"
            if lo == 0
            else f">= {lo} px"
            if hi == BINS[-1][1]
            else f"{lo}-{hi} px"
        )
        print(f"| {span} | " + " | ".join(te.auc([(x[0], x[4][n]) for x in r]) for n in names) + " |")  # fmt: skip
    for lo, hi in ((0, 150), (150, BINS[-1][1]), (0, BINS[-1][1])):
        r = [x for x in rows if lo <= x[1] < hi and x[5]]
        span = (
            "real sets, all"
            if lo == 0 and hi > 150
            else f"real sets, < {hi} px"
            if lo == 0
            else f"real sets, >= {lo} px"
        )
        print(f"| {span} | " + " | ".join(te.auc([(x[0], x[4][n]) for x in r]) for n in names) + " |")  # fmt: skip


if __name__ == "__main__":
    main()
