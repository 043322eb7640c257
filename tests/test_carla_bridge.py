"""The CARLA bridge (issue #12), without a CARLA server.

The pure parts (coordinates, control maps, camera buffer, bone offsets) are tested directly and,
where the ``carla`` client is installed, against its real types. The session, the world and the
command run against ``fake_carla``: a small stand-in for the few ``carla`` classes the bridge uses,
with a kinematic car that follows CARLA's conventions (left-handed, positive steer turns right),
injected as the ``carla`` module. A test with a real server skips when none answers.
"""

from __future__ import annotations

import argparse
import dataclasses
import fnmatch
import json
import math
import os
import signal
import socket
import subprocess
import sys
import types

import numpy as np
import pytest

from trustnav.carla_bridge.control import PedalMap, VehicleCommand, max_steer_angle, to_vehicle_command
from trustnav.carla_bridge.frames import (
    MapFrame,
    bgra_to_rgb,
    carla_camera_project,
    carla_to_physical,
    physical_yaw,
)
from trustnav.carla_bridge.posing import bone_targets, pose_walker
from trustnav.carla_bridge.session import CarlaError, CarlaOptions, CarlaSession, CarlaUnavailable
from trustnav.geometry.camera import CameraPose, CameraSpec
from trustnav.sim.driving.world import load_drive_scenario

FRAMES = [MapFrame(), MapFrame(flip_y=True)]


# ---------------------------------------------------------------------------------------- fake carla
class _Vec:
    def __init__(self, x: float = 0.0, y: float = 0.0, z: float = 0.0) -> None:
        self.x, self.y, self.z = float(x), float(y), float(z)


class _Rotation:
    def __init__(self, pitch: float = 0.0, yaw: float = 0.0, roll: float = 0.0) -> None:
        self.pitch, self.yaw, self.roll = float(pitch), float(yaw), float(roll)


class _Transform:
    def __init__(self, location: _Vec | None = None, rotation: _Rotation | None = None) -> None:
        self.location = location or _Vec()
        self.rotation = rotation or _Rotation()


class _Settings:
    def __init__(self, synchronous_mode: bool = False, fixed_delta_seconds: float | None = None) -> None:
        self.synchronous_mode = synchronous_mode
        self.fixed_delta_seconds = fixed_delta_seconds
        self.no_rendering_mode = False

    def copy(self) -> _Settings:
        return _Settings(self.synchronous_mode, self.fixed_delta_seconds)


class _Blueprint:
    def __init__(self, bp_id: str) -> None:
        self.id = bp_id
        self.attributes: dict[str, str] = {}
        self.known = (
            {"role_name", "is_invincible"}
            if not bp_id.startswith("sensor")
            else {"image_size_x", "image_size_y", "fov", "sensor_tick", "bloom_intensity", "motion_blur_intensity"}
        )

    def has_attribute(self, name: str) -> bool:
        return name in self.known

    def set_attribute(self, name: str, value: str) -> None:
        if name not in self.known:
            raise IndexError(f"no attribute {name}")
        self.attributes[name] = value


class _Library:
    IDS = ("vehicle.tesla.model3", "sensor.camera.rgb", *(f"walker.pedestrian.{i:04d}" for i in range(1, 16)))

    def find(self, bp_id: str) -> _Blueprint:
        if bp_id not in self.IDS:
            raise IndexError(f"blueprint {bp_id!r} not found")
        return _Blueprint(bp_id)

    def filter(self, pattern: str) -> list[_Blueprint]:
        return [_Blueprint(i) for i in self.IDS[::-1] if fnmatch.fnmatch(i, pattern)]


class _Actor:
    def __init__(self, server: _Server, bp: _Blueprint, tf: _Transform, parent: _Actor | None = None) -> None:
        server.next_id += 1
        self.id, self.server, self.type_id = server.next_id, server, bp.id
        self.blueprint, self.transform, self.parent = bp, tf, parent
        self.spawn_z = tf.location.z
        self.velocity = _Vec()
        self.alive = True
        server.alive[self.id] = self

    def get_transform(self) -> _Transform:
        return self.transform

    def get_location(self) -> _Vec:
        return self.transform.location

    def get_velocity(self) -> _Vec:
        return self.velocity

    def destroy(self) -> bool:
        self.alive = False
        self.server.alive.pop(self.id, None)
        return True


