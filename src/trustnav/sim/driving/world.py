"""The driving world of the paper's Section IV (Cases I and II) as data: road, ego vehicle, camera,
pedestrians, controller and sensing parameters, loaded from TOML (``sim/scenarios/case-*.toml``);
plus the world's mechanics: the ego plant (kinematic bicycle with actuation latency, integrated
finer than the controller step) and the pedestrians (constant velocity, posed 3-D bodies).

Coordinates are the paper's map coordinates (CARLA Town map): metres, x/y on the ground, z up,
yaw in radians counter-clockwise from +x. Case I drives from (33.5, 129) to (33.5, 75), heading
-pi/2.
"""

from __future__ import annotations

import math
import tomllib
from collections import deque
from dataclasses import dataclass, field, fields, replace
from importlib import resources
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.control import (
    BoundedProportionalReference,
    CautionConfig,
    KinematicBicycle,
    LaneTrackingCost,
    MpcConfig,
    RoadEdgeBarrier,
    YieldConfig,
    reaction_time,
)
from trustnav.geometry.camera import CameraSpec
from trustnav.perception.localisation import LocaliserConfig
from trustnav.perception.world_tracking import WorldTrackerConfig
from trustnav.schema import (
    Either,
    Flag,
    InFile,
    Integer,
    Invalid,
    Maybe,
    Number,
    OneOf,
    Pair,
    Place,
    SchemaError,
    Seq,
    Text,
    bad,
    check_fields,
    check_keys,
    load,
    load_each,
    rules_of,
)
from trustnav.sim.driving import body
from trustnav.sim.driving.behaviour import BehaviourSpec, PedestrianMotion, behaviour_from
from trustnav.sim.driving.street import StreetSpec
from trustnav.trust import PAPER_GAMMA_CARLA, PAPER_TRUST, SECONDS_TRUST, GammaParams, TrustParams

__all__ = [
    "DRIVE_SCENARIOS",
    "CarlaRouteSpec",
    "ControlSpec",
    "DriveScenario",
    "PedestrianSpec",
    "RoadSpec",
    "SensingSpec",
    "VehiclePlant",
    "VehicleSpec",
    "load_drive_scenario",
    "pedestrian_states",
    "street_of",
]

DRIVE_SCENARIOS = ("case-1", "case-2")
#: The trust laws a scenario may choose (SensingSpec.trust_law).
TRUST_LAWS: dict[str, TrustParams] = {"seconds": SECONDS_TRUST, "paper": PAPER_TRUST}


#: The rules of the scenario's keys (trustnav.schema): a value refused names its key and the form.
POSITIVE = Number(lo=0, lo_open=True)
NON_NEGATIVE = Number(lo=0)
SHARE = Number(0.0, 1.0, hi_open=True)  # a probability below 1
XY = Pair()


@dataclass(frozen=True)
class RoadSpec:
    """A straight road: its centre line from ``start`` to ``end``, lane and sidewalk widths."""

    start: Annotated[tuple[float, float], XY] = (33.5, 140.0)
    end: Annotated[tuple[float, float], XY] = (33.5, 60.0)
    lane_width: Annotated[float, POSITIVE] = 3.5
    lanes: Annotated[int, Integer(1)] = 2
    sidewalk_width: Annotated[float, NON_NEGATIVE] = 3.0

    def __post_init__(self) -> None:
        check_fields(self)
        if self.start == self.end:
            raise ValueError("road start and end must differ")

    @property
    def width(self) -> float:
        return self.lane_width * self.lanes


@dataclass(frozen=True)
class VehicleSpec:
    """Ego plant: kinematic bicycle (wheelbase, steer and acceleration limits), actuation latency
    (s; the paper's 100 ms) and the integration sub-step (s), finer than the control period."""

    wheelbase: Annotated[float, POSITIVE] = 2.9
    steer_max_deg: Annotated[float, Number(0, 90, lo_open=True, hi_open=True, unit=" degrees")] = 35.0
    accel_min: Annotated[float, Number(hi=0, hi_open=True, unit=" m/s^2")] = -6.0
    accel_max: Annotated[float, Number(lo=0, lo_open=True, unit=" m/s^2")] = 3.0
    speed_max: Annotated[float, POSITIVE] = 15.0
    latency: Annotated[float, NON_NEGATIVE] = 0.1
    substep: Annotated[float, POSITIVE] = 0.005

    def __post_init__(self) -> None:
        check_fields(self)

    def model(self) -> KinematicBicycle:
        """The controller's model of this vehicle (same limits)."""
        return KinematicBicycle(
            wheelbase=self.wheelbase,
            steer_max=math.radians(self.steer_max_deg),
            accel_min=self.accel_min,
            accel_max=self.accel_max,
            speed_max=self.speed_max,
        )


def camera_view(camera: CameraSpec) -> dict[str, float]:
    """The yielding layer's view of ``camera`` (:class:`~trustnav.control.YieldConfig`): its
    horizontal field of view, its place ahead of the car, and the nearest distance ahead at which a
    person standing on the ground is whole in its image (the feet inside the lower edge: where the
    ray of the lower edge's middle pixel meets the ground, by the camera's own projection)."""
    pose = camera.pose([0.0, 0.0], 0.0)  # a car at the origin heading along x
    ground = pose.ground_point([[camera.principal[0], float(camera.height)]])[0]
    if not np.isfinite(ground[0]):  # the lower edge at or above the horizon: no one's feet in the image
        return {"view_deg": 0.0}
    near = float(ground[0] - pose.position[0])
    return {"view_deg": float(camera.fov_deg), "view_forward": float(camera.forward), "view_near": near}


