"""Phone use over a track's whole life: per frame and per track, replayed on the recorded poses (issue 35, item 5).

``trustnav estimate`` runs each labelled set once (default settings, as ``trust_eval.py``), and every
call of the phone cue is recorded: the frame time, each person's track ID, keypoints, confidences and
box, and the value the default cue gave. The labels are joined on (track ID, box). Phone models are
then replayed on those poses, in the same order, so a variant costs milliseconds, not a pipeline
run; the default model replayed gives the recorded values to the bit (checked).

Figures per variant: phone P/R/F1 on the labelled person-frames (``trust_eval.py``'s "all" row: walk_a,
phone_a, street, rendered; held-out sets on their own), and *per track*: each labelled person's
label carried to the frames of its track between its first and last labelled frame where its
labels agree (the person-frames of the videos no one labelled by hand; see docs/perception.md).

    python benchmarks/phone_track_evidence.py --record /tmp/poses.pkl [--keep DIR]   # ~2 min on 2 cores
    python benchmarks/phone_track_evidence.py --poses /tmp/poses.pkl                  # the variants, ~seconds
    python benchmarks/phone_track_evidence.py --poses /tmp/poses.pkl --calibrate      # + the Platt map, LOSO
    python benchmarks/phone_track_evidence.py --poses /tmp/poses.pkl --forward        # + the forward filter
"""

from __future__ import annotations

import argparse
import itertools
import pickle
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # trust_eval, beside this file

import trust_eval as te

REAL = ("walk_a", "phone_a", "street")


def record(sets: Sequence[str], work: Path) -> dict[str, Any]:
    """Run every set through the CLI with the phone cue's calls recorded: {set: {"calls": [...],
    "records": tracks.json, "labels": labels}}; a call is (model key, time, [(track ID, keypoints,
    confidences, box, value)])."""
    from trustnav.perception import cues as cues_mod

    calls: list[tuple[int, float | None, list[tuple[int, Any, Any, tuple[float, ...], float]]]] = []
    original = cues_mod.PhoneUseCue.__call__
    models: list[Any] = []  # held, so that no two sequences' models share an id()

    def recording(self, frame, people, track_ids=None, time=None):  # type: ignore[no-untyped-def]
        values = original(self, frame, people, track_ids=track_ids, time=time)
        ids = list(track_ids) if track_ids is not None else [-1] * len(people)
        if not any(m is self.temporal for m in models):
            models.append(self.temporal)
        calls.append((id(self.temporal), time, [(int(t), np.array(p.keypoints), np.array(p.confidences),
                                                 tuple(float(v) for v in p.bbox), float(v))
                                                for t, p, v in zip(ids, people, values, strict=True)]))  # fmt: skip
        return values

    out: dict[str, Any] = {}
    cues_mod.PhoneUseCue.__call__ = recording  # type: ignore[method-assign]
    try:
        for name in sets:
            labels = te.load_labels(name)
            print(f"{name}: running trustnav estimate ...", file=sys.stderr)
            calls.clear()
            records = te.run_estimate(te.inputs_of(name, labels, work), work / f"estimate_{name}", ["--overwrite"])
            out[name] = {"calls": list(calls), "records": records, "labels": labels}
    finally:
        cues_mod.PhoneUseCue.__call__ = original  # type: ignore[method-assign]
    return out


def person_frames(data: Mapping[str, Any]) -> list[dict[str, Any]]:
    """One row per recorded person of a set: sequence key, call index, track ID, time, keypoints,
    confidences, box, recorded value, frame name (None if not in tracks.json), the label (True,
    False, None: not labelled or undecidable) and the carried label (per track)."""
    rows: list[dict[str, Any]] = []
    for k, (model, time, people) in enumerate(data["calls"]):
        for tid, kp, conf, box, value in people:
            rows.append({"model": model, "call": k, "track": tid, "time": time, "kp": kp, "conf": conf,
                         "box": box, "value": value, "frame": None, "label": None, "carried": None})  # fmt: skip
    index = {(r["track"], tuple(round(v, 1) for v in r["box"])): r for r in rows if r["track"] >= 0}
    by_frame: dict[str, list[Mapping[str, Any]]] = {}
    for rec in data["records"]:
        row = index.get((rec["track_id"], tuple(rec["bbox"])))
        if row is not None:
            row["frame"] = rec["frame"]
            row["seq"] = rec.get("sequence")
        by_frame.setdefault(rec["frame"], []).append(rec)
    labels = data["labels"]
    person_tracks: dict[str, list[tuple[float, int, bool | None]]] = {}
    for name, frame in labels["frames"].items():
        recs = by_frame.get(name, [])
        res = te.classify_frame([r["bbox"] for r in recs], frame["people"], frame.get("ignore", []))
        for g, d in res["matched"].items():
            rec = recs[d]
            row = index.get((rec["track_id"], tuple(rec["bbox"])))
            if row is None:
                raise SystemExit(f"{name}: record of track {rec['track_id']} not among the recorded calls")
            lab = frame["people"][g]
            row["label"] = lab.get("phone")
            row["person"] = str(lab["id"])
            person_tracks.setdefault(str(lab["id"]), []).append((row["time"], row["track"], row["label"]))
    if not labels.get("independent_frames"):
        # a labelled person's label carried along its track between labelled frames that agree
        for rows_of in person_tracks.values():
            rows_of.sort(key=lambda t: t[0])
            for (t0, k0, l0), (t1, k1, l1) in itertools.pairwise(rows_of):
                if k0 == k1 and l0 is not None and l0 == l1:
                    for r in rows:
                        if r["track"] == k0 and t0 <= r["time"] <= t1:
                            r["carried"] = l0
    for r in rows:
        if r["label"] is not None:
            r["carried"] = r["label"]
    return rows