class _Vehicle(_Actor):
    MAX_STEER_DEG = 35.0

    def __init__(self, *a) -> None:
        super().__init__(*a)
        self.control = types.SimpleNamespace(throttle=0.0, steer=0.0, brake=0.0)
        self.speed = 0.0

    def get_physics_control(self):
        wheels = [types.SimpleNamespace(max_steer_angle=a) for a in (self.MAX_STEER_DEG,) * 2 + (0.0,) * 2]
        return types.SimpleNamespace(wheels=wheels)

    def apply_control(self, control) -> None:
        self.control = control

    def set_target_velocity(self, v) -> None:
        yaw = math.radians(self.transform.rotation.yaw)
        self.speed = v.x * math.cos(yaw) + v.y * math.sin(yaw)

    def step(self, dt: float) -> None:
        """Kinematic bicycle in CARLA's frame: positive steer turns right, i.e. yaw grows (+x toward +y)."""
        c = self.control
        accel = 3.5 * c.throttle - 0.02 * self.speed * (c.throttle > 0) - 8.0 * c.brake
        delta = math.radians(c.steer * self.MAX_STEER_DEG)
        loc, rot = self.transform.location, self.transform.rotation
        yaw = math.radians(rot.yaw)
        loc.x += dt * self.speed * math.cos(yaw)
        loc.y += dt * self.speed * math.sin(yaw)
        loc.z = 0.0
        rot.yaw = math.degrees(yaw + dt * self.speed * math.tan(delta) / 2.9)
        self.speed = min(max(self.speed + accel * dt, 0.0), 15.0)
        yaw = math.radians(rot.yaw)
        self.velocity = _Vec(self.speed * math.cos(yaw), self.speed * math.sin(yaw), 0.0)


class _Walker(_Actor):
    BONES = ("crl_root", "crl_hips__C", "crl_neck__C", "crl_Head__C", "crl_arm__L", "crl_foreArm__L",
             "crl_arm__R", "crl_foreArm__R", "crl_hand__R")  # fmt: skip

    def __init__(self, *a) -> None:
        super().__init__(*a)
        self.bounding_box = types.SimpleNamespace(extent=_Vec(0.2, 0.2, 0.9))
        self.control = None
        self.bones_set = None
        self.blend = 0.0

    def apply_control(self, control) -> None:
        self.control = control

    def get_bones(self):
        rel = [types.SimpleNamespace(name=n, relative=_Transform(_Vec(0, 0, 0.1 * i), _Rotation(1.0, 2.0, 3.0)))
               for i, n in enumerate(self.BONES)]  # fmt: skip
        return types.SimpleNamespace(bone_transforms=rel)

    def set_bones(self, control) -> None:
        self.bones_set = control

    def blend_pose(self, blend: float) -> None:
        self.blend = blend

    def step(self, dt: float) -> None:
        if self.control is not None and self.control.speed > 0:
            d, s = self.control.direction, self.control.speed
            self.transform.location.x += dt * s * d.x
            self.transform.location.y += dt * s * d.y
            self.velocity = _Vec(s * d.x, s * d.y, 0.0)
        elif self.control is not None:  # speed 0: it stands
            self.velocity = _Vec(0.0, 0.0, 0.0)


class _Camera(_Actor):
    def __init__(self, *a) -> None:
        super().__init__(*a)
        self.callback = None

    def listen(self, callback) -> None:
        self.callback = callback

    def stop(self) -> None:
        self.callback = None
        self.server.log.append("camera stopped")

    def get_transform(self) -> _Transform:
        p, m = self.parent.transform, self.transform
        yaw = math.radians(p.rotation.yaw)
        loc = _Vec(p.location.x + m.location.x * math.cos(yaw) - m.location.y * math.sin(yaw),
                   p.location.y + m.location.x * math.sin(yaw) + m.location.y * math.cos(yaw),
                   p.location.z + m.location.z)  # fmt: skip
        return _Transform(loc, _Rotation(m.rotation.pitch, p.rotation.yaw, 0.0))

    def shoot(self, frame: int) -> None:
        if self.callback is not None:
            w, h = int(self.blueprint.attributes["image_size_x"]), int(self.blueprint.attributes["image_size_y"])
            self.callback(types.SimpleNamespace(frame=frame, width=w, height=h, raw_data=bytes(w * h * 4)))


class _World:
    def __init__(self, server: _Server) -> None:
        self.server = server
        self.settings = _Settings()
        self.frame = 100

    def get_map(self):
        road = types.SimpleNamespace(transform=_Transform(_Vec(0.0, 0.0, 0.25)))
        return types.SimpleNamespace(name="Carla/Maps/Town10HD_Opt", get_waypoint=lambda location: road)

    def get_settings(self) -> _Settings:
        return self.settings.copy()

    def apply_settings(self, settings: _Settings) -> int:
        self.server.log.append(f"settings sync={settings.synchronous_mode} dt={settings.fixed_delta_seconds}")
        self.settings = settings.copy()
        return self.frame

    def get_blueprint_library(self) -> _Library:
        return _Library()

    def spawn_actor(self, bp: _Blueprint, tf: _Transform, attach_to: _Actor | None = None) -> _Actor:
        if bp.id in self.server.fail_spawn:
            raise RuntimeError("Spawn failed because of collision at spawn position")
        tf = _Transform(_Vec(tf.location.x, tf.location.y, tf.location.z), _Rotation(
            tf.rotation.pitch, tf.rotation.yaw, tf.rotation.roll))  # fmt: skip
        cls = _Camera if bp.id.startswith("sensor") else _Walker if bp.id.startswith("walker") else _Vehicle
        actor = cls(self.server, bp, tf, attach_to)
        self.server.spawned.append(actor)
        return actor

    def tick(self, seconds: float = 0.0) -> int:
        self.server.ticks += 1
        if self.server.ticks == self.server.fail_tick:
            raise self.server.fail_with
        dt = self.settings.fixed_delta_seconds or 0.05
        for a in list(self.server.alive.values()):
            if isinstance(a, (_Vehicle, _Walker)):
                a.step(dt)
        self.frame += 1
        for a in list(self.server.alive.values()):
            if isinstance(a, _Camera):
                a.shoot(self.frame)
        return self.frame