@dataclass(frozen=True)
class ControlSpec:
    """Controller: rate (Hz), MPC step dt and horizon N_h, margin R, gamma(trust) of `weight`,
    latency compensation (s), CBF timing and the bounded proportional reference (gain, v_max).
    ``deadline``: the controller's wall-clock budget per step (s); large by default so that an
    episode does not depend on the machine's speed (simulated time is not wall time).
    ``confidence``: with perceived pedestrians, the probability with which R is kept from the true
    person (R grows by the estimate's uncertainty along the line of approach). ``road_edges``: the
    road's edges as barriers on the car's centre (:class:`~trustnav.control.RoadEdgeBarrier`),
    ``road_margin`` (m) inside them (half the car's width), approached at rate ``road_gamma``, the
    point ``road_front`` (m) ahead kept on the road too, and with ``road_recover`` (default) the arc
    that point swings through when the car turns back from an edge at its smallest turning radius
    (a car stopped turned toward the kerb can still leave; :class:`~trustnav.control.RoadEdgeBarrier`),
    with the controller's yielding layer (:mod:`~trustnav.control.yielding`: the car brakes and waits for a
    pedestrian it cannot pass on the road); on by default, ``road_edges = false`` is the paper's
    controller, which knows no road (docs/drive.md, "Road edges in the controller").
    ``caution`` (on by default; false: the paper's controller): the trust-aware speed bound
    (:mod:`~trustnav.control.caution`): the car can stop short of the region a pedestrian could
    reach, at ``caution_walking_speed`` times (1 - trust) ** ``caution_trust_exponent``, before
    the camera would show a step-out (``caution_confirm_frames`` camera periods plus the
    perception and command latencies and one control period), braking at
    ``caution_deceleration``; never below ``caution_pass_speed``; ``caution_unseen_frames`` camera
    periods of walking counted whatever the trust (0: none; docs/controller.md);
    ``caution_occlusion``: a pedestrian the camera no longer sees is kept on trust's bet that she
    keeps to her last seen velocity (:func:`~trustnav.control.caution.unseen_regions`) where that
    region is narrower than the tracker's (false: the tracker's alone)."""

    rate: Annotated[float, Number(0, 1000, lo_open=True, unit=" Hz")] = 20.0
    dt: Annotated[float, Number(lo=0, lo_open=True, unit=" s")] = 0.08
    horizon: Annotated[int, Integer(1, unit=" steps")] = 7
    safety_radius: Annotated[float, Number(lo=0, lo_open=True, unit=" m")] = 2.5
    gamma: GammaParams = field(default_factory=lambda: PAPER_GAMMA_CARLA)
    latency: Annotated[float, Number(lo=0, unit=" s")] = 0.1
    timing: Annotated[str, OneOf("paper", "authors_code")] = "paper"
    reference_gain: Annotated[float, POSITIVE] = 1.0
    reference_v_max: Annotated[float, Number(lo=0, lo_open=True, unit=" m/s")] = 8.0
    deadline: Annotated[float, Number(lo=0, lo_open=True, unit=" s")] = 10.0
    confidence: Annotated[float, Number(0.5, 1.0, hi_open=True)] = 0.95
    road_edges: bool = True
    road_margin: Annotated[float, NON_NEGATIVE] = 0.9
    road_gamma: Annotated[float, Number(0.0, 1.0, lo_open=True)] = 0.5
    road_front: Annotated[float, NON_NEGATIVE] = 2.0
    road_recover: bool = True
    caution: bool = True
    caution_walking_speed: Annotated[float, Number(lo=0, unit=" m/s")] = 1.4
    caution_trust_exponent: Annotated[float, POSITIVE] = 2.0
    caution_deceleration: Annotated[float, Number(lo=0, lo_open=True, unit=" m/s^2")] = 4.0
    caution_pass_speed: Annotated[float, Number(lo=0, unit=" m/s")] = 4.0
    caution_confirm_frames: Annotated[float, NON_NEGATIVE] = 2.0
    caution_unseen_frames: Annotated[float, NON_NEGATIVE] = 0.0
    caution_occlusion: bool = True

    def __post_init__(self) -> None:
        check_fields(self)
        self.config()  # the controller's own checks (between fields)
        BoundedProportionalReference(self.reference_gain, self.reference_v_max)

    def caution_config(self, camera_rate: float = 1.0, perception_latency: float = 0.0) -> CautionConfig | None:
        """The caution of a drive whose camera runs at ``camera_rate`` frames/s with that
        perception latency (None when ``caution`` is off)."""
        if not self.caution:
            return None
        reaction = reaction_time(camera_rate, self.caution_confirm_frames, perception_latency, self.latency,
                                 1.0 / self.rate)  # fmt: skip
        return CautionConfig(
            reaction=reaction,
            walking_speed=self.caution_walking_speed,
            trust_exponent=self.caution_trust_exponent,
            deceleration=self.caution_deceleration,
            pass_speed=self.caution_pass_speed,
            unseen=self.caution_unseen_frames / camera_rate,
            occlusion=self.caution_occlusion,
        )

    def config(
        self, camera_rate: float = 1.0, perception_latency: float = 0.0, camera: CameraSpec | None = None
    ) -> MpcConfig:
        """The controller's configuration for a camera at ``camera_rate`` frames/s (it sets the
        caution's reaction time); with caution, ``camera`` tells the yielding layer what the camera
        sees, so that one it remembers is released when it looks where she would be
        (:class:`~trustnav.control.YieldConfig`; None: not known)."""
        extra = {"deadline": self.deadline} if "deadline" in MpcConfig.__dataclass_fields__ else {}
        caution = self.caution_config(camera_rate, perception_latency)
        if caution is not None and camera is not None:
            extra["yielding"] = YieldConfig(**camera_view(camera), view_confirm=caution.reaction)
        return MpcConfig(
            caution=caution,
            confidence=self.confidence,
            horizon=self.horizon,
            dt=self.dt,
            safety_radius=self.safety_radius,
            gamma=self.gamma,
            timing=self.timing,  # type: ignore[arg-type]
            latency=self.latency,
            **extra,
        )

    def cost(self, start: tuple[float, float], goal: tuple[float, float]) -> LaneTrackingCost:
        ref = BoundedProportionalReference(self.reference_gain, self.reference_v_max)
        return LaneTrackingCost(start=start, goal=goal, reference=ref)

    def barriers(self, road: RoadSpec, vehicle: VehicleSpec | None = None) -> tuple[RoadEdgeBarrier, ...]:
        """The road's edges for the controller (none when ``road_edges`` is off); with
        ``road_recover``, the front's rows keep the arc back at ``vehicle``'s smallest turning radius
        on the road (default: the default vehicle's)."""
        if not self.road_edges:
            return ()
        half = road.width / 2
        v = vehicle or VehicleSpec()
        radius = v.wheelbase / math.tan(math.radians(v.steer_max_deg)) if self.road_recover else 0.0
        return (RoadEdgeBarrier(road.start, road.end, half, half, self.road_margin, self.road_gamma, self.road_front,
                                radius),)  # fmt: skip


