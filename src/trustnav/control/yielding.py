"""Yielding: a layer above the MPC that makes a car on a road brake and wait for pedestrians it cannot pass.

A car on a lane with the road's edges as barriers (:class:`~trustnav.control.barrier.RoadEdgeBarrier`)
cannot swerve round a pedestrian who stands or walks in the middle of the road: keeping R would
take it off the road. The MPC alone, looking a horizon of about half a second ahead, finds that out
when it is too late to brake. This layer looks further, with the same constant-velocity prediction
as the MPC, and moves the point the lane cost tracks to a stop short of such a pedestrian, so the
car slows in time, waits, and goes on when the way is clear. It never touches the CBF rows: safety
is exactly the MPC's (with caution on, the controller also bounds its speed rows by the cap: a yield
is a stop that no barrier's push creeps the car past).

For each pedestrian, predicted every ``sample`` s over ``lookahead`` s (lateral offset ``d`` from
the road's line, ``r`` its R plus any uncertainty margin; the car's centre may use
``[-room_right, room_left]``):

- **A side to pass on** has room when the car's centre can be ``r`` from the pedestrian there and
  stay on the road (``d + r <= room_left - tolerance`` on the left, ``d - r >= -room_right +
  tolerance`` on the right). A pedestrian crossing the road (lateral speed above ``crossing_speed``)
  is passed behind, never on the side they walk toward.
- **Blocking**: no side to pass on, while the pedestrian is within ``r`` of the corridor and ahead
  of the car's centre (beside or behind it, braking would stop the car next to them: the MPC's
  barrier keeps R there).
- **Yield** to a blocking pedestrian unless the car, at its present speed, has passed them
  ``clear_time`` s before their blocking begins. The stop is ``r + gap`` short of the nearest place
  the pedestrian blocks; the speed is capped to brake there at ``deceleration``.
- **An uncertain velocity** (``covariances``: the estimates' covariances of (x, y, v_x, v_y), of
  which the sigma of the speed across the road counts; ``z``: the one-sided quantile of the
  controller's confidence) enters the judgement "the car is past them well before they block" on
  the unsafe side: their blocking is taken to begin when it would at their estimated velocity
  raised by z sigma toward the road's line (a velocity estimated from a frame or two lags a
  step-out), so the car passes in front only if it would at that speed too. Who blocks is judged
  at the estimated velocity, as the MPC predicts: the bound never makes someone standing at the
  kerb a crosser.
- **Whom it waits for is remembered** (given the step's ``time`` and ``safety_radius``, as the
  controller does with caution on). A pedestrian the car yields to who then vanishes from its inputs
  (no pedestrian within ``rematch`` of where she was predicted: her track dropped while she crosses
  in front of the stopped car, cut off by the image's edge) is kept, predicted at her last velocity
  across the road (along it, a frame's estimate is mostly the monocular range's drift), and blocks
  while that prediction is ahead of the car and within R of the lane's line or of the line the car
  heads along (the MPC, not knowing her, would drive the one, and a car stopped turned toward where
  she walks drives the other first). She is clear of a line only once R
  past it the way she walks: a crosser whose track is dropped before she reaches the lane (a slow
  one below the image) is still to cross it. A dropped track says that the camera
  no longer sees her, not that she has left the car's way. Her stop lies z sigma of her last
  position along the road further short (given ``covariances``): a track coasted out of view drifts
  along the line of sight, the monocular range.
- **Released by evidence, never by a clock**: one it remembers is released when she is found
  again (within ``rematch`` of her prediction, widened by z sigma of her range), when her
  prediction is clear of the car's way or behind it (above), or when the camera looks where she
  could be and finds nobody (given the camera's view, ``view_deg``: her predicted place, z sigma
  of her range either way along the road and z sigma of her speed across it times the time since
  either way across it, with half a metre either side for her body, inside its horizontal view
  and between ``view_near`` and ``view_far`` ahead of it, for ``view_confirm`` s: the frames its
  tracker needs to confirm a person; a prediction walks at a speed estimated from a frame or two,
  and she may be where a slower or faster walk took her). Negative information
  counts only where the sensor looks (occlusion-aware planning's "unobserved is not empty"; e.g.
  Orzechowski et al. 2018 prune a reachable set by the visible area, never by elapsed time).
- **Passed around, not forgotten**: after ``memory`` s of waiting for one it remembers, the car
  stops waiting for her to cross and passes around where she would be: she joins the MPC's
  pedestrians (:meth:`Yielder.remembered`) where her last sighting puts her (given ``sightings``,
  carried at her velocity across the road then: a track coasted out of view has lost her speed
  and grown metres uncertain), trusted least (unseen), her margin z sigma of that sighting carried
  (her range's and her speed's across the road times the time since), and is judged by the room
  test as anyone seen, until one of the releases above, or her way leaves the
  road (R beyond its edge). Before, the car forgot her after ``memory`` s: a texter it stopped
  for, turned away by her barrier so that its one forward camera no longer saw her, was passed at
  1.42 m (issue 34, varied Case II worlds at 1 frame/s). A car that cannot see her, and has no
  room around where she would be, waits: with one forward camera that is the price of not
  passing blind (docs/drive.md, "Varied worlds").
- **Room behind a crosser beside others too** (with ``time`` and ``safety_radius``): for a crosser
  (lateral speed above ``crossing_speed``) the car's centre on a side of her must also be outside
  anyone else's region (their radius about their predicted place) within both radii of her along
  the road; where such a region covers the nearest place, the place moves past it, and the side has
  room if that place is still on the road. (Standing pedestrians are judged one at a time, as
  before: two on opposite kerbs whose regions meet are passed between by the barrier, relaxed and
  reported, not waited for until their unseen regions stop growing.) A crosser walking away to one side with a
  bystander on the other kerb leaves a sliver the car cannot fit in: passing behind her there,
  the barrier's push from her growing region drove the car into the bystander's corner, where it
  stopped trapped (a bicycle cannot back out) until her track was dropped and it drove past her
  within R. The car now waits until there is room for it between them.
- **Released only clear of the line the car heads along** (with ``time`` and ``heading``): a crosser
  it yielded to at the last step and still sees (within ``rematch`` of her remembered prediction)
  keeps blocking, once the room test above would let the car pass behind her, while she is ahead
  within her radius of the line the car heads along and that line is turned toward where she walks
  (at her distance ahead, more than ``tolerance`` toward her side). A car that stopped turned
  toward her side (the barrier bent it round her estimate) and went once there was room behind her
  drove toward her first; a car along the road, or turned away, passes behind her as before.
- **A stopped car waits where it stopped** (``settle``, ``settle_speed``): a car slower than
  ``settle_speed`` whose stop lies less than ``settle`` ahead takes it as reached (cap 0). The stop
  follows her estimate, which moves by tenths of a metre from step to step; a car stopped turned
  toward a crosser was given a stop 0.2 m further ahead for one step, its cap of 1.2 m/s let it
  accelerate, the command latency carried it to 0.75 m/s and it rolled from 4.1 to 2.2 m of her
  (issue 34, a lane crossing with the near-field sensor).

Applies to a car that follows a lane (``LaneTrackingCost``) with a ``RoadEdgeBarrier``. Without road
edges the car may swerve round anyone (the paper's Section IV controller) and the layer is idle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

from trustnav.control._validate import require_positive

__all__ = ["YieldConfig", "YieldDecision", "Yielder"]

_NO_COVARIANCES = np.zeros((0, 4, 4))
_NONE_PASSING = (np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))


@dataclass(frozen=True)
class YieldConfig:
    """Thresholds of :class:`Yielder` (module docstring); times in s, distances in m, speeds in
    m/s, ``deceleration`` in m/s^2. ``memory``: how long the car waits for one it remembers to
    cross before it passes around where she would be. The camera's view, for releasing whom it
    remembers when it looks where she would be: ``view_deg`` its horizontal field of view (0: not
    known; then only seeing her, passing her or her prediction leaving the way release her),
    ``view_forward`` its place ahead of the car's reference point, ``view_near`` / ``view_far``
    the distances ahead of it between which a standing person is whole in the image and
    detected, and ``view_confirm`` how long her place must have been in view, with nobody found
    there, before she is released (the camera periods its tracker needs to confirm a person, and
    the latencies: the caution's reaction time). ``settle``: a car slower than ``settle_speed``
    whose stop lies less than ``settle`` ahead takes it as reached and waits (a stop set by her
    estimate moves by tenths of a metre from step to step; crept up to, its speed cap lets a
    stopped car roll toward her)."""

    lookahead: float = 4.0
    sample: float = 0.25
    deceleration: float = 3.0
    gap: float = 1.0
    tolerance: float = 0.1
    crossing_speed: float = 0.3
    clear_time: float = 1.0
    rematch: float = 2.0
    memory: float = 8.0
    view_deg: float = 0.0
    view_forward: float = 0.0
    view_near: float = 0.0
    view_far: float = 30.0
    view_confirm: float = 0.0
    settle: float = 0.5
    settle_speed: float = 0.3

    def __post_init__(self) -> None:
        names = ("lookahead", "sample", "deceleration", "gap", "tolerance", "crossing_speed", "clear_time",
                 "rematch", "memory", "view_forward", "view_near", "view_far", "view_confirm", "settle",
                 "settle_speed")  # fmt: skip
        require_positive("yielding", self, names, zero_ok=("view_forward", "view_near", "view_confirm", "settle"))
        v = self.view_deg
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 <= v < 180.0:
            raise ValueError(f"yielding view_deg must be in [0, 180) degrees (0: the camera's view unknown), got {v!r}")


@dataclass
class _Remembered:
    """One the yielding layer remembers: predicted at ``position + velocity (t - time)`` (her
    velocity across the road), ``sigma`` m of her position along the road and ``speed_sigma`` m/s of
    her speed across it, since when her place has been in the camera's view (``looked``; nan: it is
    not), and her last sighting (``sighting``, the same fields, or None), from which she is passed
    around once the wait is over."""

    position: NDArray[np.float64]
    velocity: NDArray[np.float64]
    time: float
    sigma: float
    looked: float = math.nan
    sighting: _Remembered | None = None
    speed_sigma: float = 0.0

    def at(self, time: float) -> NDArray[np.float64]:
        return self.position + self.velocity * (float(time) - self.time)

    def drift(self, time: float) -> float:
        """The sigma of how far across the road she may be from her prediction at ``time``: her speed's
        across it, carried since."""
        return self.speed_sigma * max(float(time) - self.time, 0.0)

    def sigma_at(self, time: float) -> float:
        """Her position's sigma ``time`` s on: her range's and her speed's across the road, carried."""
        return math.hypot(self.sigma, self.drift(time))