class _Server:
    def __init__(self) -> None:
        self.up = True
        self.next_id = 0
        self.alive: dict[int, _Actor] = {}
        self.spawned: list[_Actor] = []
        self.log: list[str] = []
        self.ticks = 0
        self.fail_tick = -1
        self.fail_with: BaseException = RuntimeError("time-out of 10000ms while waiting for the simulator")
        self.fail_spawn: set[str] = set()
        self.world = _World(self)


def fake_carla(server: _Server) -> types.ModuleType:
    """A ``carla`` stand-in bound to one fake server."""
    m = types.ModuleType("carla")

    class Client:
        def __init__(self, host: str = "127.0.0.1", port: int = 2000, worker_threads: int = 0) -> None:
            self.timeout = None

        def set_timeout(self, seconds: float) -> None:
            self.timeout = seconds

        def get_server_version(self) -> str:
            if not server.up:
                raise RuntimeError("time-out of 2000ms while waiting for the simulator")
            return "0.9.16"

        def get_world(self) -> _World:
            return server.world

        def load_world_if_different(self, name: str) -> None:
            server.log.append(f"load {name}")

    m.Client = Client
    m.Location = m.Vector3D = _Vec
    m.Rotation, m.Transform, m.WorldSettings = _Rotation, _Transform, _Settings
    m.VehicleControl = lambda throttle=0.0, steer=0.0, brake=0.0: types.SimpleNamespace(
        throttle=throttle, steer=steer, brake=brake)  # fmt: skip
    m.WalkerControl = lambda direction=None, speed=0.0: types.SimpleNamespace(direction=direction, speed=speed)
    m.WalkerBoneControlIn = lambda bones: types.SimpleNamespace(bone_transforms=list(bones))
    return m


@pytest.fixture
def server():
    return _Server()


@pytest.fixture
def listening_port():
    """A local TCP port that accepts connections (the bridge probes host:port before connecting)."""
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen(8)
    yield s.getsockname()[1]
    s.close()


def _closed_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


# ---------------------------------------------------------------------------------------- coordinates
@pytest.mark.parametrize("frame", FRAMES, ids=["paper", "flip-y"])
def test_coordinates_round_trip(frame):
    rng = np.random.default_rng(0)
    for x, y, z, yaw in rng.uniform(-200, 200, size=(50, 4)):
        yaw = math.fmod(yaw, math.pi)
        assert np.allclose(frame.from_carla(*frame.to_carla(x, y, z)), (x, y, z))
        assert math.isclose(frame.yaw_from_carla(frame.yaw_to_carla(yaw)), yaw, abs_tol=1e-12)
        assert np.allclose(frame.vector_from_carla(*frame.vector_to_carla(x, y)), (x, y))
        assert -180.0 < frame.yaw_to_carla(yaw + 4 * math.pi) <= 180.0


def test_paper_frame_keeps_the_paper_numbers_and_flip_y_negates_y():
    sc = load_drive_scenario("case-1")
    paper, flip = MapFrame(), MapFrame(flip_y=True)
    assert paper.to_carla(*sc.ego_start) == (33.5, 129.0, 0.0)  # where the authors spawned
    assert paper.yaw_to_carla(sc.ego_yaw) == pytest.approx(-90.0)
    assert flip.to_carla(*sc.ego_start) == (33.5, -129.0, 0.0)
    assert flip.yaw_to_carla(sc.ego_yaw) == pytest.approx(90.0)
    assert flip.yaw_to_carla(math.radians(30)) == pytest.approx(-30.0)
    with pytest.raises(ValueError, match="finite"):
        paper.to_carla(float("nan"), 0.0)
    with pytest.raises(ValueError, match="flip_y"):
        MapFrame(flip_y=1)


