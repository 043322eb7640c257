"""The streaming perceiver (issue 20 item 1) and the real-time pose backend's contract."""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest

from trustnav.perception.streaming import StreamingPerceiver

FRAME = np.zeros((8, 8, 3), dtype=np.uint8)


def _slow(seconds: float, fail_at: float | None = None):
    def step(frame, time: float):
        import time as _t

        _t.sleep(seconds)
        if fail_at is not None and abs(time - fail_at) < 1e-9:
            raise RuntimeError("bad frame")
        return [time]

    return step


def test_realtime_mode_drops_old_frames_and_keeps_latency_bounded():
    with StreamingPerceiver(_slow(0.05), mode="realtime") as sp:
        for i in range(40):  # a camera at 200 frames/s, a step of 50 ms
            sp.submit(FRAME, i * 0.005)
            time.sleep(0.005)
        results = sp.drain(timeout=5.0)
        stats = sp.stats
    assert stats["submitted"] == 40 and stats["dropped"] > 10
    assert stats["processed"] + stats["dropped"] == 40
    assert len(results) == stats["processed"]
    times = [r.capture_time for r in results]
    assert times == sorted(times) and results[-1].capture_time == pytest.approx(39 * 0.005)
    assert all(r.people == [r.capture_time] and r.error is None for r in results)
    # a result is never older than the frame being worked on plus one waiting (~2 steps, 0.1 s);
    # had every frame been queued, the last would have waited ~40 steps (2 s)
    assert max(r.latency for r in results) < 1.0
    assert [r.dropped for r in results] == sorted(r.dropped for r in results)


def test_offline_mode_processes_every_frame_in_order():
    with StreamingPerceiver(_slow(0.002), mode="offline", max_queue=3) as sp:
        for i in range(25):
            sp.submit(FRAME, i / 10)
        results = sp.drain(timeout=10.0)
    assert [r.index for r in results] == list(range(25))
    assert [r.capture_time for r in results] == [i / 10 for i in range(25)]
    assert all(r.dropped == 0 for r in results)


def test_one_failing_frame_is_reported_and_the_stream_goes_on():
    with StreamingPerceiver(_slow(0.0, fail_at=0.2), mode="offline") as sp:
        for i in range(5):
            sp.submit(FRAME, i / 10)
        results = sp.drain(timeout=5.0)
    bad = [r for r in results if r.error]
    assert len(results) == 5 and len(bad) == 1 and bad[0].index == 2
    assert "bad frame" in bad[0].error and "t = 0.200 s" in bad[0].error and bad[0].people == []


def test_bad_input_is_refused_with_a_clear_message():
    with pytest.raises(ValueError, match="mode must be one of"):
        StreamingPerceiver(_slow(0.0), mode="fast")
    with pytest.raises(ValueError, match="step must be callable"):
        StreamingPerceiver(3)
    with pytest.raises(ValueError, match="max_queue"):
        StreamingPerceiver(_slow(0.0), mode="offline", max_queue=0)
    sp = StreamingPerceiver(_slow(0.0))
    try:
        sp.submit(FRAME, 1.0)
        with pytest.raises(ValueError, match="must not decrease"):
            sp.submit(FRAME, 0.5)
        with pytest.raises(ValueError, match="finite"):
            sp.submit(FRAME, math.nan)
    finally:
        sp.close()
    with pytest.raises(RuntimeError, match="closed"):
        sp.submit(FRAME, 2.0)
    assert not any(t.name == "trustnav-perceiver" and t.is_alive() for t in threading.enumerate() if t is sp._thread)


def test_realtime_backend_config_is_validated():
    from trustnav.perception.realtime import RealtimeConfig

    with pytest.raises(ValueError, match="landmark_every"):
        RealtimeConfig(landmark_every=0)
    with pytest.raises(ValueError, match="carry_frames"):
        RealtimeConfig(carry_frames=-1)
    with pytest.raises(ValueError, match="max_fits"):
        RealtimeConfig(max_fits=-1)
    for bad in (0, -2, 1.5, True):
        with pytest.raises(ValueError, match="search_frames"):
            RealtimeConfig(search_frames=bad)
    for bad in (300, 96, True):
        with pytest.raises(ValueError, match="detector_input"):
            RealtimeConfig(detector_input=bad)
    with pytest.raises(ValueError, match="pipelined"):
        RealtimeConfig(pipelined=1)


