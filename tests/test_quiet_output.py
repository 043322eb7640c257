"""What reaches stderr: trustnav's own lines, not MediaPipe's start-up warnings, and never lost."""

from __future__ import annotations

import os
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from trustnav.perception.frames import quiet_stderr


def _fd2() -> str:
    return os.readlink("/proc/self/fd/2")


@pytest.mark.skipif(not Path("/proc/self/fd/2").exists(), reason="needs /proc")
def test_overlapping_quiet_blocks_of_two_threads_give_stderr_back():
    """Thread A silences, thread B silences, A leaves, B leaves (MediaPipe's workers starting their
    graphs): descriptor 2 must point where it did, else every later message of the run is lost."""
    before = _fd2()
    a_in, b_in, a_out = threading.Event(), threading.Event(), threading.Event()

    def a() -> None:
        with quiet_stderr():
            a_in.set()
            b_in.wait(5)
        a_out.set()

    def b() -> None:
        a_in.wait(5)
        with quiet_stderr():
            b_in.set()
            a_out.wait(5)
            assert _fd2() == os.devnull  # still silent while B is inside

    ta, tb = threading.Thread(target=a), threading.Thread(target=b)
    ta.start(), tb.start()
    ta.join(10), tb.join(10)
    assert _fd2() == before


def test_the_pose_graphs_start_and_run_without_a_warning(capfd):
    """MediaPipe's graphs log start-up chatter (glog, TFLite) on their first call: the landmark graph
    is started quietly and its first run writes nothing to stderr."""
    pytest.importorskip("mediapipe")
    from trustnav.perception.mediapipe_backend import _Graphs, protobuf_warning_ignored

    capfd.readouterr()
    g = _Graphs()
    try:
        frame = np.zeros((120, 160, 3), dtype=np.uint8)
        with protobuf_warning_ignored():
            g.landmarks(frame, np.array([80.0, 60.0, 100.0, 0.0, np.nan, np.nan, np.nan]))
        print("trustnav: still heard", file=sys.stderr, flush=True)
        err = capfd.readouterr().err
    finally:
        g.close()
    assert err == "trustnav: still heard\n", err


def test_the_renderer_starts_without_pybullets_banner(capfd):
    """``pybullet build time: ...`` reached stderr on every render drive (the demo's first line)."""
    from trustnav.sim.driving.render import PyBulletRenderer

    capfd.readouterr()
    PyBulletRenderer().close()
    assert "pybullet" not in capfd.readouterr().err