#: The largest ``SensingSpec.perception_latency`` (s) accepted: beyond it a frame describes a street
#: that has long changed.
MAX_PERCEPTION_LATENCY = 5.0


# how a person's placement errors repeat from frame to frame (docs/perceived.md, "Calibration"):
# rendered frames through the detector repeat its bias for one pose and viewpoint; measured on Case I
# seeds 100-101 at 10 frames/s, the raw placements' whitened errors correlate by 0.66-0.71 0.1 s
# apart, falling about linearly to 0 at 2.2 s (correlation s and shared share below; the tracker
# inflates the variance along the line of sight by it, WorldTrackerConfig). Keypoint
# sensing draws its joints' errors anew in each frame (correlation 0.1-0.2 at 0.1-1 s, from the
# stature and the constant detector bias; its 90 % region holds the truth in 0.92-0.95 of the
# frames at 10 frames/s without inflation, so none: 0.1 s, one frame at 10 frames/s)
RENDER_ERROR_CORRELATION_S = 2.2
RENDER_ERROR_SHARED = 0.66
KEYPOINT_ERROR_CORRELATION_S = 0.1
KEYPOINT_ERROR_SHARED = 1.0
# ... but only while the pose repeats (issue 34 item 4): on rendered frames at 10 frames/s Case II's
# walker (a gait: her limbs move by 0.025-0.068 of her height between frames, median 0.049) has
# errors that correlate by -0.14 one frame apart, where standing and texting people (0.005-0.02,
# median 0.008-0.012) repeat theirs by 0.5-0.69, and by 0.50-0.67 one second apart at 1 frame/s
# (their sway over a second: median 0.022). A repeated share that fades as exp(-(d / 0.03)^2 / 2)
# with the limbs' move d keeps 0.92-0.95 of it at 10 frames/s, 0.76 over a second of sway and 0.26
# of a stride (WorldTrackerConfig.pose_change). Keypoint sensing has no repeated errors: 0.
RENDER_POSE_CHANGE = 0.03
KEYPOINT_POSE_CHANGE = 0.0
# Issue 34 item 4, thirteenth pass (docs/perceived.md): on rendered frames what repeats of a person's
# range error is a scale, p + s (p - c), that stays with the person (stature, a bowed head), which
# the tracker now estimates (WorldTrackerConfig.range_scale_sigma): the texting stander's along error
# 2.1 -> 1.45 sigma rms in the replays. With it the frames' remaining errors count as independent
# (error_shared 0: no inflation), a stander shuffles by 0.002 m^2/s (the 0.005 random walk had
# covered the range's drift), and the bearing is believed by its own residuals with the detector's
# centre line (LocaliserConfig separate_scales, lateral_sigma 0.01, body_sigma 5 mm). Keypoint
# sensing draws its errors anew in each frame: no scale, the defaults.
RENDER_RANGE_SCALE_SIGMA = 0.01
RENDER_FRAME_ERROR_SHARED = 0.0
RENDER_STANDING_PSD = 0.002
RENDER_LATERAL_SIGMA = 0.01
RENDER_BODY_SIGMA = 0.005
# the tracker's options that SensingSpec leaves to the sensing (None): (keypoints, rendered frames)
_TRACKER_BY_SENSING = {
    "error_correlation_s": (KEYPOINT_ERROR_CORRELATION_S, RENDER_ERROR_CORRELATION_S),
    "error_shared": (KEYPOINT_ERROR_SHARED, RENDER_FRAME_ERROR_SHARED),
    "pose_change": (KEYPOINT_POSE_CHANGE, RENDER_POSE_CHANGE),
    "range_scale_sigma": (0.0, RENDER_RANGE_SCALE_SIGMA),
    "standing_psd": (WorldTrackerConfig.standing_psd, RENDER_STANDING_PSD),
}