@pytest.mark.parametrize("frame", FRAMES, ids=["paper", "flip-y"])
def test_heading_and_steering_agree_with_carla_conventions(frame):
    """A heading maps to CARLA's forward vector, and a turn commanded in scenario coordinates turns
    CARLA's car the same way (CARLA: positive steer = right = yaw toward +y)."""
    for yaw in np.linspace(-3.0, 3.0, 13):
        yc = math.radians(frame.yaw_to_carla(yaw))
        assert np.allclose(frame.vector_to_carla(math.cos(yaw), math.sin(yaw)), (math.cos(yc), math.sin(yc)))
    L, v, dt, steer = 2.9, 5.0, 0.05, 0.2  # scenario: positive steer, yaw grows
    x, y, yaw = 10.0, 20.0, 0.7
    cmd = to_vehicle_command(steer, 0.0, v, math.radians(35.0), steer_sign=frame.steer_sign())
    cx, cy, _ = frame.to_carla(x, y)
    cyaw = math.radians(frame.yaw_to_carla(yaw))
    for _ in range(20):  # the same bicycle in each frame, CARLA's with CARLA's steer convention
        x, y, yaw = x + dt * v * math.cos(yaw), y + dt * v * math.sin(yaw), yaw + dt * v * math.tan(steer) / L
        delta_c = cmd.steer * math.radians(35.0)
        cx, cy = cx + dt * v * math.cos(cyaw), cy + dt * v * math.sin(cyaw)
        cyaw += dt * v * math.tan(delta_c) / L
    assert np.allclose(frame.from_carla(cx, cy)[:2], (x, y))
    assert math.isclose(frame.yaw_from_carla(math.degrees(cyaw)), yaw, abs_tol=1e-9)


def test_physical_frame_projects_like_carlas_camera():
    """trustnav's camera model in the physical frame (y negated) sees CARLA points where CARLA's
    camera does: a point on the car's right (CARLA's right vector) lands right of the centre."""
    spec = CameraSpec(fov_deg=45.0)
    rng = np.random.default_rng(1)
    for yaw_c, pitch_c in ((-90.0, 0.0), (30.0, -5.0), (170.0, 3.0)):
        cam_c = np.array([33.5, 129.0, 1.7])
        cam = CameraPose(spec, carla_to_physical(*cam_c), physical_yaw(yaw_c), math.radians(-pitch_c))
        fwd = np.array([math.cos(math.radians(yaw_c)), math.sin(math.radians(yaw_c)), 0.0])
        right = np.array([-fwd[1], fwd[0], 0.0])
        pts = cam_c + 20 * fwd + rng.uniform(-5, 5, (20, 1)) * right + rng.uniform(-1.5, 1.5, (20, 1)) * [0, 0, 1]
        uv_c, d_c = carla_camera_project(pts, cam_c, yaw_c, pitch_c, spec.width, spec.height, spec.fov_deg)
        uv, d = cam.project(np.array([carla_to_physical(*p) for p in pts]))
        assert np.allclose(uv, uv_c) and np.allclose(d, d_c)
        uv_r, _ = carla_camera_project(cam_c + 20 * fwd + 3 * right, cam_c, yaw_c, 0.0, 1280, 720, 45.0)
        assert uv_r[0, 0] > 640


def test_with_real_carla_types_where_installed():
    carla = pytest.importorskip("carla")
    for yaw, pitch in ((-90.0, 0.0), (30.0, -10.0)):
        r = carla.Rotation(pitch=pitch, yaw=yaw, roll=0.0)
        f, rt = r.get_forward_vector(), r.get_right_vector()
        cy, sy = math.cos(math.radians(yaw)), math.sin(math.radians(yaw))
        assert np.allclose([f.x, f.y], [cy * math.cos(math.radians(pitch)), sy * math.cos(math.radians(pitch))],
                           atol=1e-6)  # fmt: skip
        assert np.allclose([rt.x, rt.y], [-sy, cy], atol=1e-6)
    cmd = to_vehicle_command(-0.3, 1.0, 3.0, math.radians(70.0))
    vc = carla.VehicleControl(throttle=cmd.throttle, steer=cmd.steer, brake=cmd.brake)
    assert vc.steer == pytest.approx(cmd.steer, abs=1e-6) and vc.brake == 0.0
    walker = _Walker(_Server(), _Blueprint("walker.pedestrian.0001"), _Transform())
    assert pose_walker(carla, walker, "distracted") == 6
    assert isinstance(walker.bones_set, carla.WalkerBoneControlIn) and walker.blend == 1.0
    settings = carla.WorldSettings(synchronous_mode=True, fixed_delta_seconds=0.05)
    assert settings.synchronous_mode and settings.fixed_delta_seconds == pytest.approx(0.05)


# ---------------------------------------------------------------------------------------- control, image, bones
def test_control_mapping():
    max_steer = math.radians(70.0)
    cmd = to_vehicle_command(math.radians(35.0), 1.75, 0.0, max_steer)
    assert cmd == VehicleCommand(steer=0.5, throttle=0.5, brake=0.0)
    assert to_vehicle_command(-2.0, 0.0, 5.0, max_steer).steer == -1.0  # clipped
    assert to_vehicle_command(0.1, 0.0, 5.0, max_steer, steer_sign=-1.0).steer == pytest.approx(-0.1 / max_steer)
    assert to_vehicle_command(0.0, -4.0, 5.0, max_steer) == VehicleCommand(0.0, 0.0, 0.5)
    assert to_vehicle_command(0.0, -20.0, 5.0, max_steer).brake == 1.0
    assert to_vehicle_command(0.0, 0.01, 5.0, max_steer) == VehicleCommand(0.0, 0.0, 0.0)  # deadband: coast
    p = PedalMap(full_throttle_accel=4.0, drag=0.1)
    assert p.pedals(2.0, speed=10.0) == (pytest.approx(0.75), 0.0)  # drag compensation
    assert max_steer_angle([70.0, 70.0, 0.0, 0.0]) == pytest.approx(max_steer)
    with pytest.raises(ValueError, match="max_steer_angle"):
        max_steer_angle([0.0, 0.0])
    with pytest.raises(ValueError, match="full_brake_decel"):
        PedalMap(full_brake_decel=0.0)
    with pytest.raises(ValueError, match="max_steer"):
        to_vehicle_command(0.0, 0.0, 0.0, 0.0)


