"""Pedestrian bodies for the driving world: a 3-D skeleton (17 COCO joints plus what a renderer
needs) in four poses, attentive, distracted (texting), walking and texting_walk (walking while
texting), with a small natural sway.

The paper's Section IV pedestrians (Fig. ``ped_type``): the high-trust one "maintains a neutral
stance facing the ego vehicle", the low-trust one has "raised hands with bent elbows and neck".
Everything here is a pure function of its arguments; sway comes from sinusoids whose phases are
set by ``phase``, so the same arguments always give the same body.

Body frame: x forward (where the chest faces), y to the person's left, z up; a body is built in it
for ``Appearance.height`` and turned by ``body_yaw`` about the point below the pelvis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.perception.types import COCO_KEYPOINTS

__all__ = [
    "ATTENTIVE_LOOK",
    "COCO_NAMES",
    "DISTRACTED_LOOK",
    "POSES",
    "WALKER_LOOK",
    "Appearance",
    "BodyDims",
    "Skeleton",
    "body_dims",
    "pedestrian_skeleton",
    "rot_y",
    "rot_z",
]

COCO_NAMES: tuple[str, ...] = COCO_KEYPOINTS  # the 17 COCO keypoints, in the perception's order
POSES = ("attentive", "distracted", "walking", "texting_walk")

Colour = tuple[float, float, float]

STEPS_PER_SECOND = 1.8  # walking cadence
TEXTING_CADENCE = 0.8  # walking while texting: a slower cadence (share of STEPS_PER_SECOND)
NECK_YAW_LIMIT = math.radians(75.0)  # head turn relative to the chest
NECK_PITCH_LIMITS = (math.radians(-25.0), math.radians(45.0))  # up, down
TORSO_SHARE = 0.35  # share of a look's turn taken by the chest
TORSO_TWIST_LIMIT = math.radians(20.0)


@dataclass(frozen=True)
class Appearance:
    """What a pedestrian looks like: RGB colours in [0, 1] and standing height (metres)."""

    skin: Colour
    hair: Colour
    shirt: Colour
    trousers: Colour
    shoes: Colour
    height: float = 1.75

    def __post_init__(self) -> None:
        for name in ("skin", "hair", "shirt", "trousers", "shoes"):
            value = getattr(self, name)
            try:
                rgb = tuple(float(c) for c in value)
            except TypeError:
                raise ValueError(f"{name} must be an RGB triple in [0, 1], got {value!r}") from None
            if len(rgb) != 3 or not all(0.0 <= c <= 1.0 for c in rgb):
                raise ValueError(f"{name} must be an RGB triple in [0, 1], got {value!r}")
            object.__setattr__(self, name, rgb)
        if not 1.0 <= self.height <= 2.2:
            raise ValueError(f"height must be in [1.0, 2.2] metres, got {self.height!r}")


ATTENTIVE_LOOK = Appearance(
    skin=(0.86, 0.68, 0.55),
    hair=(0.20, 0.13, 0.08),
    shirt=(0.16, 0.36, 0.70),
    trousers=(0.20, 0.20, 0.24),
    shoes=(0.12, 0.10, 0.09),
    height=1.76,
)
DISTRACTED_LOOK = Appearance(
    skin=(0.66, 0.48, 0.36),
    hair=(0.07, 0.06, 0.06),
    shirt=(0.76, 0.22, 0.16),
    trousers=(0.24, 0.30, 0.46),
    shoes=(0.88, 0.88, 0.86),
    height=1.72,
)
WALKER_LOOK = Appearance(
    skin=(0.80, 0.60, 0.47),
    hair=(0.42, 0.28, 0.14),
    shirt=(0.22, 0.55, 0.30),
    trousers=(0.30, 0.26, 0.22),
    shoes=(0.20, 0.14, 0.10),
    height=1.70,
)


@dataclass(frozen=True)
class BodyDims:
    """Segment lengths and widths (metres) of a body of a given height; the renderer shapes its
    parts from these, the skeleton keeps bone lengths equal to them."""

    height: float

    @property
    def s(self) -> float:
        return self.height / 1.75

    @property
    def hip_height(self) -> float:
        return 0.93 * self.s

    @property
    def shoulder_height(self) -> float:
        return 1.425 * self.s

    @property
    def neck_top(self) -> float:  # head pivot above the ground (standing straight)
        return 1.53 * self.s

    @property
    def hip_half_width(self) -> float:
        return 0.095 * self.s

    @property
    def shoulder_half_width(self) -> float:
        return 0.172 * self.s

    @property
    def thigh(self) -> float:
        return 0.43 * self.s

    @property
    def shin(self) -> float:
        return 0.415 * self.s

    @property
    def ankle_height(self) -> float:
        return 0.085 * self.s

    @property
    def upper_arm(self) -> float:
        return 0.29 * self.s

    @property
    def forearm(self) -> float:
        return 0.255 * self.s

    @property
    def hand(self) -> float:  # wrist to hand centre
        return 0.075 * self.s

    @property
    def foot(self) -> float:  # ankle to toe
        return 0.17 * self.s

    @property
    def head_centre(self) -> NDArray[np.float64]:  # head frame, from the pivot
        return np.array([0.012, 0.0, 0.10]) * self.s

    def face(self) -> dict[str, NDArray[np.float64]]:
        """Face points in the head frame (x forward, y left, z up), from the head's centre."""
        s = self.s
        return {
            "nose": np.array([0.100, 0.0, -0.012]) * s,
            "left_eye": np.array([0.080, 0.032, 0.022]) * s,
            "right_eye": np.array([0.080, -0.032, 0.022]) * s,
            "left_ear": np.array([-0.004, 0.082, 0.004]) * s,
            "right_ear": np.array([-0.004, -0.082, 0.004]) * s,
        }


