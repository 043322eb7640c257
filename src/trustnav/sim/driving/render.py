"""Camera frames of the driving world, drawn on the CPU by PyBullet's TinyRenderer.

:class:`PyBulletRenderer` builds the street once (:class:`StreetSpec`: a textured road with lane
and edge markings along a centre line, kerbs, paved sidewalks, grass, box buildings with windows,
lamp poles; the sky is a gradient painted where no geometry is hit; long surfaces are cut into
~6 m pieces, since TinyRenderer's time goes into scanning each triangle's screen box) and one
mannequin of 31 parts per pedestrian (head with hair, eyes, brows, nose, mouth and ears; neck, torso, pelvis,
limbs, hands, shoes; a phone when held), re-posed from a :class:`~.body.Skeleton` for each frame.
All shapes are meshes made here; nothing is read from ``pybullet_data`` or downloaded (the four
small textures are written to a temporary folder, loaded and deleted).
"""

from __future__ import annotations

import itertools
import math
import os
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.geometry.camera import CameraPose
from trustnav.sim.driving.body import Appearance, Skeleton, body_dims
from trustnav.sim.driving.street import StreetSpec

__all__ = ["PyBulletRenderer", "Renderer", "StreetSpec"]

Mesh = tuple[list[list[float]], list[int], list[list[float]], list[list[float]]]  # vertices, indices, normals, uvs
RGB = tuple[float, float, float]

NEAR_CLIP = 0.15
HIDDEN = [0.0, 0.0, -50.0]  # where unused parts wait, below the ground
FAR_CLIP = 300.0
SKY_HORIZON: RGB = (0.86, 0.90, 0.94)
SKY_ZENITH: RGB = (0.42, 0.62, 0.88)


class Renderer(Protocol):
    """Draws a camera frame of the street with the given people."""

    def render(self, camera: CameraPose, people: Sequence[tuple[Skeleton, Appearance]]) -> NDArray[np.uint8]:
        """(H, W, 3) uint8 RGB."""
        ...


# ----------------------------------------------------------------------------- meshes


def _ellipsoid_mesh(n: int = 10) -> Mesh:
    """Unit sphere (scale it into an ellipsoid with meshScale)."""
    verts, norms, uvs, idx = [], [], [], []
    m = 2 * n
    for i in range(n + 1):
        th = math.pi * i / n
        for j in range(m + 1):
            ph = 2.0 * math.pi * j / m
            v = [math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)]
            verts.append(v)
            norms.append(v)
            uvs.append([j / m, i / n])
    for i in range(n):
        for j in range(m):
            a, b = i * (m + 1) + j, i * (m + 1) + j + 1
            c, d = a + m + 1, b + m + 1
            idx += [a, c, b, b, c, d]
    return verts, idx, norms, uvs


def _loft_mesh(sections: Sequence[tuple[float, float, float]], n: int = 16, power: float = 2.5) -> Mesh:
    """A closed solid along z through superelliptic cross-sections (z, half-depth x, half-width y)."""
    verts, norms, uvs, idx = [], [], [], []
    m = n
    ring = []
    for k in range(m):
        a = 2.0 * math.pi * k / m
        c, s = math.cos(a), math.sin(a)
        ring.append((math.copysign(abs(c) ** (2.0 / power), c), math.copysign(abs(s) ** (2.0 / power), s), c, s))
    for z, hx, hy in sections:
        for cx, cy, c, s in ring:
            verts.append([hx * cx, hy * cy, z])
            nn = np.array([c / max(hx, 1e-3), s / max(hy, 1e-3), 0.0])
            norms.append(list(nn / np.linalg.norm(nn)))
            uvs.append([0.0, 0.0])
    for r in range(len(sections) - 1):
        for k in range(m):
            a, b = r * m + k, r * m + (k + 1) % m
            c, d = a + m, b + m
            idx += [a, b, c, b, d, c]
    for cap, z, sign in ((0, sections[0][0], -1.0), (len(sections) - 1, sections[-1][0], 1.0)):
        centre = len(verts)
        verts.append([0.0, 0.0, z])
        norms.append([0.0, 0.0, sign])
        uvs.append([0.0, 0.0])
        for k in range(m):
            a, b = cap * m + k, cap * m + (k + 1) % m
            idx += [centre, b, a] if sign < 0 else [centre, a, b]
    return verts, idx, norms, uvs


