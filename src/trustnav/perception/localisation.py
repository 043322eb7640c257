"""Monocular ground-plane localisation: where a detected person stands, with its covariance.

One camera, one frame, one person: the 17 COCO keypoints are the image of a standing body whose
joints lie at known fractions of its stature above the soles (anthropometric ratios: eyes 0.936,
shoulders 0.818, hips 0.53, knees 0.285, ankles ~0.04-0.05; Drillis & Contini 1966, Winter's
*Biomechanics*; the renderer's bodies agree within 0.01). The ratios used are where the detector
*reports* those joints: BlazePose places them higher than the true joints by a share of the
person's height (ankles +0.040, knees +0.017, nose +0.028, eyes +0.022; measured on 334 rendered
people 8-30 m away, ``benchmarks/calibrate_keypoints.py``). The body's centre line (u of the
midpoints of the left/right pairs) and every joint's v are fitted by weighted least squares in the
pixels for five unknowns:

* the ground position (x, y) of the person, on the surface the map gives there (road, or a
  sidewalk raised by its kerb: ``ground_height(xy)``);
* the stature H, with the prior N(``stature``, ``stature_sigma``^2): the body's pixel size then
  says how far it is (the height prior of MonoLoco, Bertoni et al., ICCV 2019, in closed form);
* a pitch offset of the camera, with the prior N(0, ``pitch_sigma``^2) (braking, bumps): where the
  soles meet the ground says how far the person is (the flat-ground model) only as far as the
  pitch is known, so an uncertain pitch hands the range over to the height prior;
* an offset of both ankles (share of the stature) with the prior N(0, ``foot_sigma``^2): the
  detector's bias at the feet differs from person to person and pose to pose (the texting pose's
  ankles 6-8 % of the height above the truth where the median is 4 %) and repeats in every frame
  of that person, so it is one unknown of the body, not noise of each joint.

On rendered frames the detector's joints also sit a constant 0.2-1.8 px higher than a share of the
stature says (:data:`DETECTOR_PIXEL_BIAS`, ``pixel_bias``): in shares of the height that is more
for a far, small person than a near one, and without it people beyond 18 m were placed long and
nearer ones short (issue 34 item 4, eighth pass).

The fit's covariance (Gauss-Newton, (J' W J + priors)^-1) is the estimate's uncertainty: pixel
noise (a share of the person's pixel height, plus a floor), the spread of the body ratios, the
stature prior, the pitch and the feet. The pixels' noise is scaled by the fit's own reduced chi^2
pooled with ``noise_prior_dof`` pseudo-residuals at the model's scale: narrowed for a body that
fits the model closely (an upright stander), widened for one that does not (a body stretched or
squashed, a walker's limbs off the centre line); the priors keep their width (before 26 Nov the
whole covariance grew, the stature prior with it, and a walker's range region was too wide: issue
34). With ``separate_scales`` (off by default; on for the drive's rendered frames, thirteenth
pass) the centre line's u's (the bearing) and the joints' v's (the range) are two variance
components, each scaled by its own chi^2: a stride off the centre line widens the region across the
line of sight, not the range (issue 34 item 4, twelfth pass). The position's marginal 2x2 block is
returned in world coordinates.
Perception imports nothing of the simulator: the camera model is :mod:`trustnav.geometry`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.geometry.camera import CameraPose
from trustnav.perception.types import Person

__all__ = [
    "BODY_POINTS",
    "FixedCameraGround",
    "GroundEstimate",
    "GroundLocaliser",
    "LocaliserConfig",
    "chi2_90",
    "cut_by_image",
    "pose_change",
]

#: The body's centre-line points: (name, COCO joints, height above the soles / stature where the
#: detector reports them (true joint + the detector's median upward bias), spread of that ratio
#: across people, poses (a bowed head, a walking knee) and frames).
BODY_POINTS: tuple[tuple[str, tuple[int, ...], float, float], ...] = (
    ("nose", (0,), 0.930, 0.03),
    ("eyes", (1, 2), 0.952, 0.025),
    ("ears", (3, 4), 0.936, 0.02),
    ("shoulders", (5, 6), 0.815, 0.008),
    ("hips", (11, 12), 0.527, 0.008),
    ("knees", (13, 14), 0.300, 0.01),
    ("ankles", (15, 16), 0.092, 0.008),
)
#: Where the detector reports each body point on rendered frames, as (share of the stature at a
#: large image, pixels up): the reported height above the soles is ``share * H + offset`` pixels,
#: so a far person's joints sit higher in shares of her height than a near one's. Fitted by least
#: squares of the reported ratio on 1 / (image stature) over 2349 person-frames of rendered
#: calibration worlds (55-488 px tall, three poses); it takes the spread left at the shoulders,
#: hips and knees from 0.009-0.013 to 0.007-0.010 of the stature, and removes the range bias the
#: share-only ratios leave (people beyond 18 m placed 0.05-0.2 m long, nearer ones 0.1 m short).
DETECTOR_PIXEL_BIAS: dict[str, tuple[float, float]] = {
    "nose": (0.932, 0.46),
    "eyes": (0.948, 0.21),
    "ears": (0.934, 0.33),
    "shoulders": (0.803, 0.98),
    "hips": (0.507, 1.57),
    "knees": (0.280, 1.76),
    "ankles": (0.081, 1.12),
}

chi2_90 = 4.605  # the 90 % quantile of chi^2 with 2 degrees of freedom (a 2-D Gaussian region)


@dataclass(frozen=True)
class LocaliserConfig:
    """How a person is placed on the ground.

    stature / stature_sigma: the height prior (m; adults' standing height, ~1.70 +- 0.09);
    pitch_sigma_deg: how well the camera's pitch is known (deg; 0 = exactly, a car that brakes
    pitches by 1-2 deg); pixel_sigma: keypoint noise as a share of the person's pixel height,
    pixel_floor: its floor (px); lateral_sigma: how far the centre line wanders sideways (share of
    the stature: a walker's arms and legs); body_sigma: where on the body "the person's
    position" is (m, isotropic: added to the fit's covariance; the truth's error across the line
    of sight is ~1 cm on rendered frames and in keypoint sensing); foot_sigma: the spread of the
    feet's bias from person to person (share of the stature; the detector's ankles on rendered
    people: 0.014 robust spread less the pixels' 0.007; 0 for a sensor without one);
    pixel_bias: the detector's joints as a share of the stature plus a constant pixel offset
    (:data:`DETECTOR_PIXEL_BIAS`; False: shares only, :data:`BODY_POINTS`, for a sensor whose
    error model has no pixel offset); noise_prior_dof: how many pseudo-residuals at the model's
    pixel noise the fit's own reduced chi^2 is pooled with to scale the pixels' noise (4: a body
    that fits better than the model is narrowed, one that fits worse widened; inf: only widened,
    as before 26 Nov); separate_scales: the centre line's u's and the joints' v's each scaled by
    their own reduced chi^2 (so pooled): a stride off the centre line then widens the bearing, not
    the range; False (default): one chi^2 scales all pixels. With the detector's own centre line
    (``lateral_sigma`` 0.01, ``body_sigma`` 0.005) it calibrates the rendered bearing; the drive's
    rendered sensing uses the three with the tracker's range scale, without which the standers
    looked like walkers to the tracker (docs/perceived.md, twelfth and thirteenth passes);
    cut_range_share: the range's sigma, as a share of the distance, added along the line of sight
    for a person whose box the image's edge cuts (beside the camera, or so near that the feet fall
    below the image): the landmark model sees the body in part, in a region the border crops, and
    guesses at the rest (BlazePose placed rendered people cut by the lower edge up to 90 % of
    their range too far with a sigma of 1-2 %); cut_body_sigma: for such a person, where her
    body's centre is (m, isotropic, added as ``body_sigma``: the part of her the image shows is not
    centred on her); both measured by ``benchmarks/cut_bodies.py``, and 0 for a sensor whose
    joints the cut does not move (keypoint sensing). Joints outside the image are never used;
    min_confidence: keypoints below it are not used; max_distance: estimates farther than this
    (m) are refused (a person on the horizon)."""

    stature: float = 1.70
    stature_sigma: float = 0.09
    pitch_sigma_deg: float = 0.5
    pixel_sigma: float = 0.007
    pixel_floor: float = 0.3
    lateral_sigma: float = 0.02
    body_sigma: float = 0.01
    foot_sigma: float = 0.012
    pixel_bias: bool = True
    noise_prior_dof: float = 4.0
    separate_scales: bool = False
    cut_range_share: float = 0.12
    cut_body_sigma: float = 0.05
    min_confidence: float = 0.3
    max_distance: float = 80.0

    def __post_init__(self) -> None:
        checks = (
            ("stature", self.stature, 0.5, 2.5),
            ("stature_sigma", self.stature_sigma, 1e-3, 1.0),
            ("pitch_sigma_deg", self.pitch_sigma_deg, 0.0, 20.0),
            ("pixel_sigma", self.pixel_sigma, 0.0, 0.5),
            ("pixel_floor", self.pixel_floor, 0.01, 100.0),
            ("lateral_sigma", self.lateral_sigma, 0.0, 0.5),
            ("body_sigma", self.body_sigma, 0.0, 2.0),
            ("foot_sigma", self.foot_sigma, 0.0, 0.2),
            ("noise_prior_dof", self.noise_prior_dof, 0.0, math.inf),
            ("cut_range_share", self.cut_range_share, 0.0, 2.0),
            ("cut_body_sigma", self.cut_body_sigma, 0.0, 2.0),
            ("min_confidence", self.min_confidence, 0.0, 1.0),
            ("max_distance", self.max_distance, 1.0, 1e4),
        )
        for name, v, lo, hi in checks:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not lo <= v <= hi:
                raise ValueError(f"{name} must be a number in [{lo}, {hi}], got {v!r}")
        for name in ("pixel_bias", "separate_scales"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be true or false, got {getattr(self, name)!r}")


@dataclass(frozen=True)
class GroundEstimate:
    """A person placed on the ground: ``position`` (x, y) in the world (m), its ``covariance``
    (2 x 2, m^2), the ``distance`` from the camera over the ground (m), the fitted ``stature``
    (m), the camera's pitch offset (rad), the body points used and the fit's reduced chi^2
    (~1 or below for a body that fits the model; the pixels' noise is scaled by it when above 1);
    ``shape``: the limbs' image positions (elbows, wrists, knees, ankles; (8, 2)) about the
    shoulders' and hips' centre in shares of the body's image height (NaN where not seen): how
    the pose looks, for :func:`pose_change` between frames (None: not known)."""

    position: NDArray[np.float64]
    covariance: NDArray[np.float64]
    distance: float
    stature: float
    pitch_offset: float
    points: int
    fit: float = math.nan
    shape: NDArray[np.float64] | None = None

    def relative_to(self, camera: CameraPose) -> tuple[float, float]:
        """(ahead, left) of the camera over the ground (m): along its heading and to its left."""
        d = self.position - camera.position[:2]
        c, s = math.cos(camera.yaw), math.sin(camera.yaw)
        return float(d[0] * c + d[1] * s), float(-d[0] * s + d[1] * c)

    def relative_covariance(self, camera: CameraPose) -> NDArray[np.float64]:
        """The covariance in (ahead, left) of the camera."""
        c, s = math.cos(camera.yaw), math.sin(camera.yaw)
        r = np.array([[c, s], [-s, c]])
        return r @ self.covariance @ r.T

    def mapped(self, m: ArrayLike) -> GroundEstimate:
        """The estimate in another ground frame: position m p, covariance m S m' (m 2x2)."""
        mm = np.asarray(m, dtype=float).reshape(2, 2)
        return replace(self, position=mm @ self.position, covariance=mm @ self.covariance @ mm.T)

    def contains(self, xy: ArrayLike, chi2: float = chi2_90) -> bool:
        """Whether ``xy`` lies inside the estimate's region of Mahalanobis^2 <= ``chi2`` (90 %)."""
        d = np.asarray(xy, dtype=float).reshape(2) - self.position
        return float(d @ np.linalg.solve(self.covariance, d)) <= chi2


GroundHeight = Callable[[NDArray[np.float64]], float]

#: COCO limbs whose image positions make a pose's :attr:`GroundEstimate.shape`.
_LIMBS = (7, 8, 9, 10, 13, 14, 15, 16)


def pose_change(a: NDArray[np.float64] | None, b: NDArray[np.float64] | None) -> float:
    """How far apart two frames' poses are: the rms distance of the limbs both show (shares of the
    body's image height; :attr:`GroundEstimate.shape`); NaN when either is unknown or they share
    fewer than 3 limbs. A person standing still sways by ~0.01 of their height and the detector
    jitters by about as much; a walker's legs and arms move by ~0.1 in a tenth of a second."""
    if a is None or b is None:
        return math.nan
    d = np.sum((a - b) ** 2, axis=1)
    d = d[np.isfinite(d)]
    return float(math.sqrt(np.mean(d))) if d.size >= 3 else math.nan


def _shape(person: Person, size_px: float, min_confidence: float) -> NDArray[np.float64] | None:
    kp, conf = person.keypoints, person.confidences
    core = [j for j in (5, 6, 11, 12) if conf[j] >= min_confidence and np.all(np.isfinite(kp[j]))]
    if len(core) < 2 or not size_px > 0:
        return None
    centre = kp[core].mean(axis=0)
    out = np.full((len(_LIMBS), 2), np.nan)
    for i, j in enumerate(_LIMBS):
        if conf[j] >= min_confidence and np.all(np.isfinite(kp[j])):
            out[i] = (kp[j] - centre) / size_px
    return out


def cut_by_image(box: NDArray[np.float64], width: int, height: int) -> bool:
    """Whether a person's ``box`` (x1, y1, x2, y2, pixels) touches the edge of an image ``width`` x
    ``height`` (within its last pixel): the body is cut, seen in part (``LocaliserConfig.cut_range_share``)."""
    return bool(box[0] <= 1.0 or box[1] <= 1.0 or box[2] >= width - 2.0 or box[3] >= height - 2.0)


def _flat(_: NDArray[np.float64]) -> float:
    return 0.0


class GroundLocaliser:
    """Places each detected person on the ground: :meth:`locate` (one person) with its covariance."""

    def __init__(self, config: LocaliserConfig | None = None) -> None:
        self.config = config or LocaliserConfig()
        biased = self.config.pixel_bias
        self._ratio = np.array([DETECTOR_PIXEL_BIAS[p[0]][0] if biased else p[2] for p in BODY_POINTS])
        self._offset = np.array([DETECTOR_PIXEL_BIAS[p[0]][1] if biased else 0.0 for p in BODY_POINTS])
        self._ratio_sigma = np.array([p[3] for p in BODY_POINTS])

    def _observations(
        self, person: Person, image: tuple[int, int] | None = None
    ) -> tuple[NDArray, NDArray, NDArray, NDArray]:
        """The pixels the fit uses: per body point seen, the u of its centre (a pair's midpoint)
        and, per joint, its v; with each one's body ratio, and standard deviations (px, before
        scaling by the person's size) and confidence weights. Returns (obs, ratio, sigma_rel, weight)
        where the first ``n_u`` entries are u's (see :meth:`locate`). ``image``: (width, height); a
        joint outside it is not seen (a landmark model guesses where a body cut by the image's edge
        goes on: rendered people whose ankles lay below the image were placed with an error of 3
        sigma)."""
        cfg = self.config
        kp, conf = person.keypoints, person.confidences
        if image is not None:
            out = ~((kp[:, 0] >= 0.0) & (kp[:, 0] < image[0]) & (kp[:, 1] >= 0.0) & (kp[:, 1] < image[1]))
            if out.any():
                conf = np.where(out, 0.0, conf)
        u_obs, u_ratio, u_sig, u_w, u_foot = [], [], [], [], []
        v_obs, v_ratio, v_sig, v_w, v_foot = [], [], [], [], []
        for i, (_, joints, _r, _s) in enumerate(BODY_POINTS):
            ok = [j for j in joints if conf[j] >= cfg.min_confidence and np.all(np.isfinite(kp[j]))]
            if not ok:
                continue
            c = conf[ok]
            u_obs.append(float(c @ kp[ok, 0] / c.sum()))
            u_ratio.append(self._ratio[i])
            # one joint of a pair: off the centre line by up to half a body's width
            u_sig.append(math.hypot(cfg.pixel_sigma, cfg.lateral_sigma if len(ok) == len(joints) else 0.06))
            u_w.append(float(c.mean()))
            u_foot.append(BODY_POINTS[i][0] == "ankles")
            for j in ok:
                v_obs.append(float(kp[j, 1]) + self._offset[i])
                v_ratio.append(self._ratio[i])
                v_sig.append(math.hypot(cfg.pixel_sigma, self._ratio_sigma[i]))
                v_w.append(float(conf[j]))
                v_foot.append(BODY_POINTS[i][0] == "ankles")
        self._n_u = len(u_obs)
        self._foot = np.array(u_foot + v_foot, dtype=float)
        return (
            np.array(u_obs + v_obs),
            np.array(u_ratio + v_ratio),
            np.array(u_sig + v_sig),
            np.array(u_w + v_w),
        )

    def locate(
        self, person: Person, camera: CameraPose, ground_height: GroundHeight | None = None
    ) -> GroundEstimate | None:
        """The ground position of ``person`` seen by ``camera`` (None when fewer than two body
        points are seen confidently, or the fit does not place the person in front of the camera
        within ``max_distance``). ``ground_height(xy)``: height of the walking surface there (m;
        default flat ground at z = 0).

        Each pixel's weight is its keypoint's confidence over its variance; a keypoint that
        disagrees with the rest of the body (a foot placed on the shadow) is down-weighted by
        iteratively reweighted least squares (Cauchy, scale 2.5 sigma)."""
        cfg = self.config
        ground = ground_height or _flat
        obs, ratio, sig_rel, conf_w = self._observations(person, (camera.spec.width, camera.spec.height))
        n_u = self._n_u
        v_ratio, v_obs = ratio[n_u:], obs[n_u:]
        if n_u < 2 or v_ratio.size < 2 or np.ptp(v_ratio) < 0.2:
            return None
        f = camera.focal_px
        # pixel stature from the highest and lowest joints seen; first range from the height prior
        lo, hi = int(np.argmin(v_ratio)), int(np.argmax(v_ratio))
        size_px = (v_obs[lo] - v_obs[hi]) / (v_ratio[hi] - v_ratio[lo])
        if not size_px > 1.0:
            return None
        z0 = f * cfg.stature / size_px
        if not 0.5 < z0 < 2.0 * cfg.max_distance:
            return None
        u_lo = obs[int(np.argmin(ratio[:n_u]))]
        start = camera.back_project([[u_lo, v_obs[lo]]], [z0])[0]
        sigma = np.hypot(cfg.pixel_floor, size_px * sig_rel)
        base_w = conf_w / sigma**2
        w = base_w.copy()
        pitch_sigma = math.radians(cfg.pitch_sigma_deg)
        theta = np.array([start[0], start[1], cfg.stature, 0.0, 0.0])
        prior_w = np.array(
            [
                0.0,
                0.0,
                1.0 / cfg.stature_sigma**2,
                1.0 / max(pitch_sigma, 1e-6) ** 2,
                1.0 / max(cfg.foot_sigma, 1e-6) ** 2,
            ]
        )
        prior_mean = np.array([0.0, 0.0, cfg.stature, 0.0, 0.0])
        foot = self._foot
        g = float(ground(theta[:2]))
        for it in range(15):
            if it < 5:
                g = float(ground(theta[:2]))
            pred, jac = self._model(camera, theta, ratio, n_u, g, foot)
            if pred is None:
                return None
            r = obs - pred
            if it >= 2:  # robust reweighting once the fit is near
                z = r / sigma
                w = base_w / (1.0 + (z / 2.5) ** 2)
            normal = jac.T @ (w[:, None] * jac) + np.diag(prior_w)
            grad = jac.T @ (w * r) - prior_w * (theta - prior_mean)
            try:
                step = np.linalg.solve(normal, grad)
            except np.linalg.LinAlgError:
                return None
            theta = theta + step
            if abs(step[0]) + abs(step[1]) < 1e-4 and it >= 5:
                break
        pred, jac = self._model(camera, theta, ratio, n_u, g, foot)
        if pred is None:
            return None
        # the body is believed as far as its own residuals allow: the pixels' noise is scaled by the
        # reduced chi^2 pooled with the prior's pseudo-residuals (:meth:`_noise_scale`); the priors
        # (people's stature, the pitch, the feet) are not the pixels' and keep their width
        r2 = base_w * (obs - pred) ** 2
        fit = float(np.sum(r2) / max(len(obs) - 4, 1))
        if cfg.separate_scales:  # the u's fit the bearing (one unknown), the v's the rest (three)
            n_v = len(obs) - n_u
            scale = np.repeat(
                [
                    self._noise_scale(float(np.sum(r2[:n_u])) / max(n_u - 1, 1), n_u - 1),
                    self._noise_scale(float(np.sum(r2[n_u:])) / max(n_v - 3, 1), n_v - 3),
                ],
                [n_u, n_v],
            )
        else:
            scale = self._noise_scale(fit, len(obs) - 4)
        try:
            cov = np.linalg.inv(jac.T @ ((w / scale)[:, None] * jac) + np.diag(prior_w))
        except np.linalg.LinAlgError:
            return None
        pos = theta[:2].copy()
        dist = float(np.hypot(*(pos - camera.position[:2])))
        ahead = float((pos - camera.position[:2]) @ np.array([math.cos(camera.yaw), math.sin(camera.yaw)]))
        if not (np.all(np.isfinite(cov)) and ahead > 0.3 and dist <= cfg.max_distance):
            return None
        c2 = 0.5 * (cov[:2, :2] + cov[:2, :2].T) + cfg.body_sigma**2 * np.eye(2)
        if cut_by_image(person.bbox, camera.spec.width, camera.spec.height):
            # seen in part, the rest guessed by the landmark model: her range known to a share of
            # itself, and where her body's centre is to a few centimetres
            los = (pos - camera.position[:2]) / max(dist, 1e-9)
            c2 = c2 + (cfg.cut_range_share * dist) ** 2 * np.outer(los, los) + cfg.cut_body_sigma**2 * np.eye(2)
        shape = _shape(person, size_px, cfg.min_confidence)
        return GroundEstimate(pos, c2, dist, float(theta[2]), float(theta[3]), n_u, fit, shape)

    def _noise_scale(self, fit: float, dof: int) -> float:
        """How much the pixels' variance is scaled by: the fit's reduced chi^2 over ``dof`` residuals
        pooled with ``noise_prior_dof`` = nu0 pseudo-residuals at the model's scale 1, (nu0 + dof
        chi^2) / (nu0 + dof) (the variance's estimate under a conjugate inverse-gamma prior): a
        body that fits better than the model's noise (an upright stander, chi^2 ~0.2) is narrowed
        as one that fits worse (a walker's limbs) is widened. nu0 = inf: the reduced chi^2 when
        above 1, else 1 (before 26 Nov)."""
        nu0 = self.config.noise_prior_dof
        if math.isinf(nu0):
            return max(1.0, fit)
        dof = max(dof, 1)
        return (nu0 + dof * fit) / (nu0 + dof)

    @staticmethod
    def _model(
        camera: CameraPose,
        theta: NDArray[np.float64],
        ratio: NDArray[np.float64],
        n_u: int,
        ground: float,
        foot: NDArray[np.float64],
    ) -> tuple[NDArray[np.float64] | None, NDArray[np.float64]]:
        """The fitted pixels at parameters (x, y, H, pitch offset): u of the first ``n_u`` body
        points, v of the joints after them; and their Jacobian (central differences)."""

        def pixels(x: float, y: float, h: float, pitch: float, f: float) -> NDArray[np.float64] | None:
            pose = CameraPose(camera.spec, camera.position, camera.yaw, camera.pitch + pitch, camera.roll)
            pts = np.column_stack([np.full(len(ratio), x), np.full(len(ratio), y), ground + (ratio + f * foot) * h])
            uv, depth = pose.project(pts)
            if np.any(depth < 0.3):
                return None
            return np.concatenate([uv[:n_u, 0], uv[n_u:, 1]])

        pred = pixels(*theta)
        if pred is None:
            return None, np.zeros(0)
        jac = np.empty((len(ratio), 5))
        for k, eps in enumerate((1e-3, 1e-3, 1e-3, 1e-5, 1e-4)):
            d = np.zeros(5)
            d[k] = eps
            a, b = pixels(*(theta + d)), pixels(*(theta - d))
            if a is None or b is None:
                return None, np.zeros(0)
            jac[:, k] = (a - b) / (2 * eps)
        return pred, jac


class FixedCameraGround:
    """People in the frames of a camera at a known height above flat ground (a dash-cam, a
    recorded video): each one's position ``ahead`` and to the ``left`` of the camera (m) with its
    covariance, for `trustnav estimate`. ``fov_deg``: horizontal field of view; ``pitch_deg``
    (> 0 looking down) and its uncertainty ``config.pitch_sigma_deg``."""

    FIELDS = ("ahead_m", "left_m", "sd_ahead_m", "sd_left_m", "distance_m")

    def __init__(
        self, height: float, fov_deg: float, pitch_deg: float = 0.0, config: LocaliserConfig | None = None
    ) -> None:
        from trustnav.geometry.camera import CameraSpec

        CameraSpec(up=height, fov_deg=fov_deg, pitch_deg=pitch_deg, forward=0.0)  # validates, names the input
        self.height, self.fov_deg, self.pitch_deg = float(height), float(fov_deg), float(pitch_deg)
        self.localiser = GroundLocaliser(config)
        self._cameras: dict[tuple[int, int], CameraPose] = {}

    def camera(self, width: int, height: int) -> CameraPose:
        """The camera of a ``width`` x ``height`` frame, at the origin looking along +x."""
        key = (int(width), int(height))
        if key not in self._cameras:
            from trustnav.geometry.camera import CameraSpec

            spec = CameraSpec(width=key[0], height=key[1], fov_deg=self.fov_deg, forward=0.0, up=self.height,
                              pitch_deg=self.pitch_deg)  # fmt: skip
            self._cameras[key] = spec.pose([0.0, 0.0], 0.0)
        return self._cameras[key]

    def fields(self, person: Person, width: int, height: int) -> dict[str, float | None]:
        """The record fields of one person (None each when it cannot be placed)."""
        cam = self.camera(width, height)
        est = self.localiser.locate(person, cam)
        if est is None:
            return dict.fromkeys(self.FIELDS)
        ahead, left = est.relative_to(cam)
        cov = est.relative_covariance(cam)
        return {
            "ahead_m": round(ahead, 3),
            "left_m": round(left, 3),
            "sd_ahead_m": round(math.sqrt(cov[0, 0]), 3),
            "sd_left_m": round(math.sqrt(cov[1, 1]), 3),
            "distance_m": round(est.distance, 3),
        }
