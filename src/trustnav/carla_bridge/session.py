"""A CARLA session: connect, load or reuse a town, synchronous mode, spawn the scenario's actors,
and always undo it all.

:class:`CarlaSession` is a context manager. Entering connects (``host``, ``port``, ``timeout``),
loads ``town`` if given and different (else reuses the running world), keeps the world's settings,
switches to synchronous mode with ``fixed_delta_seconds`` = the controller's step, and spawns the
ego vehicle, its RGB camera and the walkers. Leaving, by any path (normal end, an exception,
Ctrl-C, or SIGTERM, which is turned into KeyboardInterrupt while a session is open), stops the
camera, restores the settings kept and destroys every actor it spawned (newest first); a second
Ctrl-C during that cleanup is ignored. Each cleanup step runs even if another fails.

The ``carla`` module is passed in (:func:`load_carla` imports it), never imported at module level:
the core package does not need it and tests give a stand-in.
"""

from __future__ import annotations

import importlib
import math
import queue
import signal
import socket
import threading
from dataclasses import dataclass, field
from types import ModuleType
from typing import Any

from trustnav.carla_bridge.control import PedalMap
from trustnav.carla_bridge.frames import MapFrame
from trustnav.outputs import no_interrupts
from trustnav.sim.driving.world import DriveScenario

__all__ = [
    "INSTALL_HINT",
    "CarlaError",
    "CarlaNotInstalled",
    "CarlaOptions",
    "CarlaSession",
    "CarlaUnavailable",
    "load_carla",
]

INSTALL_HINT = "pip install 'trustnav[carla]'"
START_HINT = (
    "start one with ./CarlaUE4.sh (Linux; CarlaUE4.exe on Windows; add -RenderOffScreen on a "
    "headless machine), or point --host/--port at a running one"
)


class CarlaError(RuntimeError):
    """Something went wrong talking to CARLA (spawning, ticking, a missing camera frame)."""


class CarlaNotInstalled(CarlaError):
    """The ``carla`` client package is not installed."""


class CarlaUnavailable(CarlaError):
    """No CARLA server answered at host:port within the timeout."""


def load_carla() -> ModuleType:
    """Import the ``carla`` client package, or raise :class:`CarlaNotInstalled` saying how to get it."""
    try:
        return importlib.import_module("carla")
    except ImportError as exc:
        raise CarlaNotInstalled(
            f"the CARLA client package is not installed ({exc}); install it with {INSTALL_HINT}"
        ) from None


