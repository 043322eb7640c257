"""Issue #10: the CLI and the public entry points under bad input and interruption.

One test (or a few) per finding: separate sequences (1), records kept on Ctrl-C (2), corrupt
frames skipped and counted (3), non-zero exit when nothing was read (4), one-line errors without
traceback (5), no silent overwrite (6), validation messages (7), the authors'-style baseline (8).
Perception runs on a scripted pose backend here (fast, deterministic); the real backend is covered
by tests/test_perception.py and one slow test below.
"""

from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from trustnav.cli import main
from trustnav.perception.frames import plan_sequences, read_image
from trustnav.perception.types import Person

# -- a scripted pose backend and eye model -------------------------------------------------------


def _person(x: float = 100.0, y: float = 100.0) -> Person:
    """An upright person in the box (x, y) .. (x + 60, y + 200)."""
    kp = np.array([
        [30, 15], [25, 12], [35, 12], [20, 14], [40, 14],  # nose, eyes, ears
        [15, 45], [45, 45], [10, 80], [50, 80], [8, 110], [52, 110],  # shoulders, elbows, wrists
        [20, 110], [40, 110], [20, 150], [40, 150], [20, 195], [40, 195],  # hips, knees, ankles
    ], dtype=float) + [x, y]  # fmt: skip
    return Person(np.array([x, y, x + 60, y + 200]), kp, np.ones(17), 0.9)


class ScriptedBackend:
    """Finds one person at the same place in every frame; ``interrupt_at``: raise KeyboardInterrupt
    on that call (as Ctrl-C would); counts calls and resets."""

    def __init__(self, interrupt_at: int | None = None) -> None:
        self.calls = 0
        self.resets = 0
        self.closed = False
        self.interrupt_at = interrupt_at

    def __call__(self, frame):
        self.calls += 1
        if self.calls == self.interrupt_at:
            raise KeyboardInterrupt
        return [_person()]

    def reset(self) -> None:
        self.resets += 1

    def close(self) -> None:
        self.closed = True


class _Eyes:
    def predict(self, inputs):
        return np.full(len(np.atleast_2d(inputs)), 0.3)


@pytest.fixture
def scripted(monkeypatch):
    """Replace the pose backend and the LOOKING model of `trustnav estimate`; returns the backend."""
    from trustnav.perception import optional_backends
    from trustnav.perception.looking import LookingModel

    backend = ScriptedBackend()
    monkeypatch.setattr(optional_backends, "make_backend", lambda name, **kw: backend)
    monkeypatch.setattr(LookingModel, "from_file", classmethod(lambda cls, path=None, **kw: _Eyes()))
    return backend


def _image(path: Path, value: int = 120, size=(320, 240)) -> Path:
    import cv2

    rng = np.random.default_rng(value)
    img = rng.integers(0, 255, (size[1], size[0], 3), dtype=np.uint8)
    assert cv2.imwrite(str(path), img)
    return path


def _video(path: Path, frames: int = 3, size=(320, 240)) -> Path:
    import cv2

    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 5.0, size)
    for k in range(frames):
        w.write(np.full((size[1], size[0], 3), 40 * k, dtype=np.uint8))
    w.release()
    return path


def _rows(out: Path) -> list[dict]:
    return json.loads((out / "tracks.json").read_text())


def _one_clean_line(err: str) -> None:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err and "error" in lines[0]


# -- 1. each input is its own sequence -----------------------------------------------------------


