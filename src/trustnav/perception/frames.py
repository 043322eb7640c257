"""Frame sources for `trustnav estimate`: image files, folders of frames (natural order), videos.

Inputs are grouped into *sequences* (:func:`plan_sequences`): each video, each folder of frames
and each loose image is its own sequence, with its own tracker and trust state, unless the caller
asks for one sequence. A frame that cannot be decoded completely (an empty file, a text file named
``.jpg``, a truncated JPEG that a decoder would fill with grey) is yielded with ``frame=None`` and
the reason, never as pixels.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import re
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "IMAGE_SUFFIXES",
    "VIDEO_SUFFIXES",
    "FrameItem",
    "FrameSequence",
    "expand_inputs",
    "frame_count",
    "is_live_source",
    "iter_frames",
    "natural_key",
    "plan_sequences",
    "read_image",
    "source_fps",
]

IMAGE_SUFFIXES = frozenset({".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp"})
VIDEO_SUFFIXES = frozenset({".mp4", ".avi", ".mov", ".mkv", ".m4v", ".webm"})

SequenceKind = Literal["video", "folder", "image", "joined", "live"]


@dataclass(frozen=True)
class FrameItem:
    """One input frame: its name, its RGB pixels (None if it could not be read) and why not."""

    name: str
    index: int
    frame: NDArray[np.uint8] | None
    error: str | None = None
    time: float | None = None  # capture time (s) when the source gives one (live input)


@dataclass(frozen=True)
class FrameSequence:
    """Frames that belong together (one tracker, one trust state).

    label: unique name of the sequence in a run (a video's or image's file name, a folder's name);
    kind: ``video``, ``folder``, ``image`` (a loose image), ``joined`` (inputs run as one) or
    ``live`` (a camera index or stream URL, in ``source``); files: the files, in order.
    """

    label: str
    kind: SequenceKind
    files: tuple[Path, ...]
    source: str | None = None

    def __post_init__(self) -> None:
        if self.kind == "live" and not self.source:
            raise ValueError(f"live sequence {self.label!r} has no source")
        if self.kind != "live" and not self.files:
            raise ValueError(f"sequence {self.label!r} has no files")

    @property
    def has_video(self) -> bool:
        return self.kind == "live" or any(is_video(f) for f in self.files)


def is_video(path: Path) -> bool:
    return path.suffix.lower() in VIDEO_SUFFIXES


def natural_key(path: Path) -> list[object]:
    """Sort key that orders frame_2 before frame_10."""
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", path.name)]


def _folder_files(p: Path) -> list[Path]:
    inner = [f for f in p.iterdir() if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES | VIDEO_SUFFIXES]
    if not inner:
        raise ValueError(f"input folder {p} holds no images or videos")
    return sorted(inner, key=natural_key)


def _check_exists(p: Path) -> None:
    if not p.exists():
        raise ValueError(f"input {p} does not exist (expected image files, a folder of frames or a video)")
    if not (p.is_file() or p.is_dir()):
        raise ValueError(f"input {p} is neither a file nor a folder")


def expand_inputs(inputs: list[str | Path]) -> list[Path]:
    """The files the inputs name: files as given, folders as their images and videos in natural order."""
    files: list[Path] = []
    for p in map(Path, inputs):
        _check_exists(p)
        files.extend(_folder_files(p) if p.is_dir() else [p])
    return files


_DIGITS = re.compile(r"\d+")


def _image_size(path: Path) -> tuple[int, int] | None:
    """(width, height) from the file's header (None if it cannot be read: the frame reader reports it)."""
    try:
        from PIL import Image

        with Image.open(path) as im:
            return im.size
    except Exception:  # an unreadable file is reported, and skipped, when its frame is read
        return None


def image_runs(images: list[Path]) -> list[list[Path]]:
    """A folder's images split into sequences: images whose names are one pattern with a frame
    number (``frame_0001.png``, ``image_00005310_0.png``), numbered at an even step (every frame, or
    every k-th), and of one size, are one sequence; every other image is a sequence of its own (street
    photos are not a video: track IDs and trust must not carry from one photo to the next).
    ``plan_sequences(..., one_sequence=True)`` (``--one-sequence``) joins them anyway."""
    groups: dict[str, list[Path]] = {}
    for f in images:  # the name's pattern: its digit runs masked
        groups.setdefault(_DIGITS.sub("#", f.name.lower()), []).append(f)
    runs: list[list[Path]] = []
    for pattern, members in groups.items():
        numbers = [[int(d) for d in _DIGITS.findall(f.name)] for f in members]
        varying = [k for k in range(pattern.count("#")) if len({n[k] for n in numbers}) > 1]
        # one size (a file that cannot be read is reported, and skipped, when its frame is read)
        sizes = {size for f in members if (size := _image_size(f)) is not None} if len(members) > 1 else set()
        if len(sizes) == 1 and len(varying) == 1:
            ordered = sorted(zip((n[varying[0]] for n in numbers), members, strict=True))
            steps = {b[0] - a[0] for a, b in itertools.pairwise(ordered)}
            if len(steps) == 1 and steps.pop() > 0:
                runs.append([f for _, f in ordered])
                continue
        runs.extend([f] for f in members)
    order = {f: i for i, f in enumerate(images)}
    return sorted(runs, key=lambda run: order[run[0]])


_URL = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*://")


def is_live_source(text: str) -> bool:
    """A camera index (``0``, ``1``, ...) or a URL (``rtsp://``, ``http://``, ``udp://``, ``file://``...):
    an input read by :class:`~trustnav.perception.live.LiveSource`, not from files."""
    return text.isdigit() or bool(_URL.match(text))


def plan_sequences(inputs: list[str | Path], *, one_sequence: bool = False) -> list[FrameSequence]:
    """Group the inputs into sequences: each video, each folder of frames (a video inside a
    folder is a sequence of its own) and each loose image; all as one with ``one_sequence``.
    Labels are unique: a repeated name gets its parent folder's name, then a number."""
    live = [str(i) for i in inputs if is_live_source(str(i))]
    if live and (one_sequence or len(live) < len(inputs) or len(live) > 1):
        raise ValueError(f"a live input ({live[0]}) runs alone: give one camera index or stream URL and no other input")
    if live:
        return [FrameSequence(_safe_label(live[0]), "live", (), source=live[0])]
    raw: list[tuple[Path, SequenceKind, list[Path]]] = []
    for p in map(Path, inputs):
        _check_exists(p)
        if p.is_dir():
            files = _folder_files(p)
            images = [f for f in files if not is_video(f)]
            for run in image_runs(images):  # photos are not a video: only numbered frames of one size
                raw.append((p, "folder", run) if len(run) > 1 or len(images) == 1 else (run[0], "image", run))
            raw.extend((f, "video", [f]) for f in files if is_video(f))
        else:
            raw.append((p, "video" if is_video(p) else "image", [p]))
    if one_sequence:
        files = [f for _, _, fs in raw for f in fs]
        return [FrameSequence("joined", "joined", tuple(files))]
    names = [p.resolve().name or str(p) for p, _, _ in raw]
    used: set[str] = set()
    out = []
    for (p, kind, files), name in zip(raw, names, strict=True):
        label = name
        if names.count(name) > 1:
            label = f"{p.resolve().parent.name}-{name}"
        base, k = label, 2
        while label in used:
            label, k = f"{base}-{k}", k + 1
        used.add(label)
        out.append(FrameSequence(label, kind, tuple(files)))
    return out


def _safe_label(source: str) -> str:
    """A sequence label for a live source: ``camera0``, or the URL without its scheme and with
    characters that do not belong in a file name replaced."""
    if source.isdigit():
        return f"camera{source}"
    return re.sub(r"[^A-Za-z0-9._-]+", "_", source.split("://", 1)[-1]).strip("_")[:60] or "stream"


class _Descriptor2:
    """File descriptor 2 pointed at /dev/null while any thread is inside :func:`quiet_stderr`: the
    first thread in saves it, the last one out restores it. Descriptor 2 is the process's, so the
    count is too; without it two threads overlapping (MediaPipe's workers starting their graphs)
    could restore each other's /dev/null and lose every later message of the run."""

    def __init__(self) -> None:
        import threading

        self.lock = threading.Lock()
        self.depth = 0
        self.saved: int | None = None

    def enter(self) -> None:
        with self.lock:
            if self.depth == 0:
                with contextlib.suppress(AttributeError, OSError, ValueError):
                    sys.stderr.flush()
                try:
                    saved = os.dup(2)
                except OSError:  # no descriptor 2: nothing to silence
                    saved = None
                if saved is not None:
                    with open(os.devnull, "w") as null:
                        os.dup2(null.fileno(), 2)
                self.saved = saved
            self.depth += 1

    def leave(self) -> None:
        with self.lock:
            self.depth -= 1
            if self.depth == 0 and self.saved is not None:
                os.dup2(self.saved, 2)
                os.close(self.saved)
                self.saved = None


_FD2 = _Descriptor2()


@contextlib.contextmanager
def quiet_stderr() -> Iterator[None]:
    """Silence messages that C libraries (FFmpeg, libjpeg, MediaPipe's TFLite) write straight to file
    descriptor 2, whatever Python's sys.stderr is; safe when threads overlap (the last one out
    restores the descriptor)."""
    _FD2.enter()
    try:
        yield
    finally:
        _FD2.leave()


def _video_property(path: Path, prop: str) -> float:
    import cv2

    with quiet_stderr():
        cap = cv2.VideoCapture(str(path))
        try:
            return float(cap.get(getattr(cv2, prop))) if cap.isOpened() else -1.0
        finally:
            cap.release()


def source_fps(inputs: list[str | Path], default: float) -> float:
    """Frame rate of the first video among the inputs, else ``default``."""
    for f in expand_inputs(inputs):
        if is_video(f):
            fps = _video_property(f, "CAP_PROP_FPS")
            if fps > 0:
                return fps
    return default


def frame_count(inputs: list[str | Path]) -> int | None:
    """Number of frames the inputs hold (None if a video does not say), without decoding images."""
    n = 0
    for f in expand_inputs(inputs):
        if is_video(f):
            k = int(_video_property(f, "CAP_PROP_FRAME_COUNT"))
            if k == -1:  # cannot be opened: reported as one unreadable frame
                k = 1
            if k <= 0:
                return None
            n += k
        else:
            n += 1
    return n


def read_image(path: Path) -> tuple[NDArray[np.uint8] | None, str | None]:
    """RGB pixels of an image file, or (None, reason) when it cannot be decoded completely.

    Pillow decodes the file first and refuses truncated or corrupt data (OpenCV would return the
    decoded part and grey for the rest); OpenCV then reads it (with EXIF orientation)."""
    import cv2
    from PIL import Image, UnidentifiedImageError

    try:
        size = path.stat().st_size
    except OSError as exc:
        return None, f"cannot read image {path}: {exc.strerror or exc}"
    if size == 0:
        return None, f"cannot read image {path}: the file is empty"
    try:
        with Image.open(path) as im:
            im.load()
    except UnidentifiedImageError:
        pass  # not a format Pillow knows: OpenCV decides below
    except (OSError, ValueError, SyntaxError) as exc:
        return None, f"cannot read image {path}: corrupt or truncated ({exc})"
    with quiet_stderr():
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        return None, f"cannot read image {path}: not an image file OpenCV can decode"
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), None


