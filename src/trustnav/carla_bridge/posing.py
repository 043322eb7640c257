"""Pose CARLA walkers like trustnav's pedestrians through the walker bone API.

trustnav's poses (body.py): attentive = neutral stance (CARLA's idle animation is one already;
the head toward the car comes from the walker's yaw, as the authors turned theirs 60 deg);
distracted = neck bent ~35 deg, upper arms down along the torso, forearms raised with the elbows
bent ~90 deg, hands in front of the chest (a phone held in both hands). walking = CARLA's own walk
animation (``WalkerControl``). texting_walk (a behaviour's moving pose) = distracted's upper body;
with ``blend_pose(1.0)`` CARLA may hold the legs still while the walker moves (not verified).

A pose is a set of rotation offsets (degrees, added to pitch / yaw / roll of a bone's transform
relative to its parent) for bones found by name in ``walker.get_bones()`` (case-insensitive
keywords, so no name is hard-coded: CARLA's skeletons call them e.g. ``crl_neck__C``,
``crl_foreArm__L``). The offsets are applied with ``set_bones(WalkerBoneControlIn([...]))`` and
shown with ``blend_pose(1.0)`` (custom pose only).

Not verified: without a server the axes of CARLA's bone frames could not be checked, so the
offsets' signs and sizes are a best reading of the skeleton, to be tuned against a server (see
docs/carla.md). ``CarlaOptions(pose_walkers=False)`` leaves the walkers in their animation.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import ModuleType
from typing import Any

__all__ = ["BONE_POSES", "BoneOffset", "bone_targets", "pose_walker"]


@dataclass(frozen=True)
class BoneOffset:
    """Rotation offsets (degrees) for the bones whose lower-cased name contains every ``keywords``
    entry and none of ``exclude``."""

    keywords: tuple[str, ...]
    pitch: float = 0.0
    yaw: float = 0.0
    roll: float = 0.0
    exclude: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not self.keywords or not all(isinstance(k, str) and k for k in self.keywords):
            raise ValueError(f"keywords must be non-empty strings, got {self.keywords!r}")
        for name in ("pitch", "yaw", "roll"):
            if not -180.0 <= getattr(self, name) <= 180.0:
                raise ValueError(f"{name} must be in [-180, 180] degrees, got {getattr(self, name)!r}")

    def matches(self, bone: str) -> bool:
        b = bone.lower()
        return all(k in b for k in self.keywords) and not any(e in b for e in self.exclude)


_TEXTING = (
    BoneOffset(("neck",), pitch=20.0),
    BoneOffset(("head",), pitch=15.0),
    BoneOffset(("arm", "__l"), pitch=-10.0, exclude=("fore",)),
    BoneOffset(("arm", "__r"), pitch=-10.0, exclude=("fore",)),
    BoneOffset(("forearm", "__l"), yaw=-80.0),
    BoneOffset(("forearm", "__r"), yaw=80.0),
)

BONE_POSES: dict[str, tuple[BoneOffset, ...]] = {
    "attentive": (),
    "walking": (),
    "distracted": _TEXTING,
    "texting_walk": _TEXTING,
}


def bone_targets(bones: Any, pose: str) -> list[tuple[str, tuple[float, float, float], tuple[float, float, float]]]:
    """For the bones of ``walker.get_bones()`` (``bone_transforms`` with ``name`` and ``relative``):
    (name, location (x, y, z), rotation (pitch, yaw, roll) in degrees) of each bone the pose moves,
    its relative transform plus the pose's offsets. Empty for a pose that keeps the animation."""
    if pose not in BONE_POSES:
        raise ValueError(f"pose must be one of {tuple(BONE_POSES)}, got {pose!r}")
    out = []
    for bone in bones.bone_transforms:
        name = str(bone.name)
        offsets = [o for o in BONE_POSES[pose] if o.matches(name)]
        if not offsets:
            continue
        rel = bone.relative
        loc = (float(rel.location.x), float(rel.location.y), float(rel.location.z))
        rot = (
            float(rel.rotation.pitch) + sum(o.pitch for o in offsets),
            float(rel.rotation.yaw) + sum(o.yaw for o in offsets),
            float(rel.rotation.roll) + sum(o.roll for o in offsets),
        )
        out.append((name, loc, rot))
    return out


def pose_walker(carla: ModuleType | Any, walker: Any, pose: str) -> int:
    """Pose ``walker`` (a carla.Walker) as trustnav's ``pose``; returns the number of bones set
    (0: the walker shows its animation, a pose set before released)."""
    targets = bone_targets(walker.get_bones(), pose)
    if not targets:
        walker.blend_pose(0.0)
        return 0
    c = carla
    control = c.WalkerBoneControlIn(
        [(name, c.Transform(c.Location(x=l[0], y=l[1], z=l[2]), c.Rotation(pitch=r[0], yaw=r[1], roll=r[2])))
         for name, l, r in targets]
    )  # fmt: skip
    walker.set_bones(control)
    walker.blend_pose(1.0)
    return len(targets)