@dataclass(frozen=True)
class SensingSpec:
    """How the car senses pedestrians.

    Controller inputs (from the world, as in the authors' code): ``position_noise`` and
    ``velocity_noise`` (m, m/s, Gaussian sigma). Keypoint sensing: ``pixel_noise`` (sigma as a
    share of the person's image height), ``dropout`` (probability that a visible joint is missed),
    ``miss_rate`` (probability that a visible person is not detected in a frame), ``min_joints``
    (joints inside the image needed to detect a person), ``min_height_px``. Trust memory:
    ``keep_time`` (s; inf keeps the last trust of a pedestrian who left the view, as the paper);
    ``trust_law``: "seconds" (default: the rate-invariant law, ``trust.SECONDS_TRUST``: the same
    trust after the same seconds at any camera rate) or "paper" (``PAPER_TRUST``: one step per
    frame, as the paper at 1 frame/s).
    ``detector_bias``: the detector's error model: each joint moved as BlazePose does on rendered
    frames (``sensing.DETECTOR_V_BIAS``), all joints of a person shifted by a common vertical
    offset of sigma ``common_noise``, and a share ``outlier_rate`` of joints off by sigma
    ``outlier_noise`` more (shares of the person's image height). Perceived states
    (:mod:`trustnav.perception.localisation`, :mod:`~trustnav.perception.world_tracking`):
    ``stature`` and ``stature_sigma`` (m, the height prior), ``pitch_sigma_deg`` (how well the
    camera's pitch is known: the simulated car body does not pitch: 0.03 deg, the
    detector's common vertical shift, by default), ``pixel_bias`` (the detector's constant pixel
    offset of each joint, ``localisation.DETECTOR_PIXEL_BIAS``; by sensing: true for rendered
    frames, false for keypoints, whose error model has none), ``noise_prior_dof`` (pseudo-residuals
    the fit's chi^2 is pooled with to scale the pixels' noise; by sensing: 4 for rendered frames,
    inf, only widened, for keypoints),
    ``accel_psd`` (m^2/s^3, the tracker's walking model), ``error_correlation_s`` (s over which a
    person's placement errors stay alike, fading linearly) and ``error_shared`` (their correlation
    between frames close together): frames closer together count as fewer placements, see
    :class:`~trustnav.perception.world_tracking.WorldTrackerConfig`; default by sensing: 2.2 s and
    0 for rendered frames (their repeated error, 0.66 of a frame's, is the range scale's below),
    0.1 s and 1 for keypoint sensing, whose errors are drawn anew in each frame),
    ``range_scale_sigma`` (the person's range scale the tracker estimates: a frame places p + s (p -
    c); default by sensing: 0.01 for rendered frames, 0 for keypoints) and ``standing_psd`` (m^2/s,
    the tracker's standing walk; by sensing: 0.002 for rendered frames, 0.005 for keypoints),
    ``pose_change`` (a share of the body's height: the errors repeat only while the pose does; a
    frame whose limbs moved by d since the person's last keeps exp(-(d / pose_change)^2 / 2) of
    ``error_shared``; default by sensing: 0.03 for rendered frames, 0, not looked at, for keypoints),
    ``track_keep`` (s a track lives unseen
    where the camera should see it; out of view beside the
    car it lives longer, see :class:`~trustnav.perception.world_tracking.WorldTrackerConfig`).
    ``perception_latency`` (s): how long after its capture a frame's people reach the car's
    estimates (world tracker and trust), stamped with the capture time and predicted from it to
    each control step; 0 (default, as the paper): at once. A frame still in flight at the end of
    an episode is never delivered.
    A near-field sensor (:class:`~trustnav.sim.driving.sensing.NearField`; the ground around the
    car's front that a forward camera cannot see: a bumper's short-range radars or ultrasonic
    array): ``near_range`` (m from the car's reference point; 0, the default and the paper's: none,
    the camera alone), ``near_deg`` (its field, centred on the car's heading), ``near_sigma`` (m,
    each axis of a return's position), ``near_rate`` (scans per second), ``near_max_speed`` (m/s:
    it scans only while the car is this slow, as a park-assist array does: creeping and stopped,
    where the car loses whom it waits for; inf: at any speed, which the yielding layer is not
    measured with, docs/drive.md), ``near_clutter`` (static objects per 10 m of each sidewalk that
    it returns as it returns a person: poles, bins; placed by the seed,
    :func:`~trustnav.sim.driving.sensing.street_clutter`; 0: none, a sensor that sees people only).
    Each scan returns the ground position of each person (and object) inside its field, no traits,
    stamped with its time and delivered to the tracker in time order with the frames (their
    ``perception_latency`` too); the returns follow the people the camera found, a return far from
    every track starts one of trust 0 (no traits until the camera sees it), and a track is dropped
    where the sensor looks and finds nobody
    (:meth:`~trustnav.perception.world_tracking.WorldTracker.add_returns`).
    """

    position_noise: Annotated[float, NON_NEGATIVE] = 0.0
    velocity_noise: Annotated[float, NON_NEGATIVE] = 0.0
    pixel_noise: Annotated[float, NON_NEGATIVE] = 0.01
    dropout: Annotated[float, SHARE] = 0.03
    miss_rate: Annotated[float, SHARE] = 0.0
    min_joints: Annotated[int, Integer(1, 17)] = 9
    min_height_px: Annotated[float, NON_NEGATIVE] = 24.0
    keep_time: Annotated[float, Number(lo=0, finite=False, unit=" s", note=" (inf: kept for good)")] = math.inf
    trust_law: Annotated[str, OneOf(*TRUST_LAWS)] = "seconds"
    detector_bias: bool = True
    common_noise: Annotated[float, NON_NEGATIVE] = 0.009
    outlier_rate: Annotated[float, SHARE] = 0.1
    outlier_noise: Annotated[float, NON_NEGATIVE] = 0.04
    stature: float = 1.70
    stature_sigma: float = 0.09
    pitch_sigma_deg: float = 0.03
    pixel_bias: Annotated[bool | None, Maybe(Flag(), "by sensing: true for rendered frames, false for keypoints")] = (
        None
    )
    noise_prior_dof: Annotated[
        float | None, Maybe(Number(0, finite=False), "by sensing: 4 for rendered frames, inf for keypoints")
    ] = None
    accel_psd: float = 0.25
    error_correlation_s: Annotated[
        float | None, Maybe(Number(0, 60, unit=" s"), "by sensing: 2.2 s for rendered frames, 0.1 s for keypoints")
    ] = None
    error_shared: Annotated[float | None, Maybe(Number(0, 1), "by sensing: 0 for rendered frames, 1 for keypoints")] = (
        None
    )
    pose_change: Annotated[
        float | None, Maybe(Number(0, 1), "by sensing: 0.03 for rendered frames, 0 for keypoints")
    ] = None
    range_scale_sigma: Annotated[
        float | None, Maybe(Number(0, 0.5), "by sensing: 0.01 for rendered frames, 0 for keypoints")
    ] = None
    standing_psd: Annotated[
        float | None, Maybe(Number(0, 10, unit=" m^2/s"), "by sensing: 0.002 for rendered frames, 0.005 for keypoints")
    ] = None
    track_keep: float = 2.5
    perception_latency: Annotated[float, Number(0, MAX_PERCEPTION_LATENCY, unit=" s")] = 0.0
    near_range: Annotated[float, Number(0, 30, unit=" m", note=" (0: no near-field sensor)")] = 0.0
    near_deg: Annotated[float, Number(0, 360, lo_open=True, unit=" degrees")] = 180.0
    near_sigma: Annotated[float, Number(0, 2, lo_open=True, unit=" m")] = 0.15
    near_rate: Annotated[float, Number(0, 100, lo_open=True, unit=" scans per second")] = 10.0
    near_max_speed: Annotated[float, Number(0, finite=False, unit=" m/s", note=" (inf: at any speed)")] = 3.0
    near_clutter: Annotated[float, Number(0, 20, unit=" objects per 10 m of sidewalk")] = 0.0

    def __post_init__(self) -> None:
        check_fields(self)
        self.localiser()  # validates stature, stature_sigma, pitch_sigma_deg
        self.tracker()  # validates accel_psd, track_keep, error_correlation_s, error_shared

    def trust_params(self) -> TrustParams:
        """The trust law's parameters (``trust_law``)."""
        return TRUST_LAWS[self.trust_law]

    def localiser(self, keypoints: bool = False) -> LocaliserConfig:
        """The ground-plane localiser's configuration (``keypoints``: for keypoint sensing, whose
        error model draws no per-person bias of the feet and no pixel offset, and draws the pixels'
        noise at the model's own scale, and moves no joint of a body the image cuts: ``foot_sigma``
        0, ``pixel_bias`` False, ``noise_prior_dof`` inf, ``cut_range_share`` and ``cut_body_sigma``
        0; rendered frames through the detector: ``LocaliserConfig``'s measured defaults (a body
        the image cuts among them), the bearing by its own residuals with the detector's centre
        line, :data:`RENDER_LATERAL_SIGMA`, :data:`RENDER_BODY_SIGMA`)."""
        cfg = LocaliserConfig(
            stature=self.stature, stature_sigma=self.stature_sigma, pitch_sigma_deg=self.pitch_sigma_deg
        )
        if keypoints:
            cfg = replace(cfg, foot_sigma=0.0, pixel_bias=False, noise_prior_dof=math.inf,
                          cut_range_share=0.0, cut_body_sigma=0.0)  # fmt: skip
        else:
            cfg = replace(cfg, separate_scales=True, lateral_sigma=RENDER_LATERAL_SIGMA, body_sigma=RENDER_BODY_SIGMA)
        if self.pixel_bias is not None:
            cfg = replace(cfg, pixel_bias=self.pixel_bias)
        if self.noise_prior_dof is not None:
            cfg = replace(cfg, noise_prior_dof=float(self.noise_prior_dof))
        return cfg

    def tracker(self, keypoints: bool = False) -> WorldTrackerConfig:
        """The world tracker's configuration (``keypoints``: for keypoint sensing, whose default
        ``error_correlation_s`` and ``error_shared`` are :data:`KEYPOINT_ERROR_CORRELATION_S` and
        :data:`KEYPOINT_ERROR_SHARED`, no range scale and the tracker's standing walk; rendered
        frames: a range scale of :data:`RENDER_RANGE_SCALE_SIGMA` and the frames' errors otherwise
        independent, :data:`RENDER_FRAME_ERROR_SHARED`, a standing walk of
        :data:`RENDER_STANDING_PSD`)."""
        given = {name: getattr(self, name) for name in _TRACKER_BY_SENSING}
        by_sensing = {name: float(pair[0 if keypoints else 1] if given[name] is None else given[name])
                      for name, pair in _TRACKER_BY_SENSING.items()}  # fmt: skip
        return WorldTrackerConfig(accel_psd=self.accel_psd, keep_seconds=self.track_keep, **by_sensing)


