"""A CARLA server as a :class:`trustnav.sim.driving.episode.World`, and one drive on it.

:class:`CarlaWorld` reads the ego and the walkers from CARLA (converted to the scenario's
coordinates by the session's :class:`MapFrame`), applies the controller's command as a
``VehicleControl`` (pedals and normalised steer, :mod:`trustnav.carla_bridge.control`), keeps the
walkers walking (``WalkerControl``: at their constant velocity, or as their ``[pedestrian.behaviour]``
says: standing until a step-out, along a path, waiting at a kerb for a gap, in their moving pose)
and advances CARLA by ``world.tick()`` in synchronous mode, one
tick per control period. What the camera sees goes through the physical frame
(:func:`carla_to_physical`), where trustnav's camera model and pedestrian bodies (placed at the
walkers, with their yaws) project as CARLA's camera does: keypoint sensing projects those bodies,
render sensing runs perception on CARLA's image and associates its tracks with the walkers through
the bodies' boxes. :func:`run_carla_drive_episode` puts it under a
:class:`~trustnav.sim.driving.episode.DriveEnvironment`, the episode engine's world of every drive
(:mod:`trustnav.sim.engine`), and runs :func:`trustnav.sim.driving.episode.drive` on it: the same
runner, MPC, trust memory, record and metrics as ``trustnav drive``.

No latency is added here (trustnav's own world delays each command 100 ms): CARLA's vehicle has
its own actuation dynamics; the controller still plans from the state ``control.latency`` ahead.
"""

from __future__ import annotations

import math
import queue
import time as _time
from collections.abc import Callable
from dataclasses import replace
from types import ModuleType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.carla_bridge.control import max_steer_angle, to_vehicle_command
from trustnav.carla_bridge.frames import bgra_to_rgb, carla_to_physical, physical_yaw
from trustnav.carla_bridge.posing import pose_walker
from trustnav.carla_bridge.session import CarlaError, CarlaOptions, CarlaSession
from trustnav.geometry.camera import CameraPose, CameraSpec
from trustnav.sim.driving import body
from trustnav.sim.driving.behaviour import PedestrianMotion
from trustnav.sim.driving.episode import DriveEnvironment, DriveResult, drive, make_sensor, prepare_scenario
from trustnav.sim.driving.world import DriveScenario

__all__ = ["CarlaCamera", "CarlaWorld", "carla_scenario", "run_carla_drive_episode"]


