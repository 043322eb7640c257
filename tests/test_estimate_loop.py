"""The estimate loop as a library function (issue 37): :func:`estimate_sequences` wires planned
input sequences to perception and trust and returns per-frame results, writing nothing; the CLI
writes the files."""

from __future__ import annotations

import shutil

import pytest

from trustnav.perception.estimate import EstimatedFrame, estimate_sequences
from trustnav.perception.frames import plan_sequences
from trustnav.trust.params import PAPER_TRUST, SECONDS_TRUST, TRUST_LAWS

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def two_copies(sequences, tmp_path_factory):
    """The first frames of walk_a in two folders, the second with a cut-off frame among them."""
    root = tmp_path_factory.mktemp("estimate_loop")
    frames = sorted((sequences / "walk_a").glob("*.png"))[:4]
    for name in ("first", "second"):
        (root / name).mkdir()
        for f in frames:
            shutil.copy(f, root / name / f.name)
    (root / "second" / f"{frames[1].stem}_broken.png").write_bytes(frames[1].read_bytes()[:2000])  # cut off
    return root


def _plain(records: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k != "sequence"} for r in records]


def test_no_tracker_or_trust_state_crosses_two_sequences(two_copies, mediapipe_backend, looking_model):
    planned = plan_sequences([two_copies / "first", two_copies / "second"])
    # the cut-off frame is not stitched into its folder's sequence: it is one of its own
    assert [s.label for s in planned] == ["first", "second", "image_00005311_0_broken.png"]
    out = list(estimate_sequences(planned, mediapipe_backend, looking_model, fps=10.0))
    assert all(isinstance(f, EstimatedFrame) for f in out)
    first, second, broken = ([f for f in out if f.sequence is s] for s in planned)
    assert len(first) == len(second) == 4 and all(f.fps == 10.0 for f in out)
    # an unreadable frame is reported in its place (error, no records) and the run goes on
    assert len(broken) == 1 and "broken" in broken[0].result.name and broken[0].result.error
    assert not broken[0].result.records and out[-1] is broken[0]
    good = second
    assert any(f.result.records for f in first)
    # the second sequence starts afresh: the same frames give the same tracks, traits and trusts
    # (a tracker or trust estimator carried over would continue the first sequence's tracks)
    for a, b in zip(first, good, strict=True):
        assert _plain(a.result.records) == _plain(b.result.records)
        assert {r["sequence"] for r in b.result.records} <= {planned[1].label}
        assert len(b.labels) == len(b.result.people) and b.repeat == 1


def test_the_trust_law_and_max_frames_are_honoured(two_copies, mediapipe_backend, looking_model):
    planned = plan_sequences([two_copies / "first"])
    paper = list(estimate_sequences(planned, mediapipe_backend, looking_model, trust=PAPER_TRUST, max_frames=3))
    seconds = list(estimate_sequences(planned, mediapipe_backend, looking_model, trust=SECONDS_TRUST, max_frames=3))
    assert len(paper) == len(seconds) == 3
    by_frame = {law: [[r["trust"] for r in f.result.records] for f in run]
                for law, run in (("paper", paper), ("seconds", seconds))}  # fmt: skip
    assert all(0.0 <= t <= 1.0 for run in by_frame.values() for row in run for t in row)
    assert by_frame["paper"] != by_frame["seconds"]  # a step per frame is not the law in seconds
    assert TRUST_LAWS["paper"] is PAPER_TRUST and TRUST_LAWS["seconds"] is SECONDS_TRUST
