"""Frame sources for `trustnav estimate`: image files, folders of frames (natural order), videos."""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "IMAGE_SUFFIXES",
    "VIDEO_SUFFIXES",
    "FrameItem",
    "expand_inputs",
    "frame_count",
    "iter_frames",
    "natural_key",
    "source_fps",
]

IMAGE_SUFFIXES = frozenset({".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp"})
VIDEO_SUFFIXES = frozenset({".mp4", ".avi", ".mov", ".mkv", ".m4v", ".webm"})


@dataclass(frozen=True)
class FrameItem:
    """One input frame: its name, its RGB pixels (None if it could not be read) and why not."""

    name: str
    index: int
    frame: NDArray[np.uint8] | None
    error: str | None = None


def natural_key(path: Path) -> list[object]:
    """Sort key that orders frame_2 before frame_10."""
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", path.name)]


def expand_inputs(inputs: list[str | Path]) -> list[Path]:
    """The files the inputs name: files as given, folders as their images and videos in natural order."""
    inputs = [Path(p) for p in inputs]
    files: list[Path] = []
    for p in inputs:
        if p.is_dir():
            inner = [f for f in p.iterdir() if f.suffix.lower() in IMAGE_SUFFIXES | VIDEO_SUFFIXES]
            if not inner:
                raise ValueError(f"input folder {p} holds no images or videos")
            files.extend(sorted(inner, key=natural_key))
        elif p.exists():
            files.append(p)
        else:
            raise ValueError(f"input {p} does not exist (expected image files, a folder of frames or a video)")
    return files


def source_fps(inputs: list[Path], default: float) -> float:
    """Frame rate of the first video among the inputs, else ``default``."""
    import cv2

    for f in expand_inputs(inputs):
        if f.suffix.lower() in VIDEO_SUFFIXES:
            cap = cv2.VideoCapture(str(f))
            fps = cap.get(cv2.CAP_PROP_FPS)
            cap.release()
            if fps and fps > 0:
                return float(fps)
    return default


def frame_count(inputs: list[str | Path]) -> int | None:
    """Number of frames the inputs hold (None if a video does not say), without decoding images."""
    import cv2

    n = 0
    for f in expand_inputs(inputs):
        if f.suffix.lower() in VIDEO_SUFFIXES:
            cap = cv2.VideoCapture(str(f))
            k = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if cap.isOpened() else 1
            cap.release()
            if k <= 0:
                return None
            n += k
        else:
            n += 1
    return n


def iter_frames(inputs: list[str | Path]) -> Iterator[FrameItem]:
    """Frames of all inputs in order; an unreadable one is yielded with ``frame=None`` and the reason."""
    import cv2

    index = 0
    for f in expand_inputs(inputs):
        if f.suffix.lower() in VIDEO_SUFFIXES:
            cap = cv2.VideoCapture(str(f))
            if not cap.isOpened():
                yield FrameItem(f.name, index, None, f"cannot open video {f}")
                index += 1
                continue
            k = 0
            while True:
                ok, bgr = cap.read()
                if not ok:
                    break
                yield FrameItem(f"{f.name}#{k}", index, cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
                index += 1
                k += 1
            cap.release()
            continue
        bgr = cv2.imread(str(f), cv2.IMREAD_COLOR)
        if bgr is None:
            yield FrameItem(f.name, index, None, f"cannot read image {f}")
        else:
            yield FrameItem(f.name, index, cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
        index += 1
