"""Issue 23, nothing lost, nothing mixed: output folders written whole or not at all, a campaign
folder that resumes only its own campaign, Ctrl-C on a sweep that keeps what finished.

Interruptions are simulated by a function that raises KeyboardInterrupt (as Ctrl-C would in the
main thread); one test sends a real SIGINT to this process to check how a LocalCluster start holds
it back.
"""

from __future__ import annotations

import json
import os
import signal
import threading
from pathlib import Path

import pytest
import yaml

import trustnav.sim.driving.variants as variants
from trustnav.cli import main
from trustnav.outputs import OutputFolder

OUTPUTS = ("metrics.json", "frames", "top_view.png")


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _partials(parent: Path) -> list[Path]:
    return sorted(parent.glob(".*.partial"))


def _one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.fixture
def earlier(tmp_path: Path) -> Path:
    """A folder with the outputs of an earlier run and one file of the user's."""
    out = tmp_path / "out"
    (out / "frames").mkdir(parents=True)
    (out / "frames" / "0001.png").write_bytes(b"old frame")
    (out / "metrics.json").write_text('{"run": "earlier"}')
    (out / "notes.txt").write_text("mine")
    return out


# -- OutputFolder ---------------------------------------------------------------------------------


def test_a_run_is_written_beside_and_moved_into_place_when_done(tmp_path):
    out = tmp_path / "a" / "out"
    with OutputFolder(out, False, OUTPUTS) as folder:
        assert folder.path.parent == out.parent.resolve() and folder.path.name.startswith(".out.trustnav-")
        (folder.path / "metrics.json").write_text("{}")
        assert not out.exists()  # nothing in place until the run is done
    assert _tree(out) == {"metrics.json": b"{}"} and not _partials(out.parent)
    assert folder.final(folder.path / "metrics.json") == out / "metrics.json"


def test_an_interrupted_write_keeps_the_earlier_folder(earlier):
    before = _tree(earlier)
    with pytest.raises(KeyboardInterrupt), OutputFolder(earlier, True, OUTPUTS) as folder:
        (folder.path / "metrics.json").write_text('{"run": "new"}')
        (folder.path / "frames").mkdir()
        raise KeyboardInterrupt
    assert _tree(earlier) == before and not _partials(earlier.parent)


def test_overwrite_replaces_our_outputs_and_leaves_other_files(earlier):
    with OutputFolder(earlier, True, OUTPUTS) as folder:
        (folder.path / "frames").mkdir()
        (folder.path / "frames" / "0002.png").write_bytes(b"new frame")
        (folder.path / "metrics.json").write_text('{"run": "new"}')
    assert _tree(earlier) == {"frames/0002.png": b"new frame", "metrics.json": b'{"run": "new"}', "notes.txt": b"mine"}


def test_a_folder_of_a_killed_run_is_cleared_and_a_live_ones_kept(tmp_path):
    dead = tmp_path / ".out.trustnav-999999999-abcd.partial"  # no such process
    live = tmp_path / f".out.trustnav-{os.getpid()}-abcd.partial"  # another run of this process
    other = tmp_path / ".other.trustnav-999999999-abcd.partial"  # another folder's
    for d in (dead, live, other):
        d.mkdir()
    with OutputFolder(tmp_path / "out", False, OUTPUTS):
        pass
    assert not dead.exists() and live.exists() and other.exists()


def test_an_interrupted_run_is_kept_aside_when_out_held_earlier_outputs(tmp_path, earlier):
    before = _tree(earlier)
    folder = OutputFolder(earlier, True, OUTPUTS)
    folder.open()
    (folder.path / "metrics.json").write_text('{"run": "interrupted"}')
    kept, note = folder.keep(folder.has_earlier_outputs())
    assert _tree(earlier) == before and kept.name == "out.interrupted" and str(earlier) in note
    assert _tree(tmp_path / "out.interrupted") == {"metrics.json": b'{"run": "interrupted"}'}
    fresh = OutputFolder(tmp_path / "new", False, OUTPUTS)
    fresh.open()
    (fresh.path / "metrics.json").write_text("{}")
    assert fresh.keep(False) == (tmp_path / "new", "") and (tmp_path / "new" / "metrics.json").is_file()
    assert not _partials(tmp_path)


def test_refusals_come_before_anything_is_written(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="is a file"):
        OutputFolder(tmp_path / "file", True, OUTPUTS)
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("x")
    with pytest.raises(ValueError, match="--overwrite"):
        OutputFolder(tmp_path / "full", False, OUTPUTS)
    assert not _partials(tmp_path)


# -- the commands ---------------------------------------------------------------------------------


def test_ctrl_c_during_demo_leaves_the_previous_demo_as_it_was(tmp_path, monkeypatch, capsys, quick_demo):
    from trustnav.sim.driving import demo as story
    from trustnav.viz import drive_plots

    def first(demo, out, video=True):
        (out / "metrics.json").write_text('{"run": 1}')

    def interrupted(demo, out, video=True):
        (out / "metrics.json").write_text('{"run": 2}')  # half written when Ctrl-C comes
        raise KeyboardInterrupt

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(story, "run_demo", lambda seed, progress=None: quick_demo)
    monkeypatch.setattr(drive_plots, "write_demo_outputs", first)
    assert main(["demo"]) == 0
    demo = tmp_path / "out" / "demo"
    before = _tree(demo)
    monkeypatch.setattr(drive_plots, "write_demo_outputs", interrupted)
    assert main(["demo"]) == 130
    assert "interrupted" in _one_line(capsys.readouterr().err)
    assert _tree(demo) == before == {"metrics.json": b'{"run": 1}'}
    assert not _partials(demo.parent)