@dataclass(frozen=True)
class PedestrianSpec:
    """One pedestrian: where (m), how fast (m/s), ground truth ``attentive``, and how the body is
    posed and dressed (``pose`` one of body.POSES, ``body_yaw_deg`` where the chest faces,
    ``look_at_camera`` turns the head to the car, ``phase`` and ``sway`` of the body's sway,
    ``appearance`` a preset name of body.py (attentive, distracted, walker) or colours).
    ``alternative`` holds the overrides that make the other behaviour (Case II runs the same
    pedestrian attentive and distracted). ``behaviour`` (optional, ``[pedestrian.behaviour]``):
    a path, a step-out time, a kerb wait with gap acceptance and a pose while moving
    (:mod:`trustnav.sim.driving.behaviour`); None: constant ``velocity`` from t = 0."""

    name: Annotated[str, Text()]
    position: Annotated[tuple[float, float], XY]
    velocity: Annotated[tuple[float, float], XY] = (0.0, 0.0)
    attentive: bool = True
    pose: Annotated[str, OneOf(*body.POSES)] = "attentive"
    body_yaw_deg: Annotated[float, Number()] = 0.0
    look_at_camera: bool = True
    phase: Annotated[float, Number()] = 0.0
    sway: Annotated[float, Number(0, 10)] = 1.0
    appearance: body.Appearance = field(default_factory=lambda: body.ATTENTIVE_LOOK)
    alternative: tuple[tuple[str, Any], ...] = ()
    behaviour: BehaviourSpec | None = None

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "behaviour", behaviour_from(self.behaviour))
            check_fields(self)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"pedestrian {self.name}: {exc}") from None

    @property
    def body_yaw(self) -> float:
        return math.radians(self.body_yaw_deg)

    def with_attention(self, attentive: bool | None) -> PedestrianSpec:
        """This pedestrian attentive or distracted (None: as given); applies ``alternative``."""
        if attentive is None or attentive == self.attentive:
            return self
        if not self.alternative:
            raise ValueError(f"pedestrian {self.name} has no alternative behaviour in the scenario")
        kw = dict(self.alternative)
        if "appearance" in kw:
            kw["appearance"] = _appearance(kw["appearance"])
        return replace(self, attentive=attentive, alternative=(), **kw)


