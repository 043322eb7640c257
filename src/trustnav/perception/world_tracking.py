"""Pedestrians followed on the ground: a Kalman filter per person in world (road) coordinates,
fed by :class:`~trustnav.perception.localisation.GroundEstimate` s.

The camera moves with the car; placing each detection in the world with the ego's pose
(odometry) makes a person who stands still stand still for the filter, whatever the car does, so
identity survives frames that are a second apart and people who leave the view for a while.

* **state** (x, y, v_x, v_y) under two motion models mixed by an interacting multiple model
  filter (IMM; Blom & Bar-Shalom 1988): *standing* (velocity 0, the position wanders as a random
  walk of ``standing_psd`` m^2/s) and *walking* (constant velocity, white-noise acceleration of
  ``accel_psd`` m^2/s^3); a person switches between them at ``switch_rate`` per second. A person
  seen standing is predicted standing, with the walking model's share of the uncertainty, which
  grows honestly between frames and while the person is out of sight (a single constant-velocity
  filter would lend every bystander the velocity noise of a walker);
* **association** of a frame's estimates with the tracks predicted to the frame's time: squared
  Mahalanobis distance of the ground positions (gated at ``gate``) plus ln det of its covariance
  (the normalized distance, the negative log-likelihood: a track that knows least where it is
  does not win an estimate from one that knows it well), minus a bonus for image
  overlap with the track's last box when that box is recent; one-to-one by the Hungarian method.
  Monocular range has a heavy tail, so a confirmed track may also take an estimate up to 5 gates
  away (a box overlapping its recent box, IoU >= 0.5, up to 10), that estimate then believed only
  as far as the gate allows (its covariance scaled up): one bad placement does not split a person;
  a track seen standing may also take an estimate outside the mixture's gate that lies inside the
  gate of "she started walking just after the last frame" (:func:`_started`), ranked after every
  other association: at 1 frame/s a step-out moves a person 1.3 m between frames;
* **birth** of a tentative track from an estimate no track takes, **confirmation** after
  ``confirm_hits`` hits, **deletion** of a tentative track at its first miss; a confirmed track
  is deleted when it should have been seen and was not for ``keep_seconds`` (the whole body of a
  person at its predicted position inside the camera's view), when it is out of view and unseen
  for ``out_of_view_seconds`` (people who left the view beside the car, or who stand so close in
  front that they are cut off, stay that long, predicted with growing uncertainty),
  when it is more than ``behind`` metres behind the camera (passed), when its position
  uncertainty exceeds ``max_sigma``, or, beside or behind the camera's horizontal view and walking
  away from its axis, ``out_of_view_max_sigma`` (1.5 m: by then the track no longer says where the person is, and a car
  that kept it waited for someone it could not see; a person cut off in front of the camera, where
  the car may drive into them, is kept).

:meth:`WorldTracker.add_returns` folds in a near-field sensor's scan (positions on the ground, no
image): its returns join the tracks on the ground it looks at, one far from every track starts one
(no traits: trust 0), except on ground the camera cleared (a frame looked there and found no
person: a pole, a bin), and a track there that it does not find is dropped.

:meth:`WorldTracker.predict` gives every live track's mean and covariance at any time (the
controller's rate is not the camera's).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.geometry.camera import CameraPose
from trustnav.perception.localisation import GroundEstimate, pose_change
from trustnav.perception.types import box_iou

__all__ = ["TrackState", "WorldTrack", "WorldTracker", "WorldTrackerConfig"]


@dataclass(frozen=True)
class WorldTrackerConfig:
    """accel_psd: white-noise acceleration of the walking model (m^2/s^3: pedestrians speed up,
    slow down and turn); standing_psd: the standing model's random walk (m^2/s: a bystander's
    shuffle); switch_rate: how often a person starts or stops walking (1/s); initial_standing: the
    standing model's probability for a new track; initial_speed_sigma: the velocity prior of a
    new track and of a standing track's "started walking" hypothesis (m/s); gate: squared Mahalanobis
    distance beyond which an estimate cannot join a track (chi^2_2 99.7 % = 11.6);
    overlap_bonus: subtracted from the cost per unit of box IoU when the track's last box is at
    most ``overlap_seconds`` old; confirm_hits: hits that confirm a track; keep_seconds: how long a
    track lives unseen where the camera should see it; out_of_view_seconds: how long outside the
    view; behind: metres behind the camera beyond which a track is dropped; max_sigma: the
    position sigma (m) beyond which a track is dropped; error_correlation_s: how long a person's
    placement errors stay alike (s): the same pose seen from nearly the same place gives the same
    detector bias frame after frame; error_shared: the errors' correlation between frames close
    together (the share of their variance that repeats); their correlation fades linearly to 0 at
    error_correlation_s, and a frame that follows the track's previous one by dt < error_correlation_s
    is folded in with its variance along the line of sight times the variance inflation factor of
    such errors (:func:`correlated_error_factor`, :func:`inflated_along`; 1 s and 1: the frames of
    one second count as one independent range); error_correlation_s or error_shared 0: every frame
    independent. pose_change: the errors repeat only while the pose does (the detector's bias is
    that of the image it sees): a frame whose limbs moved by d
    (:func:`~trustnav.perception.localisation.pose_change`, shares of the body's height) since the
    track's previous one shares exp(-(d / pose_change)^2 / 2) of error_shared (a walker's stride
    renews the errors, a standing person's sway does not); 0: the pose is not looked at.
    out_of_view_max_sigma: the
    position sigma (m) beyond which a track beside or behind the camera's horizontal view, walking
    away from its axis, is dropped (one cut off in front of the camera, or walking toward the car's
    path, is kept: the car may drive into them): where the camera
    cannot look, a track that has grown this uncertain no longer says where the person is, only
    that they were there (issue 34: a car waited for a crosser it could no longer see).
    normalized_distance: an estimate inside several tracks' gates goes to the track under whose
    prediction it is likeliest: the association's cost is the squared Mahalanobis distance plus
    ln det of the innovation covariance (the negative log-likelihood up to a constant); the gates
    stay on the distance alone. By the distance alone (false), the track that knows least where
    it is wins: a bystander's track unseen for 10 s beside the car (sigma 3.3 m) took a crosser's
    detection 2.9 m from it from her own track, 0.5 m from it (sigma 0.07 m), and stood as a
    ghost below the image (issue 34).
    range_scale_sigma: a monocular placement's range is off by a factor that stays with the person
    (their stature against the prior, how the pose shortens them: a texter's bowed head): a frame
    places p + s (p - c) (c the camera), and s, the person's range scale, is a state of the track
    (prior sigma ``range_scale_sigma``, constant), both models carrying it. As the car approaches, a
    fixed scale moves the placements toward the camera; without the state the tracker reads that
    as walking, or, with the frames' errors inflated instead (``error_shared``), widens every
    region for it. 0 (default): no scale state, the four-state filter.
    return_births: a near-field return (:meth:`WorldTracker.add_returns`) that joins no track and
    lies more than ``return_birth_gap`` m from every live track starts one (tentative; no traits,
    so trust 0, the cautious default, until the camera sees the person); a track no camera frame
    has placed is judged by the scans (a frame that misses it, tentative, does not drop it: the
    camera may not see that ground) and dropped once unseen for ``keep_seconds`` wherever it is
    (the sensor is its only witness). False: returns only follow the people the camera found
    (issue 34: crossers the camera never showed, beside a slow car, walked into its path unseen
    by the controller).
    clear_frames: only the camera says what is a person, and what is not: a track only the
    near-field sensor found, missed by ``clear_frames`` frames that looked where it is (a person
    standing anywhere in its 2-sigma region, half a metre either side, wholly inside the image and
    more than a metre ahead), is an object that returns like a person (a pole, a bin); it is
    dropped and its ground is cleared: a return within ``clear_radius`` m of cleared ground starts
    no track (it may still join one: a person followed walking past it; the latest 256 cleared
    places are kept). 0: the camera clears nothing (a sensor's clutter is a person of trust 0 for
    as long as the sensor sees it)."""

    accel_psd: float = 0.25
    standing_psd: float = 0.005
    switch_rate: float = 0.1
    initial_standing: float = 0.5
    initial_speed_sigma: float = 0.8
    gate: float = 11.6
    overlap_bonus: float = 4.0
    overlap_seconds: float = 0.25
    confirm_hits: int = 2
    keep_seconds: float = 2.5
    out_of_view_seconds: float = 15.0
    behind: float = 6.0
    max_sigma: float = 4.0
    error_correlation_s: float = 1.0
    error_shared: float = 1.0
    pose_change: float = 0.0
    out_of_view_max_sigma: float = 1.5
    normalized_distance: bool = True
    range_scale_sigma: float = 0.0
    return_births: bool = True
    return_birth_gap: float = 2.0
    clear_frames: int = 1
    clear_radius: float = 0.75

    def __post_init__(self) -> None:
        for name, lo, hi in (
            ("accel_psd", 0.0, 100.0),
            ("standing_psd", 0.0, 10.0),
            ("switch_rate", 0.0, 100.0),
            ("initial_standing", 0.0, 1.0),
            ("initial_speed_sigma", 0.01, 20.0),
            ("gate", 0.1, 1e4),
            ("overlap_bonus", 0.0, 1e4),
            ("overlap_seconds", 0.0, 60.0),
            ("keep_seconds", 0.0, 600.0),
            ("out_of_view_seconds", 0.0, 3600.0),
            ("behind", 0.0, 1e4),
            ("max_sigma", 0.01, 1e3),
            ("out_of_view_max_sigma", 0.01, 1e3),
            ("error_correlation_s", 0.0, 60.0),
            ("error_shared", 0.0, 1.0),
            ("pose_change", 0.0, 1.0),
            ("range_scale_sigma", 0.0, 0.5),
            ("return_birth_gap", 0.0, 100.0),
            ("clear_radius", 0.0, 100.0),
        ):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not lo <= v <= hi:
                raise ValueError(f"{name} must be a number in [{lo}, {hi}], got {v!r}")
        for name in ("normalized_distance", "return_births"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be true or false, got {getattr(self, name)!r}")
        if isinstance(self.confirm_hits, bool) or not isinstance(self.confirm_hits, int) or self.confirm_hits < 1:
            raise ValueError(f"confirm_hits must be an integer >= 1, got {self.confirm_hits!r}")
        if isinstance(self.clear_frames, bool) or not isinstance(self.clear_frames, int) or self.clear_frames < 0:
            raise ValueError(f"clear_frames must be an integer >= 0 (0: clears nothing), got {self.clear_frames!r}")


@dataclass(frozen=True)
class TrackState:
    """A track's estimate at ``time``: ``mean`` (x, y, v_x, v_y), ``covariance`` (4 x 4)."""

    track_id: int
    time: float
    mean: NDArray[np.float64]
    covariance: NDArray[np.float64]
    confirmed: bool
    last_seen: float

    @property
    def position(self) -> NDArray[np.float64]:
        return self.mean[:2]

    @property
    def velocity(self) -> NDArray[np.float64]:
        return self.mean[2:]

    @property
    def position_covariance(self) -> NDArray[np.float64]:
        return self.covariance[:2, :2]


@dataclass
class WorldTrack:
    """One person followed on the ground: the IMM's per-model means (2, 4), covariances (2, 4, 4)
    and model probabilities (standing, walking) at ``time``; :attr:`mean` and :attr:`covariance`
    are their moment-matched combination."""

    track_id: int
    time: float
    means: NDArray[np.float64]
    covariances: NDArray[np.float64]
    probabilities: NDArray[np.float64]
    hits: int = 1
    last_seen: float = 0.0
    last_placed: float = 0.0  # the last camera placement (a near-field return is not one)
    box: NDArray[np.float64] | None = None
    shape: NDArray[np.float64] | None = None  # the pose of its last frame (GroundEstimate.shape)
    confirmed: bool = False
    looks: int = 0  # frames that looked where it is and found nobody (only for one no frame placed)
    history: list[tuple[float, NDArray[np.float64]]] = field(default_factory=list, repr=False)

    @property
    def mean(self) -> NDArray[np.float64]:
        return _combine(self.means, self.covariances, self.probabilities)[0][:4]

    @property
    def covariance(self) -> NDArray[np.float64]:
        return _combine(self.means, self.covariances, self.probabilities)[1][:4, :4]

    def measured(self, camera_xy: NDArray[np.float64] | None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Where the next frame from a camera at ``camera_xy`` should place this person: mean (2,)
        and covariance (2, 2) of the position, scaled about the camera by the track's range
        scale if it has one."""
        mean, cov = _combine(self.means, self.covariances, self.probabilities)
        h = _h(mean, camera_xy)
        return _measure(mean, camera_xy), h @ cov @ h.T


def _combine(means, covs, probs) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    mean = probs @ means
    d = means - mean
    cov = np.einsum("m,mij->ij", probs, covs) + np.einsum("m,mi,mj->ij", probs, d, d)
    return mean, 0.5 * (cov + cov.T)


def _models(dt: float, cfg: WorldTrackerConfig) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """(F, Q) of the standing and the walking model over ``dt`` seconds (with ``range_scale_sigma``,
    both carry the person's range scale, constant)."""
    f_walk = np.eye(4)
    f_walk[0, 2] = f_walk[1, 3] = dt
    a, b, c = dt**3 / 3.0, dt**2 / 2.0, dt
    q_walk = cfg.accel_psd * np.array([[a, 0, b, 0], [0, a, 0, b], [b, 0, c, 0], [0, b, 0, c]])
    f_stand = np.diag([1.0, 1.0, 0.0, 0.0])
    q_stand = np.diag([cfg.standing_psd * dt] * 2 + [1e-6] * 2)
    if cfg.range_scale_sigma <= 0.0:
        return [(f_stand, q_stand), (f_walk, q_walk)]
    out = []
    for f, q in ((f_stand, q_stand), (f_walk, q_walk)):
        f5, q5 = np.eye(5), np.zeros((5, 5))
        f5[:4, :4], q5[:4, :4] = f, q
        out.append((f5, q5))
    return out


def _mix(t: WorldTrack, dt: float, cfg: WorldTrackerConfig):
    """The IMM's interaction and prediction over ``dt``: per-model predicted means, covariances
    and the predicted model probabilities."""
    p = 1.0 - math.exp(-cfg.switch_rate * max(dt, 0.0))
    pi = np.array([[1.0 - p, p], [p, 1.0 - p]])  # pi[i, j]: from model i to j
    c = t.probabilities @ pi
    means, covs = np.empty_like(t.means), np.empty_like(t.covariances)
    for j, (f, q) in enumerate(_models(dt, cfg)):
        w = pi[:, j] * t.probabilities / max(c[j], 1e-300)
        m0, p0 = _combine(t.means, t.covariances, w)
        means[j] = f @ m0
        covs[j] = f @ p0 @ f.T + q
    return means, covs, c


def _started(t: WorldTrack, dt: float, cfg: WorldTrackerConfig) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The walking model's mean and covariance ``dt`` seconds on if the person, standing at the
    track's last update, started walking just after it: the standing model's position, a velocity
    of walking speed's prior (``initial_speed_sigma`` in each axis, as a new track's), carried by the
    walking model. The IMM's own standing-to-walking transition carries the standing model's
    velocity (0, certain), so one camera period of walking from rest lies outside the gate of a
    track long seen standing (issue 34: at 1 frame/s a step-out of 1.3 m split a person into a
    standing track and a new one without velocity)."""
    mean = t.means[0].copy()
    mean[2:4] = 0.0
    cov = t.covariances[0].copy()
    cov[2:4, :] = 0.0
    cov[:, 2:4] = 0.0
    cov[2:4, 2:4] = cfg.initial_speed_sigma**2 * np.eye(2)
    f, q = _models(dt, cfg)[1]
    return f @ mean, f @ cov @ f.T + q


_H = np.hstack([np.eye(2), np.zeros((2, 2))])


def _h(mean: NDArray[np.float64], camera_xy: NDArray[np.float64] | None) -> NDArray[np.float64]:
    """The measurement matrix at ``mean``: a frame places the position; with a range scale state
    (n = 5), the position moved away from the camera by the scale (z = p + s (p - c), linearised)."""
    if mean.size == 4:
        return _H
    h = np.zeros((2, 5))
    if camera_xy is None:  # no camera to scale about: the position alone
        h[:, :2] = np.eye(2)
        return h
    h[:, :2] = np.eye(2) * (1.0 + mean[4])
    h[:, 4] = mean[:2] - camera_xy
    return h


def _measure(mean: NDArray[np.float64], camera_xy: NDArray[np.float64] | None) -> NDArray[np.float64]:
    """Where a frame from a camera at ``camera_xy`` places a person of state ``mean``."""
    if mean.size == 4 or camera_xy is None:
        return mean[:2].copy()
    return mean[:2] + mean[4] * (mean[:2] - camera_xy)


def _log_det(s: NDArray[np.float64]) -> float:
    """ln det of a 2 x 2 innovation covariance: with the squared Mahalanobis distance, the negative
    log-likelihood of an estimate under a track's prediction, up to a constant (the normalized
    distance of a global-nearest-neighbour tracker)."""
    det = float(s[0, 0] * s[1, 1] - s[0, 1] * s[1, 0])
    return math.log(det) if det > 1e-300 else -690.0


def correlated_error_factor(dt: float, correlation_s: float, shared: float = 1.0) -> float:
    """The factor on a placement's covariance for a frame ``dt`` seconds after the track's previous
    one (``WorldTrackerConfig``): placement errors ``t`` seconds apart correlate by
    ``shared * max(0, 1 - t / correlation_s)`` (a share ``shared`` of their variance repeats, and
    the repetition fades out over ``correlation_s``: the same pose seen from a place that slowly
    changes). Fusing a run of such frames as if independent would shrink the covariance by the
    variance inflation factor 1 + 2 sum_k r(k dt) too much, so each frame is folded in with its
    variance along the line of sight times that factor (:func:`inflated_along`; the usual
    inflation for correlated measurements; with
    ``shared`` = 1 about ``correlation_s / dt``: the frames of one span count as one placement).
    The track's covariance after a span of frames is then about the same at any frame rate.
    1 (no change) from ``dt >= correlation_s`` on, and for a first frame or a track found again
    after a gap."""
    if correlation_s <= 0.0 or shared <= 0.0 or not 0.0 < dt < correlation_s:
        return 1.0
    k = math.ceil(correlation_s / dt - 1e-9) - 1  # lags k dt < correlation_s
    return 1.0 + 2.0 * shared * (k - dt / correlation_s * k * (k + 1) / 2.0)


def inflated_along(covariance: NDArray[np.float64], factor: float) -> NDArray[np.float64]:
    """A placement's 2 x 2 ``covariance`` with its variance along the line of sight (its major
    axis: monocular range) times ``factor`` and its variance across unchanged. Along the line of
    sight the errors fade within seconds, as :func:`correlated_error_factor` models; across it a
    person's placement repeats for the whole drive (rendered frames: 0.87 over 21 s), an error no
    per-frame factor describes: inflating it too made the region across 2-3 times the error, while
    the track's own motion noise already keeps its memory, and its region across, about one
    placement's (docs/perceived.md, eleventh pass)."""
    lam, u = np.linalg.eigh(covariance)
    return covariance + (factor - 1.0) * max(float(lam[1]), 0.0) * np.outer(u[:, 1], u[:, 1])


def _shared(t: WorldTrack, e: GroundEstimate, cfg: WorldTrackerConfig) -> float:
    """The share of ``e``'s error that repeats the track's previous frame's: ``error_shared``, less
    as far as the pose changed since (``pose_change``; unknown poses: all of it)."""
    if cfg.pose_change <= 0.0:
        return cfg.error_shared
    d = pose_change(t.shape, e.shape)
    if not math.isfinite(d):
        return cfg.error_shared
    return cfg.error_shared * math.exp(-0.5 * (d / cfg.pose_change) ** 2)


def _standing(camera: CameraPose, ground: list[NDArray[np.float64]]) -> NDArray[np.float64]:
    """Head, middle and feet (3K, 3) of a person standing at each ground point (K of (2,)), the
    camera at about head height."""
    z = float(camera.position[2])
    return np.array([[g[0], g[1], z - h] for g in ground for h in (0.0, 0.8, 1.6)])


def _wholly_in_view(camera: CameraPose, ground: list[NDArray[np.float64]]) -> bool:
    """Whether a person standing at each ground point would be wholly inside ``camera``'s image,
    her middle more than a metre ahead (where a frame that misses her says she is not there)."""
    body = _standing(camera, ground)
    return bool(camera.in_view(body).all()) and float(camera.to_camera(body[1::3])[:, 2].min()) > 1.0


class WorldTracker:
    """Follows the people of successive frames on the ground (call :meth:`add_frame` once per frame,
    in time order; :meth:`predict` at any later time)."""

    def __init__(self, config: WorldTrackerConfig | None = None) -> None:
        self.config = config or WorldTrackerConfig()
        self.tracks: list[WorldTrack] = []
        self.time = -math.inf
        self._next_id = 0
        # ground where the camera saw an object, not a person (the latest 256: a drive passes them by)
        self.cleared: deque[NDArray[np.float64]] = deque(maxlen=256)

    def _predict_track(self, t: WorldTrack, time: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Combined mean and covariance of ``t`` predicted to ``time`` (the track unchanged)."""
        if time <= t.time:
            return t.mean.copy(), t.covariance.copy()
        means, covs, probs = _mix(t, time - t.time, self.config)
        mean, cov = _combine(means, covs, probs)
        return mean[:4], cov[:4, :4]

    def add_frame(
        self,
        time: float,
        estimates: list[GroundEstimate | None],
        boxes: list[ArrayLike] | None = None,
        camera: CameraPose | None = None,
        to_world: NDArray[np.float64] | None = None,
    ) -> list[int | None]:
        """Fold in one frame taken at ``time`` (s): the ground estimates of its people (None where
        a person could not be placed), their image boxes and the ``camera`` that took it (None:
        every track counts as in view; ``to_world``: the orthogonal 2x2 map from the camera's ground
        frame to the tracks', if they differ). Returns each person's track ID (None for a person
        without estimate). Tracks are predicted to ``time`` first; deletions follow."""
        return self._fold(time, estimates, boxes, camera, to_world)

    def add_returns(
        self,
        time: float,
        positions: ArrayLike,
        covariances: ArrayLike,
        covers: Callable[[NDArray[np.float64]], bool],
    ) -> list[int | None]:
        """Fold in one scan of a near-field sensor taken at ``time`` (s; not before the last frame):
        the ground ``positions`` (M, 2) of the people it returns, in the tracks' coordinates, with
        their ``covariances`` (M, 2, 2) (a range sensor measures the position itself: no camera,
        no range scale, no image), and the ground it ``covers`` (a point's (2,) -> whether the
        sensor would return a person standing there). Only the tracks predicted on that ground
        take part: they are associated and corrected as with a frame's estimates (the same gates,
        the same "started walking" hypothesis), and a tentative one the scan missed, or a confirmed
        one unseen for ``keep_seconds``, is dropped (nobody stands where the sensor looks and finds
        nobody); every other track is left as it is, to the camera's frames, except one no frame
        has placed, dropped once unseen for ``keep_seconds`` wherever it is. A return that joins no
        track starts one if it lies more than ``return_birth_gap`` m from every live track
        (``return_births``; a person the camera never showed: no traits, trust 0 until it does)
        and from ground the camera cleared (``clear_frames``: an object, not a person), else it is
        dropped (a second return of someone followed). A return is not a camera
        placement: it shares none of a placement's correlated error, box or pose. Returns each
        return's track ID (None: it joined none)."""
        pos = np.asarray(positions, dtype=float).reshape(-1, 2)
        cov = np.asarray(covariances, dtype=float).reshape(-1, 2, 2)
        if len(cov) != len(pos) or not (np.isfinite(pos).all() and np.isfinite(cov).all()):
            raise ValueError(f"positions (M, 2) and covariances (M, 2, 2) must be finite and match, got "
                             f"{pos.shape} and {cov.shape}")  # fmt: skip
        estimates: list[GroundEstimate | None] = [
            GroundEstimate(
                position=p.copy(), covariance=c.copy(), distance=math.nan, stature=math.nan, pitch_offset=0.0, points=0
            )
            for p, c in zip(pos, cov, strict=True)
        ]
        return self._fold(time, estimates, None, None, None, covers)

    def _fold(
        self,
        time: float,
        estimates: list[GroundEstimate | None],
        boxes: list[ArrayLike] | None,
        camera: CameraPose | None,
        to_world: NDArray[np.float64] | None,
        covers: Callable[[NDArray[np.float64]], bool] | None = None,
    ) -> list[int | None]:
        """:meth:`add_frame` (``covers`` None: a camera's frame) or :meth:`add_returns`."""
        if not math.isfinite(time) or time < self.time:
            raise ValueError(f"time must be finite and not go back (last {self.time}), got {time!r}")
        cfg = self.config
        placed = covers is None  # a camera's placements (else a near-field sensor's returns)
        # a camera's frame takes in every track; a scan only those on the ground it looks at (the
        # others are not predicted to its time: an IMM's mixing at each update is no idle step)
        pool = self.tracks if placed else [t for t in self.tracks if covers(self._predict_track(t, time)[0][:2])]
        self.time = float(time)
        cam_xy = None
        if camera is not None and cfg.range_scale_sigma > 0.0:
            cam_xy = np.asarray(camera.position[:2], dtype=float)
            cam_xy = cam_xy if to_world is None else np.asarray(to_world) @ cam_xy
        started: dict[int, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}
        for a, t in enumerate(pool):
            if time > t.time and t.probabilities[0] >= 0.5:  # seen standing: she may have started walking
                started[a] = _started(t, time - t.time, cfg)
            if time > t.time:
                t.means, t.covariances, t.probabilities = _mix(t, time - t.time, cfg)
                t.time = float(time)
        idx = [i for i, e in enumerate(estimates) if e is not None]
        ids: list[int | None] = [None] * len(estimates)
        n_t, n_d = len(pool), len(idx)
        taken_t: set[int] = set()
        if n_t and n_d:
            from scipy.optimize import linear_sum_assignment

            cost = np.full((n_t, n_d), np.inf)
            dist2 = np.full((n_t, n_d), np.inf)
            moved = np.zeros((n_t, n_d), dtype=bool)
            for a, t in enumerate(pool):
                z_pos, s_pos = t.measured(cam_xy)
                recent = t.box is not None and time - t.last_seen <= cfg.overlap_seconds
                for b, i in enumerate(idx):
                    e = estimates[i]
                    assert e is not None
                    d = e.position - z_pos
                    s_in = s_pos + e.covariance
                    m2 = float(d @ np.linalg.solve(s_in, d))
                    iou = 0.0
                    if recent and boxes is not None and boxes[i] is not None:
                        iou = box_iou(t.box, np.asarray(boxes[i], dtype=float))
                    # one bad placement (the heavy tail of monocular range) must not split a person in
                    # two: a confirmed track may take an estimate up to 5 gates away, a box that
                    # overlaps the track's box of a moment ago up to 10 (at a higher cost)
                    if m2 > cfg.gate and a in started:
                        # outside the mixture's gate: she may have started walking since the last
                        # frame (one camera period of walking from standing moves her further than
                        # the mixture, dominated by standing, allows); ranked after every other
                        # association, loose ones included (a walker's estimate that strays from
                        # her own track must not make a bystander's track walk off with her)
                        m0, p0 = started[a]
                        h0 = _h(m0, cam_xy)
                        r = e.position - _measure(m0, cam_xy)
                        m2s = float(r @ np.linalg.solve(h0 @ p0 @ h0.T + e.covariance, r))
                        if m2s <= cfg.gate:
                            dist2[a, b] = m2
                            cost[a, b] = 10.0 * cfg.gate + m2s
                            moved[a, b] = True
                            continue
                    loose = (t.confirmed and m2 <= 5.0 * cfg.gate) or (iou >= 0.5 and m2 <= 10.0 * cfg.gate)
                    if m2 > cfg.gate and not loose:
                        continue
                    dist2[a, b] = m2
                    cost[a, b] = m2 - cfg.overlap_bonus * iou + (_log_det(s_in) if cfg.normalized_distance else 0.0)
            finite = np.where(np.isfinite(cost), cost, 1e9)
            rows, cols = linear_sum_assignment(finite)
            for a, b in zip(rows, cols, strict=True):
                if not np.isfinite(cost[a, b]):
                    continue
                i = idx[b]
                e = estimates[i]
                assert e is not None
                t = pool[a]
                if moved[a, b]:  # she started walking: the walking model from her standing place
                    t.means[1], t.covariances[1] = started[a]
                elif dist2[a, b] > cfg.gate:  # taken by overlap: believed only as far as the gate allows
                    e = replace(e, covariance=e.covariance * (dist2[a, b] / cfg.gate))
                if placed:  # a frame soon after the last placement: its range error is mostly that one's again
                    alike = correlated_error_factor(time - t.last_placed, cfg.error_correlation_s, _shared(t, e, cfg))
                    if alike > 1.0:
                        e = replace(e, covariance=inflated_along(e.covariance, alike))
                self._correct(t, e, cam_xy)
                t.hits += 1
                if placed:
                    t.last_placed = float(time)
                    t.box = None if boxes is None or boxes[i] is None else np.asarray(boxes[i], dtype=float)
                    t.shape = e.shape
                elif t.last_seen < time:  # found by the scan, not the frame: her last box is no longer recent
                    t.box = None
                t.last_seen = float(time)
                t.confirmed = t.confirmed or t.hits >= cfg.confirm_hits
                ids[i] = t.track_id
                taken_t.add(a)
        missed = [t for a, t in enumerate(pool) if a not in taken_t]
        births = placed or cfg.return_births
        unjoined = births and not placed and any(ids[i] is None for i in idx)
        # where every followed person is now: only a scan with a return that joined nobody needs it
        others = [self._predict_track(t, time)[0][:2] for t in self.tracks] if unjoined else []
        for i in idx if births else ():
            if ids[i] is None:
                e = estimates[i]
                assert e is not None
                if any(math.dist(e.position, q) <= cfg.return_birth_gap for q in others):
                    continue  # a return beside someone followed is theirs, not a new person
                if not placed and any(math.dist(e.position, q) <= cfg.clear_radius for q in self.cleared):
                    continue  # an object the camera looked at (clear_frames)
                ids[i] = self._birth(e, time, None if boxes is None else boxes[i], cam_xy, placed)
        if covers is not None:  # a scan: deletions inside the ground it covers only
            gone = [t for t in missed if not t.confirmed or time - t.last_seen > cfg.keep_seconds]
            gone += [t for t in self.tracks if t not in gone and self._unwitnessed(t, time)]
            self.tracks = [t for t in self.tracks if t not in gone]
            self._history(time)
            return ids
        # a tentative track missed once is dropped; a confirmed one unseen too long where it should
        # have been seen (or out of view), passed, or too uncertain
        keep = []
        for t in self.tracks:
            unseen = time - t.last_seen
            sigma = math.sqrt(max(np.linalg.eigvalsh(t.covariance[:2, :2])[-1], 0.0))
            if t in missed and not t.confirmed and t.last_placed > -math.inf:
                continue  # (one only the near-field sensor found is the scans' to judge)
            if sigma > cfg.max_sigma or self._unwitnessed(t, time):
                continue
            if t in missed and self._cleared_by(t, sigma, camera, to_world):
                continue
            if unseen > 0.0 and camera is not None:
                xy = t.mean[:2] if to_world is None else np.asarray(to_world).T @ t.mean[:2]
                mid = camera.to_camera(_standing(camera, [xy])[1:2])[0]  # her middle
                depth = float(mid[2])
                if depth < -cfg.behind:
                    continue
                # should have been seen: the whole body in the image (near the car, or at the image's
                # edge, a person is cut off and often missed: they are kept as out of view)
                visible = _wholly_in_view(camera, [xy])
                if unseen > (cfg.keep_seconds if visible else cfg.out_of_view_seconds):
                    continue
                # beside or behind the camera's horizontal view (not merely cut off in front of
                # it, where the car may drive into them) a track this uncertain says nothing useful,
                # and walking away from the camera's axis (not toward the car's path)
                u = camera.spec.principal[0] + camera.focal_px * float(mid[0]) / depth if depth > 1e-9 else math.nan
                vel = t.mean[2:4] if to_world is None else np.asarray(to_world).T @ t.mean[2:4]
                lateral = float(np.asarray(vel) @ np.asarray(camera.right)[:2])  # m/s to the image's right
                away = abs(lateral) > 0.3 and lateral * float(mid[0]) > 0.0  # walking, not standing
                if not 0.0 <= u < camera.spec.width and away and sigma > cfg.out_of_view_max_sigma:
                    continue
            elif unseen > cfg.keep_seconds:
                continue
            keep.append(t)
        self.tracks = keep
        self._history(time)
        return ids

    def _cleared_by(
        self, t: WorldTrack, sigma: float, camera: CameraPose | None, to_world: NDArray[np.float64] | None
    ) -> bool:
        """A frame by ``camera`` missed ``t``: if no frame ever placed it and this one looked where
        it is (``clear_frames``), one look more; at ``clear_frames`` looks its ground is cleared."""
        n = self.config.clear_frames
        if n == 0 or camera is None or t.last_placed > -math.inf:
            return False
        xy = t.mean[:2] if to_world is None else np.asarray(to_world).T @ t.mean[:2]
        ahead, right = np.asarray(camera.forward, dtype=float)[:2], np.asarray(camera.right, dtype=float)[:2]
        ahead, right = ahead / np.linalg.norm(ahead), right / np.linalg.norm(right)
        wide, deep = 0.5 + 2.0 * sigma, 2.0 * sigma
        if not _wholly_in_view(
            camera, [xy + a * wide * right + b * deep * ahead for a in (-1, 0, 1) for b in (-1, 0, 1)]
        ):
            return False
        t.looks += 1
        if t.looks < n:
            return False
        self.cleared.append(np.asarray(t.mean[:2], dtype=float).copy())
        return True

    def _unwitnessed(self, t: WorldTrack, time: float) -> bool:
        """A track only the near-field sensor has seen (no frame placed it) and that it has not
        seen for ``keep_seconds``: out of its field nothing says where, or whether, the person is."""
        return t.last_placed == -math.inf and time - t.last_seen > self.config.keep_seconds

    def _history(self, time: float) -> None:
        """Each track seen at ``time``: its mean then in its history (once per time)."""
        for t in self.tracks:
            if t.last_seen == time:
                if t.history and t.history[-1][0] == time:
                    t.history[-1] = (float(time), t.mean.copy())
                else:
                    t.history.append((float(time), t.mean.copy()))

    def _correct(self, t: WorldTrack, e: GroundEstimate, camera_xy: NDArray[np.float64] | None = None) -> None:
        """Kalman update of each model (Joseph form) and of the model probabilities."""
        like = np.empty(2)
        n = t.means.shape[1]
        for j in range(2):
            p = t.covariances[j]
            h = _h(t.means[j], camera_xy)
            s = h @ p @ h.T + e.covariance
            s_inv = np.linalg.inv(s)
            r = e.position - _measure(t.means[j], camera_xy)
            k = p @ h.T @ s_inv
            t.means[j] = t.means[j] + k @ r
            i_kh = np.eye(n) - k @ h
            pj = i_kh @ p @ i_kh.T + k @ e.covariance @ k.T
            t.covariances[j] = 0.5 * (pj + pj.T)
            like[j] = math.exp(-0.5 * float(r @ s_inv @ r)) / (2.0 * math.pi * math.sqrt(max(np.linalg.det(s), 1e-300)))
        post = t.probabilities * like
        total = float(post.sum())
        if total > 0 and math.isfinite(total):
            t.probabilities = np.clip(post / total, 1e-6, 1.0)
            t.probabilities /= t.probabilities.sum()

    def _birth(
        self,
        e: GroundEstimate,
        time: float,
        box: ArrayLike | None,
        camera_xy: NDArray[np.float64] | None = None,
        placed: bool = True,
    ) -> int:
        cfg = self.config
        n = 5 if cfg.range_scale_sigma > 0.0 else 4
        walk = np.zeros((n, n))
        walk[:2, :2] = e.covariance
        walk[2:4, 2:4] = cfg.initial_speed_sigma**2 * np.eye(2)
        if n == 5:  # the frame placed p (1 + s) - s c: the position uncertain by the scale's prior along the ray
            walk[4, 4] = cfg.range_scale_sigma**2
            if camera_xy is not None:
                ray = np.asarray(e.position) - camera_xy
                walk[:2, :2] += cfg.range_scale_sigma**2 * np.outer(ray, ray)
                walk[:2, 4] = walk[4, :2] = -(cfg.range_scale_sigma**2) * ray
        stand = walk.copy()
        stand[2:4, 2:4] = 1e-6 * np.eye(2)
        mean = np.zeros(n)
        mean[:2] = e.position
        t = WorldTrack(
            track_id=self._next_id,
            time=float(time),
            means=np.stack([mean, mean]),
            covariances=np.stack([stand, walk]),
            probabilities=np.array([cfg.initial_standing, 1.0 - cfg.initial_standing]),
            last_seen=float(time),
            last_placed=float(time) if placed else -math.inf,
            box=None if box is None else np.asarray(box, dtype=float),
            shape=e.shape,
            confirmed=cfg.confirm_hits <= 1,
        )
        t.history.append((float(time), t.mean.copy()))
        self._next_id += 1
        self.tracks.append(t)
        return t.track_id

    def predict(self, time: float) -> list[TrackState]:
        """Every live track's state predicted to ``time`` (s; not before the last frame), oldest
        track first. Nothing changes in the tracker."""
        if not math.isfinite(time) or time < self.time - 1e-9:
            raise ValueError(f"time must be finite and not before the last frame ({self.time}), got {time!r}")
        out = []
        for t in self.tracks:
            mean, cov = self._predict_track(t, time)
            out.append(TrackState(t.track_id, float(time), mean, cov, t.confirmed, t.last_seen))
        return out
