"""The one episode engine: every kind of episode runs through trustnav.sim.engine."""

from __future__ import annotations

import numpy as np
import pytest

from trustnav.sim import engine
from trustnav.sim.engine import (
    RECORD_FIELDS,
    Decision,
    Environment,
    EpisodeResult,
    FunctionController,
    Observation,
    Rollout,
    Sample,
    run,
)


@pytest.fixture
def runs(monkeypatch):
    """Every call of engine.run, with its world (counted where the episode kinds call it)."""
    seen: list[tuple[Environment, EpisodeResult]] = []
    real = engine.run

    def spy(world, controller, **kw):
        res = real(world, controller, **kw)
        seen.append((world, res))
        return res

    for mod in ("trustnav.sim.paper", "trustnav.sim.random_worlds", "trustnav.sim.driving.episode"):
        monkeypatch.setattr(f"{mod}.run", spy)
    return seen


def _assert_record_shape(rec: dict) -> None:
    assert tuple(k for k in rec if k in RECORD_FIELDS) == RECORD_FIELDS
    assert len(rec["ped_min_distance"]) == len(rec["ped_trust"]) == rec["n_p"]
    assert rec["steps"] > 0 and rec["safety_radius"] > 0 and rec["horizon"] >= 1


def test_paper_random_and_drive_run_on_the_engine_with_one_record_shape(runs):
    from trustnav.sim.driving import load_drive_scenario, run_drive
    from trustnav.sim.paper import load_scenario, run_episode
    from trustnav.sim.random_worlds import RandomWorldSpec, run_world, sample_world

    ep = run_episode(load_scenario("paper-2"))
    rec_w = run_world(sample_world(RandomWorldSpec(family="bicycle"), 2))
    dr = run_drive(load_drive_scenario("case-1"), seed=0)
    assert [type(w).__name__ for w, _ in runs] == ["PaperEnvironment", "RandomEnvironment", "DriveEnvironment"]
    assert all(isinstance(w, Environment) for w, _ in runs)
    recs = [res.to_record() for _, res in runs]
    for rec in recs:
        _assert_record_shape(rec)
    assert [list(r)[: len(RECORD_FIELDS)] for r in recs] == [list(RECORD_FIELDS)] * 3
    # the episode types are read from the engine's result
    assert ep.result is runs[0][1] and dr.episode is runs[2][1]
    assert ep.reached_goal and recs[0]["breach"] is False
    assert rec_w["steps"] == recs[1]["steps"] and rec_w["min_distance"] == recs[1]["min_distance"]
    # the drive's closest approach is measured over the plant's sub-steps, at most the sampled one
    assert np.all(np.array(recs[2]["ped_min_distance"]) <= dr.distances.min(axis=0) + 1e-12)
    assert recs[2]["ped_min_distance"][0] < recs[2]["ped_min_distance"][1]  # Case I: bends away from the distracted


def test_same_seed_same_episode():
    from trustnav.sim.driving import load_drive_scenario, run_drive
    from trustnav.sim.random_worlds import RandomWorldSpec, run_world, sample_world

    sc = load_drive_scenario("case-2").with_attention(False)
    a, b, c = (run_drive(sc, seed=s) for s in (4, 4, 5))
    assert np.array_equal(a.ego, b.ego) and np.array_equal(a.trusts, b.trusts)
    assert not np.array_equal(a.trusts, c.trusts)  # the seed drives the sensing noise
    timing = ("step_ms", "step_cpu")
    w1, w2 = (run_world(sample_world(RandomWorldSpec(), 7)) for _ in range(2))
    assert {k: v for k, v in w1.items() if not k.startswith(timing)} == {
        k: v for k, v in w2.items() if not k.startswith(timing)
    }


def test_drive_world_resets_to_the_same_episode():
    from trustnav.sim.driving import DriveEnvironment, load_drive_scenario
    from trustnav.sim.engine import make_mpc

    sc = load_drive_scenario("case-1")
    sim = DriveEnvironment(sc, seed=1)

    def policy():
        return make_mpc(sc.vehicle.model(), sc.control.cost(sc.ego_start, sc.goal), sc.control.config(), timed=True)

    first = run(sim, policy(), max_steps=30)
    again = run(sim, policy(), seed=1, max_steps=30)
    assert first.reason == again.reason == "max_steps" and first.steps == 30
    assert np.array_equal(first.ego, again.ego) and np.array_equal(first.trusts, again.trusts)