#: A CARLA walker: a blueprint id or an index into the sorted ``walker.pedestrian.*`` ids.
WALKER = Maybe(Either(Text(what="a walker blueprint id"), Integer(0, note=" (an index into the walkers)")))


@dataclass(frozen=True)
class CarlaRouteSpec:
    """Optional ``[carla]`` section: how the scenario runs on a CARLA server (``--world carla``).
    ``town`` a map to load (None: the running world), ``fov_deg`` CARLA's camera field of view
    (None: the scenario's camera), ``attentive_walker`` / ``distracted_walker`` a walker blueprint
    id or an index into the sorted ``walker.pedestrian.*`` ids, ``vehicle_blueprint`` the ego car
    (None: the bridge's defaults). Passed through to the bridge's ``CarlaOptions``; the own world
    ignores it."""

    town: Annotated[str | None, Maybe(Text())] = None
    fov_deg: Annotated[float | None, Maybe(Number(1, 170, unit=" degrees"))] = None
    attentive_walker: Annotated[int | str | None, WALKER] = None
    distracted_walker: Annotated[int | str | None, WALKER] = None
    vehicle_blueprint: Annotated[str | None, Maybe(Text())] = None

    def __post_init__(self) -> None:
        check_fields(self)

    def options(self) -> dict[str, Any]:
        """The keyword arguments of the bridge's ``CarlaOptions`` that this section sets."""
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}