@dataclass(frozen=True)
class YieldDecision:
    """Where the car must stop (``stop``: a point on its lane), the speed cap that brakes there, the
    pedestrian it yields to (index into this step's pedestrians; -1: one it remembers, no longer
    among them) and a note for the step's report."""

    stop: NDArray[np.float64]
    speed_cap: float
    pedestrian: int
    note: str


class Yielder:
    """Call :meth:`decide` with the step's car and pedestrians. Its one state: the pedestrian it
    last yielded to (position, velocity, time), for when she vanishes from the inputs (module
    docstring); :meth:`reset` forgets her."""

    def __init__(self, config: YieldConfig) -> None:
        self.config = config
        self._memory: _Remembered | None = None  # the one it waits for, no longer among its inputs
        # those it waited for ``memory`` s without finding them again: passed around where they would be
        self._passing: list[_Remembered] = []

    def reset(self) -> None:
        self._memory = None
        self._passing = []

    def _looked(self, item: _Remembered, pred: NDArray[np.float64], position: NDArray[np.float64],
                heading: float | None, time: float, axis: NDArray[np.float64], reach: float,
                across: float = 0.0) -> bool:  # fmt: skip
        """Whether the camera has looked where a remembered pedestrian could be for ``view_confirm``
        s and found nobody there (the caller has checked that no one is within ``rematch``): her
        prediction ``pred``, ``reach`` m either way along the road ``axis`` (z sigma of her range,
        the error of a place estimated by a monocular camera) and ``across`` m either way across it
        (z sigma of her speed across the road times the time since it was estimated), each corner
        with her body's half width, inside the image; keeps in ``item`` since when it looks (module
        docstring)."""
        c = self.config
        if c.view_deg <= 0.0 or heading is None:
            return False
        u = np.array([math.cos(heading), math.sin(heading)])
        cam = position + c.view_forward * u
        normal = np.array([-axis[1], axis[0]])
        in_view = True
        # the region is a rectangle and the view convex: its corners and centre in view, it is
        for p in [pred] + [pred + a * reach * axis + b * across * normal for a in (-1, 1) for b in (-1, 1)]:
            rel = p - cam
            ahead = float(rel @ u)
            dist = float(np.hypot(*rel))
            bearing = abs(math.atan2(float(u[0] * rel[1] - u[1] * rel[0]), ahead))
            # her whole body (half a metre either side of her place) inside the image, at a distance it detects
            in_view = in_view and (
                c.view_near <= ahead
                and dist <= c.view_far
                and (bearing + math.atan2(0.5, dist) <= math.radians(0.5 * c.view_deg))
            )
        if not in_view:
            item.looked = math.nan
            return False
        if math.isnan(item.looked):
            item.looked = float(time)
        return float(time) - item.looked >= c.view_confirm

    def remembered(
        self,
        time: float,
        position: NDArray[np.float64],
        heading: float,
        road_start: NDArray[np.float64],
        road_normal: NDArray[np.float64],
        room: tuple[float, float],
        safety_radius: float,
        pedestrians: NDArray[np.float64],
        seen_times: NDArray[np.float64] | None = None,
        z: float = 1.645,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Those it waited for ``memory`` s without finding them again, to be passed around where
        they would be (module docstring, "Passed around, not forgotten"), at ``time``: positions
        (M, 2), velocities (M, 2) and the sigma (M,) of each position (her range's and her speed's
        across the road, carried). One is released
        once the car's ``position`` is ``safety_radius`` past her along the road, her prediction
        is ``safety_radius`` beyond the road's edge the way she walks (``room``: the car centre's
        (left, right) from the road's line through ``road_start``), one of the step's
        ``pedestrians`` (N, 2) is within ``rematch`` of her (and, given their ``seen_times`` (N,),
        was seen after her: a track coasted there is no sighting), or the camera (the car's
        ``heading``, rad) has looked where she could be (z sigma of her range either way) for
        ``view_confirm`` s."""
        if not self._passing:
            return _NONE_PASSING
        axis = np.array([road_normal[1], -road_normal[0]])
        seen = np.asarray(pedestrians, dtype=float).reshape(-1, 2)
        keep, out = [], []
        r = float(safety_radius)
        found = None if seen_times is None else np.asarray(seen_times, dtype=float).reshape(-1)
        for item in self._passing:
            vel, t0, sigma = item.velocity, item.time, item.sigma
            pred = item.at(time)
            d = float((pred - road_start) @ road_normal)
            off_road = _past(d - room[0], float(vel @ road_normal), r) if d > 0 else _past(
                d + room[1], float(vel @ road_normal), r)  # fmt: skip
            if float((pred - position) @ axis) < -r or off_road:
                continue
            near = np.hypot(*(seen - pred).T) <= self._gate(sigma, z) if len(seen) else np.zeros(0, dtype=bool)
            if found is not None and len(found) == len(near):
                near &= found > t0
            if near.any():
                continue  # found again: her track is the camera's
            if self._looked(item, pred, position, heading, time, axis, z * sigma, z * item.drift(time)):
                continue
            keep.append(item)
            out.append((pred, vel, item.sigma_at(time)))
        self._passing = keep
        if not out:
            return _NONE_PASSING
        return (np.array([o[0] for o in out]), np.array([o[1] for o in out]),
                np.array([o[2] for o in out], dtype=float))  # fmt: skip

    def _gate(self, sigma: float, z: float) -> float:
        """How near her prediction someone must be to be her, found again: ``rematch``, widened by z
        sigma of her range (a monocular placement jumps metres along the line of sight)."""
        return self.config.rematch + float(z) * sigma

    @property
    def passing(self) -> bool:
        """Whether it holds someone it waited for and now passes around (:meth:`remembered`)."""
        return bool(self._passing)

    @property
    def remembers(self) -> bool:
        """Whether it holds someone it yielded to (:meth:`decide` with nobody seen then still judges her)."""
        return self._memory is not None

    def decide(
        self,
        position: NDArray[np.float64],
        speed: float,
        lane_start: NDArray[np.float64],
        lane_goal: NDArray[np.float64],
        road_start: NDArray[np.float64],
        road_normal: NDArray[np.float64],
        room: tuple[float, float],
        pedestrians: NDArray[np.float64],
        velocities: NDArray[np.float64],
        radii: NDArray[np.float64],
        covariances: NDArray[np.float64] | None = None,
        z: float = 1.645,
        time: float | None = None,
        safety_radius: float | None = None,
        heading: float | None = None,
        sightings: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]] | None = None,
    ) -> YieldDecision | None:
        """The stop for the nearest pedestrian the car must yield to, or None (drive on).

        position (2,) and speed of the car; its lane ``lane_start -> lane_goal``; the road's line
        through ``road_start`` with unit ``road_normal`` (left of the driving direction) and the
        room (left, right) the car's centre has from it; pedestrians and velocities (N, 2); radii
        (N,) (R plus any uncertainty margin); ``covariances`` (N, 4, 4) of each estimated (x, y, v_x,
        v_y) (None: the velocities are taken as exact) and ``z`` the quantile of its velocity;
        ``time`` (s) and ``safety_radius`` (R): remember whom the car waits for (None: stateless);
        ``heading`` (rad) of the car: one it remembers also blocks within R of the line it heads
        along (None: the lane's direction); ``sightings``: each pedestrian's state (N, 4),
        covariance (N, 4, 4) and time (N,) when the camera last saw her, from which one it waited
        for is passed around after ``memory`` s (None: from her last input)."""
        if not len(pedestrians) and self._memory is None:
            return None  # nobody seen, nobody remembered: nothing to yield to (and nothing to remember)
        c = self.config
        axis = np.array([road_normal[1], -road_normal[0]])  # the driving direction
        left, right = room
        s_car = float((position - road_start) @ axis)
        n_real = len(pedestrians)
        remember = time is not None and safety_radius is not None
        d_lane = float((lane_start - road_start) @ road_normal)  # the lane's line, where the car drives
        # the line the car heads along (a car stopped turned toward where she walks drives it first)
        ahead = axis if heading is None else np.array([math.cos(heading), math.sin(heading)])
        extra = np.zeros(1)  # how much further short of her the stop lies (one remembered: her range error)
        held = -1  # the pedestrian it yielded to at the last step, still seen (index into this step's)
        if remember and self._memory is not None:  # she vanished from the inputs? keep her prediction
            item = self._memory
            vel, t0, along_sigma = item.velocity, item.time, item.sigma
            pred = item.at(time)
            near = float(safety_radius)
            # clear of a line once R past it the way she walks (one still walking toward it is not)
            off_lane = _past(float((pred - road_start) @ road_normal) - d_lane, float(vel @ road_normal), near)
            rel = pred - position
            off_heading = _past(float(ahead[0] * rel[1] - ahead[1] * rel[0]),
                                float(ahead[0] * vel[1] - ahead[1] * vel[0]), near)  # fmt: skip
            gone = (off_lane and off_heading) or float((pred - road_start) @ axis) <= s_car
            dist = np.hypot(*(np.asarray(pedestrians, dtype=float).reshape(-1, 2) - pred).T) if n_real else None
            # found again near her prediction (a monocular place: a track's next placement jumped 2.2 m)
            seen = dist is not None and float(dist.min()) <= self._gate(along_sigma, z)
            waited = float(time) - t0 > c.memory
            if seen and not waited:
                held = int(dist.argmin())  # still seen: released only once clear of the line it heads along
            if not (gone or seen):  # the camera looked where she could be and found nobody: gone
                gone = self._looked(item, pred, position, heading, float(time), axis, float(z) * along_sigma,
                                    float(z) * item.drift(float(time)))  # fmt: skip
            if gone or seen or waited:
                if not (gone or seen):  # waited for long enough, not found: passed around, not forgotten,
                    # where her last sighting says she would be (a track coasted out of view has lost her speed)
                    self._passing.append(item.sighting or item)
                self._memory = None
            else:
                pedestrians = np.vstack([np.asarray(pedestrians, dtype=float).reshape(-1, 2), pred])
                velocities = np.vstack([np.asarray(velocities, dtype=float).reshape(-1, 2), vel])
                radii = np.append(np.asarray(radii, dtype=float), near)
                extra[0] = float(z) * along_sigma
                if covariances is not None:
                    covariances = np.concatenate([np.asarray(covariances, dtype=float), np.zeros((1, 4, 4))])
        if len(pedestrians) == 0:
            return None
        cov = _NO_COVARIANCES if covariances is None else np.ascontiguousarray(covariances, dtype=float)
        if cov.shape[0] and cov.shape != (len(pedestrians), 4, 4):
            raise ValueError(f"covariances must have shape ({len(pedestrians)}, 4, 4), got {cov.shape}")
        stop_s, j = _blocking(
            np.ascontiguousarray(pedestrians, dtype=float), np.ascontiguousarray(velocities, dtype=float),
            np.ascontiguousarray(radii, dtype=float), np.ascontiguousarray(road_start, dtype=float), axis,
            np.ascontiguousarray(road_normal, dtype=float), float(left), float(right), s_car, float(c.lookahead),
            float(c.sample), float(c.crossing_speed), float(c.tolerance), float(c.clear_time), float(c.gap),
            max(float(speed), 0.1), cov, float(z), n_real, d_lane, np.ascontiguousarray(position, dtype=float),
            np.ascontiguousarray(ahead, dtype=float), extra, held, remember,
        )  # fmt: skip
        if remember and 0 <= j < n_real:
            # remembered as crossing: her velocity across the road only (along it, a frame's estimate
            # is the monocular range's drift; kept, it moved her prediction, and the stop, ahead of a
            # creeping car while she crossed in front of it)
            across = float(np.asarray(velocities[j], dtype=float) @ road_normal) * np.asarray(road_normal, dtype=float)
            # and her position's uncertainty along the road (the monocular range's), which sets how far
            # short of her remembered place the car stops
            along_sigma = 0.0 if not cov.shape[0] else _spread(cov[j, :2, :2], axis)
            sighting = None
            if sightings is not None:  # where the camera last saw her, carried at her velocity then
                x_s, p_s, t_s = sightings
                v_s = float(np.asarray(x_s[j][2:4], dtype=float) @ road_normal) * np.asarray(road_normal, dtype=float)
                p_j = np.asarray(p_s[j], dtype=float)
                sig_s, sig_v = _spread(p_j[:2, :2], axis), _spread(p_j[2:4, 2:4], road_normal)
                sighting = _Remembered(np.array(x_s[j][:2], dtype=float), v_s, float(t_s[j]), sig_s, speed_sigma=sig_v)
            # and her speed's across the road: where she may have walked to, for looking where she could be
            speed_sigma = 0.0 if not cov.shape[0] else _spread(cov[j, 2:4, 2:4], road_normal)
            self._memory = _Remembered(np.array(pedestrians[j], dtype=float), across, float(time), along_sigma,
                                       sighting=sighting, speed_sigma=speed_sigma)  # fmt: skip
        best = None if j < 0 else (stop_s, j)
        if best is None:
            return None
        stop_s, j = best
        room_to_stop = max(stop_s - s_car, 0.0)
        if float(speed) < c.settle_speed and room_to_stop < c.settle:
            room_to_stop = 0.0  # stopped just short of a stop that moves with her estimate: wait there
        cap = math.sqrt(2.0 * c.deceleration * room_to_stop)
        lane = lane_goal - lane_start
        length = float(np.hypot(*lane))
        lane_dir = lane / length
        s_lane = float((position - lane_start) @ lane_dir)  # the car on its lane
        along = s_lane + (stop_s - s_car) / max(float(axis @ lane_dir), 1e-6)
        along = min(max(along, min(0.01, length)), length)  # never the lane's start: a lane needs a length
        stop = lane_start + along * lane_dir
        who = "a pedestrian the car cannot pass on the road"
        if j >= n_real:
            who = "a pedestrian it no longer sees, last seen crossing in front of it"
            j = -1  # not one of this step's pedestrians
        if room_to_stop > 0:
            note = f"yielding: stopping {room_to_stop:.1f} m ahead for {who}"
        else:
            note = f"yielding: waiting for {who}"
        return YieldDecision(stop, cap, j, note)


def _spread(cov: NDArray[np.float64], direction: NDArray[np.float64]) -> float:
    """The sigma of a 2 x 2 covariance ``cov`` along the unit ``direction``."""
    return math.sqrt(max(float(direction @ cov @ direction), 0.0))


def _past(offset: float, speed: float, near: float) -> bool:
    """A remembered pedestrian ``offset`` m beside a line (signed), moving ``speed`` m/s across it,
    is clear of it once ``near`` m past it the way she walks; one walking toward it is not (she has
    yet to cross it). Without a speed across it, ``near`` either side."""
    if speed == 0.0:
        return abs(offset) >= near
    return offset * math.copysign(1.0, speed) >= near


@njit(cache=True)
def _blocking(peds, vels, radii, road_start, axis, normal, left, right, s_car, lookahead, sample, crossing, tol,
              clear_time, gap, v, cov, z, n_real, d_lane, car, ahead, extra, held, joint):  # fmt: skip
    """The nearest stop (along the road) for a pedestrian who blocks the corridor ahead within the
    lookahead, and who it is ((0, -1): none); one compiled pass of :meth:`Yielder.decide`'s test:
    sampled every ``sample`` s at constant velocity, a pedestrian blocks where they are within their
    radius of the corridor, ahead of the car, and leave no room on either side (a walker crossing
    toward a side closes it); one the car passes well before they block, at their estimated
    velocity and at it raised by z sigma (its component across the road, from ``cov`` (N, 4, 4);
    none where ``cov`` is empty) toward the road's line, is skipped. Pedestrians from ``n_real`` on
    are remembered, not seen: they block within their radius of the lane's line (``d_lane`` from the
    road's line) or of the line the car heads along (``ahead``, through ``car``), and their stop lies
    ``extra[j - n_real]`` further short (their remembered position's range error). ``joint``: a
    side's room ends at the region of anyone else beside them along the road (module docstring)."""
    ts = np.arange(0.0, lookahead + 1e-9, sample)
    n_t = ts.shape[0]
    s = np.empty(n_t)
    n_p = peds.shape[0]
    d_all = np.empty((n_p, n_t))  # everyone's offset from the road's line and place along it, at
    s_all = np.empty((n_p, n_t))  # their estimated velocity (``joint``: the room beside another)
    if joint:
        for i in range(n_p):
            for k in range(n_t):
                px = peds[i, 0] + vels[i, 0] * ts[k] - road_start[0]
                py = peds[i, 1] + vels[i, 1] * ts[k] - road_start[1]
                d_all[i, k] = px * normal[0] + py * normal[1]
                s_all[i, k] = px * axis[0] + py * axis[1]
    best_stop, best_j = 0.0, -1
    for j in range(peds.shape[0]):
        r = radii[j]
        v_lat = vels[j, 0] * normal[0] + vels[j, 1] * normal[1]
        walks_left = v_lat > crossing
        walks_right = v_lat < -crossing
        d0 = (peds[j, 0] - road_start[0]) * normal[0] + (peds[j, 1] - road_start[1]) * normal[1]
        toward = -1.0 if d0 > 0.0 else 1.0
        first = -1
        low = np.inf
        begins = np.inf  # the earliest blocking of either velocity
        fast = 0.0
        for h in range(2):
            if h == 1:
                if first <= 0 or cov.shape[0] == 0:
                    break
                var = (cov[j, 2, 2] * normal[0] * normal[0] + 2.0 * cov[j, 2, 3] * normal[0] * normal[1]
                       + cov[j, 3, 3] * normal[1] * normal[1])  # fmt: skip
                fast = z * math.sqrt(max(var, 0.0))  # only where the estimated velocity leaves the car first
                if not fast > 0.0:
                    break
            vx = vels[j, 0] + toward * fast * normal[0]
            vy = vels[j, 1] + toward * fast * normal[1]
            for k in range(n_t):
                px = peds[j, 0] + vx * ts[k] - road_start[0]
                py = peds[j, 1] + vy * ts[k] - road_start[1]
                sk = px * axis[0] + py * axis[1]
                if h == 0:
                    s[k] = sk
                d = px * normal[0] + py * normal[1]
                # the nearest place for the car's centre on each side of her, moved past anyone
                # else's region there (beside her along the road: within both radii)
                c_left, c_right = d + r, d - r
                if joint and (walks_left or walks_right):  # behind a crosser: where the car is sent
                    for _ in range(n_p):
                        moved = False
                        for i in range(n_p):
                            if i != j and abs(s_all[i, k] - sk) < radii[i] + r:
                                lo_i, hi_i = d_all[i, k] - radii[i], d_all[i, k] + radii[i]
                                if lo_i < c_left < hi_i:
                                    c_left, moved = hi_i, True
                                if lo_i < c_right < hi_i:
                                    c_right, moved = lo_i, True
                        if not moved:
                            break
                room_left = (c_left <= left - tol) and not walks_left
                room_right = (c_right >= -right + tol) and not walks_right
                near = (d - r < left) and (d + r > -right)
                # one it no longer sees (j >= n_real) blocks within r of the lane's line: the MPC,
                # not knowing her, would not steer round her
                off = abs(ahead[0] * (peds[j, 1] + vy * ts[k] - car[1]) - ahead[1] * (peds[j, 0] + vx * ts[k] - car[0]))
                if j >= n_real:
                    blocks = (abs(d - d_lane) < r or off < r) and sk > s_car
                else:
                    blocks = near and sk > s_car and not room_left and not room_right
                    if j == held and (walks_left or walks_right) and not blocks:
                        # a crosser it waits for keeps it waiting while within r of the line it heads
                        # along: a car stopped turned toward where she walks would drive into her
                        # (turned toward her side: at her distance ahead, its line has moved more than
                        # ``tolerance`` toward where she walks; a car along the road passes behind her)
                        fwd = ahead[0] * (px + road_start[0] - car[0]) + ahead[1] * (py + road_start[1] - car[1])
                        turned = (ahead[0] * normal[0] + ahead[1] * normal[1]) * (1.0 if walks_left else -1.0) * fwd
                        blocks = off < r and fwd > 0.0 and turned > tol
                if blocks:
                    begins = min(begins, ts[k])
                    if h == 1:
                        break
                    if first < 0:
                        first = k
                    low = min(low, sk)
        if first < 0:
            continue
        if first > 0:
            top = s[0]
            for k in range(1, first):
                top = max(top, s[k])
            if (top + r - s_car) / v + clear_time <= begins:
                continue  # the car is past them well before they block
        stop = low - r - gap - (extra[j - n_real] if j >= n_real else 0.0)
        if best_j < 0 or stop < best_stop:
            best_stop, best_j = stop, j
    return best_stop, best_j