def test_modelled_search_spans_the_frames_of_its_seconds():
    from trustnav.perception.realtime import modelled_search_frames

    assert modelled_search_frames(10.0, 0.5) == 5
    assert modelled_search_frames(15.0, 0.5) == 8  # 7.5 frames: handed over on the 8th
    assert modelled_search_frames(10.0, 0.3) == 3 and modelled_search_frames(30.0, 0.01) == 1
    for fps, secs in ((0.0, 0.5), (10.0, 0.0), (float("nan"), 0.5), (10.0, float("inf"))):
        with pytest.raises(ValueError, match="positive"):
            modelled_search_frames(fps, secs)


@pytest.mark.slow
def test_realtime_backend_is_deterministic_and_refits_each_person_within_its_budget(sequences, read_rgb):
    """Issue 35: the detector on every frame, everything in the frame loop (no thread): two runs over
    the same frames give the same people to the bit; a frame fits at most max_fits followed people
    (new boxes beside them), and a followed person is refitted within a few frames (traits refreshed)."""
    from trustnav.perception.realtime import RealtimeConfig, RealtimePoseBackend

    frames = [read_rgb(f) for f in sorted((sequences / "walk_a").iterdir())[:12]]
    runs = []
    for _ in range(2):
        rt = RealtimePoseBackend(realtime=RealtimeConfig(landmark_every=2, max_fits=2))
        try:
            out, ages = [], []
            for f in frames:
                people = rt(f)
                out.append([(p.bbox.tolist(), p.keypoints.tolist(), bool(p.extra.get("carried"))) for p in people])
                ages.append([rt._frame_index - 1 - q.fitted_at for q in rt._people])
            assert rt.stats["frames"] == 12 and rt.stats["searches"] == 12  # a detection on every frame
        finally:
            rt.close()
        runs.append(out)
    assert runs[0] == runs[1]
    assert any(c for frame in runs[0] for *_, c in frame)  # people carried between their fits
    assert any(not c for frame in runs[0][1:] for *_, c in frame)  # and refitted
    assert max(a for frame in ages for a in frame) <= 8  # nobody waits long for a refit


@pytest.mark.slow
def test_pipelined_fits_are_taken_in_on_the_next_frame_and_find_the_in_frame_people(sequences, read_rgb):
    """Pipelined (the default): the fits chosen on frame k run while frame k + 1 is detected and are
    reported there (fresh, not carried) on that frame's boxes; the stream's first frame waits for its
    own fits. The people >= 80 px tall are those the in-frame schedule reports (a new one a frame later)."""
    from trustnav.perception.realtime import RealtimeConfig, RealtimePoseBackend
    from trustnav.perception.types import box_iou

    frames = [read_rgb(f) for f in sorted((sequences / "walk_a").iterdir())[:8]]
    found = {}
    for pipelined in (True, False):
        rt = RealtimePoseBackend(realtime=RealtimeConfig(pipelined=pipelined))
        try:
            out = []
            for k, f in enumerate(frames):
                people = rt(f)
                fresh = [q for q in rt._people if not q.person.extra.get("carried")]
                assert fresh or k > 0
                lag = 1 if pipelined and k > 0 else 0
                assert all(q.fitted_at == k - lag for q in fresh)
                out.append([p.bbox for p in people if p.bbox[3] - p.bbox[1] >= 80])
            found[pipelined] = out
        finally:
            rt.close()
    # a new person is reported one frame later; the first frame and, once settled, the rest agree
    for a, b in [*zip(found[True], found[False], strict=True)][:1] + [*zip(found[True], found[False], strict=True)][4:]:
        assert len(a) == len(b) and all(max(box_iou(p, q) for q in b) > 0.7 for p in a)