@dataclass(frozen=True)
class DriveScenario:
    """A driving scenario: ego start, heading and speed, goal, road, pedestrians, camera, vehicle,
    controller, sensing, CARLA route (optional), time limit. ``variants``: the behaviours a plain
    run covers ("attentive", "distracted": Case II runs its pedestrian both ways; empty: as given)."""

    name: Annotated[str, Text()]
    title: Annotated[str, Text(empty=True)]
    ego_start: Annotated[tuple[float, float], XY]
    goal: Annotated[tuple[float, float], XY]
    pedestrians: tuple[PedestrianSpec, ...]
    ego_yaw_deg: Annotated[float | None, Maybe(Number(), "from the start toward the goal")] = None
    ego_speed: Annotated[float, NON_NEGATIVE] = 0.0
    road: RoadSpec = field(default_factory=RoadSpec)
    camera: CameraSpec = field(default_factory=CameraSpec)
    vehicle: VehicleSpec = field(default_factory=VehicleSpec)
    control: ControlSpec = field(default_factory=ControlSpec)
    sensing: SensingSpec = field(default_factory=SensingSpec)
    carla: CarlaRouteSpec = field(default_factory=CarlaRouteSpec)
    variants: Annotated[tuple[str, ...], Seq(OneOf("attentive", "distracted"))] = ()
    duration: Annotated[float, Number(lo=0, lo_open=True, unit=" s")] = 25.0
    goal_tolerance: Annotated[float, Number(lo=0, lo_open=True, unit=" m")] = 1.0
    notes: str = ""

    def __post_init__(self) -> None:
        check_fields(self)
        if self.ego_start == self.goal:
            raise ValueError(f"scenario {self.name}: ego_start and goal must differ")
        if not self.pedestrians:
            raise ValueError(f"scenario {self.name}: needs at least one pedestrian")
        names = [p.name for p in self.pedestrians]
        if len(set(names)) != len(names):
            raise ValueError(f"scenario {self.name}: pedestrian names must be unique, got {names}")
        if not self.ego_speed <= self.vehicle.speed_max:
            raise ValueError(f"scenario {self.name}: ego_speed must be in [0, speed_max]")

    @property
    def ego_yaw(self) -> float:
        """Initial heading (rad): given, or from the start toward the goal."""
        if self.ego_yaw_deg is not None:
            return math.radians(self.ego_yaw_deg)
        d = np.subtract(self.goal, self.ego_start)
        return math.atan2(d[1], d[0])

    def initial_state(self) -> NDArray[np.float64]:
        """Ego state (x, y, yaw, v) at t = 0."""
        return np.array([*self.ego_start, self.ego_yaw, self.ego_speed])

    def with_attention(self, attentive: bool | None) -> DriveScenario:
        """Every pedestrian attentive (True) or distracted (False); None: as given."""
        if attentive is None:
            return self
        return replace(self, pedestrians=tuple(p.with_attention(attentive) for p in self.pedestrians), variants=())

    def with_options(self, duration: float | None = None, **sections: dict[str, Any]) -> DriveScenario:
        """The scenario with fields of its sections replaced (``camera={"fov_deg": 60.0}``; also
        ``control``, ``sensing``, ``carla``; a value None leaves the field as it is) and, given,
        another ``duration``; each section validated as when loaded."""
        changes: dict[str, Any] = {}
        for name, values in sections.items():
            given = {k: v for k, v in values.items() if v is not None}
            if given:
                changes[name] = replace(getattr(self, name), **given)
        if duration is not None:
            changes["duration"] = float(duration)
        return replace(self, **changes) if changes else self


def _appearance(v: Any, place: Place | None = None) -> body.Appearance:
    """A preset name of body.py (attentive, distracted, walker) or a table of colours."""
    if isinstance(v, body.Appearance):
        return v
    if isinstance(v, str):
        preset = getattr(body, f"{v.upper()}_LOOK", None)
        if not isinstance(preset, body.Appearance):
            raise Invalid("a preset name ('attentive', 'distracted', 'walker') or a table of colours", v)
        return preset
    if isinstance(v, dict) and place is not None:
        return load(body.Appearance, v, place)
    if isinstance(v, dict):
        return body.Appearance(**v)
    raise Invalid("a preset name ('attentive', 'distracted', 'walker') or a table of colours", v)


#: The keys ``[pedestrian.alternative]`` may override (the other behaviour of the same pedestrian).
ALTERNATIVE_KEYS = tuple(f.name for f in fields(PedestrianSpec) if f.name not in ("name", "alternative"))


def _alternative(v: Any, place: Place) -> tuple[tuple[str, Any], ...]:
    """``[pedestrian.alternative]``: keys of the pedestrian, each checked by its rule."""
    if not isinstance(v, dict):
        raise SchemaError(f"{place.table} must be a table of keys, got {v!r}")
    errors = check_keys(v, ALTERNATIVE_KEYS, place)
    rules = rules_of(PedestrianSpec)
    for key, value in v.items():
        try:
            if key == "appearance":
                _appearance(value, place.sub(key))
            elif key in rules and key in ALTERNATIVE_KEYS:
                rules[key](value)
        except Invalid as exc:
            errors.append(bad(place, key, exc))
        except SchemaError as exc:
            errors.extend(exc.errors)
    if errors:
        raise SchemaError(errors)
    return tuple(sorted(v.items()))


def _pedestrians(v: Any, place: Place) -> tuple[PedestrianSpec, ...]:
    """The ``[[pedestrian]]`` tables, each named in its errors by its name (or number)."""
    if not isinstance(v, list) or not v:
        raise SchemaError(f"{place.table} needs [[pedestrian]] tables, each with name and position = [x, y]")
    file = place.file if isinstance(place, InFile) else str(place.table)
    places = [
        InFile(file, f"pedestrian {p['name']!r}" if isinstance(p, dict) and isinstance(p.get("name"), str)
               else f"pedestrian {i + 1}")
        for i, p in enumerate(v)
    ]  # fmt: skip
    return load_each(PedestrianSpec, v, places, convert={"appearance": _appearance, "alternative": _alternative})


def _scenario_from_dict(d: dict[str, Any], source: str) -> DriveScenario:
    """A scenario from its TOML document; every error names ``source`` (the file or preset)."""
    place = InFile(source)
    return load(DriveScenario, d, place, convert={"pedestrians": lambda v, _: _pedestrians(v, place)},
                rename={"pedestrian": "pedestrians"})  # fmt: skip


