"""The project's labelled evaluation: detection, tracking, phone use and eye contact against hand labels.

Labels: ``benchmarks/data/labels/*.json`` (one file per set; how they were decided is in each file's
``_doc`` and in docs/perception.md, "Labelled evaluation"). Each set runs through the pipeline exactly
as ``trustnav estimate INPUTS --out DIR`` does (the CLI itself, default settings), and its
``tracks.json`` is compared with the labels of every labelled frame:

- detections are matched to labelled people by IoU >= 0.5 (Hungarian assignment);
- recall: labelled (clearly visible) people matched;
- duplicate boxes: unmatched detections lying on a matched person (IoU >= 0.3 with, or >= 70 % of
  their area inside, that person's box);
- false boxes: the other unmatched detections, unless >= 50 % of their area lies in an "ignore region"
  (a person present but too small, cut off or hidden to be labelled) or on a labelled person;
- ID switches: changes of track ID along each labelled person's matched frames (sets of unrelated
  images, "independent_frames", count none);
- phone use and eye contact: on matched people whose label is true/false (null = undecidable, skipped),
  the detection's ``phone`` / ``eye_contact`` >= 0.5 against the label: TP, FP, FN, TN, precision,
  recall, F1. A missing score (null) counts as a negative prediction.

Held-out sets (``"held_out": true`` in their file: ``rendered_heldout`` and ``rendered_sequence``, a
rendered video; nothing was tuned on them) are reported on their own rows and left out of the "all" row.

    python benchmarks/trust_eval.py                      # all sets, ~1 min on 2 cores
    python benchmarks/trust_eval.py --set phone_a --set street
    python benchmarks/trust_eval.py --json /tmp/trust_eval.json
    python benchmarks/trust_eval.py --estimate-arg=--face     # a non-default option of estimate
    python benchmarks/trust_eval.py --jitter 3  # also on frames shifted by 1-2 px: the figures' spread
    python benchmarks/trust_eval.py --by-height # also phone use and eye contact per labelled person height
    python benchmarks/trust_eval.py --mp4       # also the frame sequences through an MP4 round trip
                                                # (records kept: their count, and those of the same person)
"""

from __future__ import annotations

import argparse
import contextlib
import io
import itertools
import json
import sys
import tempfile
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
LABELS = ROOT / "benchmarks" / "data" / "labels"
SETS = ("walk_a", "phone_a", "street", "rendered", "rendered_heldout", "rendered_sequence")
MATCH_IOU = 0.5
DUPLICATE_IOU = 0.3
DUPLICATE_INSIDE = 0.7
IGNORE_INSIDE = 0.5
THRESHOLD = 0.5
#: Person-height bands (labelled box height, pixels) of the per-height cue table (``--by-height``).
HEIGHT_BANDS = ((0, 100), (100, 150), (150, 250), (250, 10_000))
#: Whole-pixel translations (dx, dy) of the frames tried by ``--jitter K`` (the first K).
JITTER_SHIFTS = ((1, 0), (0, 1), (1, 1), (2, 0), (0, 2), (2, 2))


# ---------------------------------------------------------------- geometry and matching


def iou(a: Sequence[float], b: Sequence[float]) -> float:
    """Intersection over union of two [x1, y1, x2, y2] boxes."""
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    if w <= 0 or h <= 0:
        return 0.0
    inter = w * h
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return float(inter / union) if union > 0 else 0.0


def inside_fraction(a: Sequence[float], region: Sequence[float]) -> float:
    """Share of box ``a``'s area that lies inside ``region``."""
    w = min(a[2], region[2]) - max(a[0], region[0])
    h = min(a[3], region[3]) - max(a[1], region[1])
    area = (a[2] - a[0]) * (a[3] - a[1])
    if w <= 0 or h <= 0 or area <= 0:
        return 0.0
    return float(w * h / area)


def match(
    dets: Sequence[Sequence[float]], labels: Sequence[Sequence[float]], thr: float = MATCH_IOU
) -> list[tuple[int, int]]:
    """(detection index, label index) pairs of the Hungarian assignment maximising total IoU, kept
    where IoU >= ``thr``."""
    if not len(dets) or not len(labels):
        return []
    from scipy.optimize import linear_sum_assignment

    m = np.array([[iou(d, g) for g in labels] for d in dets])
    rows, cols = linear_sum_assignment(-m)
    return sorted((int(r), int(c)) for r, c in zip(rows, cols, strict=True) if m[r, c] >= thr)