def test_inputs_are_planned_as_separate_sequences_with_unique_labels(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    (tmp_path / "seq").mkdir()
    a = _image(tmp_path / "a" / "crossing.jpg")
    b = _image(tmp_path / "b" / "crossing.jpg")
    for k in (10, 9, 8):
        _image(tmp_path / "seq" / f"f{k}.png")
    clip = _video(tmp_path / "seq" / "clip.mp4")
    seqs = plan_sequences([a, b, tmp_path / "seq"])
    assert [(s.kind, len(s.files)) for s in seqs] == [("image", 1), ("image", 1), ("folder", 3), ("video", 1)]
    assert [f.name for f in seqs[2].files] == ["f8.png", "f9.png", "f10.png"]  # natural order
    assert seqs[3].files == (clip,)
    labels = [s.label for s in seqs]
    assert len(set(labels)) == 4 and labels[:2] == ["a-crossing.jpg", "b-crossing.jpg"]
    joined = plan_sequences([a, b], one_sequence=True)
    assert len(joined) == 1 and joined[0].files == (a, b)


def test_a_folder_of_photos_is_not_a_video(tmp_path):
    """Issue 35: images of different sizes, or not numbered at an even step, are sequences of their
    own (track IDs and trust do not carry from one photo to the next); --one-sequence joins them."""
    photos = tmp_path / "photos"
    photos.mkdir()
    for name in ("street_1.png", "street_2.png", "street_4.png"):  # numbered, but 1, 2, 4: not frames
        _image(photos / name)
    _image(photos / "crossing.jpg", size=(80, 60))  # no number, another size
    _image(photos / "frame_1.png", size=(80, 60))  # numbered frames 1-3, each of another size
    _image(photos / "frame_2.png", size=(64, 48))
    _image(photos / "frame_3.png", size=(72, 54))
    seqs = plan_sequences([photos])
    assert [(s.kind, len(s.files)) for s in seqs] == [("image", 1)] * 7
    assert len({s.label for s in seqs}) == 7
    clip = tmp_path / "clip"
    clip.mkdir()
    for k in range(0, 50, 5):  # every 5th frame of a clip: one sequence, in frame order
        _image(clip / f"image_{k:08d}_0.png")
    (seq,) = plan_sequences([clip])
    assert seq.kind == "folder" and [f.name for f in seq.files][:2] == ["image_00000000_0.png", "image_00000005_0.png"]
    assert len(plan_sequences([photos], one_sequence=True)) == 1


def test_two_photos_do_not_share_tracks_or_trust_unless_asked(tmp_path, scripted, capsys):
    a = _image(tmp_path / "street_1.png", 1)
    b = _image(tmp_path / "street_2.png", 2)
    assert main(["estimate", str(a), str(b), "--out", str(tmp_path / "sep")]) == 0
    rows = _rows(tmp_path / "sep")
    assert [r["sequence"] for r in rows] == ["street_1.png", "street_2.png"]
    # nothing carried over: the second photo's person is a first observation, as on its own
    assert rows[0]["track_id"] == rows[1]["track_id"] and rows[0]["trust"] == rows[1]["trust"]
    assert rows[1]["fluctuation"] is None
    assert scripted.resets == 2  # the backend forgets the people it followed, per sequence
    assert sorted(p.name for p in (tmp_path / "sep" / "frames").iterdir()) == ["street_1.png", "street_2.png"]
    assert "2 sequences" in capsys.readouterr().out
    # asked for: one sequence, one trust state (frames 1 s apart: pose fluctuation compares poses
    # a second apart under the default trust law, SECONDS_TRUST)
    assert main(["estimate", str(a), str(b), "--out", str(tmp_path / "one"), "--one-sequence", "--fps", "1"]) == 0
    one = _rows(tmp_path / "one")
    assert one[1]["fluctuation"] is not None and one[1]["trust"] != one[0]["trust"]


def test_a_photo_is_not_squashed_into_a_videos_mp4(tmp_path, scripted):
    import cv2

    clip = _video(tmp_path / "clip.avi", frames=4)
    photo = _image(tmp_path / "crossing.jpg", size=(640, 360))
    out = tmp_path / "out"
    assert main(["estimate", str(clip), str(photo), "--out", str(out)]) == 0
    cap = cv2.VideoCapture(str(out / "annotated.mp4"))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 4  # the video's frames only
    cap.release()
    assert [p.name for p in (out / "frames").iterdir()] == ["crossing.png"]
    assert {r["sequence"] for r in _rows(out)} == {"clip.avi", "crossing.jpg"}


# -- 2. Ctrl-C keeps the records ------------------------------------------------------------------


def test_interrupt_keeps_the_records_written_so_far(tmp_path, scripted, capsys):
    seq = tmp_path / "seq"
    seq.mkdir()
    for k in range(6):
        _image(seq / f"f{k}.png", k)
    scripted.interrupt_at = 4
    out = tmp_path / "out"
    assert main(["estimate", str(seq), "--out", str(out)]) == 130
    rows = _rows(out)
    assert [r["frame"] for r in rows] == ["f0.png", "f1.png", "f2.png"]
    csv_lines = (out / "tracks.csv").read_text().splitlines()
    assert len(csv_lines) == 1 + len(rows)
    err = capsys.readouterr().err
    assert "interrupted after 3 frames; kept 3 records" in err and "Traceback" not in err
    assert scripted.closed


@pytest.mark.slow
def test_sigint_to_a_real_run_keeps_csv_and_json(sequences, looking_weights, out_dir):
    out = out_dir
    cmd = [sys.executable, "-m", "trustnav.cli", "estimate", str(sequences / "walk_a"), "--out", str(out),
           "--no-images"]  # fmt: skip
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # Ctrl-C reaches it
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            # the run writes beside --out until it is done (OutputFolder): its records grow there
            partial = list(out.parent.glob(f".{out.name}.trustnav-*.partial/tracks.csv"))
            if partial and len(partial[0].read_text().splitlines()) > 2:
                break
            time.sleep(0.2)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    rows = _rows(out)  # a new --out: the records so far are moved into place
    assert rows and len((out / "tracks.csv").read_text().splitlines()) == 1 + len(rows)
    assert "Traceback" not in err and "kept" in err.splitlines()[-1]
    assert "trustnav: walk_a: interrupted: " in err and "(100 %)" not in err  # the progress stops where the run did
    assert not list(out.parent.glob(".*.partial"))


# -- 3. a corrupt frame is detected, reported and skipped ----------------------------------------


def test_truncated_jpeg_is_skipped_and_counted_not_annotated_grey(tmp_path, scripted, capfd):
    seq = tmp_path / "seq"
    seq.mkdir()
    _image(seq / "f1.jpg", 1, size=(640, 480))
    data = _image(tmp_path / "whole.jpg", 2, size=(640, 480)).read_bytes()
    (seq / "f2.jpg").write_bytes(data[:2000])  # as `head -c 2000`
    _image(seq / "f3.jpg", 3, size=(640, 480))
    rgb, why = read_image(seq / "f2.jpg")
    assert rgb is None and "truncated" in why
    out = tmp_path / "out"
    assert main(["estimate", str(seq), "--out", str(out)]) == 0
    captured = capfd.readouterr()
    assert "skipped frame f2.jpg" in captured.err and "Premature end of JPEG" not in captured.err
    assert "2 frames in 1 sequence" in captured.out and "1 frames skipped" in captured.out
    assert {r["frame"] for r in _rows(out)} == {"f1.jpg", "f3.jpg"}
    assert sorted(p.name for p in (out / "frames").iterdir()) == ["f1.png", "f3.png"]


def test_video_cut_off_in_the_middle_is_reported_as_damaged(tmp_path, scripted, capfd):
    import cv2

    whole = tmp_path / "whole.avi"
    writer = cv2.VideoWriter(str(whole), cv2.VideoWriter_fourcc(*"MJPG"), 10, (160, 120))
    rng = np.random.default_rng(0)
    for _ in range(30):
        writer.write(rng.integers(0, 255, (120, 160, 3), dtype=np.uint8))
    writer.release()
    data = whole.read_bytes()
    (tmp_path / "cut.avi").write_bytes(data[: int(0.6 * len(data))])  # as a copy that stopped part-way
    out = tmp_path / "out"
    assert main(["estimate", str(tmp_path / "cut.avi"), "--out", str(out)]) == 0  # the frames it has still count
    captured = capfd.readouterr()
    assert "skipped frame cut.avi#" in captured.err and "of the 30 frames its header announces" in captured.err
    assert "truncated or damaged" in captured.err and "1 frames skipped" in captured.out
    assert 10 < scripted.calls < 30


# -- 4. non-zero exit when nothing could be read ---------------------------------------------------


def test_nothing_readable_exits_non_zero_with_clean_messages(tmp_path, scripted, capfd):
    (tmp_path / "x.png").write_bytes(b"")
    (tmp_path / "y.jpg").write_text("this is text, not a photo\n")
    (tmp_path / "z.mp4").write_bytes(np.random.default_rng(0).integers(0, 255, 5000, dtype=np.uint8).tobytes())
    inputs = [str(tmp_path / n) for n in ("x.png", "y.jpg", "z.mp4")]
    assert main(["estimate", *inputs, "--out", str(tmp_path / "out")]) == 1
    err = capfd.readouterr().err
    assert "moov atom" not in err and "Traceback" not in err  # no raw FFmpeg lines
    for name in ("x.png", "y.jpg", "z.mp4"):
        assert f"skipped frame {name}" in err
    assert "none of the 3 input frames could be read" in err.splitlines()[-1]
    assert scripted.calls == 0


# -- 5. one-line errors instead of tracebacks -------------------------------------------------------


def test_out_pointing_at_a_file_is_a_one_line_error(tmp_path, scripted, capsys):
    target = tmp_path / "taken.txt"
    target.write_text("x")
    img = _image(tmp_path / "a.png")
    assert main(["estimate", str(img), "--out", str(target)]) == 2
    _one_clean_line(capsys.readouterr().err)
    assert main(["scenario", "paper-2", "--out", str(target)]) == 2
    err = capsys.readouterr().err
    _one_clean_line(err)
    assert "is a file" in err


def test_missing_weights_file_is_a_one_line_error(tmp_path, capsys):
    img = _image(tmp_path / "a.png")
    assert main(["estimate", str(img), "--out", str(tmp_path / "o"), "--looking-weights", "/nope.p"]) == 2
    err = capsys.readouterr().err
    _one_clean_line(err)
    assert "/nope.p" in err
    assert not (tmp_path / "o").exists()  # refused before anything was written


def test_no_weights_and_no_network_says_how_to_give_them(tmp_path, monkeypatch, capsys):
    from trustnav.perception import looking

    def offline(*args, **kwargs):
        raise urllib.error.URLError("[Errno -3] Temporary failure in name resolution")

    monkeypatch.setattr(looking, "_candidates", lambda: ([tmp_path / "none.p"], tmp_path / "cache" / "w.p"))
    monkeypatch.setattr(urllib.request, "urlopen", offline)
    with pytest.raises(FileNotFoundError, match=r"--looking-weights.*TRUSTNAV_LOOKING_WEIGHTS"):
        looking.resolve_weights()
    assert not list((tmp_path / "cache").glob("*"))  # no partial file left
    img = _image(tmp_path / "a.png")
    assert main(["estimate", str(img), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "URLError" not in err
    assert err.strip().splitlines()[-1].startswith("trustnav: error: LOOKING eye-contact weights not found")


# -- 6. no silent overwrite ---------------------------------------------------------------------------


def test_non_empty_out_is_refused_and_overwrite_replaces_only_our_outputs(tmp_path, scripted, capsys):
    seq = tmp_path / "seq"
    seq.mkdir()
    _image(seq / "new.png")
    out = tmp_path / "out"
    (out / "frames").mkdir(parents=True)
    (out / "frames" / "stale.png").write_bytes(b"old")
    (out / "notes.txt").write_text("mine")
    assert main(["estimate", str(seq), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    _one_clean_line(err)
    assert "--overwrite" in err
    assert main(["estimate", str(seq), "--out", str(out), "--overwrite"]) == 0
    assert [p.name for p in (out / "frames").iterdir()] == ["new.png"]  # no stale frame beside new tables
    assert (out / "notes.txt").read_text() == "mine"  # not ours: left alone


def test_same_stem_inputs_write_one_annotated_frame_each(tmp_path, scripted):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    a = _image(tmp_path / "a" / "crossing.jpg", 1)
    b = _image(tmp_path / "b" / "crossing.png", 2)
    out = tmp_path / "out"
    assert main(["estimate", str(a), str(b), "--out", str(out)]) == 0
    assert len(list((out / "frames").iterdir())) == 2


def test_bad_fps_leaves_no_folder(tmp_path, scripted, capsys):
    img = _image(tmp_path / "a.png")
    assert main(["estimate", str(img), "--out", str(tmp_path / "o"), "--fps", "0"]) == 2
    _one_clean_line(capsys.readouterr().err)
    assert not (tmp_path / "o").exists()


# -- issue 23: nothing lost, nothing mixed (estimate) ------------------------------------------------


def _partials(parent: Path) -> list[Path]:
    return list(parent.glob(".*.partial"))


def test_failed_estimate_leaves_nothing_that_blocks_a_rerun(tmp_path, scripted, capfd):
    (tmp_path / "x.png").write_bytes(b"")  # unreadable: the run fails (exit 1)
    out = tmp_path / "out"
    assert main(["estimate", str(tmp_path / "x.png"), "--out", str(out)]) == 1
    assert not out.exists() and not _partials(tmp_path)  # no header-only tables
    good = _image(tmp_path / "good.png")
    assert main(["estimate", str(good), "--out", str(out)]) == 0  # the same --out, no --overwrite
    assert [r["frame"] for r in _rows(out)] == ["good.png"]


def test_estimate_that_raises_leaves_the_earlier_outputs(tmp_path, scripted, monkeypatch, capsys):
    img = _image(tmp_path / "a.png")
    out = tmp_path / "out"
    assert main(["estimate", str(img), "--out", str(out)]) == 0
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}

    def broken(*args, **kwargs):
        raise OSError(28, "No space left on device")

    import trustnav.viz.annotate

    monkeypatch.setattr(trustnav.viz.annotate, "annotate", broken)
    assert main(["estimate", str(img), "--out", str(out), "--overwrite"]) == 2
    assert "No space left on device" in capsys.readouterr().err
    assert {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert not _partials(tmp_path)


def test_interrupted_overwrite_keeps_the_earlier_outputs_and_the_new_records_beside(tmp_path, scripted, capsys):
    seq = tmp_path / "seq"
    seq.mkdir()
    for k in range(4):
        _image(seq / f"f{k}.png", k)
    out = tmp_path / "out"
    assert main(["estimate", str(seq), "--out", str(out)]) == 0
    before = (out / "tracks.json").read_text()
    scripted.calls, scripted.interrupt_at = 0, 3  # Ctrl-C at the third frame of the rerun
    assert main(["estimate", str(seq), "--out", str(out), "--overwrite"]) == 130
    assert (out / "tracks.json").read_text() == before  # the earlier run, whole
    aside = tmp_path / "out.interrupted"
    assert [r["frame"] for r in _rows(aside)] == ["f0.png", "f1.png"]
    err = capsys.readouterr().err
    assert f"kept 2 records in {aside / 'tracks.csv'}" in err and "keeps the earlier outputs" in err
    assert not _partials(tmp_path)


# -- issue 23: bounds on every number ---------------------------------------------------------------


@pytest.mark.parametrize(
    ("argv", "message"),
    [(["drive", "case-1", "--control-rate", "100000"],
      "--control-rate must be in [1, 200] steps per second, got 100000"),
     (["drive", "case-1", "--rate", "1e9"], "--rate must be in (0, 60] frames per second, got 1e+09"),
     (["drive", "case-1", "--rate", "nan"], "--rate must be in (0, 60] frames per second, got nan"),
     (["drive", "case-1", "--seed", "-1"], "--seed must be an integer >= 0, got -1"),
     (["drive", "case-1", "--world", "carla", "--port", "0"], "--port must be an integer in [1, 65535], got 0"),
     (["drive", "case-1", "--world", "carla", "--timeout", "1e6"], "--timeout must be in (0, 600] s, got 1e+06"),
     (["demo", "--seed", "-1"], "--seed must be an integer >= 0, got -1"),
     (["estimate", "IMG", "--fps", "1000"], "--fps must be in (0, 240] frames per second, got 1000"),
     (["sweep", "SPEC", "--workers", "0"], "--workers must be an integer in [1, 256], got 0"),
     (["sweep", "SPEC", "--batch", "100001"], "--batch must be an integer in [1, 10000], got 100001")],
)  # fmt: skip
def test_numbers_out_of_range_are_one_line_naming_the_option(tmp_path, scripted, capsys, argv, message):
    spec = tmp_path / "spec.yaml"
    spec.write_text("name: x\nsweeps: [{name: s, family: random_si, seeds: 1}]\n")
    img = _image(tmp_path / "a.png")
    argv = [{"IMG": str(img), "SPEC": str(spec)}.get(a, a) for a in argv]
    out = tmp_path / "o"
    assert main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    _one_clean_line(err)
    assert err.strip() == f"trustnav: error: {message}"
    assert not out.exists() and not _partials(tmp_path)  # refused before anything was written


@pytest.mark.parametrize(
    ("option", "why"),
    [
        ("--no-body-search", "the HOG body-shape search"),
        ("--proposer", "BlazePose's tiled person search"),
        ("--scan-frames", "it shared out BlazePose's tiled search"),
        ("--sharpen", "it sharpened the frame for BlazePose's tiled search"),
    ],
)
def test_a_retired_option_is_one_line_saying_so(tmp_path, capsys, option, why):
    """Issue 35 retired the HOG body-shape search and BlazePose's tiled search: their options are
    refused by name with the reason, not ignored, with or without a value, before anything is
    written, and they are not in --help."""
    img, out = _image(tmp_path / "a.png"), tmp_path / "o"
    for value in ([], ["2"]):
        with pytest.raises(SystemExit) as exit_:
            main(["estimate", str(img), "--out", str(out), option, *value])
        assert exit_.value.code == 2
        err = capsys.readouterr().err
        _one_clean_line(err)
        assert err.startswith(f"trustnav estimate: error: {option} was removed: {why}")
        assert "issue 35" in err and not out.exists()
    with pytest.raises(SystemExit):
        main(["estimate", "--help"])
    assert option not in capsys.readouterr().out


def test_every_number_option_documents_its_range(capsys):
    from trustnav.cli import BOUNDS, build_parser

    parser = build_parser()
    commands = parser._subparsers._group_actions[0].choices  # type: ignore[union-attr]
    seen = set()
    for name, sub in commands.items():
        for action in sub._actions:
            if action.type in (int, float):
                dest = action.dest
                assert dest in BOUNDS, f"{name} {action.option_strings}: no documented range"
                lo, hi = BOUNDS[dest].lo, BOUNDS[dest].hi
                text = " ".join(action.help.split())
                assert f"{lo:g}" in text and (hi == math.inf or f"{hi:g}" in text), (name, dest, text)
                seen.add(dest)
    assert seen == set(BOUNDS)


def test_version_and_help_of_the_perception_benchmark(repo_root, capsys):
    import trustnav

    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and capsys.readouterr().out.strip() == f"trustnav {trustnav.__version__}"
    proc = subprocess.run([sys.executable, str(repo_root / "benchmarks" / "perception_eval.py"), "--help"],
                          capture_output=True, text=True, timeout=60)  # fmt: skip
    assert proc.returncode == 0 and proc.stdout.startswith("usage: perception_eval.py") and not proc.stderr


def test_scenario_solvers_get_their_own_default_folders_and_reruns_need_overwrite(tmp_path, monkeypatch, capsys):
    from trustnav.sim import paper

    real = paper.run_scenario
    monkeypatch.setattr(paper, "run_scenario", lambda name, solver="sqp": real(name, solver="sqp"))
    monkeypatch.chdir(tmp_path)
    assert main(["scenario", "paper-2"]) == 0
    assert main(["scenario", "paper-2", "--solver", "slsqp"]) == 0
    assert (tmp_path / "out" / "paper-2" / "metrics.json").is_file()
    assert (tmp_path / "out" / "paper-2-slsqp" / "metrics.json").is_file()
    capsys.readouterr()
    assert main(["scenario", "paper-2"]) == 2
    _one_clean_line(capsys.readouterr().err)
    assert main(["scenario", "paper-2", "--overwrite"]) == 0


def test_demo_replaces_its_own_default_folder_but_not_a_named_one(tmp_path, monkeypatch, capsys, quick_demo):
    from trustnav.sim.driving import demo as story

    monkeypatch.setattr(story, "run_demo", lambda seed, progress=None: quick_demo)
    monkeypatch.chdir(tmp_path)
    assert main(["demo"]) == 0
    assert main(["demo"]) == 0  # run again and again: replaced
    assert (tmp_path / "out" / "demo" / "metrics.json").is_file()
    named = tmp_path / "mine"
    named.mkdir()
    (named / "x.txt").write_text("x")
    assert main(["demo", "--out", str(named)]) == 2
    assert main(["drive", "case-1", "--sensing", "keypoints", "--out", str(named)]) == 2


# -- 7. every public entry point validates its inputs ------------------------------------------------


def test_validation_messages_name_the_argument():
    from trustnav.control import MpcConfig, MpcController, SingleIntegrator, VelocityTrackingCost
    from trustnav.control.solvers import make_solver
    from trustnav.trust import GammaParams, Sighting, TrustEstimator, TrustParams

    with pytest.raises(ValueError, match="rho must have 3 weights"):
        TrustParams(rho="abc")
    with pytest.raises(ValueError, match=r"rho\[0\] must be a number, got 'a'"):
        TrustParams(rho=("a", 0.5, 0.5))
    assert TrustParams(beta=np.float32(0.1)).beta == pytest.approx(0.1)  # numpy scalars are numbers
    assert TrustParams(rho=np.array([0.4, 0.5, 0.1])).rho == (0.4, 0.5, 0.1)
    assert GammaParams(lam=np.int64(2)).lam == 2.0
    with pytest.raises(ValueError, match="alpha must be a number, got True"):
        TrustParams(alpha=True)
    with pytest.raises(ValueError, match="c_eye must be a confidence in"):
        Sighting(track_id=1, time=0.0, c_eye=2.0)
    with pytest.raises(ValueError, match="track_id must be an integer"):
        Sighting(track_id="a", time=0.0)
    with pytest.raises(ValueError, match="keep_time must be a number"):
        TrustEstimator(keep_time="x")
    with pytest.raises(ValueError, match="goal must be 2 finite coordinates"):
        VelocityTrackingCost(goal=(np.nan, 45))
    ctl = MpcController(SingleIntegrator(), VelocityTrackingCost(goal=(20, 45)), MpcConfig(horizon=3))
    for peds in ([[24, 22, 0]], [24, 22, 0]):
        with pytest.raises(ValueError, match=r"pedestrians must be an \(N, 2\) array"):
            ctl.step([17, 5], peds, None, [0.5])
    with pytest.raises(ValueError, match="unknown solver 'bogus'"):
        make_solver("bogus")


@pytest.mark.parametrize(
    ("line", "match"),
    [('safety_radius = "three"', "safety_radius in {file} must be a number > 0, got 'three'"),
     ("dt = -0.05", "dt in {file} must be a number > 0, got -0.05"),
     ("horizons = [1, 2.5]", "horizons[1] in {file} must be an integer >= 1, got 2.5"),
     ('timing = "later"', "timing in {file} must be one of 'paper', 'authors_code', got 'later'"),
     ("compare_timings = 1", "compare_timings in {file} must be true or false, got 1"),
     ("horizns = [1]", "unknown key 'horizns' in {file}: did you mean 'horizons'?")],
)  # fmt: skip
def test_scenario_toml_values_are_validated(tmp_path, repo_root, paper_scenario, line, match):
    load_scenario = paper_scenario
    text = (repo_root / "src/trustnav/sim/scenarios/paper-3.toml").read_text()
    key = line.split(" = ")[0]
    lines = [ln for ln in text.splitlines() if not ln.startswith(f"{key} =")]
    bad = tmp_path / "bad.toml"
    bad.write_text("\n".join([line, *lines]))
    with pytest.raises(ValueError, match=re.escape(match.format(file=bad))):
        load_scenario(bad)


def test_scenario_toml_pedestrians_are_validated(tmp_path, paper_scenario):
    load_scenario = paper_scenario

    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\ntitle = "x"\nego_start = [0, 0]\ngoal = [1, 1]\n[[pedestrian]]\nposition = [0]\n')
    with pytest.raises(ValueError, match=r"position in pedestrian 1 of .*bad.toml must be two finite numbers \[x, y\]"):
        load_scenario(bad)
    bad.write_text('name = "x"\ntitle = "x"\nego_start = [0, 0]\ngoal = [1, 1]\n')
    with pytest.raises(ValueError, match=r"needs \[\[pedestrian\]\] tables"):
        load_scenario(bad)


# -- 8. the baseline as the authors wrote it ----------------------------------------------------------


def test_authors_style_baseline_is_one_closure_per_row_with_scipy_defaults(monkeypatch):
    import scipy.optimize

    from trustnav.control import KinematicBicycle, LaneTrackingCost, MpcConfig, MpcController
    from trustnav.control import solvers as slv

    calls = []
    real = scipy.optimize.minimize

    def spy(fun, x0, **kw):
        res = real(fun, x0, **kw)
        calls.append((np.array(x0), kw, res.x.copy()))
        return res

    monkeypatch.setattr(slv, "minimize", spy)
    assert isinstance(slv.make_solver("slsqp-authors"), slv.AuthorsSlsqpSolver)
    assert isinstance(slv.make_solver("slsqp"), slv.SlsqpSolver)
    cfg = MpcConfig(horizon=4, dt=0.1, safety_radius=2.5)
    model = KinematicBicycle(integration_step=None)  # one Euler step per dt: k = 0 rows decided
    ctl = MpcController(model, LaneTrackingCost(start=(0, 0), goal=(100, 0)), cfg, slv.AuthorsSlsqpSolver())
    x = np.array([0.0, 0.0, 0.0, 8.0])
    peds = np.array([[12.0, 3.0], [20.0, -3.5], [30.0, 4.0]])
    for _ in range(2):
        sol = ctl.step(x, peds, None, [0.2, 0.5, 0.9])
        x = ctl.model.step(x, sol.control, cfg.dt)
    (x0_first, kw_first, x_first), (x0_second, _, _) = calls
    assert "options" not in kw_first  # scipy's default ftol and maxiter
    # one closure per pedestrian and horizon step that an input can change (the bicycle's k = 0 rows
    # are decided by the state), plus one per speed row (lower and upper)
    assert len(kw_first["constraints"]) == 3 * (4 - 1) + 2 * 4
    assert np.all(x0_first == 0)  # first step: from rest
    # then the previous solution as it was, not shifted by one step
    assert np.allclose(x0_second, np.clip(x_first, ctl.problem.lo, ctl.problem.hi))


def test_reference_baselines_keep_the_margin_on_paper_3_and_agree_with_the_default(paper_scenario):
    """The breach reported on `scenario paper-3 --solver slsqp` came from the old controller applying
    an unchecked stop after a failed SLSQP solve (docs/fidelity.md); with checked fallbacks every
    solver keeps the default's distances."""
    from trustnav.sim import run_episode

    sc = paper_scenario("paper-3")
    ref = run_episode(sc, horizon=4, timing="authors_code")
    for solver in ("slsqp", "slsqp-authors"):
        ep = run_episode(sc, horizon=4, timing="authors_code", solver=solver)
        d = ep.distances.min(axis=0)
        assert d.min() >= 3.0 - 1e-6, (solver, d)
        assert np.allclose(d, ref.distances.min(axis=0), atol=0.05), (solver, d)


def test_bench_mpc_reports_both_baselines(repo_root):
    sys.path.insert(0, str(repo_root / "benchmarks"))
    try:
        import bench_mpc
    finally:
        sys.path.pop(0)
    row = bench_mpc.run_case("single_integrator", 2, 3, "paper-2", steps=4, baseline_steps=2)
    assert row["default_steps"] == 4 and row["failures"] == 0
    assert row["default_p95_ms"] >= row["default_median_ms"] > 0
    for tag in ("authors", "tuned"):
        assert row[f"{tag}_steps"] == 2 and row[f"{tag}_failures"] == 0, row
        assert row[f"{tag}_p95_ms"] >= row[f"{tag}_median_ms"] > 0
        # the speed-up is the ratio of the two medians, and both solvers drive the same first steps
        assert row[f"{tag}_speedup"] == pytest.approx(row[f"{tag}_median_ms"] / row["default_median_ms"])
        assert row[f"{tag}_max_trajectory_diff"] < 1e-3, row


@pytest.mark.skipif(os.environ.get("CI_NO_SUBPROCESS") == "1", reason="no subprocesses")
def test_cli_entry_point_has_no_traceback_on_bad_input(tmp_path):
    """The installed command, not only main(): a missing input is one line and exit 2."""
    proc = subprocess.run([sys.executable, "-m", "trustnav.cli", "estimate", str(tmp_path / "missing.png"),
                           "--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 2
    _one_clean_line(proc.stderr)
    assert "does not exist" in proc.stderr


# -- 9. readable labels in crowds ------------------------------------------------------------------


def test_labels_of_neighbouring_people_do_not_overlap():
    from trustnav.viz.annotate import _overlap, annotate, place_labels

    boxes = [(100, 100, 140, 200), (110, 104, 150, 204), (120, 98, 160, 210), (300, 50, 340, 150)]
    rects = place_labels(boxes, [(60, 14)] * 4, 640, 480)
    assert all(_overlap(a, b) == 0 for i, a in enumerate(rects) for b in rects[i + 1 :])
    assert all(0 <= r[0] and r[2] <= 640 and 0 <= r[1] and r[3] <= 480 for r in rects)
    # next to its own box: within a label's size of it
    for (x1, y1, x2, y2), r in zip(boxes, rects, strict=True):
        assert x1 - 62 <= r[0] <= x2 + 2 and y1 - 16 <= r[1] <= y2 + 2
    recs = [{"bbox": list(b), "trust": 0.5, "eye_contact": 0.5, "track_id": i} for i, b in enumerate(boxes)]
    img = annotate(np.zeros((480, 640, 3), np.uint8), recs, [np.full((17, 2), np.nan)] * 4, ["N"] * 4)
    assert img.shape == (480, 640, 3)
