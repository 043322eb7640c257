"""Offline landmark fits on moved crops (issue 35, item 5): the median, its options and errors, and
that it makes the keypoints steadier under a one-pixel shift of the frame."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from trustnav.perception.crop_ensemble import CROP_PERTURBATIONS, median_landmarks

_fits = st.integers(1, 7).flatmap(
    lambda n: st.lists(
        arrays(np.float64, (33, 5), elements=st.floats(-1e3, 1e3, allow_nan=False)), min_size=n, max_size=n
    )
)


@settings(max_examples=60, deadline=None)
@given(_fits, st.randoms(use_true_random=False))
def test_the_median_lies_within_the_fits_and_ignores_their_order(fits, rnd):
    med = median_landmarks(fits)
    stack = np.stack(fits)
    assert med.shape == (33, 5)
    assert np.all(med >= stack.min(axis=0) - 1e-9) and np.all(med <= stack.max(axis=0) + 1e-9)
    shuffled = list(fits)
    rnd.shuffle(shuffled)
    np.testing.assert_allclose(median_landmarks(shuffled), med)


def test_one_wild_fit_among_five_does_not_move_the_median():
    base = np.tile(np.arange(5.0), (33, 1))
    wild = base + 40.0  # a fit that jumped (a wrist on the neighbour)
    np.testing.assert_allclose(median_landmarks([base, base + 0.5, base - 0.5, base, wild]), base)


def test_bad_fits_are_refused_with_a_clear_message():
    with pytest.raises(ValueError, match="at least one fit"):
        median_landmarks([])
    with pytest.raises(ValueError, match="share one shape"):
        median_landmarks([np.zeros((33, 5)), np.zeros((17, 5))])


def test_crop_fits_out_of_range_or_off_the_offline_mediapipe_path_is_refused():
    pytest.importorskip("mediapipe")
    from trustnav.perception.crop_ensemble import CropEnsembleBackend
    from trustnav.perception.optional_backends import make_backend

    with pytest.raises(ValueError, match=r"crop fits must be an integer in \[1, 7\], got 0"):
        CropEnsembleBackend(fits=0)
    with pytest.raises(ValueError, match="offline mediapipe backend only"):
        make_backend("mediapipe", realtime=True, crop_fits=3)
    with pytest.raises(ValueError, match="offline mediapipe backend only"):
        make_backend("yolo", crop_fits=3)
    assert len(CROP_PERTURBATIONS) + 1 == 7


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        (["--crop-fits", "0"], "--crop-fits must be an integer in [1, 7], got 0"),
        (["--crop-fits", "3", "--realtime"], "--crop-fits applies to offline perception"),
        (["--crop-fits", "3", "--proposer", "blazepose"], "--crop-fits applies to offline perception"),
    ],
)
def test_estimate_refuses_crop_fits_it_cannot_use_in_one_line(sequences, out_dir, capsys, extra, needle):
    from trustnav.cli import main

    code = main(["estimate", str(sequences / "phone_a"), "--out", str(out_dir), *extra])
    err = capsys.readouterr().err
    assert code == 2 and needle in err and err.count("\n") == 1
    assert not out_dir.exists() or not any(out_dir.iterdir())


@pytest.mark.slow
def test_the_median_of_moved_crops_holds_the_keypoints_steadier_under_a_one_pixel_shift(sequences, read_rgb):
    """The point of the ensemble: moving the frame by one pixel moves a single fit's keypoints by more
    than the pixel; the median of five fits follows the pixel more closely (walk_a, several people)."""
    pytest.importorskip("mediapipe")
    from trustnav.perception.crop_ensemble import CropEnsembleBackend
    from trustnav.perception.mediapipe_backend import MediaPipePoseBackend
    from trustnav.perception.types import box_iou

    frames = [read_rgb(f) for f in sorted((sequences / "walk_a").glob("*.png"))[:40:10]]

    def moved(frame: np.ndarray) -> np.ndarray:
        out = np.empty_like(frame)
        out[:, 1:], out[:, 0] = frame[:, :-1], frame[:, 0]
        return out

    def jitter(backend) -> float:
        errs = []
        for frame in frames:
            for p in backend(frame):
                q = max(backend(moved(frame)), key=lambda q: box_iou(q.bbox - [1, 0, 1, 0], p.bbox), default=None)
                if q is None or box_iou(q.bbox - [1, 0, 1, 0], p.bbox) < 0.7:
                    continue
                seen = (p.confidences > 0.3) & (q.confidences > 0.3)
                move = np.linalg.norm(q.keypoints - [1, 0] - p.keypoints, axis=1)[seen]
                errs.append(float(np.median(move)) / (p.bbox[3] - p.bbox[1]))
        assert len(errs) >= 8
        return float(np.mean(errs))

    with MediaPipePoseBackend() as single, CropEnsembleBackend(fits=5) as ensemble:
        # detection and the boxes are the plain backend's; only the landmarks are the fits' median
        a, b = single(frames[0]), ensemble(frames[0])
        assert [p.bbox.tolist() for p in a] == [p.bbox.tolist() for p in b]
        assert all(1 <= p.extra["crop_fits"] <= 5 for p in b) and max(p.extra["crop_fits"] for p in b) >= 2
        assert jitter(ensemble) < 0.85 * jitter(single)