def _video_frames(f: Path, index: int) -> Iterator[FrameItem]:
    import cv2

    with quiet_stderr():
        cap = cv2.VideoCapture(str(f))
    if not cap.isOpened():
        cap.release()
        yield FrameItem(f.name, index, None, f"cannot open video {f} (not a video, or a codec OpenCV lacks)")
        return
    declared = cap.get(cv2.CAP_PROP_FRAME_COUNT)  # from the container's header (<= 0: unknown)
    k = 0
    try:
        while True:
            with quiet_stderr():
                ok, bgr = cap.read()
            if not ok:
                break
            yield FrameItem(f"{f.name}#{k}", index + k, cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
            k += 1
    finally:
        cap.release()
    if k == 0:
        yield FrameItem(f.name, index, None, f"video {f} holds no frame that can be decoded")
    elif declared > 0 and k < declared - max(2.0, 0.01 * declared):
        # decoding stopped well before the end the header announces: a cut-off or damaged file
        yield FrameItem(
            f"{f.name}#{k}", index + k, None,
            f"video {f} ended after {k} of the {int(declared)} frames its header announces: truncated or damaged",
        )  # fmt: skip


def iter_sequence(files: tuple[Path, ...] | list[Path]) -> Iterator[FrameItem]:
    """Frames of the given files in order, indexed from 0; an unreadable one is yielded with
    ``frame=None`` and the reason."""
    index = 0
    for f in files:
        if is_video(f):
            last = index - 1
            for item in _video_frames(f, index):
                last = item.index
                yield item
            index = last + 1
            continue
        rgb, error = read_image(f)
        yield FrameItem(f.name, index, rgb, error)
        index += 1


def iter_frames(inputs: list[str | Path]) -> Iterator[FrameItem]:
    """Frames of all inputs in order (as one sequence); an unreadable one is yielded with
    ``frame=None`` and the reason."""
    yield from iter_sequence(expand_inputs(inputs))