def replay(rows: Sequence[dict[str, Any]], make: Callable[[], Any]) -> list[float]:
    """Each row's phone value from a fresh model per sequence (``make()``, a ``TemporalPhoneModel``
    or anything with ``add_pose``), fed in the recorded order."""
    return [float(res.phone) for res in _replay_results(rows, make)]


def scores(rows: Sequence[Mapping[str, Any]], values: Sequence[float], key: str = "label") -> dict[str, Any]:
    """trust_eval's binary scores of ``values`` against the rows' ``key`` labels."""
    return te.binary_scores((r[key], v) for r, v in zip(rows, values, strict=True) if r[key] is not None)


def _f(s: Mapping[str, Any]) -> str:
    f1 = s["f1"]
    return f"{s['tp']}/{s['fp']}/{s['fn']}/{s['tn']} F1 {'-' if f1 is None else f'{f1:.3f}'}"


def variants() -> dict[str, Callable[[], Any]]:
    """The phone models compared: name -> factory (the first is the default cues' model)."""
    from trustnav.perception.phone import LABELLED_PHONE_CALIBRATION, TemporalPhoneModel

    return {
        "default: temporal model, calibrated": lambda: TemporalPhoneModel(calibration=LABELLED_PHONE_CALIBRATION),
        "temporal model, raw (before)": TemporalPhoneModel,
    }


class ForwardFilter:
    """The lead "evidence over a track's whole life" as a two-state HMM forward filter (not kept; measured
    by ``--forward``): phone use u in {0, 1} per track, sticky (it relaxes to ``prior`` with time
    constant ``persist_s``); each frame's single-frame geometry g (``TemporalPhoneModel``'s) is
    evidence through a Platt map ``frame_map`` (P(u | g) on person-frames), its log-likelihood ratio
    tempered by min(1, dt / ``corr_s``) (frames closer than the evidence's correlation time are not
    independent looks). Output: P(u = 1 | the track's frames so far)."""

    def __init__(self, frame_map: Any, prior: float = 0.5, persist_s: float = 10.0, corr_s: float = 0.1) -> None:
        from trustnav.perception.phone import TemporalPhoneModel

        self.frame_map, self.prior, self.persist_s, self.corr_s = frame_map, prior, persist_s, corr_s
        self.geometry = TemporalPhoneModel()
        self.state: dict[int, tuple[float, float]] = {}

    def add_pose(self, track_id: int, time: float | None, kp: Any, conf: Any) -> Any:
        from trustnav.perception.phone import TemporalPhoneResult

        g = self.geometry.add_pose(track_id, time, kp, conf).geometry
        p = min(max(self.frame_map(g), 1e-6), 1 - 1e-6)
        prior_lo = np.log(self.prior / (1 - self.prior))
        llr = float(np.log(p / (1 - p))) - prior_lo
        last = self.state.get(track_id)
        if track_id < 0 or time is None or last is None or time - last[0] > 3.0 or time < last[0]:
            lo = prior_lo + llr
        else:
            dt = time - last[0]
            q = self.prior + (1 / (1 + np.exp(-last[1])) - self.prior) * np.exp(-dt / self.persist_s)
            lo = float(np.log(q / (1 - q))) + min(1.0, dt / self.corr_s) * llr
        if track_id >= 0 and time is not None:
            self.state[track_id] = (time, lo)
        out = float(1 / (1 + np.exp(-lo)))
        return TemporalPhoneResult(out, g, out, 0.0, 0.0)


