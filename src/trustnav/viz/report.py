"""Text reports of results, as the commands print them: each function returns its lines.

Reads results only (metrics dicts, as ``DriveResult.metrics()`` and the paper scenarios give them);
imports nothing of trustnav's.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["comparison_table", "demo_headline", "drive_summary", "estimate_summary", "scenario_summary"]


def scenario_summary(m: dict) -> list[str]:
    """The paper scenario's metrics as text lines: per run the closest approaches, steps to goal,
    margin violations and solver failures."""
    lines: list[str] = []

    def line(tag: str, r: dict) -> None:
        dist = ", ".join(f"{d:.3f}" for d in r["min_distance"])
        lines.append(f"  {tag:<28} min distance [{dist}]  steps to goal {r['steps_to_goal']}  "
              f"margin violations {r['margin_violations']}  solver failures {r['solver_failures']}")  # fmt: skip

    if "runs" in m:
        for r in m["runs"]:
            line(f"trust {r['trust']:g}" if "trust" in r else f"N_h {r['horizon']}", r)
        for timing, runs in m.get("timings", {}).items():
            if timing == m["timing"]:
                continue
            for r in runs:
                line(f"N_h {r['horizon']} ({timing})", r)
    else:
        line("trust-aware", m)
        if "control_equal_trust" in m:
            line("control (all trusts 1.0)", m["control_equal_trust"])
    return lines


def drive_summary(done: list[tuple[str, dict, Path]]) -> list[str]:
    """A drive's runs as text lines (``done``: (tag, metrics, folder) per run): goal, margin
    violations, solver figures, per pedestrian the closest approach, trust and localisation."""
    lines: list[str] = []
    for tag, m, where in done:
        ttg = "not reached" if m["time_to_goal"] is None else f"{m['time_to_goal']:.1f} s"
        extra = f"  detection recall {m['detection_recall']:.2f}" if m.get("detection_recall") is not None else ""
        if m.get("perception_ms_median") is not None:
            extra += f"  perception {m['perception_ms_median']:.0f} ms (p95 {m['perception_ms_p95']:.0f})"
        if m.get("road_departure_max"):
            extra += f"  off the road by up to {m['road_departure_max']:.2f} m"
        if m.get("yield_s"):
            extra += f"  yielded {m['yield_s']:.1f} s"
        lines.append(f"  {tag}: goal {ttg}  margin violations {m['margin_violations']}  relaxed steps "
              f"{m['relaxed_steps']}  fallback steps {m['fallback_steps']}  solve {m['solve_ms_median']:.2f} ms "
              f"(p95 {m['solve_ms_p95']:.2f}){extra}  -> {where}")  # fmt: skip
        for p in m["pedestrians"]:
            kind = "attentive" if p["attentive"] else "distracted"
            who = p["name"] if kind in p["name"] else f"{p['name']} ({kind})"  # not "attentive (attentive)"
            loc = ""
            if p.get("localisation_error_median") is not None:
                loc = (f"  located to {p['localisation_error_median']:.2f} m (p95 {p['localisation_error_p95']:.2f}), "
                       f"truth in the 90 % region {p['interval_coverage']:.0%}")  # fmt: skip
            lines.append(f"      {who:<24} min distance {p['min_distance']:.2f} m  "
                  f"final trust {p['final_trust']:.2f}  frames seen {p['frames_seen']}{loc}")  # fmt: skip
        if m.get("state") == "perceived":
            near = f" and followed by a near-field sensor to {m['near_range']:g} m" if m.get("near_range") else ""
            if near and m.get("near_clutter"):
                near += f" (which also returns {m['near_clutter']:g} object(s) per 10 m of sidewalk)"
            lines.append(f"      pedestrians perceived by the camera{near} (--state true: the world's); "
                  f"identity switches {m.get('id_switches', 0)}")  # fmt: skip
    return lines


def comparison_table(rows: list[dict], radius: float) -> list[str]:
    """The comparison as a text table: one line per run, closest approach per pedestrian."""
    lines: list[str] = []
    names = [p["name"] for p in rows[0]["pedestrians"]]
    head = f"  {'run':<30}{'gamma':>7}" + "".join(f"{'min d ' + n:>18}" for n in names)
    lines.append(head + f"{'goal':>9}{'bend':>8}{'in R':>6}")
    for r in rows:
        label = f"{r['variant'] + ': ' if r['variant'] else ''}{r['mode']}"
        gamma = "est." if r["gamma"] is None else f"{r['gamma']:.2f}"
        goal = "-" if r["time_to_goal"] is None else f"{r['time_to_goal']:.1f} s"
        cells = "".join(f"{p['min_distance']:>16.2f} m" for p in r["pedestrians"])
        lines.append(
            f"  {label:<30}{gamma:>7}{cells}{goal:>9}{r['max_lateral_offset']:>6.2f} m{r['margin_violations']:>6}"
        )
    lines.append(
        f"  (min d: closest true distance, R = {radius:g} m; gamma: the barrier rate the controller got, est. = "
        "from each pedestrian's estimated trust; bend: largest offset from the lane centre; in R: steps inside R)"
    )
    return lines


def demo_headline(runs: dict[str, dict]) -> list[str]:
    """The demo's numbers: per pedestrian the closest approach and the final trust, the time to
    goal and the bend, for the trust-aware run, the equal-trust run and keypoint sensing."""
    lines: list[str] = []
    given = runs["equal_trust"]["trust_given_to_controller"]
    cols = [("trust-aware", runs["trust-aware"]), (f"equal trust {given:g} (trust-blind)",
            runs["equal_trust"]), ("trust-aware, keypoint sensing", runs["keypoints_sensing"])]  # fmt: skip
    m0 = runs["trust-aware"]
    lines.append(
        f"headline (Case I, R = {m0.get('safety_radius', 2.5):g} m): closest approach (final trust) per pedestrian"
    )
    lines.append((f"  {'':<22}" + "".join(f"{name:<32}" for name, _ in cols)).rstrip())
    for j, p in enumerate(m0["pedestrians"]):
        cells = []
        for name, m in cols:
            q = m["pedestrians"][j]
            trust = f"{given:.2f} fixed" if name.startswith("equal") else f"{q['final_trust']:.2f}"
            cells.append(f"{q['min_distance']:.2f} m (trust {trust})")
        lines.append((f"  {p['name']:<22}" + "".join(f"{c:<32}" for c in cells)).rstrip())
    ttg = ["not reached" if m["time_to_goal"] is None else f"{m['time_to_goal']:.1f} s" for _, m in cols]
    rows = [("time to goal", ttg), ("bend off the lane", [f"{m['max_lateral_offset']:.2f} m" for _, m in cols]),
            ("margin violations", [str(m["margin_violations"]) for _, m in cols])]  # fmt: skip
    for head, cells in rows:
        lines.append((f"  {head:<22}" + "".join(f"{c:<32}" for c in cells)).rstrip())
    return lines


def estimate_summary(read: int, sequences: int, rows: list[dict], skipped: int, dropped: int | None,
                     rejected: list[dict], ground: Any, out: Path) -> list[str]:  # fmt: skip
    """`trustnav estimate`'s closing lines: frames, records, tracks, skipped and (``dropped`` not
    None: live input) dropped frames; the detector boxes rejected; the records placed on the ground
    (``ground``: the FixedCameraGround, None: no positions)."""
    tracks = len({(r["sequence"], r["track_id"]) for r in rows})
    lost = "" if dropped is None else f", {dropped} live frames dropped (slower than the camera)"
    lines = [f"estimate: {read} frames in {sequences} sequence{'s' * (sequences > 1)}, {len(rows)} records, "
             f"{tracks} tracks, {skipped} frames skipped{lost}; wrote {out}"]  # fmt: skip
    if rejected:
        gate = sum("landmark model" not in r["reason"] for r in rejected)
        lines.append(f"  {len(rejected)} detector boxes rejected ({gate} by the geometry gate, {len(rejected) - gate} "
                     f"not confirmed by the landmark model): rejected.json")  # fmt: skip
    if ground is None:
        lines.append("  no ground positions: give --camera-height (and --fov, --pitch) to place people on the ground")
    else:
        placed = sum(r.get("distance_m") is not None for r in rows)
        lines.append(f"  {placed} of {len(rows)} records placed on the ground (ahead_m, left_m with sd; camera "
                     f"{ground.height:g} m up, {ground.fov_deg:g} deg, pitch {ground.pitch_deg:g} deg)")  # fmt: skip
    return lines
