"""Shared test fixtures: the toolkit every test file may use instead of rebuilding its own.

Paths and data (session scope; a test that asks for data that is not here is skipped, not failed):

- ``repo_root``: this checkout's root folder.
- ``shared_dir``: ``../shared`` beside the checkout (paper, data, models).
- ``street_images``: ``../shared/data/street_images`` (photos of streets: crossing.jpg, street_2.png ...).
- ``sequences``: ``../shared/data/sequences`` (folders of frames: walk_a, phone_a).
- ``looking_weights``: the LOOKING eye-contact weights file in ``../shared/models/looking``.
- ``perception_truth``: ``tests/data/perception_truth.json``, hand-made ground truth of the shared images.

Models and perception (built once per session; pure numpy or closed at the end):

- ``looking_model``: the LOOKING eye-contact model loaded from ``looking_weights``.
- ``mediapipe_backend``: a MediaPipe BlazePose backend in image mode (no state kept between frames).
- ``make_pipeline``: factory ``make_pipeline(backend=None, *, fps=10.0, cues=None)`` -> a
  :class:`~trustnav.perception.pipeline.PerceptionPipeline` on ``backend`` (default: the session's
  MediaPipe backend), a fresh OC-SORT tracker at ``fps`` and the LOOKING model (or ``cues``).
- ``read_rgb``: function ``read_rgb(path)`` -> the image's RGB pixels (H x W x 3 uint8).

Scenarios and outputs:

- ``paper_scenario``: function ``paper_scenario(name)`` -> ``trustnav.sim.load_scenario(name)`` (Section III).
- ``drive_scenario``: function ``drive_scenario(name)`` -> ``load_drive_scenario(name)`` (Section IV).
- ``out_dir``: a fresh, not yet created output folder ``tmp_path / "out"`` (as ``--out`` gets it).

Markers: ``slow`` (registered in pyproject.toml) marks tests that take more than ~5 s; CI runs them.
"""

from __future__ import annotations

import json
import signal
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

# Ctrl-C behaves as in a terminal whatever launched the tests: a shell's background job inherits
# SIGINT ignored, and then Python installs no KeyboardInterrupt handler (the signal tests need one)
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
LOOKING_WEIGHTS = SHARED / "models" / "looking" / "LookingModel_LOOK+PIE.p"


def _existing(path: Path, what: str) -> Path:
    if not path.exists():
        pytest.skip(f"{what} not present at {path}")
    return path


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return ROOT


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    return _existing(SHARED, "../shared")


@pytest.fixture(scope="session")
def street_images(shared_dir: Path) -> Path:
    return _existing(shared_dir / "data" / "street_images", "the shared street images")


@pytest.fixture(scope="session")
def sequences(shared_dir: Path) -> Path:
    return _existing(shared_dir / "data" / "sequences", "the shared frame sequences")


@pytest.fixture(scope="session")
def looking_weights() -> Path:
    return _existing(LOOKING_WEIGHTS, "the LOOKING weights")


@pytest.fixture(scope="session")
def perception_truth() -> dict[str, Any]:
    return json.loads((ROOT / "tests" / "data" / "perception_truth.json").read_text())


@pytest.fixture(scope="session")
def looking_model(looking_weights: Path) -> Any:
    from trustnav.perception.looking import LookingModel

    return LookingModel.from_file(looking_weights)


@pytest.fixture(scope="session")
def mediapipe_backend() -> Iterator[Any]:
    pytest.importorskip("mediapipe")
    from trustnav.perception.mediapipe_backend import MediaPipePoseBackend

    with MediaPipePoseBackend() as backend:
        yield backend


@pytest.fixture
def make_pipeline(request: pytest.FixtureRequest) -> Callable[..., Any]:
    from trustnav.perception.pipeline import PerceptionPipeline
    from trustnav.perception.tracking import PersonTracker

    def make(backend: Any = None, *, fps: float = 10.0, cues: Sequence[Any] | None = None) -> PerceptionPipeline:
        if backend is None:
            backend = request.getfixturevalue("mediapipe_backend")
        if cues is not None:
            return PerceptionPipeline(backend, PersonTracker(fps=fps), cues=cues)
        return PerceptionPipeline(backend, PersonTracker(fps=fps), request.getfixturevalue("looking_model"))

    return make


@pytest.fixture(scope="session")
def read_rgb() -> Callable[[Path], np.ndarray]:
    from trustnav.perception.frames import iter_frames

    def read(path: Path) -> np.ndarray:
        item = next(iter_frames([path]))
        assert item.frame is not None, item.error
        return item.frame

    return read


@pytest.fixture(scope="session")
def paper_scenario() -> Callable[[str], Any]:
    from trustnav.sim import load_scenario

    return load_scenario


@pytest.fixture(scope="session")
def drive_scenario() -> Callable[[str], Any]:
    from trustnav.sim.driving.world import load_drive_scenario

    return load_drive_scenario


@pytest.fixture
def out_dir(tmp_path: Path) -> Path:
    return tmp_path / "out"


@pytest.fixture(scope="session")
def quick_demo() -> Any:
    """A :class:`~trustnav.sim.driving.demo.DemoRuns` of one-second keypoint drives of Case I (fast;
    for the demo command's folder handling, not its numbers)."""
    import dataclasses

    from trustnav.sim.driving import load_drive_scenario, run_drive
    from trustnav.sim.driving.compare import ConstantTrustEnvironment
    from trustnav.sim.driving.demo import DEMO_EQUAL_TRUST, DemoRuns
    from trustnav.sim.driving.episode import DriveEnvironment, drive, prepare_scenario

    sc = dataclasses.replace(load_drive_scenario("case-1"), duration=1.0)
    equal = drive(
        ConstantTrustEnvironment(DriveEnvironment(prepare_scenario(sc), seed=0), DEMO_EQUAL_TRUST), "keypoints"
    )
    aware = run_drive(sc, sensing="keypoints")
    return DemoRuns(aware, equal, aware, "keypoints")
