"""Annotated frames for `trustnav estimate` and the drives: trust-coloured boxes, eye-contact
skeletons, phone N/U/Y; in a drive also the pedestrian's name and its colour
(:func:`trustnav.viz.style.person_colour`, a chip beside the label, as in every figure)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from trustnav.viz import style

__all__ = [
    "SKELETON",
    "AnnotatedOutput",
    "EstimateOutput",
    "annotate",
    "gui_available",
    "label_rects",
    "place_labels",
    "safe_name",
    "show",
    "trust_colour",
]

# COCO 17 limbs
SKELETON: tuple[tuple[int, int], ...] = (
    (0, 1), (0, 2), (1, 3), (2, 4), (5, 6), (5, 7), (7, 9), (6, 8), (8, 10),
    (5, 11), (6, 12), (11, 12), (11, 13), (13, 15), (12, 14), (14, 16),
)  # fmt: skip

GREEN, ORANGE, RED = (style.hex_bgr(c) for _, c in style.TRUST_BANDS)  # BGR, as every figure


def trust_colour(trust: float) -> tuple[int, int, int]:
    """BGR colour of a trust value: green > 0.7, orange > 0.4, red otherwise."""
    return style.trust_bgr(trust)


def _eye_colour(c: float) -> tuple[int, int, int]:
    """Red (no eye contact) through yellow to green (eye contact), BGR."""
    c = float(np.clip(c, 0.0, 1.0))
    return (0, round(255 * min(1.0, 2 * c)), round(255 * min(1.0, 2 * (1 - c))))


Rect = tuple[int, int, int, int]  # x1, y1, x2, y2


def _overlap(a: Rect, b: Rect) -> int:
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    return max(w, 0) * max(h, 0)


def place_labels(boxes: Sequence[Rect], sizes: Sequence[tuple[int, int]], width: int, height: int) -> list[Rect]:
    """A rectangle per label (its size ``(w, h)``) near its box, placed so that labels overlap each
    other as little as possible: above the box, then inside its top, below it, inside its bottom,
    then shifted sideways by a label width; the first free place wins, else the least covered one.
    Labels are placed top-down in the order of their boxes' tops."""
    placed: list[Rect | None] = [None] * len(boxes)
    taken: list[Rect] = []
    for i in sorted(range(len(boxes)), key=lambda k: (boxes[k][1], boxes[k][0])):
        x1, y1, x2, y2 = boxes[i]
        w, h = sizes[i]
        ys = [y1 - h - 1, y1 + 1, y2 + 1, y2 - h - 1]
        xs = [x1, x2 - w, x1 - w - 1, x2 + 1]
        best: tuple[int, int, Rect] | None = None
        for order, (x, y) in enumerate((x, y) for x in xs for y in ys):
            x = min(max(x, 0), max(width - w, 0))
            y = min(max(y, 0), max(height - h, 0))
            r = (x, y, x + w, y + h)
            cover = sum(_overlap(r, t) for t in taken)
            if best is None or (cover, order) < best[:2]:
                best = (cover, order, r)
            if cover == 0:
                break
        assert best is not None
        placed[i] = best[2]
        taken.append(best[2])
    return [r for r in placed if r is not None]


def _label_layout(
    shape: tuple[int, ...], records: Sequence[dict], phone_labels: Sequence[str]
) -> tuple[list[tuple[str, int, int]], list[Rect], int, float]:
    """Per person (text, text baseline, chip width) and the label's rectangle, with the line
    thickness and font size of a frame of ``shape``."""
    import cv2

    scale = max(1.0, shape[0] / 480)
    thick = max(1, round(scale))
    size = 0.4 * scale
    texts, boxes, sizes = [], [], []
    for rec, label in zip(records, phone_labels, strict=True):
        trust = rec["trust"]  # None: a person carried under a new track ID, no trust yet
        text = f"{rec.get('name', rec['track_id'])} {'-' if trust is None else f'{trust:.2f}'} {label}"
        (tw, th), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, size, thick)
        chip = th + base + 3 if rec.get("colour") is not None else 0
        boxes.append(tuple(round(v) for v in rec["bbox"][:4]))
        texts.append((text, base, chip))
        sizes.append((tw + 4 + chip, th + base + 3))
    return texts, place_labels(boxes, sizes, shape[1], shape[0]), thick, size  # type: ignore[arg-type]


