"""Live input for `trustnav estimate` (issue 20 item 3): camera index or stream URL, newest frame
first, capture time stamps, drops counted, bounded waits, clean stops."""

from __future__ import annotations

import itertools
import json
import threading
import time

import numpy as np
import pytest

from trustnav.perception.frames import plan_sequences
from trustnav.perception.live import LiveSource, frames_due, is_live_source


class FakeCapture:
    """A camera giving ``n`` frames, one every ``period`` s; ``clock``: report POS_MSEC."""

    def __init__(self, n: int, period: float, clock: bool = True, opened: bool = True) -> None:
        self.n, self.period, self.clock, self.opened = n, period, clock, opened
        self.k = 0
        self.released = False

    def isOpened(self) -> bool:
        return self.opened

    def read(self):
        if self.k >= self.n:
            return False, None
        time.sleep(self.period)
        frame = np.full((4, 6, 3), self.k % 256, dtype=np.uint8)
        self.k += 1
        return True, frame

    def get(self, prop: int) -> float:
        if prop == 0:  # CAP_PROP_POS_MSEC
            return 1000.0 * (self.k - 1) * 0.1 if self.clock else 0.0
        if prop == 5:  # CAP_PROP_FPS
            return 10.0
        return 0.0

    def release(self) -> None:
        self.released = True


def test_live_sources_are_camera_indices_and_urls():
    assert is_live_source("0") and is_live_source("12")
    assert is_live_source("rtsp://10.0.0.2/cam") and is_live_source("file:///tmp/x.mp4")
    assert is_live_source("http://example.org/stream.m3u8")
    assert not is_live_source("clip.mp4") and not is_live_source("frames/") and not is_live_source("-1")


def test_a_slow_consumer_gets_the_newest_frame_and_the_rest_are_counted_as_dropped():
    cap = FakeCapture(n=30, period=0.005)
    with LiveSource("0", capture_factory=lambda s, t: cap) as src:
        got = []
        for item in src.frames():
            got.append(item)
            time.sleep(0.03)  # perception slower than the camera
        dropped = src.dropped
    numbers = [int(i.name.split("#")[1]) for i in got]
    assert numbers == sorted(numbers) and len(got) < 30 and dropped > 0
    assert len(got) + dropped == 30 or len(got) + dropped == 29  # the last frame may be taken or not
    assert [i.index for i in got] == list(range(len(got)))
    times = [i.time for i in got]
    assert times == sorted(times) and times[0] == pytest.approx(0.0)
    np.testing.assert_allclose(times, [0.1 * k for k in numbers])  # the stream's own clock
    assert cap.released


def test_without_a_stream_clock_frames_are_stamped_by_the_wall_clock():
    with LiveSource("0", capture_factory=lambda s, t: FakeCapture(n=5, period=0.02, clock=False)) as src:
        items = list(src.frames())
    times = [i.time for i in items]
    assert len(items) >= 3 and all(b > a for a, b in itertools.pairwise(times))


def test_max_frames_and_max_seconds_stop_the_stream():
    with LiveSource("0", capture_factory=lambda s, t: FakeCapture(n=1000, period=0.002)) as src:
        assert len(list(src.frames(max_frames=4))) == 4
    with LiveSource("0", capture_factory=lambda s, t: FakeCapture(n=10_000, period=0.002)) as src:
        t0 = time.monotonic()
        list(src.frames(max_seconds=0.2))
        assert time.monotonic() - t0 < 1.0


def test_sources_that_do_not_open_fail_fast_naming_the_input():
    with pytest.raises(ValueError, match="cannot open live input camera 3"):
        LiveSource("3", capture_factory=lambda s, t: FakeCapture(1, 0.0, opened=False))
    hang = threading.Event()

    def stuck(source, timeout):
        hang.wait(5.0)  # a capture that never answers
        return FakeCapture(1, 0.0)

    t0 = time.monotonic()
    with pytest.raises(ValueError, match=r"did not open within 0\.2 s"):
        LiveSource("rtsp://10.255.255.1/cam", open_timeout=0.2, capture_factory=stuck)
    assert time.monotonic() - t0 < 3.0
    hang.set()
    with pytest.raises(ValueError, match="camera index or a URL"):
        LiveSource("clip.mp4")


def test_a_stream_that_stops_sending_times_out():
    class Silent(FakeCapture):
        def read(self):
            time.sleep(10.0)
            return False, None

    src = LiveSource("0", read_timeout=0.2, capture_factory=lambda s, t: Silent(1, 0.0))
    with pytest.raises(TimeoutError, match=r"no frame for 0\.2 s"):
        list(src.frames())
    src._stop = True  # the grabber is blocked in read(); it is a daemon thread


