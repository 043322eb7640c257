"""End-to-end trust-aware driving (issue #9): the paper's Section IV Cases I and II, offline."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from trustnav.cli import main
from trustnav.geometry.camera import CameraSpec
from trustnav.sim.driving.episode import DriveEnvironment, run_drive
from trustnav.sim.driving.sensing import KeypointSensor, hidden_joint_confidences
from trustnav.sim.driving.world import (
    PedestrianSpec,
    VehiclePlant,
    VehicleSpec,
    load_drive_scenario,
    pedestrian_bodies,
)


@pytest.fixture(scope="module")
def case1():
    return run_drive(load_drive_scenario("case-1"), sensing="keypoints", seed=0)


@pytest.fixture(scope="module")
def case2():
    sc = load_drive_scenario("case-2")
    return {tag: run_drive(sc, sensing="keypoints", seed=0, attentive=tag == "attentive")
            for tag in ("attentive", "distracted")}  # fmt: skip


def test_case_files_hold_the_paper_initial_conditions():
    c1 = load_drive_scenario("case-1")
    assert c1.ego_start == (33.5, 129.0) and c1.goal == (33.5, 75.0)
    assert math.isclose(c1.ego_yaw, -math.pi / 2)
    assert [(p.position, p.attentive) for p in c1.pedestrians] == [((29.5, 101.0), True), ((37.5, 101.0), False)]
    c2 = load_drive_scenario("case-2")
    assert c2.ego_start == (34.5, 125.0) and c2.goal == (34.0, 75.0)
    assert c2.pedestrians[0].position == (37.5, 101.0) and c2.pedestrians[0].velocity == (-0.1, 0.0)
    assert c2.variants == ("attentive", "distracted")
    for sc in (c1, c2):
        c = sc.control
        assert (c.safety_radius, c.horizon, c.latency) == (2.5, 7, 0.1)
        assert (c.gamma.gamma_ini, c.gamma.delta, c.gamma.lam) == (0.08, 0.55, 2.0)
        assert sc.camera == CameraSpec()  # 1280 x 720, 70 deg, 1.5 m forward, 1.7 m up, 1 frame/s
        assert sc.vehicle.latency == 0.1


def test_bad_scenarios_are_refused(tmp_path):
    with pytest.raises(ValueError, match="unknown driving scenario"):
        load_drive_scenario("case-3")
    bad = tmp_path / "bad.toml"
    text = (load_drive_scenario.__globals__["resources"].files("trustnav.sim") / "scenarios/case-1.toml").read_text()
    bad.write_text(text.replace("[camera]", "[camera]\nzoom = 2"))
    with pytest.raises(ValueError, match="zoom"):
        load_drive_scenario(bad)
    with pytest.raises(ValueError, match="pose"):
        PedestrianSpec("p", (0, 0), pose="dancing")


def test_case1_keypoints_attentive_trusted_more_and_distracted_given_more_room(case1):
    m = case1.metrics()
    att, dis = m["pedestrians"]
    assert att["attentive"] and not dis["attentive"]
    # trust ends higher and rises faster for the attentive pedestrian (Fig. trust_scene1)
    assert att["final_trust"] > dis["final_trust"] + 0.3
    assert att["first_trust"] > dis["first_trust"]
    assert att["trust_gain_per_frame"] > dis["trust_gain_per_frame"]
    # the car keeps more room from the distracted pedestrian (Fig. path_carla1), never inside R
    assert dis["min_distance"] > att["min_distance"] + 1.0
    assert min(att["min_distance"], dis["min_distance"]) >= 2.5
    assert m["margin_violations"] == 0
    assert m["reached_goal"] and m["time_to_goal"] < 15.0
    # it bends away from the distracted pedestrian (toward smaller x), off the lane centre
    assert case1.ego[:, 0].min() < 33.5 - 0.5
    assert case1.ego[:, 0].max() < 33.5 + 0.1


def test_case1_trust_only_from_observed_frames_and_kept_out_of_view(case1):
    # trust is 0 before the first frame, changes only at frames that observed the pedestrian
    assert np.all(case1.trusts[0] == 0.0)
    frame_times = {round(f.time, 6) for f in case1.frames}
    changed = np.flatnonzero(np.any(np.diff(case1.trusts, axis=0) != 0, axis=1))
    assert all(round(case1.times[i], 6) in frame_times for i in changed)
    # the distracted pedestrian leaves the view as the car bends away (paper, Fig. frame4); its last
    # trust stays in the controller
    dis_seen = [f.views[1].observed for f in case1.frames]
    assert dis_seen[0] and not dis_seen[-1]
    last_seen = max(i for i, s in enumerate(dis_seen) if s)
    assert case1.trusts[-1, 1] == pytest.approx(case1.frames[last_seen].views[1].trust)
    m = case1.metrics()
    assert all(p["frames_seen"] == sum(f.views[j].observed for f in case1.frames)
               for j, p in enumerate(m["pedestrians"]))  # fmt: skip


def test_case2_keypoints_distracted_walker_gets_more_room(case2):
    ma, md = case2["attentive"].metrics(), case2["distracted"].metrics()
    pa, pd = ma["pedestrians"][0], md["pedestrians"][0]
    assert pa["attentive"] and not pd["attentive"]
    assert pa["final_trust"] > pd["final_trust"]
    assert pd["min_distance"] > pa["min_distance"] + 0.5
    assert ma["margin_violations"] == 0 and md["margin_violations"] == 0
    assert ma["reached_goal"] and md["reached_goal"]
    # the pedestrian walks: its position moves with v = (-0.1, 0)
    r = case2["attentive"]
    assert r.pedestrians[-1, 0, 0] == pytest.approx(37.5 - 0.1 * r.times[-1], abs=1e-9)


def test_same_seed_same_metrics_and_seed_matters_only_through_noise(case1):
    again = run_drive(load_drive_scenario("case-1"), sensing="keypoints", seed=0)

    def stable(m):  # wall-clock solve times aside
        return json.dumps({k: v for k, v in m.items() if not k.startswith("solve_ms")}, sort_keys=True)

    assert stable(again.metrics()) == stable(case1.metrics())
    np.testing.assert_array_equal(again.ego, case1.ego)
    other = run_drive(load_drive_scenario("case-1"), sensing="keypoints", seed=1)
    assert not np.array_equal(other.trusts, case1.trusts)  # sensing noise differs


def test_plant_applies_commands_after_the_latency():
    plant = VehiclePlant(VehicleSpec(latency=0.1, substep=0.005), [0.0, 0.0, 0.0, 5.0])
    plant.send([0.0, -4.0])
    states = plant.advance(0.1)
    assert states[-2, 3] == pytest.approx(5.0)  # not yet braking
    plant.send([0.0, -4.0])
    states = plant.advance(0.1)
    assert states[-1, 3] == pytest.approx(5.0 - 0.4, abs=1e-6)  # braking for the last 0.1 s
    plant.send([10.0, 100.0])  # clipped to the limits
    plant.advance(0.2)
    assert plant.applied[0] == pytest.approx(math.radians(35.0)) and plant.applied[1] == pytest.approx(3.0)


def test_keypoint_sensing_culls_hides_and_sees_nobody_behind():
    sc = load_drive_scenario("case-1")
    spec = sc.camera
    rng = np.random.default_rng(0)
    sensor = KeypointSensor(sc.sensing, rng)
    cam = spec.pose((33.5, 115.0), -math.pi / 2)
    bodies = pedestrian_bodies(sc, 0.0, cam.position)
    people = [sensor.person(cam, sk) for sk, _ in bodies]
    assert all(p is not None for p in people)
    # the distracted pedestrian is in profile with the head bowed: its far eye and ear are hidden
    conf = hidden_joint_confidences(cam, bodies[1][0])
    assert conf[[1, 2]].min() < 0.2 and conf[[3, 4]].min() < 0.2
    sensed, _, _, _ = sensor.sense(cam, bodies)
    eye = {s.index: s.eye_contact for s in sensed}
    phone = {s.index: s.phone for s in sensed}
    assert eye[0] > eye[1] + 0.2 and phone[1] > 0.6 > phone[0]
    # past the pedestrians nobody is in view (behind the camera)
    cam_past = spec.pose((33.5, 95.0), -math.pi / 2)
    assert all(sensor.person(cam_past, sk) is None for sk, _ in pedestrian_bodies(sc, 0.0, cam_past.position))


def test_capture_rate_sets_the_number_of_trust_updates():
    sc = load_drive_scenario("case-1")
    slow = DriveEnvironment(sc, capture_rate=1.0)
    fast = DriveEnvironment(sc, capture_rate=10.0)
    for sim in (slow, fast):
        for _ in range(40):  # 2 s at 20 Hz, car at rest
            if sim.capture_due():
                sim.capture()
            sim.advance([0.0, 0.0])
    assert len(slow.frames) == 2 and len(fast.frames) == 20
    # monotone trust (alpha = 1): more frames, more trust
    assert fast.pedestrian_trusts()[0] > slow.pedestrian_trusts()[0]


def test_cli_drive_keypoints_writes_outputs(tmp_path, capsys):
    out = tmp_path / "c1"
    assert main(["drive", "case-1", "--sensing", "keypoints", "--out", str(out), "--no-video"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    for key in ("pedestrians", "reached_goal", "time_to_goal", "margin_violations", "relaxed_steps",
                "fallback_steps", "solve_ms_median", "solve_ms_p95"):  # fmt: skip
        assert key in m
    assert [p["name"] for p in m["pedestrians"]] == ["attentive", "distracted"]
    assert {"name", "attentive", "min_distance", "final_trust", "frames_seen"} <= set(m["pedestrians"][0])
    for name in ("top_view.png", "trust.png", "distance.png"):
        assert (out / name).stat().st_size > 10_000
    assert len(list((out / "frames").glob("frame_*.png"))) == m["frames"]
    assert "min distance" in capsys.readouterr().out


@pytest.mark.parametrize(
    "argv", [["drive", "case-9"], ["drive", "case-1", "--sensing", "lidar"], ["drive", "case-1", "--rate", "0"],
             ["drive", "case-1", "--attentive", "--distracted"], ["drive", "case-1", "--bogus"]],
)  # fmt: skip
def test_cli_bad_arguments_one_line_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        code = main(argv)
        raise SystemExit(code)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "error" in err and "Traceback" not in err


def test_gym_environment_steps_the_world():
    import gymnasium as gym

    import trustnav.sim.driving.gym_env  # noqa: F401  (registers the id)

    env = gym.make("trustnav/Drive-v0", scenario="case-1", max_episode_steps=400, render_mode="rgb_array")
    obs, _ = env.reset(seed=3)
    assert obs["ego"].shape == (4,) and obs["pedestrians"].shape == (8, 2) and obs["trusts"].shape == (8,)
    # perceived by default: the frame at t = 0 found both, placed near where they stand, with trust
    assert obs["present"].tolist() == [1, 1, 0, 0, 0, 0, 0, 0]
    truth = np.array([p.position for p in env.unwrapped.scenario.pedestrians])
    found = obs["pedestrians"][:2]
    assert np.sort(np.linalg.norm(found[:, None] - truth[None], axis=2).min(axis=1)).max() < 1.5
    assert np.all(obs["trusts"][:2] > 0) and np.all(obs["covariances"][:2, 0, 0] > 0)
    # the world's states on request (no covariance, the scenario's order)
    true_env = gym.make("trustnav/Drive-v0", scenario="case-1", state="true", max_pedestrians=2)
    tobs, _ = true_env.reset(seed=3)
    np.testing.assert_allclose(tobs["pedestrians"], truth)
    true_env.close()
    total = 0.0
    for _ in range(30):
        obs, reward, terminated, truncated, _info = env.step(np.array([0.0, 0.5], dtype=np.float32))  # 1.5 m/s^2
        total += reward
        if terminated or truncated:
            break
    assert obs["ego"][3] > 0.5  # it accelerated
    assert env.observation_space.contains(obs)
    top = env.unwrapped.render()
    assert top.ndim == 3 and top.dtype == np.uint8
    env.close()


@pytest.mark.slow
def test_a_texter_the_detector_scores_low_is_seen_where_the_camera_vouches_and_passed_at_r(repo_root):
    """Issue 34: in a varied Case II world (perceived_drive.py --vary, seed 629) YOLOX-Nano scores
    the texting walker, 11-22 m ahead in profile and unoccluded, 0.17-0.21, under its 0.25: without
    proposals the car never sees her and passes at 2.37 m, inside R. The drive's known camera lets
    the geometry gate vouch for such a box (MediaPipeConfig.proposal_score): she is seen, trusted
    little, and passed at R or more, with nothing else boxed."""
    import sys

    from trustnav.sim.driving.sensing import make_render_sensing

    sys.path.insert(0, str(repo_root / "benchmarks"))
    try:
        from perceived_drive import varied
    finally:
        sys.path.pop(0)
    sc = varied(load_drive_scenario("case-2"), 629)
    out = {}
    for proposals in (True, False):
        renderer, pipeline = make_render_sensing(sc)
        if not proposals:  # the detector's own threshold only
            pipeline.backend.detector.min_score = pipeline.backend.config.detector_min_score
        try:
            out[proposals] = run_drive(sc, sensing="render", seed=629, attentive=False, renderer=renderer,
                                       pipeline=pipeline, max_frames=5).metrics()  # fmt: skip
        finally:
            renderer.close()
            pipeline.backend.close()
    without, walker = out[False]["pedestrians"][0], out[True]["pedestrians"][0]
    assert without["frames_seen"] == 0 and without["min_distance"] < sc.control.safety_radius
    assert walker["frames_seen"] >= 2 and walker["final_trust"] < 0.2
    assert walker["min_distance"] >= sc.control.safety_radius and out[True]["margin_violations"] == 0
    assert out[True]["false_positives"] == 0 and out[True]["reached_goal"]


@pytest.mark.slow
def test_render_mode_case1_detects_both_tells_them_apart_and_bends_away():
    """Case I through rendered frames and the real perception, frames 0-4 (after 4 s nobody is in
    view any more, so later frames would only cost time): both pedestrians detected and associated
    with the right world pedestrian, the attentive one trusted more and faster, the distracted one
    given more room, no violation, goal reached."""
    from trustnav.sim.driving.sensing import make_render_sensing

    sc = load_drive_scenario("case-1")
    renderer, pipeline = make_render_sensing(sc)
    try:
        r = run_drive(sc, sensing="render", renderer=renderer, pipeline=pipeline, max_frames=5)
    finally:
        renderer.close()
        pipeline.backend.close()
    m = r.metrics()
    assert len(r.frames) == 5
    assert m["detection_recall"] >= 0.8 and m["false_positives"] == 0
    assert [f.ground_truth for f in r.frames[:4]] == [2, 2, 2, 2]
    att, dis = m["pedestrians"]
    assert att["frames_seen"] >= 3 and dis["frames_seen"] >= 3
    assert att["final_trust"] > dis["final_trust"]
    assert att["first_trust"] > dis["first_trust"] and att["trust_gain_per_frame"] > dis["trust_gain_per_frame"]
    phone = [[f.views[j].phone for f in r.frames if f.views[j].observed] for j in (0, 1)]
    assert max(phone[1]) > 0.5 > max(phone[0])
    assert dis["min_distance"] > att["min_distance"]
    assert m["margin_violations"] == 0 and m["reached_goal"]


def test_case1_keypoints_at_ten_frames_per_second_keeps_the_claim_trust_in_seconds():
    """Trust grows with time, not with frames (SECONDS_TRUST): at 10 frames/s the distracted
    pedestrian is still given more room, and trusts after the same seconds match 1 frame/s."""
    sc = load_drive_scenario("case-1")
    fast = run_drive(sc, sensing="keypoints", seed=4, capture_rate=10.0)
    slow = run_drive(sc, sensing="keypoints", seed=4, capture_rate=1.0)
    att, dis = fast.metrics()["pedestrians"]
    assert dis["min_distance"] > att["min_distance"] + 1.0 and fast.metrics()["margin_violations"] == 0
    t = 3.0  # both pedestrians still in view
    i_fast, i_slow = np.searchsorted(fast.times, t), np.searchsorted(slow.times, t)
    np.testing.assert_allclose(fast.trusts[i_fast], slow.trusts[i_slow], atol=0.12)
    assert fast.trusts[i_fast, 0] > fast.trusts[i_fast, 1] + 0.3