def _box_colour(trust: float | None) -> tuple[int, int, int]:
    """The box's colour by trust; grey for a person with no trust yet."""
    return trust_colour(trust) if trust is not None else (160, 160, 160)


def label_rects(shape: tuple[int, ...], records: Sequence[dict], phone_labels: Sequence[str]) -> list[Rect]:
    """Where :func:`annotate` puts each person's label on a frame of ``shape`` (x1, y1, x2, y2 px),
    in the order of ``records``: e.g. to crop a frame without cutting a label."""
    return _label_layout(shape, records, phone_labels)[1]


def annotate(
    frame_rgb: NDArray[np.uint8],
    records: Sequence[dict],
    keypoints: Sequence[NDArray[np.float64]],
    phone_labels: Sequence[str],
) -> NDArray[np.uint8]:
    """BGR image with, per person: box coloured by trust with 'id trust phone', skeleton coloured by
    eye contact. ``records`` are the rows of tracks.csv for this frame, in the order of ``keypoints``;
    a record may also carry ``name`` (shown instead of the track id) and ``colour`` (BGR of the
    person, drawn as a chip at the label's left). Labels are placed so that neighbouring people's
    labels stay readable (:func:`place_labels`)."""
    import cv2

    img = cv2.cvtColor(frame_rgb, cv2.COLOR_RGB2BGR)
    texts, rects, thick, size = _label_layout(img.shape, records, phone_labels)
    for rec, kp in zip(records, keypoints, strict=True):
        x1, y1, x2, y2 = (round(v) for v in rec["bbox"])
        trust = rec["trust"]  # None: a person carried under a new track ID, no trust yet
        colour = _box_colour(trust)
        eye = _eye_colour(rec["eye_contact"] if rec["eye_contact"] is not None else 0.0)
        for a, b in SKELETON:
            pa, pb = kp[a], kp[b]
            if np.isfinite(pa).all() and np.isfinite(pb).all():
                cv2.line(img, (round(pa[0]), round(pa[1])), (round(pb[0]), round(pb[1])), eye, thick, cv2.LINE_AA)
        cv2.rectangle(img, (x1, y1), (x2, y2), colour, thick + 1)
    # labels last, over every box and skeleton, each at a free place near its own box
    for rec, (text, base, chip), (lx1, ly1, lx2, ly2) in zip(records, texts, rects, strict=True):
        colour, person = _box_colour(rec["trust"]), rec.get("colour")
        cv2.rectangle(img, (lx1, ly1), (lx2, ly2), colour, -1)
        if chip:
            cv2.rectangle(img, (lx1, ly1), (lx1 + chip - 1, ly2), tuple(int(c) for c in person), -1)
        cv2.putText(img, text, (lx1 + chip + 2, ly2 - base - 1), cv2.FONT_HERSHEY_SIMPLEX, size, (255, 255, 255),
                    thick, cv2.LINE_AA)  # fmt: skip
    return img


def safe_name(label: str) -> str:
    """A label as a file name: letters, digits, - and _ kept, the rest _."""
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in label) or "input"