def test_gym_environment_steps_the_engine_world_like_the_runner():
    """The Gym env's step is the engine's Rollout on the same DriveEnvironment: the MPC's commands
    sent through env.step give the episode run() gives."""
    import gymnasium as gym

    import trustnav.sim.driving.gym_env  # noqa: F401
    from trustnav.sim.driving import DriveEnvironment, load_drive_scenario
    from trustnav.sim.engine import make_mpc

    sc = load_drive_scenario("case-1")

    def policy():
        return make_mpc(sc.vehicle.model(), sc.control.cost(sc.ego_start, sc.goal), sc.control.config(), timed=True)

    ref = run(DriveEnvironment(sc, seed=2), policy(), max_steps=40)
    env = gym.make("trustnav/Drive-v0", config={"scenario": "case-1", "normalize_actions": False})  # physical
    obs, _ = env.reset(seed=2)
    assert isinstance(env.unwrapped.sim, Environment) and isinstance(env.unwrapped.rollout, Rollout)
    mpc = policy()
    for _ in range(40):
        o = Observation(float(obs["time"][0]), obs["ego"], obs["pedestrians"], obs["velocities"], obs["trusts"])
        obs, *_ = env.step(mpc.step(o).control)
    res = env.unwrapped.rollout.result()
    assert np.allclose(res.ego, ref.ego, atol=1e-5)  # float32 action space rounds the commands
    assert np.array_equal(res.trusts, ref.trusts)
    env.close()


class _Line:
    """A toy world: a point on a line driven to x = 1 by velocity commands."""

    name = "line"
    period = 0.1

    def reset(self, seed: int | None = None) -> None:
        self.x, self.k = 0.0, 0

    def __init__(self) -> None:
        self.reset()

    def observe(self) -> Observation:
        z = np.zeros((0, 2))
        return Observation(self.k * self.period, np.array([self.x, 0.0]), z, z, np.zeros(0))

    def advance(self, command, duration: float) -> None:
        self.x += float(np.asarray(command)[0]) * duration
        self.k += 1

    def done(self) -> str | None:
        return "goal" if self.x >= 1.0 - 1e-9 else None

    def record(self) -> Sample:
        return Sample(self.k * self.period, np.array([self.x, 0.0]), np.zeros((0, 2)), np.zeros(0))


def test_a_user_world_and_a_user_controller():
    res = run(_Line(), FunctionController(lambda o: [2.0, 0.0]))
    assert res.reason == "goal" and res.steps == 5 and res.reached_goal
    assert res.to_record()["time_to_goal"] == pytest.approx(0.5)
    stopped = run(_Line(), FunctionController(lambda o: [0.0, 0.0]), max_steps=3)
    assert stopped.reason == "max_steps" and not stopped.reached_goal
    assert isinstance(Decision(np.zeros(2)).stats.solve_time, float)


def test_carla_world_runs_on_the_engine(runs, monkeypatch):
    """The CARLA bridge's drive (fake carla module of test_carla_bridge) goes through engine.run."""
    import socket

    tcb = pytest.importorskip("test_carla_bridge")  # tests/ is on sys.path under pytest's default import mode
    from trustnav.carla_bridge.world import run_carla_drive_episode
    from trustnav.sim.driving import load_drive_scenario

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen(8)
    try:
        server = tcb._Server()
        r = run_carla_drive_episode(tcb.fake_carla(server), load_drive_scenario("case-1"),
                                    tcb._options(s.getsockname()[1]), sensing="keypoints")  # fmt: skip
    finally:
        s.close()
    ((world, res),) = runs
    assert type(world).__name__ == "DriveEnvironment" and world.world.name == "carla"
    assert r.episode is res and res.environment == "carla" and r.metrics()["world"] == "carla"
    _assert_record_shape(res.to_record())


@pytest.mark.parametrize(
    ("command", "message"),
    [
        (np.zeros(3), "controller command must be 2 numbers for environment 'paper'"),
        (np.array([np.nan, 0.0]), "controller command must be finite"),
        ("fast", "controller command must be a vector of numbers"),
    ],
)
def test_a_bad_command_is_refused_by_name(command, message):
    from trustnav.sim.paper import PaperEnvironment, load_scenario

    world = PaperEnvironment(load_scenario("paper-1"))
    with pytest.raises(ValueError, match=message):
        engine.run(world, engine.FunctionController(lambda obs: command), max_steps=3)