def forward(rows: Mapping[str, Sequence[dict[str, Any]]], tuned: Sequence[str], held: Sequence[str]) -> None:
    """The forward filter: the per-frame geometry's autocorrelation along tracks (its correlation
    time), then the filter leave-one-set-out (per-frame map fitted on the other tuned sets' carried
    labels) and, fitted on all tuned sets, on the held-out sets, for a few persistence times."""
    from trustnav.perception.phone import PhoneCalibration, TemporalPhoneModel

    geo = {n: [m.geometry for m in _replay_results(r, TemporalPhoneModel)] for n, r in rows.items()}
    print("\nAutocorrelation of the per-frame geometry along tracks (each track's mean removed; 10 frames/s):")
    for n in ("walk_a", "rendered_sequence"):
        if n not in rows:
            continue
        tracks: dict[int, dict[int, float]] = {}
        for r, g in zip(rows[n], geo[n], strict=True):
            if r["track"] >= 0:
                tracks.setdefault(r["track"], {})[round(r["time"] * 10)] = g
        acf = []
        for lag in range(6):
            num = cnt = 0.0
            for frames in tracks.values():
                if len(frames) < 10:
                    continue
                x = np.array(list(frames.values()))
                mean, var = x.mean(), x.var()
                if var < 1e-6:
                    continue
                pairs = [(frames[i] - mean) * (frames[i + lag] - mean) / var for i in frames if i + lag in frames]
                num, cnt = num + sum(pairs), cnt + len(pairs)
            acf.append(f"{lag / 10:.1f} s: {num / max(cnt, 1):.2f}")
        print(f"- {n}: " + ", ".join(acf))

    def xy(names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
        pairs = [
            (g, r["carried"]) for n in names for r, g in zip(rows[n], geo[n], strict=True) if r["carried"] is not None
        ]
        return np.array([p[0] for p in pairs], dtype=float), np.array([bool(p[1]) for p in pairs])

    full = PhoneCalibration.fit(*xy(tuned))
    print(
        f"\nForward filter (per-frame map on all tuned sets: PhoneCalibration({full.intercept:.3f}, {full.slope:.3f})):"
    )
    print("| persistence, correlation time | LOSO labelled frames | LOSO carried | held out (map on all tuned) |")
    print("|---|---|---|---|")
    for persist, corr in ((5.0, 0.1), (10.0, 0.1), (20.0, 0.1), (10.0, 0.2), (10.0, 0.3)):
        pooled: dict[str, list[tuple[bool, float]]] = {"label": [], "carried": []}
        for s in tuned:
            fmap = PhoneCalibration.fit(*xy([n for n in tuned if n != s]))
            vals = replay(rows[s], lambda f=fmap, a=persist, b=corr: ForwardFilter(f, persist_s=a, corr_s=b))
            for key in pooled:
                pooled[key] += [(r[key], v) for r, v in zip(rows[s], vals, strict=True) if r[key] is not None]
        ho = []
        for n in held:
            vals = replay(rows[n], lambda a=persist, b=corr: ForwardFilter(full, persist_s=a, corr_s=b))
            ho += [(r["label"], v) for r, v in zip(rows[n], vals, strict=True) if r["label"] is not None]
        print(f"| {persist:.0f} s, {corr:.1f} s | {_f(_counts(pooled['label']))} | {_f(_counts(pooled['carried']))} | "
              f"{_f(_counts(ho))} |")  # fmt: skip


def _replay_results(rows: Sequence[dict[str, Any]], make: Callable[[], Any]) -> list[Any]:
    """As :func:`replay`, the models' whole results."""
    models: dict[int, Any] = {}
    out = []
    for r in rows:
        if r["model"] not in models:
            models[r["model"]] = make()
        out.append(models[r["model"]].add_pose(r["track"], r["time"], r["kp"], r["conf"]))
    return out


def _counts(pairs: Sequence[tuple[bool, float]]) -> dict[str, Any]:
    return te.binary_scores(pairs)


def calibrate(rows: Mapping[str, Sequence[dict[str, Any]]], tuned: Sequence[str], held: Sequence[str]) -> None:
    """Reliability of the raw cue, the Platt map leave-one-set-out (fitted on the carried labels of
    the other tuned sets, scored on the left-out set) and fitted on all tuned sets."""
    from trustnav.perception.phone import PhoneCalibration, TemporalPhoneModel

    raw = {n: replay(r, TemporalPhoneModel) for n, r in rows.items()}

    def xy(names: Sequence[str], key: str) -> tuple[np.ndarray, np.ndarray]:
        pairs = [(v, r[key]) for n in names for r, v in zip(rows[n], raw[n], strict=True) if r[key] is not None]
        return np.array([p[0] for p in pairs], dtype=float), np.array([bool(p[1]) for p in pairs])

    print("\nReliability of the raw cue (share of phone users per value bin; labelled frames | labels carried):")
    print("| sets | C | labelled frames: n, users | carried: n, users |")
    print("|---|---|---|---|")
    for group, names in (("tuned", tuned), ("held out", held)):
        (xl, yl), (xc, yc) = xy(names, "label"), xy(names, "carried")
        for lo in np.arange(0.0, 1.0, 0.1):
            hi = lo + 0.1 + (1e-9 if lo > 0.85 else 0.0)
            ml, mc = (xl >= lo) & (xl < hi), (xc >= lo) & (xc < hi)
            if ml.any() or mc.any():
                cl = f"{ml.sum()}, {yl[ml].mean():.2f}" if ml.any() else "0"
                cc = f"{mc.sum()}, {yc[mc].mean():.2f}" if mc.any() else "0"
                print(f"| {group} | {lo:.1f}-{lo + 0.1:.1f} | {cl} | {cc} |")
    print("\nPlatt map leave-one-set-out (fitted on the carried labels of the other tuned sets):")
    print("| left out | map (intercept, slope; 0.5 at C) | labelled frames TP/FP/FN/TN F1 | carried |")
    print("|---|---|---|---|")
    pooled: dict[str, list[tuple[bool, float]]] = {"label": [], "carried": []}
    for s in tuned:
        cal = PhoneCalibration.fit(*xy([n for n in tuned if n != s], "carried"))
        cells = []
        for key in ("label", "carried"):
            x, y = xy([s], key)
            pairs = [(bool(t), cal(v)) for v, t in zip(x, y, strict=True)]
            pooled[key] += pairs
            cells.append(_f(_counts(pairs)))
        print(f"| {s} | {cal.intercept:.3f}, {cal.slope:.3f}; {cal.threshold:.3f} | {cells[0]} | {cells[1]} |")
    print(f"| **pooled (cross-validated)** | | {_f(_counts(pooled['label']))} | {_f(_counts(pooled['carried']))} |")
    cal = PhoneCalibration.fit(*xy(tuned, "carried"))
    n = len(xy(tuned, "carried")[0])
    print(f"\nFitted on all tuned sets ({n} person-frames, labels carried): PhoneCalibration({cal.intercept:.3f}, "
          f"{cal.slope:.3f}), 0.5 at C = {cal.threshold:.3f}")  # fmt: skip


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="phone_track_evidence.py", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("--record", type=Path, help="run the sets and write the recorded poses here (pickle)")
    parser.add_argument("--poses", type=Path, help="replay the variants on poses recorded by --record")
    parser.add_argument("--keep", type=Path, help="keep the estimate outputs and rendered frames here")
    parser.add_argument("--set", action="append", choices=te.SETS, dest="sets", help="a set (default all)")
    parser.add_argument(
        "--calibrate",
        action="store_true",
        help="also the raw cue's reliability and its Platt map, leave-one-set-out and on all sets",
    )
    parser.add_argument("--forward", action="store_true",
                        help="also the lead not kept: a two-state forward filter over each track's life")  # fmt: skip
    parser.add_argument("--raw-recording", action="store_true",
                        help="the poses were recorded before the calibration (skip the replay check)")  # fmt: skip
    args = parser.parse_args(argv)
    if args.record:
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            data = record(args.sets or list(te.SETS), args.keep or Path(tmp))
        args.record.write_bytes(pickle.dumps(data))
        print(f"recorded {sum(len(d['calls']) for d in data.values())} cue calls to {args.record}")
        if not args.poses:
            args.poses = args.record
    if not args.poses:
        parser.error("give --record FILE or --poses FILE")
    try:
        data = pickle.loads(args.poses.read_bytes())
    except (OSError, pickle.UnpicklingError, EOFError) as exc:
        parser.error(f"--poses '{args.poses}': not a file of --record ({exc})")
    rows = {name: person_frames(d) for name, d in data.items() if not args.sets or name in args.sets}
    tuned = [n for n in rows if not data[n]["labels"].get("held_out")]
    held = [n for n in rows if data[n]["labels"].get("held_out")]
    print("| variant | group | labelled frames TP/FP/FN/TN F1 | per track (labels carried) TP/FP/FN/TN F1 |")
    print("|---|---|---|---|")
    for vname, make in variants().items():
        vals = {n: replay(r, make) for n, r in rows.items()}
        if vname.startswith("default") and not args.raw_recording:
            worst = max((abs(a - r["value"]) for n in rows for a, r in zip(vals[n], rows[n], strict=True)), default=0)
            print(f"(default replayed: largest difference from the recorded values {worst:.2e})", file=sys.stderr)
        groups = [("all", tuned), *[(n, [n]) for n in (*tuned, *held)]]
        for gname, names in groups:
            rr = [r for n in names for r in rows[n]]
            vv = [v for n in names for v in vals[n]]
            print(f"| {vname} | {gname} | {_f(scores(rr, vv))} | {_f(scores(rr, vv, 'carried'))} |")
    if args.calibrate:
        calibrate(rows, tuned, held)
    if args.forward:
        forward(rows, tuned, held)


if __name__ == "__main__":
    main()