@pytest.mark.slow
def test_a_person_the_landmark_model_keeps_refusing_is_refitted_less_often(sequences, read_rgb):
    """REFIT_BACKOFF: after k refits in a row that found no body, a followed person waits landmark_every
    x 2^min(k, REFIT_BACKOFF) frames for the next, so the frame's fits go to people who can be fitted."""
    from trustnav.perception import realtime as rtm

    frames = [read_rgb(f) for f in sorted((sequences / "walk_a").iterdir())[:24]]
    rt = rtm.RealtimePoseBackend(realtime=rtm.RealtimeConfig(landmark_every=2, max_fits=20, carry_frames=30))
    try:
        rt(frames[0])
        followed = list(rt._people)
        assert followed
        rt._confirm = lambda *args, **kwargs: None  # from now on the landmark model finds nobody
        fits: dict[int, list[int]] = {id(f): [f.fitted_at] for f in followed}
        for f in frames[1:]:
            rt(f)
            for q in followed:
                if fits[id(q)][-1] != q.fitted_at:
                    fits[id(q)].append(q.fitted_at)
    finally:
        rt.close()
    gaps = [np.diff(v).tolist() for v in fits.values()]
    assert all(g[:3] == [2, 4, 8] for g in gaps if len(g) >= 3) and any(len(g) >= 3 for g in gaps)
    assert all(x == 8 for g in gaps for x in g[3:])  # capped at 2^REFIT_BACKOFF
    assert all(q.failed >= 3 for q in followed if len(fits[id(q)]) >= 4)


@pytest.mark.slow
def test_realtime_backend_answers_the_first_frame_like_the_offline_one(sequences, read_rgb):
    """The first frame: every box the detector proposes is fitted at once (max_fits large), so the
    real-time backend reports the offline backend's people; after reset() the same again."""
    from trustnav.perception.mediapipe_backend import MediaPipePoseBackend
    from trustnav.perception.realtime import RealtimeConfig, RealtimePoseBackend
    from trustnav.perception.types import box_iou

    frames = [read_rgb(f) for f in sorted((sequences / "walk_a").iterdir())[:4]]
    with MediaPipePoseBackend(video=True) as ref:
        first = ref(frames[0])
    rt = RealtimePoseBackend(realtime=RealtimeConfig(max_fits=20))
    try:
        got = rt(frames[0])
        assert len(first) >= 3
        tall = [p for p in first if p.bbox[3] - p.bbox[1] >= 80]
        assert all(max(box_iou(p.bbox, q.bbox) for q in got) > 0.9 for p in tall)
        seen = [rt(f) for f in frames[1:]]
        assert all(len(s) >= len(tall) for s in seen)
        rt.reset()
        again = rt(frames[0])
        assert [p.bbox.tolist() for p in again] == [p.bbox.tolist() for p in got]
    finally:
        rt.close()


def test_benchmark_comparison_of_realtime_with_reference():
    """bench_perception --realtime: recall over the reference's person-frames (a dropped frame
    reports nobody), the worst first-detection delay in stream seconds, trait agreement."""
    bench = _bench_module()

    def person(pid, x, eye=0.2, phone=0.9):
        return {"id": pid, "bbox": np.array([x, 0.0, x + 10.0, 30.0]), "eye": eye, "phone": phone}

    reference = [[person(1, 0)], [person(1, 2), person(2, 50)], [person(1, 4), person(2, 52)], [person(2, 54)]]
    realtime = [[person(7, 0)], None, [person(7, 4), person(8, 52, eye=0.5)], [person(8, 54)]]
    out = bench.compare(reference, realtime, fps=10.0, settle_s=0.1)
    assert out["recall_vs_reference"] == pytest.approx(4 / 6)
    assert out["first_detection_s"] == pytest.approx(0.1)  # person 2: frame 1 -> frame 2
    assert out["first_detection_people"] == 2 and out["never_found"] == 0
    # a person the reference follows for less than settle_s is not judged; one never found counts to the end
    short = bench.compare(reference, realtime, fps=10.0, settle_s=0.4)  # both are followed 3 frames
    assert short["first_detection_people"] == 0 and short["first_detection_s"] == 0.0
    lost = bench.compare(reference, [[person(7, 0)], None, [person(7, 4)], []], fps=10.0, settle_s=0.1)
    assert lost["never_found"] == 1 and lost["first_detection_s"] == pytest.approx(0.3)  # frame 1 -> end (4)
    assert out["traits_within_0_1"] == pytest.approx(3 / 4)
    # recall over clearly visible people (>= 80 px tall) only: here nobody is, so it is undefined
    assert np.isnan(out["recall_clear"])
    tall = [[{**p, "bbox": p["bbox"] * [1, 1, 1, 3]} for p in frame] if frame is not None else None
            for frame in reference]  # fmt: skip
    tall_rt = [[{**p, "bbox": p["bbox"] * [1, 1, 1, 3]} for p in frame] if frame is not None else None
               for frame in realtime]  # fmt: skip
    assert bench.compare(tall, tall_rt, fps=10.0, settle_s=0.1)["recall_clear"] == pytest.approx(4 / 6)


