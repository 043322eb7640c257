"""Do the face mesh's eyelids and irises tell eyes cast down from eyes on the camera? (issue 35, item 5)

For every eye-contact-labelled person (true or false) of the labelled sets, the person detector path
(``MediaPipePoseBackend``, default settings, one frame at a time) is fitted and matched to the label
(IoU >= 0.5), and the face cue (``FaceEyeContact``, default settings) is run on it. Where it finds a
face, the face alone is cut again from the frame itself (a square of 1.6 x the detected face box),
upscaled to ``--side`` px (bicubic) and the face mesh with attention (478 landmarks, refined eyelids
and irises) fitted on it, as the face cue reads the irises (``FaceConfig.eye_crop_px``). From those
landmarks, per eye (corners 33-133 and 362-263, lids 159/145 and 386/374, irises 468/473), averaged
over the two eyes:

- *eye opening*: the lids' gap over the eye's width (eyes cast down close the upper lid);
- *iris low*: the iris centre's offset below the corners' line, over the eye's width;
- *iris aside*: the iris centre's horizontal offset from the corners' middle, over half the width.

Printed: one row per person (set, frame, label, height, face and eye size in frame px, the face cue's
yaw / pitch / p_face / c_face, the three numbers, iris aside again with the cut moved by 1 px, and
p_gaze: the face cue's cone on yaw + ``iris_gain_deg`` x iris aside, whatever the eyes' size), then
the AUC of each number (looking against not looking; eye opening and minus iris low count "more open /
higher = looking") per face size.

    python benchmarks/gaze_evidence.py --rendered /tmp/te    # rendered frames from trust_eval.py --keep /tmp/te
"""

from __future__ import annotations

import argparse
import math
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # trust_eval, beside this file

REAL = ("walk_a", "phone_a", "street")
EYES = ((33, 133, 159, 145, 468), (362, 263, 386, 374, 473))  # (corner a, corner b, upper lid, lower lid, iris)


def eye_numbers(lm: np.ndarray) -> tuple[float, float, float, float]:
    """(opening, iris low, iris aside, eye width in the landmarks' pixels), both eyes averaged."""
    opening, low, aside, widths = [], [], [], []
    for a, b, up, dn, iris in EYES:
        pa, pb = lm[a, :2], lm[b, :2]
        axis = pb - pa
        w = float(np.linalg.norm(axis))
        if w <= 0:
            continue
        ex = axis / w
        ey = np.array([-ex[1], ex[0]])  # image down for an upright face
        mid = (pa + pb) / 2
        opening.append(float(abs((lm[dn, :2] - lm[up, :2]) @ ey)) / w)
        low.append(float((lm[iris, :2] - mid) @ ey) / w)
        aside.append(float((lm[iris, :2] - mid) @ ex) / (w / 2))
        widths.append(w)
    if not widths:
        return math.nan, math.nan, math.nan, 0.0
    return float(np.mean(opening)), float(np.mean(low)), float(np.mean(aside)), float(np.mean(widths))