def test_camera_buffer_decoding():
    w, h = 4, 3
    bgra = np.zeros((h, w, 4), np.uint8)
    bgra[0, 1] = (10, 20, 30, 255)  # B, G, R, A
    bgra[2, 3] = (1, 2, 3, 255)
    rgb = bgra_to_rgb(bgra.tobytes(), w, h)
    assert rgb.shape == (h, w, 3) and rgb.flags.c_contiguous
    assert tuple(rgb[0, 1]) == (30, 20, 10) and tuple(rgb[2, 3]) == (3, 2, 1)
    assert np.array_equal(bgra_to_rgb(memoryview(bgra.tobytes()), w, h), rgb)
    with pytest.raises(ValueError, match="47 bytes, expected 4 x 3 x 4 = 48"):
        bgra_to_rgb(bytes(47), w, h)


def test_bone_targets_come_from_the_walkers_bone_names():
    walker = _Walker(_Server(), _Blueprint("walker.pedestrian.0001"), _Transform())
    targets = {name: rot for name, _, rot in bone_targets(walker.get_bones(), "distracted")}
    assert set(targets) == {"crl_neck__C", "crl_Head__C", "crl_arm__L", "crl_foreArm__L", "crl_arm__R",
                            "crl_foreArm__R"}  # fmt: skip
    assert targets["crl_neck__C"] == (21.0, 2.0, 3.0)  # relative (1, 2, 3) + neck bend
    assert targets["crl_foreArm__L"][1] == pytest.approx(2.0 - 80.0)
    assert bone_targets(walker.get_bones(), "attentive") == []
    assert pose_walker(fake_carla(_Server()), walker, "attentive") == 0 and walker.bones_set is None
    with pytest.raises(ValueError, match="pose"):
        bone_targets(walker.get_bones(), "dancing")


# ---------------------------------------------------------------------------------------- session
def _options(port: int, **kw) -> CarlaOptions:
    return CarlaOptions(host="127.0.0.1", port=port, timeout=2.0, **kw)


def _assert_clean(server: _Server) -> None:
    assert server.alive == {}, "spawned actors left behind"
    assert server.world.settings.synchronous_mode is False and server.world.settings.fixed_delta_seconds is None
    assert "camera stopped" in server.log or not any(isinstance(a, _Camera) for a in server.spawned)


def test_session_spawns_as_the_scenario_says_and_cleans_up(server, listening_port):
    sc = load_drive_scenario("case-1")
    with CarlaSession(fake_carla(server), _options(listening_port, walker_yaws_deg=(60.0, 180.0)), sc) as s:
        assert server.world.settings.synchronous_mode and server.world.settings.fixed_delta_seconds == 0.05
        assert s.map_name.endswith("Town10HD_Opt") and s.server_version == "0.9.16"
        ego = s.vehicle.transform
        assert (ego.location.x, ego.location.y, ego.rotation.yaw) == (33.5, 129.0, pytest.approx(-90.0))
        assert s.vehicle.spawn_z == pytest.approx(0.25 + 0.5)  # above the road's waypoint
        assert s.vehicle.blueprint.attributes["role_name"] == "hero"
        cam = s.camera.blueprint.attributes
        assert (cam["image_size_x"], cam["image_size_y"], cam["fov"], cam["bloom_intensity"]) == (
            "1280", "720", "70.0", "0.0")  # fmt: skip
        assert (s.camera.transform.location.x, s.camera.transform.location.z) == (1.5, 1.7)
        assert s.camera.parent is s.vehicle
        att, dis = s.walkers
        assert (att.type_id, dis.type_id) == ("walker.pedestrian.0001", "walker.pedestrian.0009")  # indices 0, 8
        assert (att.transform.location.x, att.transform.location.y, att.transform.rotation.yaw) == (29.5, 101.0, 60.0)
        assert (dis.transform.location.x, dis.transform.rotation.yaw) == (37.5, 180.0)
        assert len(server.alive) == 4 and s.first_frame == 101
    _assert_clean(server)
    assert server.log[-1] != "settings sync=True dt=0.05"