def test_benchmark_traits_rate_and_labelled_recall():
    """bench_perception --realtime: traits_hz_median counts a track's frames judged afresh (not
    carried) per second of stream; recall_labelled scores walk_a's labelled people >= 80 px tall with
    the labelled evaluation's rules (a dropped frame finds nobody)."""
    bench = _bench_module()

    def person(pid, carried, bbox=(0.0, 0.0, 10.0, 10.0)):
        return {"id": pid, "bbox": np.array(bbox), "eye": 0.0, "phone": 0.0, "carried": carried}

    # track 1 over 15 frames at 15 frames/s, judged on every 3rd: 5 per second; track 2 too short
    frames = [[person(1, k % 3 != 0)] + ([person(2, False)] if k < 3 else []) for k in range(15)]
    assert bench.traits_hz(frames, 15.0) == pytest.approx(5.0)
    import trust_eval

    labels = trust_eval.load_labels("walk_a")
    names = sorted(labels["frames"])
    truth = [[{"id": 0, "bbox": np.array(p["bbox"], dtype=float)} for p in labels["frames"][n]["people"]]
             for n in names]  # fmt: skip
    got = bench.labelled_scores(truth, names)
    assert got["recall_labelled"] == 1.0 and got["false_boxes"] == 0
    half = [people if k % 2 else None for k, people in enumerate(truth)]  # every other frame dropped
    assert bench.labelled_scores(half, names)["recall_labelled"] < 0.7


def _bench_module():
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_perception.py"
    spec = importlib.util.spec_from_file_location("bench_perception", path)
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    return bench


def test_drive_refuses_realtime_perception_without_rendered_frames(capsys, tmp_path):
    from trustnav.cli import main

    code = main(["drive", "case-1", "--sensing", "keypoints", "--perception", "realtime", "--out", str(tmp_path / "o")])
    assert code == 2 and "--perception realtime needs --sensing render" in capsys.readouterr().err
    # below 10 frames/s its search reaches the controller too late (Case I came within R at 5)
    assert main(["drive", "case-1", "--perception", "realtime", "--rate", "5", "--out", str(tmp_path / "o")]) == 2
    assert "needs --rate >= 10" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_render_drive_with_the_realtime_perceiver_reports_latency_per_frame():
    """Case I at 10 frames/s, first 8 frames, with the real-time backend: the drive completes,
    every frame reports the wall time perception took, people are carried between their landmark
    fits, and people the backend only carried by their velocity (no box on that frame) never reach
    the world tracker or trust (they were not measured on that frame)."""
    from trustnav.sim.driving import load_drive_scenario, run_drive
    from trustnav.sim.driving.sensing import make_render_sensing

    sc = load_drive_scenario("case-1")
    renderer, pipeline = make_render_sensing(sc, 10.0, realtime=True)
    backend = pipeline.backend
    carried = []

    class Watched:  # the backend, noting the people it only carried
        def __call__(self, frame):
            out = backend(frame)
            carried.extend(p for p in out if p.extra.get("carried"))
            return out

    pipeline.backend = Watched()
    try:
        r = run_drive(sc, sensing="render", renderer=renderer, pipeline=pipeline, capture_rate=10.0, max_frames=8)
    finally:
        renderer.close()
        backend.close()
    m = r.metrics()
    assert len(r.frames) == 8 and m["margin_violations"] == 0
    assert all(f["perception_ms"] is not None and f["perception_ms"] >= 0 for f in m["per_frame"])
    assert m["perception_ms_median"] is not None and m["perception_ms_p95"] >= m["perception_ms_median"]
    sensed = [s.person for f in r.frames for s in f.sensed]
    assert carried and sensed and not any(p.extra.get("predicted") for p in sensed)


