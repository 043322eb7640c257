"""People the pose detector misses, proposed by person segmentation (issue 19, item 4): the regions
proposed, the checks that tie a fit to its region, and the people found on real frames."""

from __future__ import annotations

import numpy as np
import pytest

from trustnav.perception.mediapipe_backend import MediaPipeConfig
from trustnav.perception.segment_search import MIN_HEIGHT_PX, blob_regions, plausible, segment_windows
from trustnav.perception.types import box_iou


def test_windows_cover_the_frame_with_half_overlap():
    wins = segment_windows(480, 640, 0.33)
    cover = np.zeros((480, 640), int)
    for x0, y0, x1, y1 in wins:
        assert x1 - x0 == y1 - y0 == 158
        cover[y0:y1, x0:x1] += 1
    assert cover.min() >= 1 and cover.max() >= 4  # every pixel, most of them by several windows
    assert segment_windows(100, 50, 1.0) == [(0, 0, 50, 50), (0, 25, 50, 75), (0, 50, 50, 100)]


def test_a_region_per_person_and_a_wide_region_split_per_person_width():
    mask = np.zeros((300, 400), np.float32)
    mask[50:250, 20:60] = 1.0  # one person, 200 px tall
    mask[50:250, 150:330] = 0.9  # two people side by side (180 px wide)
    mask[10:30, 350:360] = 1.0  # too small to be anybody
    regions = blob_regions(mask, 68)
    assert len(regions) == 3
    (one, blob_one), *pair = sorted(regions, key=lambda r: r[0][0])
    assert blob_one == (20, 50, 40, 200) and one[:3] == pytest.approx([40.0, 150.0, 250.0])
    assert [round(r[0]) for r, _ in pair] == [195, 285] and all(np.isnan(r[4]) for r, _ in pair)


def _standing(x: float, top: float, height: float) -> np.ndarray:
    """33 landmarks of an upright person: feet (27-32) at top + height."""
    lm = np.zeros((33, 5))
    lm[:, 0] = x
    lm[:, 1] = np.linspace(top, top + height, 33)
    lm[27:33, 1] = top + height
    return lm


def test_a_fit_must_be_tall_enough_not_solid_and_stand_at_its_regions_bottom():
    mask = np.zeros((400, 300), np.float32)
    mask[100:300, 100:140] = 1.0  # a person-shaped region: a 40 px wide column in a 100 px wide box
    blob = (100, 100, 40, 200)
    box = np.array([80.0, 100.0, 160.0, 300.0])
    assert plausible(box, _standing(120, 100, 200), mask, blob)
    # feet far above the region's bottom: a fit on something above the region's object
    assert not plausible(np.array([80.0, 40.0, 160.0, 160.0]), _standing(120, 40, 120), mask, blob)
    # a solid silhouette filling its box (a sign, a pictogram)
    solid = mask.copy()
    solid[100:300, 80:160] = 1.0
    assert not plausible(box, _standing(120, 100, 200), solid, (80, 100, 80, 200))
    # smaller than a person the checks can trust
    small = MIN_HEIGHT_PX - 5
    assert not plausible(np.array([100.0, 100.0, 140.0, 100.0 + small]), _standing(120, 100, small), mask, blob)


def test_config_refuses_bad_segmentation_settings():
    with pytest.raises(ValueError, match="segment_tile"):
        MediaPipeConfig(segment_tile=0.05)
    with pytest.raises(ValueError, match="segment_frames"):
        MediaPipeConfig(segment_frames=0)
    with pytest.raises(ValueError, match="segment_search"):
        MediaPipeConfig(segment_search="yes")


@pytest.mark.slow
def test_segmentation_finds_the_pair_in_profile_that_the_detector_misses(sequences, read_rgb):
    """walk_a, frame 8: a man in a grey coat and a woman in a beige coat stand side by side in
    profile, ~100 px tall; the face-based detector finds neither (labelled boxes below, from
    benchmarks/data/labels/walk_a.json), segmentation finds both, and no box lands off a person
    (the body-shape search, which finds them too, left out)."""
    from trustnav.perception.mediapipe_backend import MediaPipePoseBackend

    frame = read_rgb(sequences / "walk_a" / "image_00005318_0.png")
    pair = [np.array([507.0, 152.0, 543.0, 246.0]), np.array([544.0, 155.0, 580.0, 252.0])]
    found = {}
    for search in (False, True):
        config = MediaPipeConfig(segment_search=search, body_search=False, proposer="blazepose")
        with MediaPipePoseBackend(config) as backend:
            people = backend(frame)
        found[search] = [max((box_iou(b, p.bbox) for p in people), default=0.0) >= 0.5 for b in pair]
        if search:
            assert any(p.extra.get("segmented") for p in people)
            assert all(p.bbox[3] - p.bbox[1] >= 50 for p in people)
    assert found == {False: [False, False], True: [True, True]}
