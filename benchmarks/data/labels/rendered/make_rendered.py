"""Regenerates the rendered labelled set: Case I/II pedestrians drawn by the drive's PyBullet renderer.

20 frames (seed 0) of case-1's camera and street, each with three pedestrians 7-13 m ahead:
the attentive pose (body facing the camera +- 20 deg, head turned to it: eye contact, no phone),
the distracted pose (phone held in both hands, head bent over it: phone, no eye contact) and the
walking pose in profile (body yaw 90 deg +- 15: no phone, no eye contact). Boxes are the projected
body points (``trustnav.sim.driving.sensing.projected_box``). The frames (~6 MB) are not stored:
``benchmarks/trust_eval.py`` regenerates them into a cache folder and checks the boxes against
``../rendered.json``, the labels this script wrote.

The held-out set ``../rendered_heldout.json`` (variant "heldout", seed 11) is made by the same
generator with other poses, turns, looks and distances (``HELDOUT_ROLES``): standing attentive
people turned up to 30 deg, people walking while texting turned 15-75 deg, people walking away;
6-15 m. It was made, and its figures taken, before issue 19's cue changes; nothing was tuned on it.

    python benchmarks/data/labels/rendered/make_rendered.py OUT_DIR   # frames + OUT_DIR/labels.json
    python benchmarks/data/labels/rendered/make_rendered.py OUT_DIR 11 heldout   # the held-out set
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from PIL import Image

from trustnav.sim.driving import body
from trustnav.sim.driving.render import PyBulletRenderer
from trustnav.sim.driving.sensing import projected_box
from trustnav.sim.driving.world import load_drive_scenario, street_of

HERE = Path(__file__).resolve().parent
PED_Y = 101.0  # case-1's pedestrian line (m)
ROLES = (  # pose, appearance, phone, eye contact, body yaw offset from facing the camera (deg)
    ("attentive", body.ATTENTIVE_LOOK, False, True, 0.0),
    ("distracted", body.DISTRACTED_LOOK, True, False, 0.0),
    ("walking", body.WALKER_LOOK, False, False, 90.0),
)
# The held-out variant (``rendered_heldout.json``, recipe "variant": "heldout"): other poses, body
# turns, looks and distances, made so that nothing was tuned on it. id, pose, appearance, phone,
# eye contact, body yaw offset (deg; its sign drawn at random), yaw jitter (+- deg).
HELDOUT_ROLES = (
    ("attentive", "attentive", body.WALKER_LOOK, False, True, 0.0, 30.0),
    ("texting", "texting_walk", body.ATTENTIVE_LOOK, True, False, 45.0, 30.0),
    ("walking", "walking", body.DISTRACTED_LOOK, False, False, 135.0, 30.0),
)
VARIANTS = {
    "default": {"roles": tuple((r[0], r[0], r[1], r[2], r[3], r[4], 15.0) for r in ROLES), "dist": (7.0, 13.0)},
    "heldout": {"roles": HELDOUT_ROLES, "dist": (6.0, 15.0)},
}


def generate(out: Path, n: int = 20, seed: int = 0, variant: str = "default") -> dict:
    """Renders the frames into ``out``; returns their labels (file name -> people). ``variant``:
    "default" (the labelled set ``rendered.json``), "heldout" (``rendered_heldout.json``) or
    "sequence" (``rendered_sequence.json``: one scene over ``n`` frames at 10 frames/s,
    :func:`generate_sequence`)."""
    if variant == "sequence":
        return generate_sequence(out, n, seed)
    out.mkdir(parents=True, exist_ok=True)
    roles, (d_lo, d_hi) = VARIANTS[variant]["roles"], VARIANTS[variant]["dist"]
    rng = np.random.default_rng(seed)
    scenario = load_drive_scenario("case-1")
    street = street_of(scenario)
    renderer = PyBulletRenderer(street)
    frames = {}
    try:
        for k in range(n):
            yaw = -0.5 * math.pi
            ego = np.array([float(street.start[0]) + rng.uniform(-0.4, 0.4), PED_Y + 12.0 + scenario.camera.forward])
            camera = scenario.camera.pose(ego, yaw)
            fwd, right = np.array([0.0, -1.0]), camera.right[:2]
            laterals = rng.permutation([-2.6, 0.0, 2.6]) + rng.uniform(-0.3, 0.3, 3)
            bodies, people = [], []
            for j, (pid, pose, look, phone, eye, yaw_off, jitter) in enumerate(roles):
                dist = rng.uniform(d_lo, d_hi)
                xy = camera.position[:2] + dist * fwd + laterals[j] * right
                ground = float(street.ground_height(xy))
                # body facing the camera: chest towards +y (the camera looks along -y)
                face = 0.5 * math.pi + math.radians(yaw_off * rng.choice([-1, 1]) + rng.uniform(-jitter, jitter))
                target = camera.position if pose == "attentive" else None
                sk = body.pedestrian_skeleton(pose, (xy[0], xy[1], ground), face, float(rng.uniform(0, 10)), look,
                                              look_at=target, phase=float(rng.uniform(0, 1)))  # fmt: skip
                box = projected_box(camera, sk)
                bodies.append((sk, look))
                people.append({"id": pid, "bbox": [round(float(v), 1) for v in box], "phone": phone,
                               "eye_contact": eye, "distance_m": round(float(dist), 2)})  # fmt: skip
            rgb = renderer.render(camera, bodies)
            name = f"frame_{k:02d}.png"
            Image.fromarray(rgb).save(out / name)
            frames[name] = {"people": people, "ignore": []}
    finally:
        renderer.close()
    return frames


#: The sequence variant: id, pose, appearance, phone, eye contact, distance (m), lateral start (m,
#: on the camera's right), lateral speed (m/s; 0 = standing).
SEQUENCE_ROLES = (
    ("walker", "walking", body.WALKER_LOOK, False, False, (8.0, 11.0), (-4.0, -3.0), (1.2, 1.5)),
    ("texter", "texting_walk", body.DISTRACTED_LOOK, True, False, (11.0, 14.0), (2.5, 3.5), (-1.1, -0.8)),
    ("attentive", "attentive", body.ATTENTIVE_LOOK, False, True, (6.5, 8.0), (2.5, 3.5), (0.0, 0.0)),
)
SEQUENCE_FPS = 10.0
#: A person whose box is covered by a nearer person's box by more than this share is hidden: their
#: box becomes an ignore region for that frame (the labelled sets' rule: not hidden by more than ~30 %).
HIDDEN_SHARE = 0.3


def generate_sequence(out: Path, n: int = 40, seed: int = 23) -> dict:
    """One street scene seen by case-1's camera, standing still, over ``n`` frames at
    :data:`SEQUENCE_FPS`: a man walking across the view (arms swinging: no phone, in profile: no
    eye contact), a woman walking across the other way while texting (phone, head bent: no eye
    contact) and a man standing turned to the camera with his head on it (eye contact, no phone);
    distances, starts and speeds drawn from ``seed``. Boxes are the projected body points; a person
    hidden behind a nearer one by more than :data:`HIDDEN_SHARE` of their box, or cut by the image
    edge, is an ignore region on that frame instead."""
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    scenario = load_drive_scenario("case-1")
    street = street_of(scenario)
    renderer = PyBulletRenderer(street)
    yaw = -0.5 * math.pi
    ego = np.array([float(street.start[0]), PED_Y + 12.0 + scenario.camera.forward])
    camera = scenario.camera.pose(ego, yaw)
    fwd, right = np.array([0.0, -1.0]), camera.right[:2]
    w, h = camera.spec.width, camera.spec.height
    drawn = [
        (pid, pose, look, phone, eye, rng.uniform(*dist), rng.uniform(*start), rng.uniform(*speed), rng.uniform(0, 1))
        for pid, pose, look, phone, eye, dist, start, speed in SEQUENCE_ROLES
    ]
    frames = {}
    try:
        for k in range(n):
            t = k / SEQUENCE_FPS
            bodies, placed = [], []
            for pid, pose, look, phone, eye, dist, start, speed, phase in drawn:
                xy = camera.position[:2] + dist * fwd + (start + speed * t) * right
                ground = float(street.ground_height(xy))
                if speed == 0.0:
                    face = math.atan2(-fwd[1], -fwd[0])  # chest towards the camera
                else:
                    heading = right if speed > 0 else -right
                    face = math.atan2(heading[1], heading[0])
                target = camera.position if eye else None
                sk = body.pedestrian_skeleton(pose, (xy[0], xy[1], ground), face, t, look, look_at=target, phase=phase)
                bodies.append((sk, look))
                box = projected_box(camera, sk)
                placed.append((dist, pid, phone, eye, box))
            people, ignore = [], []
            for dist, pid, phone, eye, box in placed:
                if box is None:
                    continue
                covered = max((_covered(box, b) for d, _, _, _, b in placed if b is not None and d < dist), default=0.0)
                cut = box[0] <= 0.0 or box[1] <= 0.0 or box[2] >= w - 1.0 or box[3] >= h - 1.0
                rounded = [round(float(v), 1) for v in box]
                if covered > HIDDEN_SHARE or cut:
                    ignore.append(rounded)
                else:
                    people.append({"id": pid, "bbox": rounded, "phone": phone, "eye_contact": eye,
                                   "distance_m": round(float(dist), 2)})  # fmt: skip
            rgb = renderer.render(camera, bodies)
            name = f"frame_{k:02d}.png"
            Image.fromarray(rgb).save(out / name)
            frames[name] = {"people": people, "ignore": ignore}
    finally:
        renderer.close()
    return frames


def _covered(box: np.ndarray, other: np.ndarray) -> float:
    """Share of ``box``'s area that ``other`` covers."""
    iw = min(box[2], other[2]) - max(box[0], other[0])
    ih = min(box[3], other[3]) - max(box[1], other[1])
    area = (box[2] - box[0]) * (box[3] - box[1])
    return float(iw * ih / area) if iw > 0 and ih > 0 and area > 0 else 0.0


if __name__ == "__main__":
    import sys

    dest = Path(sys.argv[1] if len(sys.argv) > 1 else "rendered_frames")
    seed = int(sys.argv[2]) if len(sys.argv) > 2 else 0
    variant = sys.argv[3] if len(sys.argv) > 3 else "default"
    (dest / "labels.json").write_text(json.dumps(generate(dest, seed=seed, variant=variant), indent=1))