def test_failed_drive_and_scenario_leave_nothing_behind(tmp_path, monkeypatch, capsys):
    from trustnav.sim import paper

    def failing(*args, **kwargs):
        raise ValueError("the world fell apart")

    monkeypatch.setattr(variants, "drive_variants", failing)
    assert main(["drive", "case-1", "--out", str(tmp_path / "d")]) == 2
    assert "the world fell apart" in _one_line(capsys.readouterr().err)
    monkeypatch.setattr(paper, "run_scenario", lambda name, solver="sqp": (_ for _ in ()).throw(KeyboardInterrupt))
    assert main(["scenario", "paper-1", "--out", str(tmp_path / "s")]) == 130
    capsys.readouterr()
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no folder, no partial: a rerun is free


# -- campaign folders -----------------------------------------------------------------------------

TINY = {"name": "tiny", "sweeps": [{"name": "si", "family": "random_si", "seeds": 3,
                                    "params": {"max_pedestrians": 2, "max_steps": 60}}]}  # fmt: skip


def _spec(tmp_path: Path, doc: dict, name: str = "spec.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(doc))
    return path


def test_sweep_refuses_the_folder_of_another_campaign(tmp_path, capsys):
    other = tmp_path / "other"
    other.mkdir()
    (other / "spec.json").write_text(json.dumps({"name": "trust_horizon", "points": []}))
    (other / "records.jsonl").write_text('{"key": "a:1:0"}\n{"key": "a:1:1"}\n')
    before = _tree(other)
    assert main(["sweep", str(_spec(tmp_path, TINY)), "--out", str(other)]) == 2
    line = _one_line(capsys.readouterr().err)
    assert f"--out {other} holds campaign 'trust_horizon' (2 records), not 'tiny'" in line
    assert _tree(other) == before


def test_sweep_refuses_a_folder_of_unrelated_files(tmp_path, capsys):
    photos = tmp_path / "photos"
    photos.mkdir()
    for name in ("a.jpg", "b.jpg", "c.jpg", "d.jpg"):
        (photos / name).write_bytes(b"jpeg")
    assert main(["sweep", str(_spec(tmp_path, TINY)), "--out", str(photos)]) == 2
    line = _one_line(capsys.readouterr().err)
    assert f"--out {photos} holds 4 files that are not a campaign's (a.jpg, b.jpg, c.jpg and 1 more)" in line
    assert sorted(p.name for p in photos.iterdir()) == ["a.jpg", "b.jpg", "c.jpg", "d.jpg"]


def test_a_campaign_folder_passes_for_its_own_campaign_only(tmp_path):
    from trustnav.campaigns.runner import CampaignFolderError, _write_spec, check_campaign_folder
    from trustnav.campaigns.spec import spec_from_dict

    out = tmp_path / "c"
    tiny = spec_from_dict(TINY)
    check_campaign_folder(tiny, out)  # new
    out.mkdir()
    check_campaign_folder(tiny, out)  # empty
    _write_spec(tiny, out)
    (out / "notes.md").write_text("my notes")
    grown = spec_from_dict({**TINY, "sweeps": [{**TINY["sweeps"][0], "seeds": 10}]})
    check_campaign_folder(grown, out)  # its own campaign, grown: resumes
    with pytest.raises(CampaignFolderError, match="holds campaign 'tiny'"):
        check_campaign_folder(spec_from_dict({**TINY, "name": "other"}), out)
    (out / "spec.json").unlink()
    with pytest.raises(CampaignFolderError, match="not a campaign's"):
        check_campaign_folder(tiny, out)


def test_ctrl_c_on_a_sweep_keeps_the_finished_records_and_says_so_in_one_line(tmp_path, monkeypatch, capsys):
    from trustnav.campaigns.records import RecordStore

    real = RecordStore.append
    calls: list[str] = []

    def append_then_ctrl_c(self, record):
        if len(calls) == 2:  # Ctrl-C while the third result comes in
            raise KeyboardInterrupt
        calls.append(record["key"])
        real(self, record)

    monkeypatch.setattr(RecordStore, "append", append_then_ctrl_c)
    spec = _spec(tmp_path, {**TINY, "batch": 1})
    out = tmp_path / "out"
    assert main(["sweep", str(spec), "--out", str(out), "--workers", "1", "--quiet"]) == 130
    captured = capsys.readouterr()
    line = _one_line(captured.err)
    assert line == (f"trustnav: interrupted; 2 of the 3 episodes of tiny are recorded in {out / 'records.jsonl'} "
                    "(summary and figures updated); rerun the same command to resume")  # fmt: skip
    assert [r["key"] for r in RecordStore(out / "records.jsonl")] == calls
    assert json.loads((out / "summary.json").read_text())["sweeps"]["si"]["episodes"] == 2


def test_ctrl_c_while_a_local_cluster_starts_waits_for_it(monkeypatch):
    """The start of a LocalCluster holds SIGINT back (blocked: the threads and worker processes it
    starts inherit the block) and raises it once the cluster is up."""
    from trustnav.campaigns.runner import _sigint_held

    seen: list[set] = []
    with pytest.raises(KeyboardInterrupt), _sigint_held():
        os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C now: not raised inside
        t = threading.Thread(target=lambda: seen.append(signal.pthread_sigmask(signal.SIG_BLOCK, [])))
        t.start()
        t.join()
        inside = True
    assert inside and signal.SIGINT in seen[0]  # a thread started meanwhile blocks it too
    assert signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, [])  # unblocked again
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