def test_the_annotated_video_holds_each_frame_until_the_next_one():
    # frames taken at 0, 0.35 and 0.4 s into a 10 frames/s video: 1, then 3 more, then 1 more
    assert frames_due(5.0, 5.0, 10.0, 0, 50) == 1
    assert frames_due(5.35, 5.0, 10.0, 1, 50) == 3
    assert frames_due(5.4, 5.0, 10.0, 4, 50) == 1
    assert frames_due(5.41, 5.0, 10.0, 5, 50) == 1  # never fewer than one
    assert frames_due(900.0, 5.0, 10.0, 5, 50) == 50  # a jump in the stream's clock is bounded
    assert frames_due(float("nan"), 5.0, 10.0, 5, 50) == 1


def test_a_live_input_runs_alone():
    with pytest.raises(ValueError, match="runs alone"):
        plan_sequences(["0", "frames/"])
    with pytest.raises(ValueError, match="runs alone"):
        plan_sequences(["0", "1"])
    (seq,) = plan_sequences(["rtsp://cam.local:554/stream1"])
    assert seq.kind == "live" and seq.source == "rtsp://cam.local:554/stream1" and seq.has_video
    assert seq.label == "cam.local_554_stream1"


def _mp4(sequences, tmp_path, n=8):
    import cv2

    path = tmp_path / "walk.mp4"
    files = sorted((sequences / "walk_a").iterdir())[:n]
    first = cv2.imread(str(files[0]))
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, (first.shape[1], first.shape[0]))
    for f in files:
        writer.write(cv2.imread(str(f)))
    writer.release()
    return path


@pytest.mark.slow
def test_estimate_reads_a_stream_url_and_writes_its_tables(sequences, looking_weights, tmp_path, capsys):
    from trustnav.cli import main

    url = f"file://{_mp4(sequences, tmp_path)}"
    out = tmp_path / "out"
    args = [url, "--out", str(out), "--looking-weights", str(looking_weights), "--max-frames", "3"]
    assert main(["estimate", *args]) == 0
    text = capsys.readouterr().out
    assert "live frames dropped" in text
    recs = json.loads((out / "tracks.json").read_text())
    assert recs and all("#" in r["frame"] for r in recs)
    assert len({r["frame"] for r in recs}) <= 3 and (out / "annotated.mp4").is_file()
    import cv2

    # the video plays in real time: frames perception skipped are filled by the frame before them
    numbers = sorted({int(r["frame"].split("#")[1]) for r in recs})
    cap = cv2.VideoCapture(str(out / "annotated.mp4"))
    written = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    cap.release()
    assert numbers[-1] - numbers[0] + 1 <= written <= 8


def test_ctrl_c_on_a_live_input_keeps_the_tables_and_counts_the_drops(
    sequences, looking_weights, tmp_path, capsys, monkeypatch
):
    import signal

    import cv2

    from trustnav.cli import main
    from trustnav.perception import live

    frames = [cv2.imread(str(f)) for f in sorted((sequences / "walk_a").iterdir())[:30]]

    class Camera(FakeCapture):
        def read(self):  # a camera that never stops, faster than perception
            time.sleep(0.01)
            self.k += 1
            return True, frames[self.k % len(frames)]

    taken = live.LiveSource.frames

    def frames_then_ctrl_c(self, *args):
        for k, item in enumerate(taken(self, *args)):
            if k == 3:
                signal.raise_signal(signal.SIGINT)  # Ctrl-C in the middle of the run
            yield item

    monkeypatch.setattr(live, "_open_cv", lambda source, timeout: Camera(n=0, period=0.0, clock=False))
    monkeypatch.setattr(live.LiveSource, "frames", frames_then_ctrl_c)
    out = tmp_path / "out"
    args = ["0", "--out", str(out), "--looking-weights", str(looking_weights)]
    assert main(["estimate", *args]) == 130
    err = capsys.readouterr().err
    assert "interrupted after" in err and "live frames dropped" in err
    recs = json.loads((out / "tracks.json").read_text())
    assert recs and all(r["frame"].startswith("0#") for r in recs) and (out / "tracks.csv").is_file()
    assert len({r["frame"] for r in recs}) <= 3  # the frames done before Ctrl-C


def test_a_camera_that_does_not_exist_is_refused_naming_it(tmp_path, capsys):
    from trustnav.cli import main

    t0 = time.monotonic()
    assert main(["estimate", "99", "--out", str(tmp_path / "o"), "--open-timeout", "2"]) == 2
    assert time.monotonic() - t0 < 10.0
    err = capsys.readouterr().err
    assert "camera 99" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_estimate_refuses_a_stream_that_does_not_answer_quickly(tmp_path, capsys):
    from trustnav.cli import main

    t0 = time.monotonic()
    code = main(["estimate", "rtsp://127.0.0.1:9/x", "--out", str(tmp_path / "o"), "--open-timeout", "2"])
    assert code == 2 and time.monotonic() - t0 < 10.0
    err = capsys.readouterr().err
    assert "cannot open live input rtsp://127.0.0.1:9/x" in err or "did not open within" in err
    assert not (tmp_path / "o").exists()
    assert main(["estimate", "file:///nowhere.mp4", "--out", str(tmp_path / "o"), "--show"]) == 2