class CarlaWorld:
    """The drive loop's world on an open :class:`CarlaSession` (see the module's docstring)."""

    name = "carla"

    def __init__(self, session: CarlaSession, camera_spec: CameraSpec, image_timeout: float | None = None) -> None:
        if session.vehicle is None or session.camera is None:
            raise ValueError("the CARLA session must be open (entered) with its vehicle and camera spawned")
        self.session = session
        self.carla = session.carla
        self.frame = session.options.frame
        self.spec = camera_spec
        self.delta = session.delta
        self.image_timeout = float(image_timeout or session.options.timeout)
        self.ticks = 0
        wheels = session.vehicle.get_physics_control().wheels
        self.max_steer = max_steer_angle([w.max_steer_angle for w in wheels])
        self._image: Any = None  # the camera's latest carla.Image
        self._rgb: NDArray[np.uint8] | None = None
        self._frame_id: int | None = session.first_frame
        # behaving walkers follow the same behaviour model as trustnav's own world, from where CARLA has them
        self.motions: list[PedestrianMotion | None] = [
            None if p.behaviour is None else PedestrianMotion(p.position, p.velocity, p.behaviour)
            for p in session.scenario.pedestrians
        ]
        self._posed: list[str | None] = [None] * len(self.motions)  # the pose each walker's bones hold
        self._take_images(wait=session.options.sensor_tick == 0)
        self._walk(0.0)

    @property
    def time(self) -> float:
        return self.ticks * self.delta

    @property
    def camera_to_scenario(self) -> NDArray[np.float64]:
        """Ground points of the camera's (physical, right-handed) frame -> scenario coordinates:
        y is negated unless the map frame flips it already."""
        return np.diag([1.0, -self.frame.sign])

    def ego_state(self) -> NDArray[np.float64]:
        v = self.session.vehicle
        tf = v.get_transform()
        x, y, _ = self.frame.from_carla(tf.location.x, tf.location.y)
        yaw_c = math.radians(tf.rotation.yaw)
        vel = v.get_velocity()
        speed = vel.x * math.cos(yaw_c) + vel.y * math.sin(yaw_c)  # along the heading (CARLA frame)
        return np.array([x, y, self.frame.yaw_from_carla(tf.rotation.yaw), speed])

    def pedestrian_states(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        pos, vel = [], []
        for w in self.session.walkers:
            loc, v = w.get_location(), w.get_velocity()
            pos.append(self.frame.from_carla(loc.x, loc.y)[:2])
            vel.append(self.frame.vector_from_carla(v.x, v.y))
        n = len(self.session.walkers)
        return np.array(pos, dtype=float).reshape(n, 2), np.array(vel, dtype=float).reshape(n, 2)

    def camera_view(self) -> tuple[CameraPose, list[tuple[body.Skeleton, body.Appearance]]]:
        """CARLA's camera and trustnav bodies at the walkers, in the physical (right-handed) frame."""
        tf = self.session.camera.get_transform()
        loc, rot = tf.location, tf.rotation
        cam = CameraPose(self.spec, carla_to_physical(loc.x, loc.y, loc.z), physical_yaw(rot.yaw),
                         math.radians(-rot.pitch))  # fmt: skip
        bodies = []
        for j, (w, p) in enumerate(zip(self.session.walkers, self.session.scenario.pedestrians, strict=True)):
            wtf = w.get_transform()
            ground = carla_to_physical(wtf.location.x, wtf.location.y, wtf.location.z - _half_height(w))
            m = self.motions[j]
            pose = p.pose if m is None else m.pose(p.pose)
            sk = body.pedestrian_skeleton(
                pose, ground, physical_yaw(wtf.rotation.yaw), self.time, p.appearance,
                look_at=cam.position if p.look_at_camera else None, phase=p.phase, sway=p.sway,
            )  # fmt: skip
            bodies.append((sk, p.appearance))
        return cam, bodies

    def frame_image(self) -> NDArray[np.uint8] | None:
        """The camera's latest image as RGB (decoded once per image)."""
        if self._image is None:
            return None
        if self._rgb is None:
            img = self._image
            self._rgb = bgra_to_rgb(img.raw_data, int(img.width), int(img.height))
        return self._rgb

    def send(self, command: ArrayLike) -> None:
        steer, accel = (float(u) for u in np.asarray(command, dtype=float).reshape(2))
        cmd = to_vehicle_command(steer, accel, float(self.ego_state()[3]), self.max_steer,
                                 self.session.options.pedals, self.frame.steer_sign())  # fmt: skip
        self.session.vehicle.apply_control(
            self.carla.VehicleControl(throttle=cmd.throttle, steer=cmd.steer, brake=cmd.brake)
        )

    def advance(self, duration: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        n = max(1, round(duration / self.delta))
        ego, peds = [], []
        for _ in range(n):
            self._walk(self.delta)
            try:
                self._frame_id = int(self.session.world.tick(self.session.options.timeout))
            except RuntimeError as exc:
                raise CarlaError(f"world.tick() failed at t = {self.time:.2f} s: {exc}") from None
            self.ticks += 1
            self._take_images(wait=self.session.options.sensor_tick == 0)
            ego.append(self.ego_state())
            peds.append(self.pedestrian_states()[0])
        return np.array(ego), np.array(peds)

    def _walk(self, h: float) -> None:
        """Before each tick (CARLA's WalkerControl): a walker without a behaviour keeps walking its
        scenario velocity; one with a behaviour (:class:`~trustnav.sim.driving.behaviour.PedestrianMotion`)
        is advanced ``h`` s (the tick; 0 before the first) from where CARLA has it, with the car where
        it is, and walks the velocity that gives (speed 0: it stands). With ``pose_walkers`` each
        walker's bones hold its pose, its moving pose while it walks."""
        c = self.carla
        walkers, specs = self.session.walkers, self.session.scenario.pedestrians
        ego = self.ego_state() if any(m is not None for m in self.motions) else np.zeros(4)
        for j, (w, p, m) in enumerate(zip(walkers, specs, self.motions, strict=True)):
            velocity, pose = p.velocity, p.pose
            if m is not None:
                loc = w.get_location()
                m.position = np.asarray(self.frame.from_carla(loc.x, loc.y)[:2], dtype=float)
                m.advance(h, ego)
                velocity, pose = m.velocity, m.pose(p.pose)
            speed = math.hypot(*velocity)
            if speed > 0 or m is not None:
                dx, dy = (1.0, 0.0) if speed == 0 else self.frame.vector_to_carla(velocity[0] / speed,
                                                                                  velocity[1] / speed)  # fmt: skip
                w.apply_control(c.WalkerControl(direction=c.Vector3D(x=dx, y=dy, z=0.0), speed=speed))
            if self.session.options.pose_walkers and pose != self._posed[j]:
                pose_walker(self.carla, w, pose)
                self._posed[j] = pose

    def _take_images(self, wait: bool) -> None:
        """Keep the newest queued camera image; with ``wait``, block (up to ``image_timeout``) until
        there is one of the current frame or later."""
        q = self.session.images
        while True:
            try:
                self._keep(q.get_nowait())
            except queue.Empty:
                break
        if not wait:
            return
        deadline = _time.monotonic() + self.image_timeout
        while self._image is None or (self._frame_id is not None and int(self._image.frame) < self._frame_id):
            remaining = deadline - _time.monotonic()
            try:
                if remaining <= 0:
                    raise queue.Empty
                self._keep(q.get(timeout=remaining))
            except queue.Empty:
                raise CarlaError(f"no camera image within {self.image_timeout:g} s of frame {self._frame_id}") from None

    def _keep(self, image: Any) -> None:
        self._image, self._rgb = image, None


class CarlaCamera:
    """The "renderer" of render sensing on CARLA: the camera's image of the current tick."""

    def __init__(self, world: CarlaWorld) -> None:
        self.world = world

    def render(self, camera: CameraPose, people: Any) -> NDArray[np.uint8]:
        img = self.world.frame_image()
        if img is None:
            raise CarlaError("the CARLA camera has produced no image yet")
        return img


def carla_scenario(
    scenario: DriveScenario,
    options: CarlaOptions,
    attentive: bool | None = None,
    control_rate: float | None = None,
) -> DriveScenario:
    """The scenario as driven on CARLA: behaviour and control rate as asked, the camera's field of
    view as CARLA's camera is set (``options.fov_deg``, default the scenario's); CARLA's car body
    pitches when it brakes, so the localiser's pitch uncertainty is at least 0.5 deg."""
    sc = prepare_scenario(scenario, attentive, control_rate)
    if options.fov_deg is not None:
        sc = replace(sc, camera=replace(sc.camera, fov_deg=float(options.fov_deg)))
    if sc.sensing.pitch_sigma_deg < 0.5:
        sc = replace(sc, sensing=replace(sc.sensing, pitch_sigma_deg=0.5))
    return sc


def run_carla_drive_episode(
    carla: ModuleType | Any,
    scenario: DriveScenario,
    options: CarlaOptions,
    sensing: str = "render",
    seed: int = 0,
    attentive: bool | None = None,
    capture_rate: float | None = None,
    control_rate: float | None = None,
    pipeline: Any = None,
    progress: Callable[[float, float], None] | None = None,
    on_session: Callable[[CarlaSession], None] | None = None,
    state: str = "perceived",
) -> DriveResult:
    """One drive of ``scenario`` on the CARLA server of ``options``: the trust-aware MPC, the trust
    memory and the metrics of ``trustnav drive``. ``render`` sensing needs a perception ``pipeline``.
    ``state``: "perceived" (the controller's pedestrians from CARLA's camera frames through the same
    localiser and tracker as ``trustnav drive``) or "true" (CARLA's walker states).
    The session is closed (settings restored, actors destroyed) however this returns or raises.
    ``on_session`` is called with the open session (e.g. to report the town)."""
    sc = carla_scenario(scenario, options, attentive, control_rate)
    if sensing == "render" and pipeline is None:
        raise ValueError("render sensing on CARLA needs a perception pipeline")
    with CarlaSession(carla, options, sc) as session:
        if on_session is not None:
            on_session(session)
        world = CarlaWorld(session, sc.camera)
        sensor = make_sensor(sensing, CarlaCamera(world) if sensing == "render" else None, pipeline)
        sim = DriveEnvironment(sc, seed=seed, sensor=sensor, capture_rate=capture_rate, world=world, state=state)
        return drive(sim, sensing, progress=progress)


def _half_height(walker: Any) -> float:
    """Half the walker's height (its location is the capsule's centre), 0.9 m if unknown."""
    try:
        h = float(walker.bounding_box.extent.z)
    except (AttributeError, TypeError, ValueError):
        return 0.9
    return h if 0.2 < h < 2.0 else 0.9