def classify_frame(
    dets: Sequence[Sequence[float]],
    people: Sequence[Mapping[str, Any]],
    ignore: Sequence[Sequence[float]] = (),
) -> dict[str, Any]:
    """One frame: matches {label index: detection index}, duplicate, false and ignored detection indices."""
    boxes = [p["bbox"] for p in people]
    pairs = match(dets, boxes)
    matched = {g: d for d, g in pairs}
    used = {d for d, _ in pairs}
    dup, false, ignored = [], [], []
    for d, box in enumerate(dets):
        if d in used:
            continue
        on_matched = any(
            iou(box, boxes[g]) >= DUPLICATE_IOU or inside_fraction(box, boxes[g]) >= DUPLICATE_INSIDE for g in matched
        )
        if on_matched:
            dup.append(d)
        elif any(inside_fraction(box, r) >= IGNORE_INSIDE for r in [*ignore, *boxes]):
            ignored.append(d)
        else:
            false.append(d)
    return {"matched": matched, "duplicate": dup, "false": false, "ignored": ignored}


def id_switches(tracks: Iterable[int | None]) -> int:
    """Changes of track ID along one labelled person's frames (frames where it was missed skipped)."""
    seen = [t for t in tracks if t is not None]
    return sum(a != b for a, b in itertools.pairwise(seen))


def binary_scores(pairs: Iterable[tuple[bool | None, float | None]], thr: float = THRESHOLD) -> dict[str, Any]:
    """(label, score) pairs -> TP/FP/FN/TN, precision, recall, F1; null labels skipped, null scores negative."""
    tp = fp = fn = tn = 0
    for truth, score in pairs:
        if truth is None:
            continue
        pred = score is not None and score >= thr
        if truth and pred:
            tp += 1
        elif truth:
            fn += 1
        elif pred:
            fp += 1
        else:
            tn += 1
    precision = tp / (tp + fp) if tp + fp else None
    recall = tp / (tp + fn) if tp + fn else None
    f1 = 2 * precision * recall / (precision + recall) if precision and recall else (0.0 if tp + fn else None)
    return {"tp": tp, "fp": fp, "fn": fn, "tn": tn, "precision": precision, "recall": recall, "f1": f1}


def band_name(lo: float, hi: float) -> str:
    """'< 100 px', '100-150 px', '>= 250 px'."""
    return f"< {hi} px" if lo <= 0 else f">= {lo} px" if hi >= HEIGHT_BANDS[-1][1] else f"{lo}-{hi} px"