def main() -> None:

    import trust_eval as te
    from trustnav.perception.face import FaceConfig, FaceEyeContact, eye_contact_probability
    from trustnav.perception.mediapipe_backend import MediaPipePoseBackend

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rendered", type=Path, help="folder holding the rendered sets' frames (trust_eval.py --keep)")
    ap.add_argument("--side", type=int, default=256, help="side of the upscaled face crop (px, default 256)")
    args = ap.parse_args()
    if args.rendered is not None and not (args.rendered / "rendered").is_dir():
        ap.error(f"--rendered {str(args.rendered)!r}: expected the folder trust_eval.py --keep wrote (with rendered/)")
    if args.side < 64:
        ap.error(f"--side {args.side}: expected the upscaled face crop's side in px, >= 64")
    warnings.filterwarnings("ignore", message="SymbolDatabase.GetPrototype")
    sets = te.evidence_sets(args.rendered, ("rendered", "rendered_heldout", "rendered_sequence"))
    face = FaceEyeContact()
    graphs = face._load()
    head_crop = FaceEyeContact(FaceConfig(eye_crop_px=0, min_eye_px=10.0))  # the irises before issue 35's pass
    head_crop._graphs = graphs
    rows = []
    with MediaPipePoseBackend(video=False) as backend:
        for name, frame_name, frame, lab, person in te.labelled_people(sets, backend, "eye_contact"):
            res = face.analyse(frame, person)
            before = head_crop.analyse(frame, person).probability
            row = {"set": name, "frame": frame_name, "id": lab.get("id", ""), "y": bool(lab["eye_contact"]),
                   "h": float(person.bbox[3] - person.bbox[1]), "face_px": res.face_px, "yaw": res.yaw,
                   "pitch": res.pitch, "p": res.probability, "c": res.confidence, "p_old": before,
                   "open": math.nan, "low": math.nan, "aside": math.nan, "eye_px": math.nan,
                   "aside_moved": math.nan, "p_gaze": math.nan}  # fmt: skip
            lm = _face_mesh(frame, person, face, graphs, args.side)
            if lm is not None:
                o, lo, asd, w = eye_numbers(lm[0])
                row |= {"open": o, "low": lo, "aside": asd, "eye_px": w / lm[1]}
                moved = _face_mesh(frame, person, face, graphs, args.side, shift=1)
                row["aside_moved"] = eye_numbers(moved[0])[2] if moved is not None else math.nan
                row["p_gaze"] = eye_contact_probability(res.yaw + face.config.iris_gain_deg * asd, res.pitch)
            rows.append(row)
    print("| set | frame | person | label | height | face px | eye px | yaw | pitch | p_face | c_face | opening | "
          "iris low | iris aside | moved 1 px | p_gaze |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['set']} | {r['frame']} | {r['id'][:28]} | {int(r['y'])} | {r['h']:.0f} | {r['face_px']:.0f} | "
              f"{r['eye_px']:.1f} | {r['yaw']:.0f} | {r['pitch']:.0f} | {r['p']:.2f} | {r['c']:.2f} | "
              f"{r['open']:.3f} | {r['low']:.3f} | {r['aside']:.2f} | {r['aside_moved']:.2f} | "
              f"{r['p_gaze']:.2f} |")  # fmt: skip
    print()
    print("AUC, looking against not looking (people measured: looking + not)")
    print("| face size | p_face, irises on the head crop's mesh | p_face (default) | opening | -iris low | "
          "-abs(iris aside) | p_face, the iris at any size |")  # fmt: skip
    print("|---|---|---|---|---|---|---|")
    numbers = (
        lambda x: x["p_old"],
        lambda x: x["p"],
        lambda x: x["open"],
        lambda x: -x["low"],
        lambda x: -abs(x["aside"]),
        lambda x: x["p_gaze"],
    )
    groups = [
        (f"{span}", [x for x in rows if lo <= x["face_px"] < hi])
        for lo, hi, span in ((0, 20, "< 20 px"), (20, 40, "20-40 px"), (40, 1e9, ">= 40 px"), (0, 1e9, "all"))
    ]
    groups.append(("real sets", [x for x in rows if x["set"] in REAL]))  # fmt: skip
    for span, r in groups:
        print(f"| {span} | " + " | ".join(te.auc([(x["y"], f(x)) for x in r]) for f in numbers) + " |")


def _face_mesh(frame: np.ndarray, person: object, face: object, graphs: object, side: int, shift: int = 0):
    """The face mesh fitted on the face alone as the face cue reads the irises
    (``FaceEyeContact._eye_fit``: 1.6 x the detected face box cut from the frame, upscaled to ``side``
    px), the cut moved ``shift`` px right: (landmarks in frame pixels, 1.0), or None where no face is
    found."""
    import dataclasses

    from trustnav.perception.face import FaceEyeContact, _crop, head_box, nearest_face
    from trustnav.perception.mediapipe_backend import protobuf_warning_ignored

    head = head_box(person)
    if head is None:
        return None
    cx, cy, hs = head
    n = face.config.crop_px
    crop, scale, x0, y0 = _crop(frame, cx, cy, hs, n)
    with protobuf_warning_ignored():
        dets = [d for d in (graphs.detector.process({"image": crop}).detections or []) if d.score[0] >= 0.5]
    if not dets:
        return None
    det = nearest_face(dets)
    b, kps = det.location_data.relative_bounding_box, det.location_data.relative_keypoints
    rot = -math.atan2(-(kps[1].y - kps[0].y) * n, (kps[1].x - kps[0].x) * n)
    box = (x0 + b.xmin * n / scale + shift, y0 + b.ymin * n / scale, b.width * n / scale, b.height * n / scale)
    fitter = FaceEyeContact(dataclasses.replace(face.config, eye_crop_px=side))
    fitter._graphs = face._graphs
    lm = fitter._eye_fit(frame, box, rot)
    return None if lm is None else (lm, 1.0)


if __name__ == "__main__":
    main()