def load_drive_scenario(name_or_path: str | Path) -> DriveScenario:
    """Load a named preset (``case-1|case-2``, shipped in sim/scenarios) or a scenario file (TOML of
    the same form; sections other than the top level are optional). Every refusal is a ValueError
    naming the input: a missing file, a folder, text that is not TOML, an unknown key."""
    name = str(name_or_path)
    path = Path(name_or_path)
    if name in DRIVE_SCENARIOS:
        text = resources.files("trustnav.sim").joinpath(f"scenarios/{name}.toml").read_text()
    elif path.is_file():
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise ValueError(f"scenario file {name}: cannot be read ({exc})") from None
    elif path.is_dir():
        raise ValueError(f"scenario file {name} is a folder, expected a .toml file")
    elif path.suffix == ".toml" or path.parent != Path("."):
        raise ValueError(f"scenario file {name} does not exist")
    else:
        raise ValueError(f"unknown driving scenario {name!r}: expected one of {DRIVE_SCENARIOS} or a .toml file")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{name}: not valid TOML ({exc})") from None
    if "trust_sweep" in data or "horizons" in data:
        raise ValueError(f"{name}: a numerical scenario of the paper (run it with `trustnav scenario`), "
                         "not a driving scenario")  # fmt: skip
    return _scenario_from_dict(data, name)


def pedestrian_states(scenario: DriveScenario, t: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Positions (N, 2) and velocities (N, 2) of the pedestrians at time t (constant velocity; a
    behaving pedestrian's state is the world's, :class:`~trustnav.sim.driving.episode.SimWorld`)."""
    p0 = np.array([p.position for p in scenario.pedestrians], dtype=float)
    v = np.array([p.velocity for p in scenario.pedestrians], dtype=float)
    return p0 + v * t, v


def street_of(scenario: DriveScenario) -> StreetSpec:
    """The street (road, sidewalks, kerb) of a scenario's road, as the renderer draws it."""
    r = scenario.road
    return StreetSpec(start=r.start, end=r.end, road_width=r.width, sidewalk_width=r.sidewalk_width)


def pedestrian_bodies(
    scenario: DriveScenario,
    t: float,
    look_at: ArrayLike | None,
    motions: list[PedestrianMotion | None] | None = None,
) -> list[tuple[body.Skeleton, body.Appearance]]:
    """Each pedestrian's posed 3-D body at time t (head toward ``look_at`` where the scenario says);
    ``motions``: the world's behaving pedestrians (their position, pose and heading), None for the rest."""
    pos, _ = pedestrian_states(scenario, t)
    street = street_of(scenario)
    out = []
    for j, (p, xy) in enumerate(zip(scenario.pedestrians, pos, strict=True)):
        m = None if motions is None else motions[j]
        pose, yaw = (p.pose, p.body_yaw) if m is None else (m.pose(p.pose), m.body_yaw(p.body_yaw))
        if m is not None:
            xy = m.position
        target = look_at if (p.look_at_camera and look_at is not None) else None
        ground = (float(xy[0]), float(xy[1]), street.ground_height(xy))  # on the kerb where it stands
        sk = body.pedestrian_skeleton(pose, ground, yaw, t, p.appearance, look_at=target, phase=p.phase,
                                      sway=p.sway)  # fmt: skip
        out.append((sk, p.appearance))
    return out


class VehiclePlant:
    """The ego car: kinematic bicycle integrated with a fine sub-step; a command (steer, accel)
    takes effect ``latency`` seconds after it is sent (the paper's 100 ms), clipped to the limits."""

    def __init__(self, spec: VehicleSpec, state: ArrayLike, time: float = 0.0) -> None:
        self.spec = spec
        self.model = spec.model()
        self.state = np.asarray(state, dtype=float).copy()
        self.time = float(time)
        self.applied = np.zeros(2)
        self._pending: deque[tuple[float, NDArray[np.float64]]] = deque()
        self._lo, self._hi = self.model.input_bounds()

    def send(self, command: ArrayLike) -> None:
        """Send a command now; it acts from now + latency."""
        u = np.clip(np.asarray(command, dtype=float).reshape(2), self._lo, self._hi)
        if not np.all(np.isfinite(u)):
            raise ValueError(f"command must be finite (steer, accel), got {command!r}")
        self._pending.append((self.time + self.spec.latency, u))

    def advance(self, duration: float) -> NDArray[np.float64]:
        """Integrate for ``duration`` seconds; returns the states at each sub-step (n, 4)."""
        n = max(1, math.ceil(duration / self.spec.substep - 1e-9))
        h = duration / n
        m = self.model
        out = np.empty((n, 4))
        for i in range(n):
            while self._pending and self._pending[0][0] <= self.time + 1e-9:
                self.applied = self._pending.popleft()[1]
            x, y, yaw, v = self.state
            steer, acc = self.applied
            # midpoint rule on the bicycle equations (more exact than the controller's Euler step)
            v_mid = min(max(v + 0.5 * acc * h, m.speed_min), m.speed_max)
            yaw_mid = yaw + 0.5 * h * v * math.tan(steer) / m.wheelbase
            self.state = np.array(
                [
                    x + h * v_mid * math.cos(yaw_mid),
                    y + h * v_mid * math.sin(yaw_mid),
                    yaw + h * v_mid * math.tan(steer) / m.wheelbase,
                    min(max(v + acc * h, m.speed_min), m.speed_max),
                ]
            )
            self.time += h
            out[i] = self.state
        return out