def evaluate(labels: Mapping[str, Any], records: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Compare ``tracks.json`` records with one set's labels (only the labelled frames count)."""
    by_frame: dict[str, list[Mapping[str, Any]]] = {}
    for r in records:
        by_frame.setdefault(r["frame"], []).append(r)
    people = found = dup = false = ignored = 0
    tracks: dict[str, list[int | None]] = {}
    phone, eye, misses, false_boxes = [], [], [], []
    heights: list[float] = []
    for name, frame in labels["frames"].items():
        recs = by_frame.get(name, [])
        labelled = frame["people"]
        res = classify_frame([r["bbox"] for r in recs], labelled, frame.get("ignore", []))
        people += len(labelled)
        found += len(res["matched"])
        dup += len(res["duplicate"])
        false += len(res["false"])
        ignored += len(res["ignored"])
        false_boxes += [(name, [round(v) for v in recs[d]["bbox"]]) for d in res["false"]]
        for g, p in enumerate(labelled):
            d = res["matched"].get(g)
            key = f"{name}/{p['id']}" if labels.get("independent_frames") else str(p["id"])
            tracks.setdefault(key, []).append(None if d is None else recs[d]["track_id"])
            if d is None:
                misses.append((name, str(p["id"])))
                continue
            phone.append((p.get("phone"), recs[d].get("phone")))
            eye.append((p.get("eye_contact"), recs[d].get("eye_contact")))
            heights.append(p["bbox"][3] - p["bbox"][1])
    return {
        "frames": len(labels["frames"]),
        "people": people,
        "found": found,
        "recall": found / people if people else None,
        "detections": sum(len(by_frame.get(name, [])) for name in labels["frames"]),  # on labelled frames
        "duplicates": dup,
        "false_boxes": false,
        "ignored_boxes": ignored,
        "id_switches": sum(id_switches(t) for t in tracks.values()),
        "persons": len(tracks),
        "phone": binary_scores(phone),
        "eye_contact": binary_scores(eye),
        "by_height": {
            band_name(lo, hi): {
                "phone": binary_scores(pair for pair, h in zip(phone, heights, strict=True) if lo <= h < hi),
                "eye_contact": binary_scores(pair for pair, h in zip(eye, heights, strict=True) if lo <= h < hi),
            }
            for lo, hi in HEIGHT_BANDS
        },
        "missed": misses,
        "false_list": false_boxes,
    }


# ---------------------------------------------------------------- labels and inputs


def load_labels(name: str) -> dict[str, Any]:
    return json.loads((LABELS / f"{name}.json").read_text())


def evidence_sets(rendered: Path | None, names: Sequence[str] = ("rendered", "rendered_heldout")) -> dict[str, Path]:
    """The labelled sets the cue-evidence scripts read (``gaze_evidence.py``, ``phone_*_evidence.py``):
    the real ones in ../shared, and the rendered ``names`` under ``rendered`` (``--keep DIR``)."""
    seq = SHARED / "data" / "sequences"
    sets = {"walk_a": seq / "walk_a", "phone_a": seq / "phone_a", "street": SHARED / "data" / "street_images"}
    if rendered is not None:
        sets |= {name: rendered / name for name in names}
    return sets


def labelled_people(sets: Mapping[str, Path], backend: Any, cue: str) -> Iterator[tuple[str, str, Any, Any, Any]]:
    """(set, frame name, RGB frame, label, person) for every person labelled for ``cue``
    ("phone" or "eye_contact") whom ``backend`` (a still-image pose backend) boxes at IoU >= 0.5."""
    import cv2

    from trustnav.perception.types import box_iou

    for name, folder in sets.items():
        for frame_name, labelled in load_labels(name)["frames"].items():
            wanted = [lab for lab in labelled["people"] if lab.get(cue) is not None]
            if not wanted:
                continue
            image = cv2.imread(str(folder / frame_name))
            if image is None:
                raise SystemExit(f"cannot read {folder / frame_name}")
            frame = np.ascontiguousarray(image[:, :, ::-1])
            people = backend(frame)
            for lab in wanted:
                if not people:
                    continue
                person = max(people, key=lambda q: box_iou(q.bbox, lab["bbox"]))
                if box_iou(person.bbox, lab["bbox"]) >= 0.5:
                    yield name, frame_name, frame, lab, person


def auc(pairs: Iterable[tuple[bool, float]]) -> str:
    """Mann-Whitney AUC of the positives' scores above the negatives' (ties a half), with the counts
    (non-finite scores left out)."""
    pairs = list(pairs)
    pos = [v for y, v in pairs if y and np.isfinite(v)]
    neg = [v for y, v in pairs if not y and np.isfinite(v)]
    if not pos or not neg:
        return f"- ({len(pos)}+{len(neg)})"
    a, b = np.array(pos)[:, None], np.array(neg)[None, :]
    return f"{float(np.mean((a > b) + 0.5 * (a == b))):.2f} ({len(pos)}+{len(neg)})"


def inputs_of(name: str, labels: Mapping[str, Any], cache: Path) -> list[Path]:
    """The files or folder ``trustnav estimate`` is given for a set (rendered sets, those with a
    ``recipe``, are regenerated)."""
    if labels.get("recipe"):
        folder = render_frames(labels, cache / name)
        if labels.get("input") == "folder":
            return [folder]  # one scene over time: one sequence
        return [folder / f for f in labels["frames"]]  # unrelated scenes: one sequence each
    base = (ROOT / labels["source"]).resolve()
    if base.is_dir() and labels.get("input") == "folder":
        return [base]
    return [base / f for f in labels["frames"]]


def _frame_files(folder: Path) -> list[Path]:
    """The image files of a frame folder, in name order."""
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg"))


def mp4_of(folder: Path, out: Path, fps: float = 10.0) -> tuple[Path, float]:
    """The frames of ``folder`` written as an MP4 (OpenCV's mp4v, its default quality) and the mean
    PSNR (dB) of the decoded frames against the originals."""
    import cv2

    files = _frame_files(folder)
    frames = [cv2.imread(str(f)) for f in files]
    h, w = frames[0].shape[:2]
    out.parent.mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(out), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    if not writer.isOpened():
        raise SystemExit("OpenCV cannot write mp4v video here: --mp4 needs an OpenCV with FFmpeg")
    for f in frames:
        writer.write(f)
    writer.release()
    cap = cv2.VideoCapture(str(out))
    psnr = []
    for f in frames:
        ok, g = cap.read()
        if not ok:
            break
        psnr.append(cv2.PSNR(f, g))
    cap.release()
    return out, float(np.mean(psnr))


def video_records(records: Sequence[Mapping[str, Any]], folder: Path) -> list[dict[str, Any]]:
    """``tracks.json`` records of a video made by :func:`mp4_of`, their frames ("NAME#i") renamed to
    the source folder's i-th file, so that the folder's labels apply."""
    files = [p.name for p in _frame_files(folder)]
    return [{**r, "frame": files[int(str(r["frame"]).rsplit("#", 1)[1])]} for r in records]


#: People at least this tall (pixels) are reported apart in the MP4 comparison: the size from which
#: the segmentation search proposes people, and below which one frame's pose models find a person
#: or not by chance (walk_a's far crowd, 60-75 px, found in scattered frames either way).
TALL_PX = 80


def records_matched(
    uncompressed: Sequence[Mapping[str, Any]], coded: Sequence[Mapping[str, Any]], thr: float = MATCH_IOU
) -> int:
    """How many records of the uncompressed frames have a record of the coded video on the same
    frame with IoU >= ``thr`` (Hungarian assignment per frame): the same person kept, where the
    plain record count would also count different people found instead."""
    coded_by: dict[str, list[Sequence[float]]] = {}
    for r in coded:
        coded_by.setdefault(r["frame"], []).append(r["bbox"])
    base_by: dict[str, list[Sequence[float]]] = {}
    for r in uncompressed:
        base_by.setdefault(r["frame"], []).append(r["bbox"])
    return sum(len(match(coded_by.get(f, []), boxes, thr)) for f, boxes in base_by.items())


def render_frames(labels: Mapping[str, Any], out: Path) -> Path:
    """Regenerates the rendered frames (recipe and seed in labels['recipe']) and checks their boxes."""
    import importlib.util

    path = LABELS / "rendered" / "make_rendered.py"
    spec = importlib.util.spec_from_file_location("make_rendered", path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    with contextlib.redirect_stdout(io.StringIO()):
        recipe = labels["recipe"]
        made = mod.generate(out, n=recipe["frames"], seed=recipe["seed"], variant=recipe.get("variant", "default"))
    for name, frame in labels["frames"].items():
        for a, b in zip(frame["people"], made[name]["people"], strict=True):
            if a["id"] != b["id"] or max(abs(u - v) for u, v in zip(a["bbox"], b["bbox"], strict=True)) > 1.0:
                raise SystemExit(f"regenerated {name} differs from the labels ({a['id']}): renderer changed?")
    return out


def shift_image(src: Path, dst: Path, dx: int, dy: int) -> None:
    """``src`` translated by (dx, dy) whole pixels (edges repeated) and written to ``dst`` (PNG
    lossless; JPEG at quality 100)."""
    import cv2

    img = cv2.imread(str(src), cv2.IMREAD_COLOR)
    if img is None:
        raise SystemExit(f"cannot read {src}")
    h, w = img.shape[:2]
    moved = cv2.warpAffine(img, np.float32([[1, 0, dx], [0, 1, dy]]), (w, h), borderMode=cv2.BORDER_REPLICATE)
    dst.parent.mkdir(parents=True, exist_ok=True)
    jpeg = dst.suffix.lower() in (".jpg", ".jpeg")
    cv2.imwrite(str(dst), moved, [cv2.IMWRITE_JPEG_QUALITY, 100] if jpeg else [])


def shifted_inputs(inputs: Sequence[Path], out: Path, dx: int, dy: int) -> list[Path]:
    """The inputs of a set (files, or a folder of frames) translated by (dx, dy) into ``out``,
    with their names kept (so that the labels, shifted by :func:`shifted_labels`, apply)."""
    moved = []
    for path in inputs:
        if path.is_dir():
            for f in _frame_files(path):
                shift_image(f, out / path.name / f.name, dx, dy)
            moved.append(out / path.name)
        else:
            shift_image(path, out / path.name, dx, dy)
            moved.append(out / path.name)
    return moved


def shifted_labels(labels: Mapping[str, Any], dx: int, dy: int) -> dict[str, Any]:
    """A set's labels with every box and ignore region translated by (dx, dy) pixels."""

    def move(box: Sequence[float]) -> list[float]:
        return [max(0.0, box[0] + dx), max(0.0, box[1] + dy), box[2] + dx, box[3] + dy]

    frames = {
        name: {**frame, "people": [{**p, "bbox": move(p["bbox"])} for p in frame["people"]],
               "ignore": [move(r) for r in frame.get("ignore", [])]}
        for name, frame in labels["frames"].items()
    }  # fmt: skip
    return {**labels, "frames": frames}


def run_estimate(inputs: Sequence[Path], out: Path, extra: Sequence[str] = ()) -> list[dict[str, Any]]:
    """``trustnav estimate INPUTS --out OUT --no-images [EXTRA]`` through the CLI; its tracks.json records."""
    from trustnav.cli import main as cli

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        cli(["estimate", *map(str, inputs), "--out", str(out), "--no-images", *extra])
    return json.loads((out / "tracks.json").read_text())


# ---------------------------------------------------------------- printing


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{x:.2f}"


def _trait(s: Mapping[str, Any]) -> str:
    return (f"P {_pct(s['precision'])} R {_pct(s['recall'])} F1 {_pct(s['f1'])} "
            f"(TP {s['tp']} FP {s['fp']} FN {s['fn']} TN {s['tn']})")  # fmt: skip


def total(results: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    """The sets summed (MP4 round trips left out: they are the same people again; held-out sets left
    out: they are reported on their own)."""
    results = {k: v for k, v in results.items() if "psnr_db" not in v and not v.get("held_out")}
    keys = ("frames", "people", "found", "detections", "duplicates", "false_boxes", "ignored_boxes", "id_switches",
            "persons")  # fmt: skip
    out: dict[str, Any] = {k: sum(r[k] for r in results.values()) for k in keys}
    out["recall"] = out["found"] / out["people"] if out["people"] else None
    for trait in ("phone", "eye_contact"):
        c = {k: sum(r[trait][k] for r in results.values()) for k in ("tp", "fp", "fn", "tn")}
        out[trait] = _from_counts(c)
    out["by_height"] = {}
    for band in next(iter(results.values()), {}).get("by_height", {}):
        out["by_height"][band] = {}
        for trait in ("phone", "eye_contact"):
            c = {k: sum(r["by_height"][band][trait][k] for r in results.values()) for k in ("tp", "fp", "fn", "tn")}
            out["by_height"][band][trait] = _from_counts(c)
    return out


def _from_counts(c: Mapping[str, int]) -> dict[str, Any]:
    """:func:`binary_scores` of TP/FP/FN/TN counts."""
    return binary_scores([(True, 1.0)] * c["tp"] + [(False, 1.0)] * c["fp"] + [(True, 0.0)] * c["fn"]
                         + [(False, 0.0)] * c["tn"])  # fmt: skip


def print_table(results: Mapping[str, Mapping[str, Any]], tuned: Mapping[str, str]) -> None:
    head = ("set", "frames", "people", "recall", "false", "dup", "IDsw", "phone P/R/F1", "eye P/R/F1")
    rows = []
    counted = [k for k, v in results.items() if "psnr_db" not in v and not v.get("held_out")]
    for name, r in [*results.items(), *([("all", total(results))] if len(counted) > 1 else [])]:
        p, e = r["phone"], r["eye_contact"]
        rows.append((name, str(r["frames"]), str(r["people"]), f"{r['found']}/{r['people']} {_pct(r['recall'])}",
                     str(r["false_boxes"]), str(r["duplicates"]), str(r["id_switches"]),
                     f"{_pct(p['precision'])}/{_pct(p['recall'])}/{_pct(p['f1'])}",
                     f"{_pct(e['precision'])}/{_pct(e['recall'])}/{_pct(e['f1'])}"))  # fmt: skip
    print("| " + " | ".join(head) + " |")
    print("|" + "|".join("---" for _ in head) + "|")
    for row in rows:
        print("| " + " | ".join(row) + " |")
    print()
    for name, r in results.items():
        print(f"- {name}: phone {_trait(r['phone'])}; eye contact {_trait(r['eye_contact'])}")
        missed = ", ".join(f"{who} ({frame})" for frame, who in r["missed"][:8]) or "none"
        print(f"  {r['detections']} detections on the labelled frames, {r['ignored_boxes']} in ignore regions; "
              f"false boxes at: {r['false_list'][:6] or 'none'}; missed {len(r['missed'])}: {missed}")  # fmt: skip
    print()
    for name in results:
        print(f"- {name}: {tuned[name]}")
    if any(r.get("held_out") for r in results.values()):
        print("(held-out sets are not in 'all': nothing was tuned on them; they are reported on their own)")


def _figures(r: Mapping[str, Any]) -> dict[str, float | None]:
    return {"recall": r["recall"], "false": r["false_boxes"], "dup": r["duplicates"],
            "phone P": r["phone"]["precision"], "phone R": r["phone"]["recall"],
            "eye P": r["eye_contact"]["precision"], "eye R": r["eye_contact"]["recall"]}  # fmt: skip


def print_by_height(results: Mapping[str, Mapping[str, Any]]) -> None:
    """Phone use and eye contact per labelled person height (``--by-height``): the sets in "all"
    together, then each held-out set."""
    plain = {k: v for k, v in results.items() if "psnr_db" not in v}
    groups = [("all", total(plain))] if any(not v.get("held_out") for v in plain.values()) else []
    groups += [(k, v) for k, v in plain.items() if v.get("held_out")]
    print()
    print("Cues per labelled person height (TP/FP/FN/TN; P/R/F1):")
    print("| set | height | phone TP/FP/FN/TN | phone P/R/F1 | eye TP/FP/FN/TN | eye P/R/F1 |")
    print("|---|---|---|---|---|---|")
    for name, r in groups:
        for band, b in r["by_height"].items():
            cells = []
            for trait in ("phone", "eye_contact"):
                t = b[trait]
                cells += [f"{t['tp']}/{t['fp']}/{t['fn']}/{t['tn']}",
                          f"{_pct(t['precision'])}/{_pct(t['recall'])}/{_pct(t['f1'])}"]  # fmt: skip
            print(f"| {name} | {band} | " + " | ".join(cells) + " |")


def print_spread(results: Mapping[str, Mapping[str, Any]], spread: Sequence[Mapping[str, Any]]) -> None:
    """The figures of the unshifted run and of each shifted run, and their range (``--jitter``):
    for the sets in "all" together, and for each held-out set on its own."""
    plain = {k: v for k, v in results.items() if "psnr_db" not in v}
    groups: list[tuple[str, Any]] = []
    if any(not v.get("held_out") for v in plain.values()):
        groups.append(("all", total))
    groups += [(name, lambda sets, n=name: sets[n]) for name, v in plain.items() if v.get("held_out")]
    runs = [("none", plain)] + [(f"({s['shift_px'][0]}, {s['shift_px'][1]}) px", s["sets"]) for s in spread]
    keys = list(_figures(next(iter(plain.values()))))
    print()
    print("Sensitivity to whole-pixel shifts of the frames (MP4 rows not included):")
    print("| set | shift | " + " | ".join(keys) + " |")
    print("|" + "|".join("---" for _ in range(len(keys) + 2)) + "|")
    for group, pick in groups:
        values: dict[str, list[float]] = {k: [] for k in keys}
        for label, sets in runs:
            fig = _figures(pick(sets))
            for k, v in fig.items():
                if v is not None:
                    values[k].append(float(v))
            cells = " | ".join("-" if fig[k] is None else f"{fig[k]:.2f}" for k in keys)
            print(f"| {group} | {label} | {cells} |")
        ranges = " | ".join(f"{min(v):.2f}-{max(v):.2f}" if v else "-" for v in values.values())
        print(f"| {group} | range | {ranges} |")


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="trust_eval.py",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=f"Labels in {LABELS}; real frames read from {SHARED}.",
    )
    parser.add_argument(
        "--set", action="append", choices=SETS, dest="sets", help="a set to run (repeatable; default all)"
    )
    parser.add_argument("--json", type=Path, help="write the results to this file")
    parser.add_argument(
        "--estimate-arg",
        action="append",
        default=[],
        dest="extra",
        metavar="ARG",
        help="extra argument for trustnav estimate, e.g. --estimate-arg=--face (repeatable; default none)",
    )
    parser.add_argument(
        "--mp4",
        action="store_true",
        help="also run each frame-sequence set as an MP4 (OpenCV mp4v, ~36 dB PSNR): the records and labelled "
        "people kept under mild video compression",
    )
    parser.add_argument(
        "--by-height",
        action="store_true",
        help="also print phone use and eye contact per labelled person height (<100, 100-150, 150-250, >=250 px)",
    )
    parser.add_argument("--keep", type=Path, help="keep the estimate outputs (and rendered frames) in this folder")
    parser.add_argument(
        "--jitter",
        type=int,
        default=0,
        metavar="K",
        help="also run every set on its frames translated by K small whole-pixel shifts (1-2 px; labels shifted "
        "alike) and print the spread of the figures: how much of a difference between two settings is the "
        "pipeline's own sensitivity to where a person falls on the pixel grid (default 0: off)",
    )
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> None:
    args = parse_args(argv)
    if not 0 <= args.jitter <= len(JITTER_SHIFTS):
        raise SystemExit(f"--jitter must be 0-{len(JITTER_SHIFTS)} shifts, got {args.jitter}")
    sets = args.sets or list(SETS)
    results, tuned = {}, {}
    spread: list[dict[str, Any]] = []
    inputs: dict[str, list[Path]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        work = args.keep or Path(tmp)
        for name in sets:
            labels = load_labels(name)
            if labels.get("needs_shared", True) and not SHARED.is_dir():
                raise SystemExit(f"set {name} needs the shared data at {SHARED}")
            print(f"{name}: running trustnav estimate ...", file=sys.stderr)
            inputs[name] = inputs_of(name, labels, work)
            records = run_estimate(inputs[name], work / f"estimate_{name}", args.extra)
            results[name] = {**evaluate(labels, records), "held_out": bool(labels.get("held_out"))}
            tuned[name] = labels["tuned_on"]
            if args.mp4 and labels.get("input") == "folder":
                folder = inputs_of(name, labels, work)[0]
                video, psnr = mp4_of(folder, work / f"{name}.mp4")
                print(f"{name} as MP4 (PSNR {psnr:.1f} dB): running trustnav estimate ...", file=sys.stderr)
                coded = video_records(run_estimate([video], work / f"estimate_{name}_mp4", args.extra), folder)
                key = f"{name} mp4"
                results[key] = {**evaluate(labels, coded), "psnr_db": round(psnr, 2),
                                "records": len(coded), "records_uncompressed": len(records)}  # fmt: skip
                same = records_matched(records, coded)
                results[key]["records_kept"] = round(len(coded) / max(1, len(records)), 3)
                results[key]["records_matched"] = same
                results[key]["records_matched_share"] = round(same / max(1, len(records)), 3)
                tall = [r for r in records if r["bbox"][3] - r["bbox"][1] >= TALL_PX]
                same_tall = records_matched(tall, coded)
                results[key]["records_matched_tall"] = [same_tall, len(tall)]
                tuned[key] = (f"{labels['tuned_on']}; MP4 round trip, {len(coded)} of {len(records)} records kept, "
                              f"{same} of them the same person (IoU >= {MATCH_IOU}); of the records of people "
                              f">= {TALL_PX} px tall, {same_tall} of {len(tall)} the same person")  # fmt: skip
        for dx, dy in JITTER_SHIFTS[: args.jitter]:
            shifted = {}
            for name in sets:
                labels = shifted_labels(load_labels(name), dx, dy)
                print(f"{name} shifted by ({dx}, {dy}) px: running trustnav estimate ...", file=sys.stderr)
                moved = shifted_inputs(inputs[name], work / f"shift_{dx}_{dy}", dx, dy)
                records = run_estimate(moved, work / f"estimate_{name}_shift_{dx}_{dy}", args.extra)
                shifted[name] = {**evaluate(labels, records), "held_out": bool(labels.get("held_out"))}
            spread.append({"shift_px": [dx, dy], "sets": shifted, "all": total(shifted)})
    print_table(results, tuned)
    if args.by_height:
        print_by_height(results)
    if spread:
        print_spread(results, spread)
    if args.json:
        out = {"sets": results, "all": total(results), "tuned_on": tuned,
               "settings": {"match_iou": MATCH_IOU, "threshold": THRESHOLD, "estimate_args": args.extra}}  # fmt: skip
        if spread:
            out["jitter"] = spread
        args.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