def test_drive_checks_the_modelled_search_time(capsys, tmp_path):
    from trustnav.cli import main

    out = str(tmp_path / "o")
    argv = ["drive", "case-1", "--sensing", "render", "--rate", "10", "--search-seconds", "0.5", "--out", out]
    assert main(argv) == 2
    assert "--search-seconds models the real-time perceiver's search" in capsys.readouterr().err
    for bad in ("0", "-1", "nan", "11"):
        argv = ["drive", "case-1", "--sensing", "render", "--rate", "10", "--perception", "realtime",
                "--search-seconds", bad, "--out", out]  # fmt: skip
        assert main(argv) == 2
        assert "--search-seconds must be in (0, 10] s" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_render_drive_with_a_modelled_search_is_reproducible():
    """Case I at 10 frames/s, first 6 frames, real-time perception in step with the frames (search
    modelled as 0.3 s): two drives give the same car and the same sensed people."""
    from trustnav.sim.driving import load_drive_scenario, run_drive
    from trustnav.sim.driving.sensing import make_render_sensing

    sc = load_drive_scenario("case-1")
    results = []
    for _ in range(2):
        renderer, pipeline = make_render_sensing(sc, 10.0, realtime=True, search_seconds=0.3)
        try:
            r = run_drive(sc, sensing="render", renderer=renderer, pipeline=pipeline, capture_rate=10.0, max_frames=6)
        finally:
            renderer.close()
            pipeline.backend.close()
        assert pipeline.backend.realtime.search_frames == 3
        results.append(r)
    a, b = results
    assert np.array_equal(a.ego, b.ego)
    boxes = [[[s.person.bbox.tolist() for s in f.sensed] for f in r.frames] for r in results]
    assert boxes[0] == boxes[1] and any(boxes[0])


def test_estimate_refuses_realtime_perception_on_other_backends(tmp_path, capsys):
    from trustnav.cli import main

    code = main(["estimate", str(tmp_path), "--out", str(tmp_path / "o"), "--perception", "realtime",
                 "--backend", "yolo"])  # fmt: skip
    assert code == 2 and "--realtime runs on the mediapipe backend" in capsys.readouterr().err


@pytest.mark.slow
def test_estimate_with_realtime_perception_keeps_its_tables(sequences, looking_weights, tmp_path):
    import json
    import shutil

    from trustnav.cli import main

    clip = tmp_path / "clip"
    clip.mkdir()
    for f in sorted((sequences / "walk_a").iterdir())[:10]:
        shutil.copy(f, clip / f.name)
    out = tmp_path / "out"
    args = [str(clip), "--out", str(out), "--no-images", "--looking-weights", str(looking_weights)]
    assert main(["estimate", *args, "--perception", "realtime"]) == 0
    recs = json.loads((out / "tracks.json").read_text())
    assert {r["frame"] for r in recs} == {f.name for f in clip.iterdir()}  # people on every frame
    assert {"frame", "track_id", "bbox", "phone", "eye_contact", "trust"} <= set(recs[0])


def test_latency_budget_lets_a_stream_catch_up_without_losing_frames_and_bounds_the_wait():
    """max_latency: a stream that falls behind for a moment (a slow first step, as the first frame's
    full search) keeps its frames and catches up; frames older than the budget are dropped, so no
    result waits much longer than the budget plus a step."""

    def step(frame, time: float):
        import time as _t

        _t.sleep(0.15 if time == 0.0 else 0.01)  # a slow first frame, then faster than the camera
        return [time]

    def run(budget):
        with StreamingPerceiver(step, mode="realtime", max_latency=budget) as sp:
            for i in range(30):  # 50 frames/s
                sp.submit(FRAME, i * 0.02)
                time.sleep(0.02)
            results = sp.drain(timeout=5.0)
            return results, sp.stats

    _, s0 = run(None)
    kept, s1 = run(0.5)
    assert s0["dropped"] >= 3, "newest-frame-only drops the frames that came during the slow step"
    assert s1["dropped"] == 0 and len(kept) == 30, "with a 0.5 s budget every frame is processed"
    assert [r.index for r in kept] == list(range(30))
    tight, s2 = run(0.05)
    assert s2["dropped"] >= 2 and s2["processed"] + s2["dropped"] == 30
    assert max(r.latency for r in tight) < 0.05 + 0.15 + 0.1  # budget + the slow step + scheduling slack


def test_latency_budget_is_validated():
    with pytest.raises(ValueError, match="max_latency must be a number of seconds in \\(0, 10\\]"):
        StreamingPerceiver(_slow(0.0), mode="realtime", max_latency=0.0)
    with pytest.raises(ValueError, match="max_latency must be"):
        StreamingPerceiver(_slow(0.0), mode="realtime", max_latency="soon")
    with pytest.raises(ValueError, match="with mode='realtime'"):
        StreamingPerceiver(_slow(0.0), mode="offline", max_latency=0.3)