def body_dims(appearance: Appearance) -> BodyDims:
    """Body dimensions for an appearance."""
    return BodyDims(appearance.height)


@dataclass(frozen=True, eq=False)
class Skeleton:
    """A posed body in world coordinates.

    joints: (17, 3) COCO order; head_yaw: world yaw the face points to; head_pitch > 0 looks down;
    body_yaw: where the chest faces; phone: (3,) centre of the phone held, or None. For a renderer:
    pelvis and neck (3,) (the torso runs between them), head_centre (3,), head_rot and body_rot
    (3, 3) rotations whose columns are the frame's forward, left and up axes, hands and toes (2, 3)
    (left, right), phone_rot (3, 3) (columns: long side, short side, screen normal).
    """

    joints: NDArray[np.float64]
    head_yaw: float
    head_pitch: float
    body_yaw: float
    phone: NDArray[np.float64] | None = None
    pelvis: NDArray[np.float64] | None = None
    neck: NDArray[np.float64] | None = None
    head_centre: NDArray[np.float64] | None = None
    head_rot: NDArray[np.float64] | None = None
    body_rot: NDArray[np.float64] | None = None
    hands: NDArray[np.float64] | None = None
    toes: NDArray[np.float64] | None = None
    phone_rot: NDArray[np.float64] | None = None
    height: float = 1.75

    def __post_init__(self) -> None:
        joints = np.asarray(self.joints, dtype=float)
        if joints.shape != (17, 3) or not np.all(np.isfinite(joints)):
            raise ValueError(f"joints must be (17, 3) finite, got shape {joints.shape}")
        object.__setattr__(self, "joints", joints)

    def joint(self, name: str) -> NDArray[np.float64]:
        """One joint by COCO name."""
        return self.joints[COCO_NAMES.index(name)]

    def points(self) -> NDArray[np.float64]:
        """Every point of the body (joints, head top, hands, toes, phone) for bounding boxes."""
        extra = [p for p in (self.head_centre, self.phone) if p is not None]
        if self.head_centre is not None and self.head_rot is not None:
            extra.append(self.head_centre + self.head_rot[:, 2] * 0.13 * self.height / 1.75)
        pts = [self.joints, *(a for a in (self.hands, self.toes) if a is not None)]
        if extra:
            pts.append(np.stack(extra))
        return np.concatenate(pts, axis=0)


