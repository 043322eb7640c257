"""The rendered sensor's placement errors, estimated from recorded drives (issue 34 item 4, seventh pass).

Reads drives recorded by ``region_breakdown.py --render --save`` (calibration worlds, disjoint from
the worlds the regions are judged on), places every recorded person with the render sensing's
localiser (``--set`` replaces its fields) and whitens each raw placement's error against the truth
by its own sigma along and across the line of sight. Per person class (standers in each pose;
Case II's slow walker in her walking pose and in her texting pose) it prints:

* the rms of the whitened errors along and across (1 for a calibrated single frame: the sigma
  scale the localiser's covariance would need);
* the errors' correlation per lag (the sample autocorrelation, not demeaned: a person's constant
  bias is part of what repeats), pooled over person-drives and over the recordings' frame rates;
* the least-squares fit of the world tracker's model of it, ``shared * max(0, 1 - t / tau)``
  (``WorldTrackerConfig.error_shared`` / ``error_correlation_s``) to the standers' along-track
  correlation at lags 0.1-4 s, weighted by the pairs behind each lag, the same fit across the line
  of sight (tau up to 60 s: a person's lateral placement repeats for the whole drive, whatever the
  pose, so the tracker inflates only the variance along it: docs/perceived.md, tenth and eleventh
  passes), and the ``error_shared`` that gives that correlation after the tracker's pose factor
  (``pose_change``; its mean over the standers' frame pairs one camera period apart, the lags the
  tracker folds in);
* the variance inflation factor the tracker then uses (``correlated_error_factor``) at 1 and 10
  frames/s beside the one measured directly: n var(mean of n frames) / var(frame) over spans of
  the drives (batch means);
* the batch-means fit: the linear fade ends at the first lag whose correlation is <= 0 (the
  initial positive sequence of the autocorrelation, Geyer 1992), and its share makes the tracker's
  factor at 10 frames/s the inflation measured over 2-4 s spans (its plateau; the drives hold
  about 5 s of each stander at 10 frames/s).
  Unlike the least-squares fit it counts the negative correlation of far lags (a stander's range
  error changes sign as the car approaches), which is what a track's average over seconds sees.

    python benchmarks/render_error_fit.py /tmp/rec/case-1_10_4*.pkl /tmp/rec/case-1_1_4*.pkl
    python benchmarks/render_error_fit.py --body /tmp/rec/case-[12]_*_4*.pkl

``--body`` fits the detector's body model instead (eighth pass): per body point, where the
detector reports it at the truth's distance, as a share of the person's true stature, regressed on
1 / (her image stature in pixels): reported height = share * H + offset pixels
(``localisation.DETECTOR_PIXEL_BIAS``), with the spread left about either model; and the
localiser's reduced chi^2 per pose (``LocaliserConfig.noise_prior_dof`` pools it).

No model is changed: the figures are the estimate; ``region_breakdown.py --load ... --set`` replays
a fitted candidate on evaluation worlds.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import pickle
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from region_breakdown import set_value
from trustnav.perception.localisation import BODY_POINTS, GroundLocaliser, LocaliserConfig, pose_change
from trustnav.perception.world_tracking import correlated_error_factor
from trustnav.sim.driving.episode import street_of
from trustnav.sim.driving.world import SensingSpec

BATCH_SPANS = (1.0, 2.0, 3.0, 4.0)
LAGS = (0.1, 0.2, 0.3, 0.5, 0.7, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0)


def labelled_people(rec: dict):
    """The recorded people a world pedestrian stands behind, frame by frame: (time, camera, person,
    pedestrian index, her true ground position (x, y), the frame's map to the world or None)."""
    for t, camera, people, index, to_world in rec["frames"]:
        truth = rec["truth"].get(round(t, 6))
        if truth is None:
            continue
        for p, j in zip(people, index, strict=True):
            if j is not None and truth[j] is not None:
                yield t, camera, p, j, np.asarray(truth[j], dtype=float), to_world


def series(rec: dict, localiser: dict) -> list[dict]:
    """Per pedestrian of one recorded drive: times, whitened along / across errors of the raw
    placements, their poses and the person's class (standing, or moving in the run's pose)."""
    sc = rec["scenario"]
    loc = GroundLocaliser(dataclasses.replace(sc.sensing.localiser(rec["keypoints"]), **localiser))
    ground = street_of(sc).ground_height
    per: dict[int, dict] = {}
    for t, camera, p, j, xy, to_world in labelled_people(rec):
        e = loc.locate(p, camera, ground)
        if e is None:
            continue
        if to_world is not None:
            e = e.mapped(to_world)
        u = xy - camera.position[:2]
        u = u / np.hypot(*u)
        w = np.array([-u[1], u[0]])
        d = e.position - xy
        s = per.setdefault(j, {"t": [], "along": [], "across": [], "shape": [], "truth": []})
        s["t"].append(float(t))
        s["along"].append(float(d @ u / math.sqrt(u @ e.covariance @ u)))
        s["across"].append(float(d @ w / math.sqrt(w @ e.covariance @ w)))
        s["shape"].append(e.shape)
        s["truth"].append(xy)
    out = []
    for j, s in per.items():
        kind = f"standers, {sc.pedestrians[j].pose} pose"
        if any(sc.pedestrians[j].velocity):  # Case II's slow walker: her pose is the run's
            kind = "moving, " + ("texting pose" if rec["att"] is False else "walking pose")
        out.append({**s, "t": np.array(s["t"]), "along": np.array(s["along"]), "across": np.array(s["across"]),
                    "kind": kind})  # fmt: skip
    return out


def body_model(recs: list[dict]) -> None:
    """Print each body point's reported height as share * H + offset pixels (least squares on 1 /
    image stature), beside the share-only median, with the robust spread left about each; then the
    localiser's reduced chi^2 per pose (quartiles)."""
    rows, fits = [], {}
    for rec in recs:
        sc = rec["scenario"]
        ground = street_of(sc).ground_height
        loc = GroundLocaliser(sc.sensing.localiser(False))
        for _, camera, p, j, xy, to_world in labelled_people(rec):
            if to_world is not None:  # the truth is in the world's frame, the camera in another
                continue
            z0 = ground(xy)
            stature = sc.pedestrians[j].appearance.height
            _, depth = camera.project([[xy[0], xy[1], z0]])
            pts = camera.back_project(p.keypoints, np.full(17, depth[0]))  # at the truth's distance
            share = (pts[:, 2] - z0) / stature
            share[p.confidences < 0.3] = np.nan
            rows.append((camera.focal_px * stature / depth[0], share))
            e = loc.locate(p, camera, ground)
            if e is not None:
                fits.setdefault(sc.pedestrians[j].pose, []).append(e.fit)
    if not rows:
        print("no person-frames with truth in these recordings")
        return
    size = np.array([r[0] for r in rows])
    shares = np.array([r[1] for r in rows])
    print(f"{len(rows)} person-frames, image stature {size.min():.0f}-{size.max():.0f} px")
    print("  body point   share-only median (robust sd)   share + offset px (robust sd)")
    for name, joints, _, _ in BODY_POINTS:
        y = np.concatenate([shares[:, j] for j in joints])
        x = np.concatenate([size for _ in joints])
        ok = np.isfinite(y)
        a = np.column_stack([np.ones(ok.sum()), 1.0 / x[ok]])
        coef = np.linalg.lstsq(a, y[ok], rcond=None)[0]
        med = float(np.median(y[ok]))
        spread = [1.4826 * float(np.median(np.abs(r - np.median(r)))) for r in (y[ok] - med, y[ok] - a @ coef)]
        print(f"  {name:10s}   {med:.3f} ({spread[0]:.4f})                 {coef[0]:.3f} + {coef[1]:+.2f} px "
              f"({spread[1]:.4f})")  # fmt: skip
    for pose, v in sorted(fits.items()):
        q = np.percentile(v, [25, 50, 75])
        print(f"  reduced chi^2, {pose} pose: quartiles {q[0]:.2f} / {q[1]:.2f} / {q[2]:.2f} ({len(v)} placements)")


def correlation(people: list[dict], key: str, lag: float, tol: float = 0.02) -> tuple[float, int]:
    """Pooled sample correlation (not demeaned) of ``key`` errors ``lag`` seconds apart, and the
    number of pairs."""
    num = a2 = b2 = 0.0
    n = 0
    for s in people:
        t, z = s["t"], s[key]
        i, j = np.nonzero(np.abs(t[None, :] - t[:, None] - lag) < tol)
        if len(i):
            num += float(z[i] @ z[j])
            a2 += float(z[i] @ z[i])
            b2 += float(z[j] @ z[j])
            n += len(i)
    return (num / math.sqrt(a2 * b2) if n else math.nan), n


def fit_linear_fade(lags, r, n) -> tuple[float, float]:
    """Least squares (weighted by pairs) of ``shared * max(0, 1 - t / tau)`` to the correlations
    ``r`` at ``lags``: (shared, tau)."""
    lags, r, n = map(np.asarray, (lags, r, n))
    ok = np.isfinite(r) & (n > 0)
    best = (math.inf, 0.0, 0.0)
    for tau in np.concatenate([np.arange(0.2, 20.0, 0.05), np.arange(20.0, 60.0001, 0.5)]):
        basis = np.maximum(0.0, 1.0 - lags[ok] / tau)
        wts = n[ok]
        den = float(np.sum(wts * basis * basis))
        shared = min(1.0, max(0.0, float(np.sum(wts * basis * r[ok])) / den)) if den > 0 else 0.0
        sse = float(np.sum(wts * (r[ok] - shared * basis) ** 2))
        if sse < best[0]:
            best = (sse, shared, float(tau))
    return best[1], best[2]


def pose_factor(people: list[dict], lag: float, scale: float, tol: float = 0.02) -> float:
    """Mean of the tracker's pose factor exp(-(d / scale)^2 / 2) over frame pairs ``lag`` apart."""
    f = []
    for s in people:
        t = s["t"]
        for i in range(len(t) - 1):
            if abs(t[i + 1] - t[i] - lag) < tol:
                d = pose_change(s["shape"][i], s["shape"][i + 1])
                if math.isfinite(d):
                    f.append(math.exp(-0.5 * (d / scale) ** 2) if scale > 0 else 1.0)
    return float(np.mean(f)) if f else math.nan


def measured_inflation(people: list[dict], rate: float, span: float) -> float:
    """n var(mean of the n frames of a span) / var(frame), from the along errors of ``span``-second
    windows of drives at ``rate`` frames/s (not demeaned: second moments about 0)."""
    step = 1.0 / rate
    means, single = [], []
    for s in people:
        t, z = s["t"], s["along"]
        if len(t) < 2 or abs(np.median(np.diff(t)) - step) > 0.02:
            continue
        k = 0
        while k < len(t):
            sel = (t >= t[k]) & (t < t[k] + span - 1e-6)
            m = int(sel.sum())
            if m >= max(2, int(0.8 * span * rate)):
                means.append((float(z[sel].mean()), m))
            k += max(1, m)
        single.extend(z.tolist())
    if not means:
        return math.nan
    var1 = float(np.mean(np.square(single)))
    return float(np.mean([mu * mu * m for mu, m in means])) / var1


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("recordings", nargs="+", type=Path, help="files written by region_breakdown.py --save")
    ap.add_argument("--set", nargs="+", default=[], metavar="KEY=NUMBER",
                    help="LocaliserConfig fields replaced before placing the people")  # fmt: skip
    ap.add_argument("--body", action="store_true", help="fit the detector's body model (share + pixel offset)")
    args = ap.parse_args(argv)
    fields = {f.name for f in dataclasses.fields(LocaliserConfig)}
    loc: dict[str, float | bool] = {}
    for item in args.set:
        key, _, value = item.partition("=")
        try:
            loc[key] = set_value(value)
        except ValueError:
            ap.error(f"--set {item!r}: expected KEY=NUMBER (or true / false)")
        if key not in fields:
            ap.error(f"--set {item!r}: {key!r} is no field of LocaliserConfig")
    try:
        LocaliserConfig(**loc)
    except (TypeError, ValueError) as exc:
        ap.error(f"--set: {exc}")
    people: list[dict] = []
    loaded: list[dict] = []
    for path in args.recordings:
        try:
            with path.open("rb") as fh:
                recs = pickle.load(fh)
        except (OSError, pickle.UnpicklingError, EOFError) as exc:
            ap.error(f"recording {str(path)!r}: not a file of region_breakdown.py --save ({exc})")
        if any(rec["keypoints"] for rec in recs):
            ap.error(f"recording {str(path)!r}: keypoint drives; this fit is of rendered frames (--render)")
        loaded += recs
    if args.body:
        print(f"{len(args.recordings)} recordings, load {os.getloadavg()[0]:.1f}")
        body_model(loaded)
        return 0
    for rec in loaded:
        people += series(rec, loc)
    print(f"{len(args.recordings)} recordings, {len(people)} person-drives, load {os.getloadavg()[0]:.1f}"
          + (f"; localiser with {' '.join(args.set)}" if args.set else ""))  # fmt: skip
    drive = SensingSpec().tracker(keypoints=False)  # the rendered drive's tracker, as configured
    pose_scale = drive.pose_change
    groups = {name: [p for p in people if p["kind"] == name] for name in sorted({p["kind"] for p in people})}
    standers = [p for p in people if p["kind"].startswith("standers")]
    if standers:  # the tracker has one setting for every stander: the fit to use is the pooled one
        groups = {"standers, every pose (pooled)": standers, **groups}
    for name, group in groups.items():
        along = np.concatenate([p["along"] for p in group])
        across = np.concatenate([p["across"] for p in group])
        bias = np.array([p["along"].mean() for p in group])
        rms_a, rms_c, rms_b = (float(np.sqrt(np.mean(np.square(x)))) for x in (along, across, bias))
        print(f"{name}: {len(group)} person-drives, {len(along)} frames; raw rms of sigma along {rms_a:.2f}, "
              f"across {rms_c:.2f}; per-drive mean along error: rms {rms_b:.2f}")  # fmt: skip
        rows = [(lag, *correlation(group, "along", lag), correlation(group, "across", lag)[0]) for lag in LAGS]
        print("  lag s   along r (pairs)   across r")
        for lag, r, n, rc in rows:
            print(f"  {lag:5.1f}   {r:6.3f} ({n:5d})    {rc:6.3f}")
        shared, tau = fit_linear_fade([r[0] for r in rows], [r[1] for r in rows], [r[2] for r in rows])
        f10, f1 = pose_factor(group, 0.1, pose_scale), pose_factor(group, 1.0, pose_scale)
        print(f"  fit along: correlation {shared:.3f} * max(0, 1 - t / {tau:.2f} s); pose factor (pose_change "
              f"{pose_scale}) mean {f10:.3f} at 0.1 s, {f1:.3f} at 1 s")  # fmt: skip
        across_rows = [(lag, *correlation(group, "across", lag)) for lag in LAGS]
        shared_x, tau_x = fit_linear_fade(*zip(*across_rows, strict=True))
        print(f"  fit across: correlation {shared_x:.3f} * max(0, 1 - t / {tau_x:.2f} s) (the pose not looked at)")
        for rate, span, f in ((10.0, 1.0, f10), (10.0, 2.0, f10), (1.0, 3.0, f1), (1.0, 5.0, f1)):
            es = min(1.0, shared / f) if f and math.isfinite(f) else shared
            model = correlated_error_factor(1.0 / rate, tau, shared)
            main_factor = correlated_error_factor(1.0 / rate, drive.error_correlation_s, drive.error_shared * f)
            print(f"  {rate:g} frames/s: error_shared {es:.3f} (fit / pose factor); the tracker's factor {model:.2f} "
                  f"(the drive's {main_factor:.2f}); measured n var(mean) / var over "
                  f"{span:g} s spans {measured_inflation(group, rate, span):.2f}")  # fmt: skip
        # the batch-means estimate: the linear fade ends where the correlation first turns <= 0
        # (the initial positive sequence, Geyer 1992), and its share makes the tracker's factor at
        # 10 frames/s the measured inflation's plateau, its mean over 2-4 s spans (batch means: n
        # var(mean of n frames) / var(frame), which counts the negative correlations of far lags)
        zero = next((lag for lag, r, n, _ in rows if n > 0 and r <= 0.0), LAGS[-1])
        spans = [(span, measured_inflation(group, 10.0, span)) for span in BATCH_SPANS]
        spans = [(span, v) for span, v in spans if math.isfinite(v)]
        plateau = [v for span, v in spans if span >= 2.0]
        if plateau:
            vif = float(np.mean(plateau))
            unit = correlated_error_factor(0.1, zero, 1.0) - 1.0  # the factor's growth per unit share
            s_bm = min(1.0, max(0.0, (vif - 1.0) / unit)) if unit > 0 else 0.0
            es = min(1.0, s_bm / f10) if f10 and math.isfinite(f10) else s_bm
            print("  batch means at 10 frames/s: " + ", ".join(f"{a:g} s {v:.2f}" for a, v in spans)
                  + f"; fade ends at {zero:g} s (first correlation <= 0): share {s_bm:.3f}, error_shared "
                  f"{es:.3f} (/ pose factor), error_correlation_s {zero:g}; the tracker's factor "
                  f"{correlated_error_factor(0.1, zero, s_bm):.2f} at 10 frames/s, "
                  f"{correlated_error_factor(1.0, zero, es * f1):.2f} at 1")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