def _capsule_mesh(r0: float, r1: float, length: float, n: int = 10) -> Mesh:
    """A tapered capsule from z = 0 (radius r0) to z = length (radius r1)."""
    sections: list[tuple[float, float, float]] = []
    for i in range(n // 2 + 1):  # bottom cap
        a = -0.5 * math.pi + math.pi * i / n
        sections.append((r0 * math.sin(a), r0 * math.cos(a) + 1e-4, r0 * math.cos(a) + 1e-4))
    for i in range(n // 2 + 1):  # top cap
        a = math.pi * i / n
        sections.append((length + r1 * math.sin(a), r1 * math.cos(a) + 1e-4, r1 * math.cos(a) + 1e-4))
    return _loft_mesh(sections, n=2 * n, power=2.0)


def _box_mesh(hx: float, hy: float, hz: float, tile: tuple[float, float] | None = None, cell: float = 0.0) -> Mesh:
    """Box of half extents (hx, hy, hz) centred at the origin. Side uv in units of ``tile`` metres
    (the texture repeats; top and bottom get one texel); faces cut into about ``cell``-metre
    pieces when ``cell`` > 0 (TinyRenderer is faster on small triangles)."""
    verts, norms, uvs, idx = [], [], [], []
    faces = [
        ((1, 0, 0), (0, 1, 0), hy, hz, hx),
        ((-1, 0, 0), (0, -1, 0), hy, hz, hx),
        ((0, 1, 0), (-1, 0, 0), hx, hz, hy),
        ((0, -1, 0), (1, 0, 0), hx, hz, hy),
        ((0, 0, 1), (1, 0, 0), hx, hy, hz),
        ((0, 0, -1), (-1, 0, 0), hx, hy, hz),
    ]
    for normal, tangent, hu, hv, off in faces:
        nrm, tan = np.array(normal, float), np.array(tangent, float)
        bit = np.cross(nrm, tan)
        nu = max(1, math.ceil(2.0 * hu / cell)) if cell > 0 else 1
        nv = max(1, math.ceil(2.0 * hv / cell)) if cell > 0 else 1
        base = len(verts)
        for j in range(nv + 1):
            sv = -1.0 + 2.0 * j / nv
            for i in range(nu + 1):
                su = -1.0 + 2.0 * i / nu
                verts.append(list(nrm * off + tan * su * hu + bit * sv * hv))
                norms.append(list(nrm))
                if tile is not None and normal[2] == 0:
                    uvs.append([(su + 1) * hu / tile[0], (1 - sv) * hv / tile[1]])
                else:
                    uvs.append([0.01, 0.01])
        for j in range(nv):
            for i in range(nu):
                a = base + j * (nu + 1) + i
                b, c, d = a + 1, a + nu + 2, a + nu + 1
                idx += [a, b, c, a, c, d]
    return verts, idx, norms, uvs


def _quads_mesh(quads: Sequence[NDArray[np.float64]], tile: float | None = None) -> Mesh:
    """Planar quads (each (4, 3), counter-clockwise seen from the side they face) in one mesh;
    uv = world xy / tile (for textured ground)."""
    verts, norms, uvs, idx = [], [], [], []
    for q in quads:
        base = len(verts)
        n = np.cross(q[1] - q[0], q[3] - q[0])
        n = n / np.linalg.norm(n)
        for p in q:
            verts.append([float(v) for v in p])
            norms.append([float(v) for v in n])
            uvs.append([p[0] / tile, p[1] / tile] if tile else [0.5, 0.5])
        idx += [base, base + 1, base + 2, base, base + 2, base + 3]
    return verts, idx, norms, uvs


# ----------------------------------------------------------------------------- maths


def _quat(rot: NDArray[np.float64]) -> list[float]:
    """Rotation matrix -> quaternion (x, y, z, w)."""
    m = rot
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s]
    return [float(v) for v in q]


def _frame_z(axis: NDArray[np.float64], hint: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation whose z column is ``axis`` and whose x column is as close to ``hint`` as possible."""
    z = axis / np.linalg.norm(axis)
    x = hint - (hint @ z) * z
    if np.linalg.norm(x) < 1e-6:
        x = np.array([1.0, 0.0, 0.0]) - z[0] * z
        if np.linalg.norm(x) < 1e-6:
            x = np.array([0.0, 1.0, 0.0]) - z[1] * z
    x = x / np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def _frame_x(axis: NDArray[np.float64], up: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation whose x column is ``axis`` and whose z column is as close to ``up`` as possible."""
    x = axis / np.linalg.norm(axis)
    z = up - (up @ x) * x
    if np.linalg.norm(z) < 1e-6:
        z = np.array([0.0, 0.0, 1.0]) - x[2] * x
        if np.linalg.norm(z) < 1e-6:
            z = np.array([1.0, 0.0, 0.0]) - x[0] * x
    z = z / np.linalg.norm(z)
    return np.stack([x, np.cross(z, x), z], axis=1)


def _shade(c: RGB, k: float) -> RGB:
    return (min(1.0, c[0] * k), min(1.0, c[1] * k), min(1.0, c[2] * k))


# ----------------------------------------------------------------------------- people


@dataclass(frozen=True)
class _Part:
    """One rigid piece of a mannequin: its mesh, colour, and where it goes for a skeleton."""

    mesh: Mesh
    scale: tuple[float, float, float]
    colour: RGB
    place: Callable[[Skeleton], tuple[NDArray[np.float64], NDArray[np.float64]] | None]


def _mannequin(appearance: Appearance) -> list[_Part]:
    """The parts of one pedestrian (shapes sized for its height)."""
    dims = body_dims(appearance)
    s = dims.s
    sph = _ellipsoid_mesh(10)
    sph_small = _ellipsoid_mesh(6)
    skin, hair, shirt, trousers, shoes = (
        appearance.skin,
        appearance.hair,
        appearance.shirt,
        appearance.trousers,
        appearance.shoes,
    )
    face = dims.face()
    parts: list[_Part] = []

    def head_point(local: ArrayLike) -> Callable[[Skeleton], tuple[NDArray, NDArray]]:
        off = np.asarray(local, dtype=float) * s

        def place(sk: Skeleton) -> tuple[NDArray, NDArray]:
            return sk.head_centre + sk.head_rot @ off, sk.head_rot

        return place

    def feature(mesh: Mesh, semi: tuple[float, float, float], colour: RGB, at: ArrayLike) -> None:
        parts.append(_Part(mesh, tuple(v * s for v in semi), colour, head_point(at)))

    # head: skull, hair cap, face
    feature(sph, (0.098, 0.082, 0.112), skin, (0.0, 0.0, 0.0))
    feature(sph, (0.094, 0.086, 0.100), hair, (-0.020, 0.0, 0.030))
    for side in (1.0, -1.0):
        eye = face["left_eye"] / s * np.array([1.0, side, 1.0])
        feature(sph_small, (0.010, 0.014, 0.0075), (0.95, 0.95, 0.94), eye + (0.004, 0.0, 0.0))
        feature(sph_small, (0.006, 0.0075, 0.0075), (0.09, 0.06, 0.04), eye + (0.0105, 0.0, 0.0))
        feature(sph_small, (0.008, 0.021, 0.0045), _shade(hair, 0.8), eye + (0.004, 0.002, 0.026))
        ear = face["left_ear"] / s * np.array([1.0, side, 1.0])
        feature(sph_small, (0.016, 0.013, 0.029), _shade(skin, 0.93), ear)
    feature(sph_small, (0.020, 0.013, 0.024), _shade(skin, 0.92), face["nose"] / s + (-0.004, 0.0, 0.004))
    feature(sph_small, (0.006, 0.023, 0.0055), (0.62, 0.28, 0.28), (0.087, 0.0, -0.050))

    # neck: from the top of the torso to the head's pivot
    neck_len = 0.13 * s
    head_offset = dims.head_centre

    def neck(sk: Skeleton) -> tuple[NDArray, NDArray]:
        top = sk.head_centre - sk.head_rot @ head_offset
        base = top - sk.body_rot[:, 2] * (neck_len - 0.02 * s)
        return base, _frame_z(top - base, sk.body_rot[:, 0])

    parts.append(_Part(_capsule_mesh(0.046 * s, 0.044 * s, neck_len, 8), (1.0, 1.0, 1.0), skin, neck))

    # torso (shirt) and pelvis (trousers), in the torso frame from the pelvis
    chest = _loft_mesh(
        [
            (0.00, 0.100, 0.156),
            (0.12, 0.094, 0.148),
            (0.25, 0.102, 0.158),
            (0.37, 0.110, 0.174),
            (0.445, 0.104, 0.186),
            (0.485, 0.090, 0.176),
            (0.515, 0.068, 0.125),
            (0.54, 0.048, 0.068),
        ]
    )
    pelvis = _loft_mesh([(-0.11, 0.070, 0.120), (-0.06, 0.095, 0.160), (0.02, 0.100, 0.160), (0.06, 0.097, 0.156)])

    def torso(sk: Skeleton) -> tuple[NDArray, NDArray]:
        return sk.pelvis, sk.body_rot

    parts.append(_Part(chest, (s, s, s), shirt, torso))
    parts.append(_Part(pelvis, (s, s, s), trousers, torso))

    # limbs: tapered capsules between joints
    def segment(a: int, b: int, r0: float, r1: float, colour: RGB, length: float) -> None:
        def place(sk: Skeleton) -> tuple[NDArray, NDArray]:
            pa, pb = sk.joints[a], sk.joints[b]
            return pa, _frame_z(pb - pa, sk.body_rot[:, 0])

        parts.append(_Part(_capsule_mesh(r0 * s, r1 * s, length, 8), (1.0, 1.0, 1.0), colour, place))

    for j in (5, 6):  # shoulders
        parts.append(
            _Part(
                sph,
                (0.050 * s, 0.052 * s, 0.046 * s),
                shirt,
                lambda sk, j=j: (sk.joints[j] - sk.body_rot[:, 2] * 0.018 * s, sk.body_rot),
            )
        )
    for sh, el, wr in ((5, 7, 9), (6, 8, 10)):
        segment(sh, el, 0.049, 0.041, shirt, dims.upper_arm)
        segment(el, wr, 0.038, 0.030, skin, dims.forearm)
    for k, wr in ((0, 9), (1, 10)):

        def hand(sk: Skeleton, k: int = k, wr: int = wr) -> tuple[NDArray, NDArray]:
            return sk.hands[k], _frame_x(sk.hands[k] - sk.joints[wr], sk.body_rot[:, 2])

        parts.append(_Part(sph_small, (0.052 * s, 0.020 * s, 0.042 * s), skin, hand))
    for hp, kn, an in ((11, 13, 15), (12, 14, 16)):
        segment(hp, kn, 0.078, 0.056, trousers, dims.thigh)
        segment(kn, an, 0.054, 0.042, trousers, dims.shin)
    for k, an in ((0, 15), (1, 16)):

        def shoe(sk: Skeleton, k: int = k, an: int = an) -> tuple[NDArray, NDArray]:
            ankle, toe = sk.joints[an], sk.toes[k]
            heel = ankle - 0.045 * s * (toe - ankle) / np.linalg.norm(toe - ankle)
            centre = 0.5 * (heel + toe) + np.array([0.0, 0.0, 0.005 * s])
            return centre, _frame_x(toe - heel, np.array([0.0, 0.0, 1.0]))

        length = 0.5 * (dims.foot + 0.045 * s) + 0.02 * s
        parts.append(_Part(sph, (length, 0.050 * s, 0.045 * s), shoes, shoe))

    # phone: dark body with a bright screen, only when held
    def phone(offset: float) -> Callable[[Skeleton], tuple[NDArray, NDArray] | None]:
        def place(sk: Skeleton) -> tuple[NDArray, NDArray] | None:
            if sk.phone is None or sk.phone_rot is None:
                return None
            return sk.phone + sk.phone_rot[:, 2] * offset, sk.phone_rot

        return place

    parts.append(_Part(_box_mesh(0.078, 0.037, 0.005), (s, s, s), (0.07, 0.07, 0.08), phone(0.0)))
    parts.append(_Part(_box_mesh(0.070, 0.032, 0.001), (s, s, s), (0.55, 0.72, 0.95), phone(0.006 * s)))
    return parts


@dataclass(frozen=True)
class _Mannequin:
    """A pedestrian's parts and the PyBullet bodies drawing them."""

    parts: list[_Part]
    bodies: list[int]


# ----------------------------------------------------------------------------- renderer


class PyBulletRenderer:
    """:class:`Renderer` on PyBullet's TinyRenderer (``p.DIRECT``, CPU only).

    The street is built on construction (~0.3 s); mannequins are made the first time an
    appearance is drawn (one per person wearing it), kept, and re-posed for each frame by moving
    their parts (~2 ms for two people); a 1280 x 720 frame takes ~0.3 s on one core (``shadows``:
    about twice that, and barely visible). Close it (or use it as a context manager) to disconnect
    PyBullet.
    """

    def __init__(self, street: StreetSpec | None = None, *, shadows: bool = False) -> None:
        from trustnav.perception.frames import quiet_stderr

        with quiet_stderr():  # PyBullet prints its build time to stderr when it loads
            import pybullet

            self.street = street or StreetSpec()
            self.shadows = shadows
            self._p: Any = pybullet
            self._cid: int | None = self._p.connect(self._p.DIRECT)
        self._people: dict[Appearance, list[_Mannequin]] = {}
        self._textures: dict[str, int] = {}
        try:
            self._load_textures()
            self._build_street()
        except BaseException:
            self.close()
            raise

    # -- lifecycle
    def close(self) -> None:
        """Disconnect PyBullet (idempotent)."""
        if self._cid is not None:
            try:
                self._p.disconnect(physicsClientId=self._cid)
            finally:
                self._cid = None

    def __enter__(self) -> PyBulletRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass

    @property
    def client(self) -> int:
        if self._cid is None:
            raise RuntimeError("renderer is closed")
        return self._cid

    # -- building blocks
    def _visual(self, mesh: Mesh, scale: tuple[float, float, float], colour: RGB) -> int:
        verts, idx, norms, uvs = mesh
        shape = self._p.createVisualShape(
            self._p.GEOM_MESH,
            vertices=verts,
            indices=idx,
            normals=norms,
            uvs=uvs,
            meshScale=list(scale),
            rgbaColor=[*colour, 1.0],
            physicsClientId=self.client,
        )
        if shape < 0:
            raise RuntimeError("pybullet could not create a visual shape")
        return shape

    def _body(
        self,
        mesh: Mesh,
        colour: RGB,
        position: ArrayLike = (0.0, 0.0, 0.0),
        rot: NDArray[np.float64] | None = None,
        scale: tuple[float, float, float] = (1.0, 1.0, 1.0),
        texture: str | None = None,
    ) -> int:
        shape = self._visual(mesh, scale, colour)
        body = self._p.createMultiBody(
            baseMass=0.0,
            baseVisualShapeIndex=shape,
            basePosition=[float(v) for v in position],
            baseOrientation=_quat(np.eye(3) if rot is None else rot),
            physicsClientId=self.client,
        )
        if texture is not None:
            self._p.changeVisualShape(
                body, -1, textureUniqueId=self._textures[texture], rgbaColor=[*colour, 1.0], physicsClientId=self.client
            )
        return body

    def _load_textures(self) -> None:
        rng = np.random.default_rng(self.street.seed + 7)
        textures: dict[str, NDArray[np.uint8]] = {}
        n = 128
        # asphalt: grey noise, blurred a little
        noise = rng.normal(0.0, 1.0, (n, n))
        noise = 0.5 * noise + 0.125 * (np.roll(noise, 1, 0) + np.roll(noise, -1, 0) + np.roll(noise, 1, 1))
        asphalt = np.clip(200 + 22 * noise, 0, 255)
        textures["asphalt"] = np.repeat(asphalt[..., None], 3, axis=2).astype(np.uint8)
        # paving: square slabs with joints
        slab = np.clip(225 + 10 * rng.normal(0.0, 1.0, (n, n)), 0, 255)
        slab[:: n // 4, :] = 150
        slab[:, :: n // 4] = 150
        textures["paving"] = np.repeat(slab[..., None], 3, axis=2).astype(np.uint8)
        # grass: green noise (tinted by the body colour)
        g = np.clip(215 + 35 * rng.normal(0.0, 1.0, (n, n)), 0, 255)
        textures["grass"] = np.repeat(g[..., None], 3, axis=2).astype(np.uint8)
        # facade: one storey (3 m) x one bay (3 m) with a window
        facade = np.full((n, n, 3), 235, np.uint8)
        facade[int(0.28 * n) : int(0.78 * n), int(0.22 * n) : int(0.78 * n)] = (70, 85, 105)
        facade[int(0.52 * n) : int(0.54 * n), int(0.22 * n) : int(0.78 * n)] = (200, 200, 200)
        facade[int(0.28 * n) : int(0.78 * n), int(0.49 * n) : int(0.51 * n)] = (200, 200, 200)
        textures["facade"] = facade
        from PIL import Image

        with tempfile.TemporaryDirectory(prefix="trustnav-tex-") as tmp:
            for name, img in textures.items():
                path = os.path.join(tmp, f"{name}.png")
                Image.fromarray(img).save(path)
                tex = self._p.loadTexture(path, physicsClientId=self.client)
                if tex < 0:
                    raise RuntimeError(f"pybullet could not load the {name} texture")
                self._textures[name] = tex

    def _build_street(self) -> None:
        st = self.street
        d = st.direction
        nrm = np.array([-d[1], d[0]])  # left of the driving direction
        a0 = np.asarray(st.start) - st.extend * d
        total = st.length + 2.0 * st.extend

        def at(s: float, lat: float, z: float) -> NDArray[np.float64]:
            p = a0 + s * d + lat * nrm
            return np.array([p[0], p[1], z])

        def strip(s0: float, s1: float, l0: float, l1: float, z: float, step: float = 6.0) -> list[NDArray]:
            """Ground between s0..s1 along the road and l0..l1 across it, facing up, cut into
            pieces: TinyRenderer scans each triangle's whole screen box, so long ones are slow."""
            quads = []
            ss = np.linspace(s0, s1, max(1, math.ceil((s1 - s0) / step)) + 1)
            ls = np.linspace(l0, l1, max(1, math.ceil(abs(l1 - l0) / (4.0 * step))) + 1)
            for a, b in itertools.pairwise(ss):
                for c, e in itertools.pairwise(ls):
                    q = np.stack([at(a, c, z), at(b, c, z), at(b, e, z), at(a, e, z)])
                    e1, e2 = q[1] - q[0], q[3] - q[0]
                    quads.append(q if (e1[0] * e2[1] - e1[1] * e2[0]) > 0 else q[[0, 3, 2, 1]])
            return quads

        def wall(s0: float, s1: float, lat: float, z0: float, z1: float, facing: float) -> list[NDArray]:
            """A low vertical face along the road at ``lat``, facing +-lateral, in pieces."""
            quads = []
            ss = np.linspace(s0, s1, max(1, math.ceil((s1 - s0) / 6.0)) + 1)
            for a, b in itertools.pairwise(ss):
                q = np.stack([at(a, lat, z0), at(b, lat, z0), at(b, lat, z1), at(a, lat, z1)])
                n = np.cross(q[1] - q[0], q[3] - q[0])
                quads.append(q if n[:2] @ (facing * nrm) > 0 else q[[0, 3, 2, 1]])
            return quads

        half = 0.5 * st.road_width
        kh = st.kerb_height
        edge = half + 0.2 + st.sidewalk_width
        # grass around the street, not under it (TinyRenderer's time goes into filling pixels)
        far = 200.0
        grass = [q for side in (1.0, -1.0) for q in strip(-far, total + far, side * edge, side * (edge + far), -0.04)]
        grass += strip(-far, 0.0, -edge, edge, -0.04) + strip(total, total + far, -edge, edge, -0.04)
        self._body(_quads_mesh(grass, tile=2.0), (0.36, 0.55, 0.25), texture="grass")
        # road
        self._body(_quads_mesh(strip(0.0, total, -half, half, 0.0), tile=3.0), (0.42, 0.42, 0.43), texture="asphalt")
        # markings: dashed centre line (3 m dash, 6 m gap), solid edge lines
        marks = [q for s in np.arange(0.0, total, 9.0) for q in strip(s, s + 3.0, -0.07, 0.07, 0.02)]
        for side in (1.0, -1.0):
            marks += strip(0.0, total, side * (half - 0.35), side * (half - 0.22), 0.02)
        self._body(_quads_mesh(marks), (0.93, 0.93, 0.90))
        # kerbs (top and the face toward the road) and sidewalks with their outer edge
        kerbs, edges, walks = [], [], []
        for side in (1.0, -1.0):
            kerbs += strip(0.0, total, side * half, side * (half + 0.2), kh)
            kerbs += wall(0.0, total, side * half, 0.0, kh, -side)
            if st.sidewalk_width > 0:
                walks += strip(0.0, total, side * (half + 0.2), side * edge, kh)
                edges += wall(0.0, total, side * edge, -0.04, kh, side)
        self._body(_quads_mesh(kerbs), (0.80, 0.80, 0.78))
        if walks:
            self._body(_quads_mesh(walks, tile=2.4), (0.78, 0.76, 0.72), texture="paving")
            self._body(_quads_mesh(edges), (0.62, 0.62, 0.60))
        rng = np.random.default_rng(st.seed)
        if st.poles:
            pole = _capsule_mesh(0.07, 0.06, 6.5, 8)
            arm = _box_mesh(0.8, 0.05, 0.05)
            lamp = _box_mesh(0.25, 0.12, 0.06)
            start = rng.uniform(0.0, 30.0)
            for k, s in enumerate(np.arange(start, total, 30.0)):
                side = 1.0 if k % 2 == 0 else -1.0
                base = at(s, side * (edge - 0.35), kh)
                self._body(pole, (0.32, 0.33, 0.35), base)
                rot = np.eye(3)
                rot[:2, 0], rot[:2, 1] = -side * nrm, side * d
                self._body(arm, (0.32, 0.33, 0.35), at(s, side * (edge - 1.1), kh + 6.4), rot)
                self._body(lamp, (0.85, 0.85, 0.75), at(s, side * (edge - 1.8), kh + 6.35), rot)
        if st.buildings:
            palette = [
                (0.80, 0.72, 0.60),
                (0.70, 0.55, 0.45),
                (0.85, 0.84, 0.80),
                (0.60, 0.62, 0.66),
                (0.78, 0.66, 0.52),
                (0.66, 0.70, 0.62),
            ]
            for side in (1.0, -1.0):
                s = rng.uniform(-20.0, 0.0)
                while s < total + 20.0:
                    length = rng.uniform(9.0, 22.0)
                    depth = rng.uniform(10.0, 18.0)
                    height = 3.0 * rng.integers(2, 8) + 0.6
                    setback = edge + rng.uniform(2.0, 6.0)
                    centre = at(s + 0.5 * length, side * (setback + 0.5 * depth), 0.5 * height - 0.05)
                    rot = np.eye(3)
                    rot[:2, 0], rot[:2, 1] = d, nrm
                    colour = palette[int(rng.integers(len(palette)))]
                    box = _box_mesh(0.5 * length, 0.5 * depth, 0.5 * height, tile=(3.0, 3.0))
                    self._body(box, colour, centre, rot, texture="facade")
                    s += length + rng.uniform(2.0, 7.0)

    # -- people
    def _mannequin_bodies(self, appearance: Appearance) -> _Mannequin:
        parts = _mannequin(appearance)
        bodies = []
        for part in parts:
            shape = self._visual(part.mesh, part.scale, part.colour)
            bodies.append(
                self._p.createMultiBody(
                    baseMass=0.0, baseVisualShapeIndex=shape, basePosition=HIDDEN, physicsClientId=self.client
                )
            )
        return _Mannequin(parts, bodies)

    def _pose(self, man: _Mannequin, skeleton: Skeleton) -> None:
        # stand on the surface: a body built at z = 0 on a sidewalk is lifted onto it
        soles = float(min(skeleton.joints[15:17, 2].min() - 0.085 * skeleton.height / 1.75, skeleton.toes[:, 2].min()))
        lift = max(0.0, self.street.ground_height(skeleton.pelvis[:2]) - soles - 0.01)
        for part, body in zip(man.parts, man.bodies, strict=True):
            placed = part.place(skeleton)
            if placed is None:
                pos, quat = HIDDEN, [0.0, 0.0, 0.0, 1.0]
            else:
                pos, quat = [float(placed[0][0]), float(placed[0][1]), float(placed[0][2]) + lift], _quat(placed[1])
            self._p.resetBasePositionAndOrientation(body, pos, quat, physicsClientId=self.client)

    def _hide(self, man: _Mannequin) -> None:
        for body in man.bodies:
            self._p.resetBasePositionAndOrientation(body, HIDDEN, [0, 0, 0, 1], physicsClientId=self.client)

    def _place_people(self, people: Sequence[tuple[Skeleton, Appearance]]) -> None:
        """Pose one mannequin per person: mannequins are pooled by appearance and made on first
        need, so people may come and go or change order between frames at no cost."""
        used: dict[Appearance, int] = {}
        for skeleton, appearance in people:
            if skeleton.head_centre is None or skeleton.head_rot is None or skeleton.body_rot is None:
                raise ValueError("skeleton lacks the renderer's fields (make it with pedestrian_skeleton)")
            pool = self._people.setdefault(appearance, [])
            k = used.get(appearance, 0)
            if k == len(pool):
                pool.append(self._mannequin_bodies(appearance))
            used[appearance] = k + 1
            self._pose(pool[k], skeleton)
        for appearance, pool in self._people.items():
            for man in pool[used.get(appearance, 0) :]:
                self._hide(man)

    def render(self, camera: CameraPose, people: Sequence[tuple[Skeleton, Appearance]]) -> NDArray[np.uint8]:
        """Draw the frame seen by ``camera`` with ``people`` posed: (H, W, 3) uint8 RGB."""
        self._place_people(people)
        spec = camera.spec
        w, h = spec.width, spec.height
        if spec.principal != (0.5 * w, 0.5 * h):
            raise ValueError(
                f"the renderer draws the principal point at the image centre, got (cx, cy) = {spec.principal}"
            )
        view = self._p.computeViewMatrix(
            cameraEyePosition=[float(v) for v in camera.position],
            cameraTargetPosition=[float(v) for v in camera.look_target()],
            cameraUpVector=[float(v) for v in camera.up],
        )
        proj = self._p.computeProjectionMatrixFOV(spec.vfov_deg, w / h, NEAR_CLIP, FAR_CLIP)
        _, _, rgba, _, seg = self._p.getCameraImage(
            w,
            h,
            view,
            proj,
            renderer=self._p.ER_TINY_RENDERER,
            lightDirection=list(self.street.sun),
            lightColor=[1.0, 1.0, 0.97],
            lightAmbientCoeff=self.street.ambient,
            lightDiffuseCoeff=self.street.diffuse,
            lightSpecularCoeff=0.04,
            shadow=1 if self.shadows else 0,
            physicsClientId=self.client,
        )
        image = np.asarray(rgba, dtype=np.uint8).reshape(h, w, 4)[..., :3].copy()
        sky = np.asarray(seg).reshape(h, w) < 0
        if sky.any():
            image[sky] = _sky(camera, h)[np.nonzero(sky)[0]]
        return image


def _sky(camera: CameraPose, height: int) -> NDArray[np.uint8]:
    """(height, 3) sky colour per image row: horizon haze to zenith blue by elevation."""
    v = np.arange(height) + 0.5
    elev = camera.pitch * -1.0 + np.arctan((0.5 * height - v) / camera.focal_px)
    t = np.clip(elev / math.radians(35.0), 0.0, 1.0) ** 0.7
    c = (1.0 - t)[:, None] * np.array(SKY_HORIZON) + t[:, None] * np.array(SKY_ZENITH)
    return np.round(255.0 * c).astype(np.uint8)