@pytest.mark.parametrize("error", [RuntimeError("boom"), KeyboardInterrupt()], ids=["exception", "ctrl-c"])
def test_session_cleans_up_on_errors_and_interrupts(server, listening_port, error):
    with pytest.raises(type(error)):
        with CarlaSession(fake_carla(server), _options(listening_port), load_drive_scenario("case-2")):
            assert len(server.alive) == 3
            raise error
    _assert_clean(server)


def test_sigterm_during_a_session_cleans_up(server, listening_port):
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(KeyboardInterrupt):
        with CarlaSession(fake_carla(server), _options(listening_port), load_drive_scenario("case-1")):
            os.kill(os.getpid(), signal.SIGTERM)  # the session turns it into KeyboardInterrupt
            for _ in range(100):
                _ = sum(range(1000))  # the handler runs between bytecodes
    _assert_clean(server)
    assert signal.getsignal(signal.SIGTERM) is before and signal.getsignal(signal.SIGINT) is not signal.SIG_IGN


def test_session_cleans_up_when_spawning_fails(server, listening_port):
    server.fail_spawn = {"walker.pedestrian.0009"}
    with pytest.raises(CarlaError, match="could not spawn the walker distracted"):
        with CarlaSession(fake_carla(server), _options(listening_port), load_drive_scenario("case-1")):
            pass
    assert len(server.spawned) == 3
    _assert_clean(server)


def test_session_reports_an_unreachable_server(server, listening_port):
    port = _closed_port()
    with pytest.raises(CarlaUnavailable, match=f"no CARLA server at 127.0.0.1:{port}"):
        CarlaSession(fake_carla(server), _options(port), load_drive_scenario("case-1")).__enter__()
    server.up = False  # the port answers but the simulator does not
    with pytest.raises(CarlaUnavailable, match=f"no CARLA server answered at 127.0.0.1:{listening_port}"):
        with CarlaSession(fake_carla(server), _options(listening_port), load_drive_scenario("case-1")):
            pass
    assert server.alive == {}


def test_options_are_validated():
    with pytest.raises(ValueError, match="port"):
        CarlaOptions(port=0)
    with pytest.raises(ValueError, match="timeout"):
        CarlaOptions(timeout=-1.0)
    with pytest.raises(ValueError, match="distracted_walker"):
        CarlaOptions(distracted_walker=-1)
    with pytest.raises(ValueError, match="fov_deg"):
        CarlaOptions(fov_deg=500.0)


# ---------------------------------------------------------------------------------------- command
def _args(port: int, out, **kw) -> argparse.Namespace:
    base = dict(case="case-1", sensing="keypoints", attentive=None, seed=0, rate=None, control_rate=None,
                out=str(out), no_video=True, host="127.0.0.1", port=port, timeout=2.0, world="carla",
                overwrite=False)  # fmt: skip
    return argparse.Namespace(**{**base, **kw})


def run_carla_drive(args: argparse.Namespace) -> int:
    """``trustnav drive ... --world carla`` (the CLI's one drive command, output checks included)."""
    from trustnav.cli import drive

    return drive.run(args)