class AnnotatedOutput:
    """Where annotated frames go, one name per input frame: ``frames/<stem>.png`` (a folder's
    frames under ``frames/<folder>/`` when there are several sequences), ``annotated.mp4`` (or
    ``annotated_<input>.mp4`` per video sequence when there are several). ``sequences``: the planned
    inputs (:func:`trustnav.perception.frames.plan_sequences`: ``label``, ``kind``, ``has_video``);
    ``mp4``: image sequences as video too. :meth:`start` a sequence, :meth:`add` its frames."""

    def __init__(self, out: Path, sequences: list, mp4: bool) -> None:
        self.out = out
        self.mp4 = mp4
        self.n_videos = sum(s.has_video or mp4 for s in sequences)
        self.nested = len(sequences) > 1
        self.used: set[Path] = set()
        self.writer = None
        self.size: tuple[int, int] | None = None
        self.seq = None

    def _unique(self, candidates: list[Path]) -> Path:
        for c in candidates:
            if c not in self.used:
                break
        else:
            base, k = candidates[-1], 2
            while (c := base.with_name(f"{base.stem}-{k}{base.suffix}")) in self.used:
                k += 1
        self.used.add(c)
        return c

    def start(self, seq, fps: float) -> None:
        self.close()
        self.seq, self.fps = seq, fps

    def add(self, name: str, img) -> None:
        import cv2

        seq = self.seq
        if seq.has_video or self.mp4:
            if self.writer is None:
                name_mp4 = "annotated.mp4" if self.n_videos == 1 else f"annotated_{safe_name(seq.label)}.mp4"
                path = self._unique([self.out / name_mp4])
                self.size = (img.shape[1], img.shape[0])
                self.writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), self.fps, self.size)
            if (img.shape[1], img.shape[0]) != self.size:
                img = cv2.resize(img, self.size)
            self.writer.write(img)
            return
        folder = self.out / "frames"
        if self.nested and seq.kind == "folder":
            folder = folder / safe_name(seq.label)
        stem = Path(name).stem
        path = self._unique([folder / f"{stem}.png", folder / f"{safe_name(seq.label)}.png"])
        path.parent.mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(str(path), img):
            raise OSError(f"cannot write {path}")

    def close(self) -> None:
        if self.writer is not None:
            self.writer.release()
            self.writer = None


class EstimateOutput:
    """What `trustnav estimate` writes into ``out`` as the frames come: tracks.csv/json
    (:class:`trustnav.outputs.TrackTable`, with the ``extra`` fields), the annotated frames
    (:class:`AnnotatedOutput`; ``images`` False: none) and, with ``rejections``, rejected.json (the
    detector boxes turned down) on :meth:`close`. :meth:`add` takes one frame of
    :func:`trustnav.perception.estimate.estimate_sequences`."""

    def __init__(self, out: Path, sequences: list, mp4: bool, extra: tuple[str, ...], images: bool, rejections: bool):
        from trustnav.outputs import TrackTable

        self.out, self.images, self.rejections = out, images, rejections
        self.table = TrackTable(out, extra)
        self.annotated = AnnotatedOutput(out, sequences, mp4)
        self.rejected: list[dict] = []
        self.sequence = None

    def add(self, frame, draw: bool = False):  # type: ignore[no-untyped-def]
        """Record a frame read (its ``result`` without error), its picture ``frame.repeat`` times (live
        video in real time); returns the annotated picture when drawn (``draw`` or images written)."""
        res = frame.result
        if frame.sequence is not self.sequence:
            self.sequence = frame.sequence
            self.annotated.start(frame.sequence, frame.fps)
        self.table.add(res.records)
        self.rejected.extend(frame.rejected)
        if not (self.images or draw):
            return None
        img = annotate(res.rgb, res.records, [tp.person.keypoints for tp in res.people], frame.labels)
        for _ in range(frame.repeat if self.images else 0):
            self.annotated.add(res.name, img)
        return img

    @property
    def rows(self) -> list[dict]:
        return self.table.rows

    def close(self) -> None:
        """Close the video, write tracks.json and (with ``rejections``) rejected.json."""
        import json

        self.annotated.close()
        self.table.close()
        if self.rejections:
            (self.out / "rejected.json").write_text(json.dumps(self.rejected, indent=1))


def gui_available() -> bool:
    """Whether this OpenCV can open windows (the headless build trustnav depends on cannot)."""
    import cv2

    try:
        cv2.namedWindow("trustnav-probe", cv2.WINDOW_NORMAL)
        cv2.destroyWindow("trustnav-probe")
    except cv2.error:
        return False
    return True


def show(img: NDArray[np.uint8], title: str) -> bool:
    """Show an annotated frame in a window; True when the user pressed q or Esc."""
    import cv2

    cv2.imshow(f"trustnav estimate: {title}", img)
    return (cv2.waitKey(1) & 0xFF) in (ord("q"), 27)