@dataclass(frozen=True)
class CarlaOptions:
    """How to run a scenario on a CARLA server.

    ``town``: a map to load (e.g. "Town03"; loaded only if different), None to reuse the running
    world. ``frame``: scenario <-> CARLA coordinates (default: the paper's numbers). Camera:
    ``fov_deg`` None = the scenario's (70 deg; the authors' CARLA camera had 45), mount, size and
    pitch from the scenario; ``sensor_tick`` 0 = an image every tick (the loop takes the one of the
    capture tick; the authors' 1.0 s works too, the loop then takes the latest image).
    Walkers: ``attentive_walker`` / ``distracted_walker``: a blueprint id, or an index into the
    sorted ``walker.pedestrian.*`` ids (the authors': 0 attentive, 8 distracted); ``walker_yaws_deg``:
    one yaw per pedestrian in scenario coordinates (degrees), None = the scenario's ``body_yaw_deg``
    (the authors' Case I: 60 attentive, 180 distracted). ``ego_z``, ``walker_z``: spawn heights (m)
    above the road at the ego's start (its map waypoint). ``pedals``: acceleration -> throttle and
    brake. ``pose_walkers``: pose the walkers through the bone API.
    """

    host: str = "localhost"
    port: int = 2000
    timeout: float = 10.0
    town: str | None = None
    frame: MapFrame = field(default_factory=MapFrame)
    vehicle_blueprint: str = "vehicle.tesla.model3"
    fov_deg: float | None = None
    sensor_tick: float = 0.0
    attentive_walker: int | str = 0
    distracted_walker: int | str = 8
    walker_yaws_deg: tuple[float, ...] | None = None
    ego_z: float = 0.5
    walker_z: float = 1.0
    pedals: PedalMap = field(default_factory=PedalMap)
    pose_walkers: bool = True

    def __post_init__(self) -> None:
        if not isinstance(self.host, str) or not self.host:
            raise ValueError(f"host must be a non-empty string, got {self.host!r}")
        if isinstance(self.port, bool) or not isinstance(self.port, int) or not 1 <= self.port <= 65535:
            raise ValueError(f"port must be an integer in [1, 65535], got {self.port!r}")
        if not (isinstance(self.timeout, (int, float)) and math.isfinite(self.timeout) and self.timeout > 0):
            raise ValueError(f"timeout must be a positive number of seconds, got {self.timeout!r}")
        if self.town is not None and (not isinstance(self.town, str) or not self.town):
            raise ValueError(f"town must be a map name or None, got {self.town!r}")
        if not isinstance(self.frame, MapFrame):
            raise ValueError(f"frame must be a MapFrame, got {self.frame!r}")
        if self.fov_deg is not None and not 1.0 <= self.fov_deg <= 170.0:
            raise ValueError(f"fov_deg must be in [1, 170] degrees or None, got {self.fov_deg!r}")
        if not (math.isfinite(self.sensor_tick) and self.sensor_tick >= 0):
            raise ValueError(f"sensor_tick must be a non-negative number of seconds, got {self.sensor_tick!r}")
        for name in ("attentive_walker", "distracted_walker"):
            v = getattr(self, name)
            ok = (isinstance(v, str) and bool(v)) or (isinstance(v, int) and v >= 0)
            if isinstance(v, bool) or not ok:
                raise ValueError(f"{name} must be a blueprint id or an index >= 0, got {v!r}")
        if self.walker_yaws_deg is not None:
            yaws = tuple(self.walker_yaws_deg)
            if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in yaws):
                raise ValueError(f"walker_yaws_deg must be finite degrees, got {self.walker_yaws_deg!r}")
            object.__setattr__(self, "walker_yaws_deg", tuple(float(v) for v in yaws))
        for name in ("ego_z", "walker_z"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and 0 <= v <= 10):
                raise ValueError(f"{name} must be in [0, 10] m, got {v!r}")

    @property
    def address(self) -> str:
        return f"{self.host}:{self.port}"