def rot_z(a: float) -> NDArray[np.float64]:
    """Rotation about z (yaw) by ``a`` rad."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_y(a: float) -> NDArray[np.float64]:
    """Rotation about y by ``a`` rad: positive tilts the x axis down (pitch forward)."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_x(a: float) -> NDArray[np.float64]:
    """Rotation about x (roll) by ``a`` rad."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _unit(v: ArrayLike) -> NDArray[np.float64]:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def _wobble(t: float, phase: float, k: int) -> float:
    """A smooth, deterministic signal in about [-1, 1]: two slow sinusoids whose phases depend
    on ``phase`` and the channel ``k``."""
    g = 0.6180339887 * (k + 1)
    a = 2.0 * math.pi * (0.21 + 0.037 * k) * t + 2.0 * math.pi * (phase * 1.37 + g)
    b = 2.0 * math.pi * (0.53 + 0.029 * k) * t + 2.0 * math.pi * (phase * 2.11 + 2.3 * g)
    return 0.65 * math.sin(a) + 0.35 * math.sin(b)


def _arm(shoulder: NDArray, upper_dir: ArrayLike, fore_dir: ArrayLike, dims: BodyDims) -> tuple[NDArray, ...]:
    """Elbow, wrist and hand centre from a shoulder and the two segment directions (body frame)."""
    d1, d2 = _unit(upper_dir), _unit(fore_dir)
    elbow = shoulder + dims.upper_arm * d1
    wrist = elbow + dims.forearm * d2
    return elbow, wrist, wrist + dims.hand * d2


def _sagittal(angle: float) -> NDArray[np.float64]:
    """Unit vector hanging down, swung forward by ``angle`` rad (body frame)."""
    return np.array([math.sin(angle), 0.0, -math.cos(angle)])


def pedestrian_skeleton(
    pose: str,
    position: ArrayLike,
    body_yaw: float,
    t: float,
    appearance: Appearance,
    look_at: ArrayLike | None = None,
    phase: float = 0.0,
    sway: float = 1.0,
) -> Skeleton:
    """3-D body at time ``t`` (s) standing at ``position``: (x, y), or (x, y, z) with z the height
    of the ground under the feet (e.g. ``StreetSpec.ground_height``; the renderer also lifts a body
    built at z = 0 onto a sidewalk).

    attentive: neutral stance, head turned toward ``look_at`` (world (3,), e.g. the camera) within
    the neck's limits (75 deg from the chest; the chest turns along by a third of the look, at
    most 20 deg, the hips stay at ``body_yaw``); distracted: forearms raised, elbows bent, phone in both hands at chest
    height, neck bent down ~35 deg, ``look_at`` ignored; walking: gait with legs and arms swinging
    at ~1.8 steps/s (in place: moving the body is the caller's), head toward ``look_at`` if given;
    texting_walk: walking while texting: the gait at a slower cadence (``TEXTING_CADENCE``) with the
    arms, phone, rounded shoulders and bent neck of distracted, ``look_at`` ignored.
    A small sway (postural lean ~1 deg, head ~3 deg, arms ~2 deg), set by ``phase`` and scaled by
    ``sway`` (0 = none), makes consecutive frames differ a little.
    """
    if pose not in POSES:
        raise ValueError(f"pose must be one of {POSES}, got {pose!r}")
    pos = np.asarray(position, dtype=float).reshape(-1)
    if pos.shape not in ((2,), (3,)) or not np.all(np.isfinite(pos)):
        raise ValueError(f"position must be (x, y) or (x, y, z) finite, got {position!r}")
    if not (math.isfinite(body_yaw) and math.isfinite(t) and math.isfinite(phase)):
        raise ValueError("body_yaw, t and phase must be finite")
    if not 0.0 <= sway <= 10.0:
        raise ValueError(f"sway must be in [0, 10], got {sway!r}")
    dims = body_dims(appearance)
    s = dims.s
    deg = math.radians
    w = [sway * _wobble(t, phase, k) for k in range(8)]
    gait = pose in ("walking", "texting_walk")  # legs walking
    texting = pose in ("distracted", "texting_walk")  # phone in both hands, head down
    cadence = STEPS_PER_SECOND * (TEXTING_CADENCE if texting else 1.0)

    # --- legs (body frame, pelvis height found afterwards) ---
    hip_y = dims.hip_half_width
    if gait:
        stride = math.pi * cadence * t + 2.0 * math.pi * phase  # one stride = two steps
        leg_angles = []
        for side in (1.0, -1.0):  # left, right
            g = stride if side > 0 else stride + math.pi
            flex = deg(22.0) * math.sin(g)
            knee = deg(6.0) + deg(42.0) * max(0.0, math.cos(g - 0.35)) ** 2
            leg_angles.append((flex, knee))
    else:
        leg_angles = [(deg(1.5) + deg(0.8) * w[5], deg(4.0)), (deg(-1.5) - deg(0.8) * w[5], deg(3.0))]
    knees, ankles = [], []
    for (flex, knee), side in zip(leg_angles, (1.0, -1.0), strict=True):
        hip = np.array([0.0, side * hip_y, 0.0])
        k = hip + dims.thigh * _sagittal(flex)
        a = k + dims.shin * _sagittal(flex - knee)
        knees.append(k)
        ankles.append(a)
    pelvis_z = dims.ankle_height - min(a[2] for a in ankles)
    lift = np.array([0.0, 0.0, pelvis_z])
    hips = [np.array([0.0, side * hip_y, 0.0]) + lift for side in (1.0, -1.0)]
    knees = [k + lift for k in knees]
    ankles = [a + lift for a in ankles]
    if not gait:  # feet slightly apart and turned out
        ankles = [a + np.array([0.0, side * 0.02 * s, 0.0]) for a, side in zip(ankles, (1.0, -1.0), strict=True)]
    toes = []
    for a, (flex, knee) in zip(ankles, leg_angles, strict=True):
        foot_pitch = (flex - knee) * 0.6 if gait else 0.0
        toes.append(a + dims.foot * np.array([math.cos(foot_pitch), 0.0, -0.45 + math.sin(foot_pitch)]) * 0.92)

    # --- where to look: relative yaw and elevation of look_at, from about the head's position ---
    root = np.array([pos[0], pos[1], pos[2] if len(pos) == 3 else 0.0])
    r_body = rot_z(body_yaw)
    look_rel = look_elev = None
    if look_at is not None and not texting:
        target = np.asarray(look_at, dtype=float).reshape(-1)
        if target.shape != (3,) or not np.all(np.isfinite(target)):
            raise ValueError(f"look_at must be (x, y, z) finite, got {look_at!r}")
        d = target - (root + r_body @ np.array([0.0, 0.0, dims.neck_top + dims.head_centre[2]]))
        look_rel = math.atan2(d[1], d[0]) - body_yaw
        look_rel = math.atan2(math.sin(look_rel), math.cos(look_rel))
        look_elev = math.atan2(d[2], math.hypot(d[0], d[1]))
    # turning to look, people turn the chest a little too (about a third, up to 20 deg)
    twist = 0.0 if look_rel is None else float(np.clip(TORSO_SHARE * look_rel, -TORSO_TWIST_LIMIT, TORSO_TWIST_LIMIT))

    # --- torso: from the pelvis up, leaning a little ---
    lean_fwd = deg(3.0 if gait else 0.0) + deg(0.9) * w[0]
    if texting:
        lean_fwd += deg(4.0)  # shoulders rounded over the phone
    lean_side = deg(0.9) * w[1]
    if gait:
        lean_side += deg(1.5) * math.sin(math.pi * cadence * t + 2.0 * math.pi * phase)
    torso_rot = rot_z(twist) @ rot_x(lean_side) @ rot_y(lean_fwd)
    pelvis = lift.copy()
    up_len = dims.shoulder_height - dims.hip_height
    shoulder_mid = pelvis + torso_rot @ np.array([0.0, 0.0, up_len])
    shoulders = [shoulder_mid + torso_rot @ np.array([0.0, side * dims.shoulder_half_width, 0.0]) for side in (1, -1)]
    neck_top = pelvis + torso_rot @ np.array([0.0, 0.0, dims.neck_top - dims.hip_height])
    neck_base = shoulder_mid + torso_rot @ np.array([0.0, 0.0, 0.02 * s])

    # --- arms ---
    elbows, wrists, hands = [], [], []
    phone_local = None
    for side, shoulder in zip((1.0, -1.0), shoulders, strict=True):
        jit = deg(2.0) * w[2 if side > 0 else 3]
        if texting:
            upper = torso_rot @ np.array([0.26 + jit, -side * 0.13, -1.0])
            fore = np.array([0.80, -side * 0.36, 0.46 + jit])
        elif gait:
            g = math.pi * cadence * t + 2.0 * math.pi * phase + (math.pi if side > 0 else 0.0)
            swing = deg(18.0) * math.sin(g)
            upper = torso_rot @ (_sagittal(swing + jit) + np.array([0.0, side * 0.10, 0.0]))
            fore = _sagittal(swing + deg(22.0) + deg(8.0) * math.sin(g)) + np.array([0.0, side * 0.05, 0.0])
        else:
            upper = torso_rot @ np.array([0.02 + jit, side * 0.14, -1.0])
            fore = np.array([0.16 + 0.5 * jit, side * 0.05, -1.0])
        e, wr, h = _arm(shoulder, upper, rot_z(twist) @ fore, dims)
        elbows.append(e)
        wrists.append(wr)
        hands.append(h)
    if texting:
        phone_local = 0.5 * (hands[0] + hands[1]) + np.array([0.012, 0.0, 0.018]) * s

    # --- head (yaw relative to the hips' frame; the neck's limits count from the chest) ---
    if texting:
        rel_yaw = deg(2.0) * w[4]
        pitch = deg(35.0) + deg(2.0) * w[6]
    else:
        rel_yaw = twist + deg(3.0) * w[4]
        pitch = deg(2.0) * w[6]
        if look_rel is not None and look_elev is not None:
            rel_yaw += float(np.clip(look_rel - twist, -NECK_YAW_LIMIT, NECK_YAW_LIMIT))
            pitch -= look_elev
        elif gait:
            pitch += deg(6.0)
    rel_yaw = twist + float(np.clip(rel_yaw - twist, -NECK_YAW_LIMIT - deg(5), NECK_YAW_LIMIT + deg(5)))
    pitch = float(np.clip(pitch, *NECK_PITCH_LIMITS))
    head_local = rot_z(rel_yaw) @ rot_y(pitch)
    centre = neck_top + head_local @ dims.head_centre
    face = {name: centre + head_local @ p for name, p in dims.face().items()}

    # --- to the world ---
    def world(p: NDArray) -> NDArray:
        return root + r_body @ p

    local = [
        face["nose"],
        face["left_eye"],
        face["right_eye"],
        face["left_ear"],
        face["right_ear"],
        shoulders[0],
        shoulders[1],
        elbows[0],
        elbows[1],
        wrists[0],
        wrists[1],
        hips[0],
        hips[1],
        knees[0],
        knees[1],
        ankles[0],
        ankles[1],
    ]
    joints = np.stack([world(p) for p in local])
    phone = phone_rot = None
    if phone_local is not None:
        phone = world(phone_local)
        # screen faces the eyes (normal toward the head's centre), held sideways: long side
        # along the body's left-right axis, between the hands
        normal = _unit(r_body @ (centre - phone_local))
        left = r_body @ np.array([0.0, 1.0, 0.0])
        long_side = _unit(left - (left @ normal) * normal)
        phone_rot = np.stack([long_side, np.cross(normal, long_side), normal], axis=1)
    return Skeleton(
        joints=joints,
        head_yaw=float(body_yaw + rel_yaw),
        head_pitch=pitch,
        body_yaw=float(body_yaw),
        phone=phone,
        pelvis=world(pelvis),
        neck=world(neck_base),
        head_centre=world(centre),
        head_rot=r_body @ head_local,
        body_rot=r_body @ torso_rot,
        hands=np.stack([world(h) for h in hands]),
        toes=np.stack([world(p) for p in toes]),
        phone_rot=phone_rot,
        height=appearance.height,
    )