def test_command_without_the_carla_package(monkeypatch, capsys, tmp_path):
    from trustnav.cli import main

    monkeypatch.setitem(sys.modules, "carla", None)  # import carla -> ImportError
    assert main(["drive", "case-1", "--world", "carla", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install 'trustnav[carla]'" in err[0] and "Traceback" not in err[0]


def test_command_without_a_server(monkeypatch, capsys, tmp_path, server):
    from trustnav.cli import main

    monkeypatch.setitem(sys.modules, "carla", fake_carla(server))
    port = _closed_port()
    assert main(["drive", "case-1", "--world", "carla", "--port", str(port), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"no CARLA server at localhost:{port}" in err[0] and "CarlaUE4" in err[0]


def test_command_drives_case_1_on_the_fake_server(monkeypatch, capsys, tmp_path, server, listening_port):
    monkeypatch.setitem(sys.modules, "carla", fake_carla(server))
    assert run_carla_drive(_args(listening_port, tmp_path)) == 0
    _assert_clean(server)
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["world"] == "carla" and m["control_rate"] == 20.0
    assert m["reached_goal"] and m["margin_violations"] == 0
    att, dis = m["pedestrians"]
    assert att["frames_seen"] >= 3 and att["final_trust"] > dis["final_trust"]
    assert att["min_distance"] < dis["min_distance"]  # the trust-aware bend, through CARLA's conventions
    assert (tmp_path / "top_view.png").exists() and len(list((tmp_path / "frames").glob("*.png"))) == m["frames"]
    dis_walker = next(a for a in server.spawned if a.type_id == "walker.pedestrian.0009")
    assert dis_walker.blend == 1.0  # posed through the bone API
    assert "map Carla/Maps/Town10HD_Opt" in capsys.readouterr().err


@pytest.mark.parametrize(("error", "code"), [(KeyboardInterrupt(), 130), (RuntimeError("lost"), 1)],
                         ids=["ctrl-c", "server-error"])  # fmt: skip
def test_command_cleans_up_when_a_run_is_cut_short(monkeypatch, capsys, tmp_path, server, listening_port, error,
                                                  code):  # fmt: skip
    server.fail_tick, server.fail_with = 30, error
    monkeypatch.setitem(sys.modules, "carla", fake_carla(server))
    assert run_carla_drive(_args(listening_port, tmp_path, case="case-2", attentive=True)) == code
    _assert_clean(server)
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "restored" in err and "destroyed" in err


def test_the_core_package_never_imports_carla():
    code = ("import sys, trustnav, trustnav.cli, trustnav.sim.driving.episode, trustnav.carla_bridge, "
            "trustnav.carla_bridge.command; print('carla' in sys.modules)")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_with_a_real_server_if_one_answers(tmp_path):
    """End to end against a real CARLA server at $TRUSTNAV_CARLA_HOST:$TRUSTNAV_CARLA_PORT (default
    localhost:2000); skipped when none answers."""
    host = os.environ.get("TRUSTNAV_CARLA_HOST", "localhost")
    port = int(os.environ.get("TRUSTNAV_CARLA_PORT", "2000"))
    try:
        socket.create_connection((host, port), timeout=2.0).close()
    except OSError:
        pytest.skip(f"no CARLA server at {host}:{port}")
    carla = pytest.importorskip("carla")
    from trustnav.carla_bridge.world import run_carla_drive_episode

    options = CarlaOptions(host=host, port=port, timeout=20.0)
    result = run_carla_drive_episode(carla, load_drive_scenario("case-1"), options, sensing="keypoints")
    m = result.metrics()
    assert m["world"] == "carla" and m["control_steps"] > 0


def test_flip_y_frame_drives_the_mirrored_placement(server, listening_port):
    from trustnav.carla_bridge.world import run_carla_drive_episode

    options = _options(listening_port, frame=MapFrame(flip_y=True))
    r = run_carla_drive_episode(fake_carla(server), load_drive_scenario("case-1"), options, sensing="keypoints")
    ego = next(a for a in server.spawned if isinstance(a, _Vehicle))
    assert ego.transform.location.y < -74.0  # CARLA y = -y: the car drove from -129 toward -75
    m = r.metrics()
    assert m["reached_goal"] and m["margin_violations"] == 0
    att, dis = m["pedestrians"]
    assert att["final_trust"] > dis["final_trust"] and att["min_distance"] < dis["min_distance"]
    assert np.allclose(r.ego[0], [33.5, 129.0, -math.pi / 2, 0.0])  # back in scenario coordinates
    _assert_clean(server)


@pytest.mark.parametrize("caution", [True, False], ids=["caution", "paper"])
def test_a_walker_steps_out_on_carla_as_her_behaviour_says_and_the_cautious_car_keeps_r(server, listening_port,
                                                                                      caution):  # fmt: skip
    """step-out.toml on (the fake) CARLA: the texter stands at the kerb until her ``start_time``, then
    walks across in her moving pose (before, the bridge walked every walker at its velocity from
    t = 0); the trust-aware caution slows the car and keeps R from her, the paper's controller does
    not (issue 34: it works in CARLA)."""
    from pathlib import Path

    from trustnav.carla_bridge.world import run_carla_drive_episode

    sc = load_drive_scenario(Path(__file__).parents[1] / "examples" / "scenarios" / "step-out.toml")
    sc = dataclasses.replace(sc, control=dataclasses.replace(sc.control, caution=caution))
    start = sc.pedestrians[0].behaviour.start_time
    r = run_carla_drive_episode(fake_carla(server), sc, _options(listening_port), sensing="keypoints")
    texter = r.pedestrians[:, 0]
    before, after = r.times < start - 0.05, r.times > start + 1.0
    assert np.allclose(texter[before], sc.pedestrians[0].position, atol=1e-6)  # she stands until her step-out
    walked = texter[after][0] - texter[before][-1]
    assert walked[0] < -1.0 and abs(walked[1]) < 1e-6  # then walks across the lane (-x) at 1.4 m/s
    walker = next(a for a in server.spawned if isinstance(a, _Walker))
    assert walker.blend == 1.0 and walker.bones_set is not None  # posed as she texts, walking too
    m = r.metrics()
    closest = float(r.distances[:, 0].min())
    if caution:
        assert closest >= sc.control.safety_radius and m["reached_goal"] and m["road_departure_max"] == 0.0
    else:
        assert closest < sc.control.safety_radius  # the paper's controller meets her late
    _assert_clean(server)


def test_a_walker_walks_her_path_and_waits_at_the_kerb_for_a_gap_on_carla(server, listening_port):
    """kerb-gap.toml on (the fake) CARLA: the crosser walks to the kerb, waits there while the car's
    gap is short, then crosses to her last waypoint and stands; the car reaches the goal keeping R."""
    from pathlib import Path

    from trustnav.carla_bridge.world import run_carla_drive_episode

    sc = load_drive_scenario(Path(__file__).parents[1] / "examples" / "scenarios" / "kerb-gap.toml")
    kerb, end = (np.array(w) for w in sc.pedestrians[0].behaviour.waypoints)
    r = run_carla_drive_episode(fake_carla(server), sc, _options(listening_port), sensing="keypoints")
    crosser = r.pedestrians[:, 0]
    at_kerb = np.hypot(*(crosser - kerb).T) < 0.06
    assert at_kerb.sum() * (r.times[1] - r.times[0]) > 0.5  # she waited for a gap (1.1 s in trustnav's world)
    assert np.hypot(*(crosser[-1] - end)) < 0.06  # then crossed to her last point and stands there
    m = r.metrics()
    assert m["reached_goal"] and float(r.distances.min()) >= sc.control.safety_radius
    _assert_clean(server)


def test_every_pose_of_a_pedestrian_can_be_posed_on_carla():
    from trustnav.carla_bridge.posing import BONE_POSES
    from trustnav.sim.driving import body

    assert set(body.POSES) <= set(BONE_POSES)


def test_render_sensing_perceives_carlas_image(server, listening_port):
    from trustnav.carla_bridge.world import CarlaCamera, CarlaWorld
    from trustnav.sim.driving.episode import DriveEnvironment, SimWorld, World
    from trustnav.sim.driving.sensing import RenderSensor

    seen = []

    class Pipeline:
        def __call__(self, frame):
            seen.append(frame.shape)
            return []

    sc = load_drive_scenario("case-1")
    with CarlaSession(fake_carla(server), _options(listening_port), sc) as session:
        world = CarlaWorld(session, sc.camera)
        assert isinstance(world, World) and isinstance(SimWorld(sc), World)  # one interface
        sim = DriveEnvironment(sc, sensor=RenderSensor(CarlaCamera(world), Pipeline()), world=world)
        for _ in range(21):
            if sim.capture_due():
                sim.capture()
            sim.advance([0.0, 1.0])
        assert seen == [(720, 1280, 3)] * 2 and sim.frames[1].image.shape == (720, 1280, 3)
        assert sim.time == pytest.approx(21 * 0.05) and sim.state[3] > 0.5
        assert sim.frames[0].ground_truth == 2  # both walkers in view of CARLA's camera at the start
    _assert_clean(server)


def test_drive_builds_real_carla_values_where_installed(server, listening_port):
    """The bridge's Transform, Location, Rotation, VehicleControl, WalkerControl and
    WalkerBoneControlIn calls, made with the real client's types (the server still the fake)."""
    carla = pytest.importorskip("carla")
    from trustnav.carla_bridge.world import run_carla_drive_episode

    m = fake_carla(server)
    for name in ("Location", "Vector3D", "Rotation", "Transform", "VehicleControl", "WalkerControl",
                 "WalkerBoneControlIn"):  # fmt: skip
        setattr(m, name, getattr(carla, name))
    sc = load_drive_scenario("case-2").with_attention(False)  # walking, and posed through the bones
    r = run_carla_drive_episode(m, sc, _options(listening_port), sensing="keypoints")
    assert r.metrics()["reached_goal"]
    walker = next(a for a in server.spawned if isinstance(a, _Walker))
    assert isinstance(walker.control, carla.WalkerControl) and walker.control.speed == pytest.approx(0.1)
    assert isinstance(walker.bones_set, carla.WalkerBoneControlIn)
    ego = next(a for a in server.spawned if isinstance(a, _Vehicle))
    assert isinstance(ego.control, carla.VehicleControl)
    _assert_clean(server)


def test_render_sensing_on_carla_takes_the_realtime_perceiver_when_asked(monkeypatch, tmp_path, server,
                                                                        listening_port):  # fmt: skip
    """``--world carla --sensing render --perception realtime``: CARLA's images go through the same
    perception as trustnav's renders, with the realtime pose backend (issue 20: the CARLA bridge
    uses the streaming perceiver); the backend is closed when the run ends."""
    import trustnav.sim.driving.sensing as sensing
    from trustnav.perception.realtime import RealtimePoseBackend

    monkeypatch.setitem(sys.modules, "carla", fake_carla(server))
    built = []
    make = sensing.make_render_pipeline

    def spy(sc, rate=None, realtime=False, search_seconds=None):
        built.append(make(sc, rate, realtime=realtime, search_seconds=search_seconds))
        built[-1].backend.close = lambda *a, **k: closed.append(True)  # the run must close it
        return built[-1]

    closed: list[bool] = []
    monkeypatch.setattr(sensing, "make_render_pipeline", spy)
    args = _args(listening_port, tmp_path, sensing="render", perception="realtime", rate=10.0, duration=0.3,
                 attentive=True)  # fmt: skip
    assert run_carla_drive(args) == 0
    assert len(built) == 1 and isinstance(built[0].backend, RealtimePoseBackend) and closed == [True]
    _assert_clean(server)
    RealtimePoseBackend.close(built[0].backend)