class CarlaSession:
    """Connect, configure and spawn on enter; undo on exit (see the module's docstring).

    After entering: ``client``, ``world``, ``map_name``, ``vehicle``, ``camera``, ``walkers``
    (scenario order), ``images`` (a queue the camera fills), ``delta`` (s per tick).
    """

    def __init__(self, carla: ModuleType | Any, options: CarlaOptions, scenario: DriveScenario) -> None:
        self.carla = carla
        self.options = options
        self.scenario = scenario
        self.delta = 1.0 / scenario.control.rate
        self.client: Any = None
        self.world: Any = None
        self.map_name = ""
        self.server_version = ""
        self.vehicle: Any = None
        self.camera: Any = None
        self.walkers: list[Any] = []
        self.actors: list[Any] = []  # everything spawned, in spawn order
        self.images: queue.Queue[Any] = queue.Queue()
        self.cleanup_errors: list[str] = []
        self.first_frame: int | None = None  # the frame id of the tick that placed the actors
        self._settings: Any = None  # the world's settings before this session changed them
        self._old_sigterm: Any = None

    # -------------------------------------------------------------- lifetime
    def __enter__(self) -> CarlaSession:
        self._catch_sigterm()
        try:
            self.connect()
            self.configure()
            self.spawn()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Stop the camera, restore the settings, destroy the spawned actors; never raises (problems
        are kept in ``cleanup_errors``)."""
        with no_interrupts():  # cleanup is never cut short
            if self.camera is not None:
                self._try("stop the camera", self.camera.stop)
            if self._settings is not None and self.world is not None:
                self._try("restore the world settings", self.world.apply_settings, self._settings)
                self._settings = None
            for actor in reversed(self.actors):
                self._try(f"destroy actor {getattr(actor, 'id', '?')}", actor.destroy)
            self.actors.clear()
            self.walkers, self.vehicle, self.camera = [], None, None
        self._restore_sigterm()

    def _try(self, what: str, fn: Any, *args: Any) -> None:
        try:
            fn(*args)
        except Exception as exc:  # keep cleaning up
            self.cleanup_errors.append(f"could not {what}: {exc}")

    # -------------------------------------------------------------- steps
    def connect(self) -> None:
        """Probe host:port, ask the server's version (within min(timeout, 3 s)), then the world
        (``town`` loaded if different) with the full timeout."""
        o = self.options
        first = min(float(o.timeout), 3.0)  # a silent server is reported within a few seconds
        _probe(o.host, o.port, first)
        try:
            self.client = self.carla.Client(o.host, o.port)
            self.client.set_timeout(first)
            self.server_version = str(self.client.get_server_version())
        except RuntimeError as exc:
            raise CarlaUnavailable(f"no CARLA server answered at {o.address} within {first:g} s ({exc}); "
                                   f"{START_HINT}") from None  # fmt: skip
        self.client.set_timeout(float(o.timeout))
        try:
            if o.town is not None:
                self.client.load_world_if_different(o.town)
            self.world = self.client.get_world()
            self.map_name = str(self.world.get_map().name)
        except RuntimeError as exc:
            raise CarlaError(f"could not get the world{' ' + o.town if o.town else ''} at {o.address}: {exc}") from None

    def configure(self) -> None:
        """Keep the settings, then synchronous mode with a fixed step of one control period."""
        self._settings = self.world.get_settings()
        settings = self.world.get_settings()
        settings.synchronous_mode = True
        settings.fixed_delta_seconds = self.delta
        self.world.apply_settings(settings)

    def spawn(self) -> None:
        """The ego at the scenario's start (at its ``ego_speed``), its camera, the walkers; one tick to
        place them."""
        c, o, sc = self.carla, self.options, self.scenario
        lib = self.world.get_blueprint_library()
        bp = lib.find(o.vehicle_blueprint)
        if bp.has_attribute("role_name"):
            bp.set_attribute("role_name", "hero")
        ground = self._ground_z(*o.frame.to_carla(*sc.ego_start))
        x, y, z = o.frame.to_carla(*sc.ego_start, ground + o.ego_z)
        tf = c.Transform(c.Location(x=x, y=y, z=z), c.Rotation(yaw=o.frame.yaw_to_carla(sc.ego_yaw)))
        self.vehicle = self._spawn(bp, tf, f"ego vehicle {o.vehicle_blueprint} at {_xy(x, y)}")
        if sc.ego_speed > 0:  # already moving, as the scenario starts it (applied at the first tick)
            vx, vy = o.frame.vector_to_carla(sc.ego_speed * math.cos(sc.ego_yaw), sc.ego_speed * math.sin(sc.ego_yaw))
            self.vehicle.set_target_velocity(c.Vector3D(x=vx, y=vy, z=0.0))
        cam = sc.camera
        cbp = lib.find("sensor.camera.rgb")
        attrs = {"image_size_x": cam.width, "image_size_y": cam.height, "fov": o.fov_deg or cam.fov_deg,
                 "sensor_tick": o.sensor_tick}  # fmt: skip
        for name, value in attrs.items():
            cbp.set_attribute(name, str(value))
        for name in ("bloom_intensity", "lens_flare_intensity", "motion_blur_intensity"):  # the authors': off
            if cbp.has_attribute(name):
                cbp.set_attribute(name, "0.0")
        mount = c.Transform(c.Location(x=cam.forward, y=0.0, z=cam.up), c.Rotation(pitch=-cam.pitch_deg))
        self.camera = self._spawn(cbp, mount, "RGB camera", attach_to=self.vehicle)
        self.camera.listen(self.images.put)
        ids = sorted(b.id for b in lib.filter("walker.pedestrian.*"))
        yaws = o.walker_yaws_deg or tuple(p.body_yaw_deg for p in sc.pedestrians)
        if len(yaws) != len(sc.pedestrians):
            raise ValueError(f"walker_yaws_deg has {len(yaws)} yaws for {len(sc.pedestrians)} pedestrians")
        for p, yaw_deg in zip(sc.pedestrians, yaws, strict=True):
            choice = o.attentive_walker if p.attentive else o.distracted_walker
            wbp = lib.find(_walker_id(choice, ids))
            if wbp.has_attribute("is_invincible"):
                wbp.set_attribute("is_invincible", "false")
            x, y, z = o.frame.to_carla(*p.position, ground + o.walker_z)
            tf = c.Transform(c.Location(x=x, y=y, z=z), c.Rotation(yaw=o.frame.yaw_to_carla(math.radians(yaw_deg))))
            self.walkers.append(self._spawn(wbp, tf, f"walker {p.name} at {_xy(x, y)}"))
        self.first_frame = int(self.world.tick(float(o.timeout)))

    def _ground_z(self, x: float, y: float, _z: float = 0.0) -> float:
        """Height of the road nearest CARLA (x, y) (the map's waypoint), 0 if the map has none."""
        try:
            wp = self.world.get_map().get_waypoint(self.carla.Location(x=x, y=y, z=0.0))
            z = float(wp.transform.location.z)
        except (AttributeError, RuntimeError, TypeError, ValueError):
            return 0.0
        return z if math.isfinite(z) else 0.0

    def _spawn(self, blueprint: Any, transform: Any, what: str, attach_to: Any = None) -> Any:
        try:
            if attach_to is None:
                actor = self.world.spawn_actor(blueprint, transform)
            else:
                actor = self.world.spawn_actor(blueprint, transform, attach_to=attach_to)
        except RuntimeError as exc:
            where = self.map_name or "the world"
            hint = "a collision at the spawn point? is this the town the scenario is for?"
            raise CarlaError(f"could not spawn the {what} in {where}: {exc} ({hint})") from None
        self.actors.append(actor)
        return actor

    # -------------------------------------------------------------- signals
    def _catch_sigterm(self) -> None:
        """While open, SIGTERM raises KeyboardInterrupt (so ``with`` cleans up); main thread only."""
        if threading.current_thread() is not threading.main_thread():
            return
        self._old_sigterm = signal.signal(signal.SIGTERM, _raise_interrupt)

    def _restore_sigterm(self) -> None:
        if self._old_sigterm is not None:
            signal.signal(signal.SIGTERM, self._old_sigterm)
            self._old_sigterm = None


def _raise_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def _probe(host: str, port: int, timeout: float) -> None:
    """Fail fast (one line) when nothing listens at host:port."""
    try:
        with socket.create_connection((host, port), timeout=timeout):
            pass
    except OSError as exc:
        raise CarlaUnavailable(f"no CARLA server at {host}:{port} ({exc.strerror or exc}); {START_HINT}") from None


def _walker_id(choice: int | str, ids: list[str]) -> str:
    if isinstance(choice, str):
        return choice
    if not ids:
        raise CarlaError("the blueprint library has no walker.pedestrian.* blueprints")
    if choice >= len(ids):
        raise CarlaError(f"walker index {choice} out of range: {len(ids)} walker.pedestrian.* blueprints")
    return ids[choice]


def _xy(x: float, y: float) -> str:
    return f"CARLA ({x:g}, {y:g})"
