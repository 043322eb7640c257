"""Person proposals from a learned detector: YOLOX-Nano (Ge et al., 2021; Apache-2.0) on onnxruntime.

The model is the authors' released ONNX export (``yolox_nano.onnx``, 3.6 MB). Input 1 x 3 x S x S
float32 (S = 416 in the release): the frame in BGR, 0-255, resized with its aspect kept into the
top-left corner of a canvas filled with 114. Output 1 x A x 85 per anchor over strides 8, 16, 32:
centre offsets and log sizes in grid units, objectness and 80 class scores (sigmoided already).
Decoding and non-maximum suppression run in numpy and OpenCV (``cv2.dnn.NMSBoxes``); only COCO's
person class (0) is kept. The graph is fully convolutional, so the network input can be shaped to the
frame (``fit_aspect``; the real-time backend's choice, the offline pipeline keeps the square input its
labelled figures were measured with): its longer side ``input_size`` (the release's 416 unless given), the shorter
one the frame's rounded up to a multiple of 32 (a 640 x 480 frame is seen at 416 x 320, not pasted on a
416 x 416 canvas whose bottom quarter is grey: ~0.8 of the time, the same scale). The release fixes
its input's dimensions in the file, so the file is read as it is and only the declared shapes of its
input and output are rewritten in memory before onnxruntime loads it (:func:`with_input_shape`).
onnxruntime runs it on one intra-op thread by default (on two cores the
frame loop and the landmark model need the other).

The model file is found as the LOOKING weights are (:func:`resolve_model`): a path given; else
``../shared/models/yolox/`` of a development checkout; ``$TRUSTNAV_YOLOX_MODEL``; the user cache
(``~/.cache/trustnav``); else a one-time download from its public URL, announced on stderr. A path
that is given is never replaced by a download: a missing or unreadable file is one line naming the
file and how to pass another.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from trustnav.perception import model_files
from trustnav.perception.types import check_frame

__all__ = [
    "MODEL_NAME",
    "ONNXRUNTIME_VERSION",
    "PHONE_CLASS",
    "YOLOX_SHA256",
    "YOLOX_URL",
    "PersonDetector",
    "resolve_model",
]

YOLOX_URL = "https://github.com/Megvii-BaseDetection/YOLOX/releases/download/0.1.1rc0/yolox_nano.onnx"
YOLOX_SHA256 = "e8af074932d4ed7e232278e3055cefcdea3edf178874a3694ae292649fb464dd"
MODEL_NAME = "yolox_nano.onnx"
MODEL_ENV = "TRUSTNAV_YOLOX_MODEL"
MODEL_HINT = f"pass --detector-model FILE (Python: PersonDetector(FILE)) or set {MODEL_ENV}"
ONNXRUNTIME_VERSION = "1.23.2"
#: COCO's class index of a person in the detector's 80 scores.
PERSON_CLASS = 0
#: COCO's class index of a cell phone (``PersonDetector.class_scores``: image evidence of phone use).
PHONE_CLASS = 67
N_CLASSES = 80
STRIDES = (8, 16, 32)
PAD_VALUE = 114


def _candidates() -> tuple[list[Path], Path]:
    """Where the model is looked for, in order (checkout, environment, cache), and the cache."""
    cache = model_files.cache_path(MODEL_NAME)
    env = [Path(os.environ[MODEL_ENV])] if os.environ.get(MODEL_ENV) else []
    return list(dict.fromkeys([*model_files.checkout_paths("yolox", MODEL_NAME), *env, cache])), cache


def resolve_model(path: str | Path | None = None, *, download: bool = True) -> Path:
    """The YOLOX-Nano file: ``path`` (never replaced by a download); else ``../shared/models/yolox/``
    of a checkout, ``$TRUSTNAV_YOLOX_MODEL``, the user cache; else, with ``download``, fetched once
    from :data:`YOLOX_URL` into the cache (sha256 checked), saying so on stderr.
    Raises FileNotFoundError with a one-line hint when the file cannot be had."""
    if path is not None:
        p = Path(path)
        if not p.is_file():
            what = "a folder, not a file" if p.is_dir() else "no such file"
            raise FileNotFoundError(
                f"person detector model not found at {p} ({what}; expected {MODEL_NAME}); {MODEL_HINT}"
            )
        return p
    candidates, cache = _candidates()
    return model_files.find_or_download(
        candidates, cache, allow=download, url=YOLOX_URL, hint=MODEL_HINT, sha256=YOLOX_SHA256,
        missing=f"person detector {MODEL_NAME} not found (looked in {candidates[0]}, ..., {cache}); {MODEL_HINT}, "
        f"or allow the download from {YOLOX_URL}",
        notice=f"trustnav: downloading the person detector YOLOX-Nano (3.6 MB) once to {cache}",
        what=f"person detector {MODEL_NAME}",
    )  # fmt: skip


def _load_onnxruntime() -> Any:
    try:
        import onnxruntime
    except ImportError as exc:  # a dependency of trustnav; missing only in a broken environment
        raise ImportError(
            f"the person detector needs onnxruntime=={ONNXRUNTIME_VERSION}; install it with "
            f"`pip install onnxruntime=={ONNXRUNTIME_VERSION}`"
        ) from exc
    return onnxruntime


class PersonDetector:
    """YOLOX-Nano person boxes for an RGB frame (module docstring).

    ``model``: the ONNX file (None: :func:`resolve_model`; its input fixes the square network
    input S, 416 for the release); ``input_size``: the network input's longer side (a multiple of 32;
    None: S); ``fit_aspect``: shape the input to the frame (module docstring; False, the default: a square of
    ``input_size`` with the frame pasted top-left, as the release was exported); ``min_score``: objectness x person
    score kept; ``nms_iou``: overlap at which NMS merges two boxes; ``threads``: onnxruntime's
    intra-op threads; ``tile_below``: frames the network would see smaller than this scale are also
    searched in square windows (:meth:`windows`). Calling it returns (boxes (N, 4) [x1, y1, x2, y2]
    in frame pixels, scores (N,)), best first; ``last_seconds`` holds the latest call's time in the network.
    """

    def __init__(
        self,
        model: str | Path | None = None,
        *,
        min_score: float = 0.25,
        nms_iou: float = 0.45,
        threads: int = 1,
        tile_below: float = 0.5,
        input_size: int | None = None,
        fit_aspect: bool = False,
        download: bool = True,
    ) -> None:
        if not 0.0 < min_score < 1.0:
            raise ValueError(f"min_score must be in (0, 1), got {min_score!r}")
        if not 0.0 < nms_iou <= 1.0:
            raise ValueError(f"nms_iou must be in (0, 1], got {nms_iou!r}")
        if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
            raise ValueError(f"threads must be an integer >= 1, got {threads!r}")
        if not 0.0 <= tile_below <= 1.0:
            raise ValueError(f"tile_below must be in [0, 1] (0: the whole frame only), got {tile_below!r}")
        if input_size is not None and (
            isinstance(input_size, bool)
            or not isinstance(input_size, int)
            or input_size % 32
            or not 64 <= input_size <= 1280
        ):
            raise ValueError(
                f"input_size must be None (the model's) or a multiple of 32 in [64, 1280], got {input_size!r}"
            )
        self.tile_below = float(tile_below)
        self.path = resolve_model(model, download=download)
        self.min_score = float(min_score)
        self.nms_iou = float(nms_iou)
        ort = _load_onnxruntime()
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        options.log_severity_level = 3
        self._options = options
        try:
            self._bytes = self.path.read_bytes()
            self._session = ort.InferenceSession(self._bytes, options, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own exception types for a bad file
            first = str(exc).strip().splitlines()[0][:160] if str(exc).strip() else type(exc).__name__
            raise ValueError(
                f"person detector model {self.path}: not a readable ONNX model ({first}); {MODEL_HINT}"
            ) from None
        inputs = self._session.get_inputs()
        shape = inputs[0].shape if len(inputs) == 1 else []
        if len(shape) != 4 or shape[1] != 3 or not isinstance(shape[2], int) or shape[2] != shape[3] or shape[2] % 32:
            raise ValueError(
                f"person detector model {self.path}: expected one input 1 x 3 x S x S with S a multiple of 32 "
                f"(YOLOX), got {[tuple(i.shape) for i in inputs]}; {MODEL_HINT}"
            )
        self._input = inputs[0].name
        self.model_size = int(shape[2])
        self.input_size = int(input_size or self.model_size)
        self.fit_aspect = bool(fit_aspect)
        # one session per network input shape (H, W), with its anchors
        self._sessions: dict[tuple[int, int], tuple[Any, NDArray[np.float64], NDArray[np.float64]]] = {
            (self.model_size, self.model_size): (self._session, *_anchors(self.model_size, self.model_size))
        }
        self.last_seconds = 0.0

    def input_shape(self, h: int, w: int) -> tuple[int, int]:
        """The network input (rows, columns) for an h x w image: its longer side ``input_size``, the other
        the image's at that scale rounded up to a multiple of 32 (``fit_aspect``), else a square."""
        s = self.input_size
        if not self.fit_aspect:
            return s, s
        ratio = min(s / h, s / w)
        return min(s, 32 * math.ceil(h * ratio / 32 - 1e-9)), min(s, 32 * math.ceil(w * ratio / 32 - 1e-9))

    def _session_for(self, shape: tuple[int, int]) -> tuple[Any, NDArray[np.float64], NDArray[np.float64]]:
        if shape not in self._sessions:
            ort = _load_onnxruntime()
            model = with_input_shape(self._bytes, *shape)
            session = ort.InferenceSession(model, self._options, providers=["CPUExecutionProvider"])
            self._sessions[shape] = (session, *_anchors(*shape))
        return self._sessions[shape]

    def windows(self, h: int, w: int) -> list[tuple[int, int, int, int]]:
        """Where the network looks: the whole frame, and where that shrinks the frame below
        ``tile_below`` (a 1280 x 720 frame to 0.33), also square windows as tall as a landscape frame
        across its width (overlapping by at least a fifth), so that people of ~100 px keep ~40 px."""
        out = [(0, 0, w, h)]
        if self.input_size / max(h, w) >= self.tile_below or w <= h:
            return out  # a portrait frame is not cut across: its windows would halve a standing person
        n = math.ceil((w - h) / (0.8 * h)) + 1
        out += [(int(x), 0, int(x) + h, h) for x in np.linspace(0, w - h, n).round().astype(int)]
        return out

    def __call__(self, frame: NDArray[np.uint8]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Person boxes and scores of one RGB frame (H x W x 3 uint8), best first."""
        import time

        import cv2

        frame = check_frame(frame)
        h, w = frame.shape[:2]
        t0 = time.perf_counter()
        found = [self._window(frame, win) for win in self.windows(h, w)]
        self.last_seconds = time.perf_counter() - t0
        boxes = np.concatenate([b for b, _ in found])
        scores = np.concatenate([s for _, s in found])
        if len(found) == 1 or not len(boxes):
            return boxes, scores
        xywh = np.concatenate([boxes[:, :2], boxes[:, 2:] - boxes[:, :2]], axis=1)
        idx = np.asarray(cv2.dnn.NMSBoxes(xywh.tolist(), scores.tolist(), self.min_score, self.nms_iou), dtype=int)
        idx = idx.reshape(-1)
        idx = idx[np.argsort(-scores[idx], kind="stable")]
        return boxes[idx], scores[idx]

    def class_scores(
        self, frame: NDArray[np.uint8], region: tuple[float, float, float], class_index: int = PHONE_CLASS
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """One COCO class's score at every anchor of the network run on a square of ``frame``.

        ``region`` = (centre x, centre y, side) in frame pixels: the square is cut from the frame
        (outside it the detector's grey), resized (bicubic when enlarged) to the network's square
        input and run once. Returns (centres (A, 2) of the anchors' boxes in frame pixels, scores
        (A,) = objectness x class score), in anchor order, no threshold and no NMS: the evidence for
        an object of that class anywhere in the square (e.g. a phone near a person's hands, issue 35;
        docs/perception.md). ValueError for a class outside COCO's 80 or a side under 8 px."""
        import cv2

        frame = check_frame(frame)
        if isinstance(class_index, bool) or not isinstance(class_index, (int, np.integer)):
            raise ValueError(f"class_index must be a COCO class index 0-{N_CLASSES - 1}, got {class_index!r}")
        if not 0 <= int(class_index) < N_CLASSES:
            raise ValueError(f"class_index must be a COCO class index 0-{N_CLASSES - 1}, got {class_index!r}")
        cx, cy, side = (float(v) for v in region)
        if not (math.isfinite(cx) and math.isfinite(cy) and math.isfinite(side)) or side < 8:
            raise ValueError(f"region must be (centre x, centre y, side >= 8 px), finite, got {region!r}")
        s = round(side)
        x0, y0 = round(cx - s / 2), round(cy - s / 2)
        h, w = frame.shape[:2]
        crop = np.full((s, s, 3), PAD_VALUE, dtype=np.uint8)
        a, b, c, d = max(x0, 0), max(y0, 0), min(x0 + s, w), min(y0 + s, h)
        if c > a and d > b:
            crop[b - y0 : d - y0, a - x0 : c - x0] = frame[b:d, a:c]
        n = self.model_size
        session, grid, stride = self._session_for((n, n))
        interp = cv2.INTER_CUBIC if s < n else cv2.INTER_AREA
        image = cv2.resize(crop, (n, n), interpolation=interp)[:, :, ::-1]  # RGB -> BGR
        out = session.run(None, {self._input: image.transpose(2, 0, 1)[None].astype(np.float32)})[0][0]
        if out.ndim != 2 or out.shape != (len(grid), 85):
            raise ValueError(f"person detector model {self.path}: output {out.shape}, expected ({len(grid)}, 85)")
        scores = out[:, 4].astype(np.float64) * out[:, 5 + int(class_index)]
        centres = (out[:, :2].astype(np.float64) + grid) * stride * (s / n) + np.array([x0, y0], dtype=np.float64)
        return centres, scores

    def _window(
        self, frame: NDArray[np.uint8], win: tuple[int, int, int, int]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        import cv2

        x0, y0, x1, y1 = win
        crop = frame[y0:y1, x0:x1]
        h, w = crop.shape[:2]
        s = self.input_size
        ratio = min(s / h, s / w)
        nh, nw = max(1, round(h * ratio)), max(1, round(w * ratio))
        shape = self.input_shape(h, w)
        session, grid, stride = self._session_for(shape)
        canvas = np.full((*shape, 3), PAD_VALUE, dtype=np.uint8)
        canvas[:nh, :nw] = cv2.resize(crop, (nw, nh), interpolation=cv2.INTER_AREA)[:, :, ::-1]  # RGB -> BGR
        blob = canvas.transpose(2, 0, 1)[None].astype(np.float32)
        out = session.run(None, {self._input: blob})[0][0]
        if out.ndim != 2 or out.shape != (len(grid), 85):
            raise ValueError(f"person detector model {self.path}: output {out.shape}, expected ({len(grid)}, 85)")
        boxes, scores = decode(out, grid, stride, ratio, (w, h), self.min_score, self.nms_iou)
        if (x0, y0, x1, y1) != (0, 0, frame.shape[1], frame.shape[0]) and len(boxes):
            # a box cut by a window's inner edge is a part of a person the whole frame or the next window holds
            inner = ((boxes[:, 0] <= 1) & (x0 > 0)) | ((boxes[:, 2] >= w - 2) & (x1 < frame.shape[1]))
            inner |= ((boxes[:, 1] <= 1) & (y0 > 0)) | ((boxes[:, 3] >= h - 2) & (y1 < frame.shape[0]))
            boxes, scores = boxes[~inner], scores[~inner]
        return boxes + np.array([x0, y0, x0, y0], dtype=np.float64), scores


def _anchors(rows: int, cols: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Grid cells (A, 2) and their strides (A, 1) in the detector's anchor order."""
    grids, strides = [], []
    for stride in STRIDES:
        ys, xs = np.meshgrid(np.arange(rows // stride), np.arange(cols // stride), indexing="ij")
        grids.append(np.stack([xs.ravel(), ys.ravel()], axis=1))
        strides.append(np.full((xs.size, 1), stride))
    return np.concatenate(grids).astype(np.float64), np.concatenate(strides).astype(np.float64)


def decode(
    out: NDArray[np.floating],
    grid: NDArray[np.float64],
    stride: NDArray[np.float64],
    ratio: float,
    size: tuple[int, int],
    min_score: float,
    nms_iou: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """YOLOX's raw output (A, 85) to person boxes in frame pixels and scores, after NMS.

    centre = (cell + offset) x stride, size = exp(log size) x stride (network pixels), divided by the
    resize ``ratio``; score = objectness x person score; boxes clipped to the frame ``size`` (w, h)."""
    import cv2

    score = out[:, 4] * out[:, 5 + PERSON_CLASS]
    keep = score >= min_score
    if not keep.any():
        return np.zeros((0, 4)), np.zeros(0)
    o = out[keep].astype(np.float64)
    centre = (o[:, :2] + grid[keep]) * stride[keep] / ratio
    half = np.exp(np.clip(o[:, 2:4], -10.0, 10.0)) * stride[keep] / ratio / 2.0
    boxes = np.concatenate([centre - half, centre + half], axis=1)
    boxes[:, [0, 2]] = boxes[:, [0, 2]].clip(0.0, size[0] - 1.0)
    boxes[:, [1, 3]] = boxes[:, [1, 3]].clip(0.0, size[1] - 1.0)
    scores = score[keep].astype(np.float64)
    xywh = np.concatenate([boxes[:, :2], boxes[:, 2:] - boxes[:, :2]], axis=1)
    idx = cv2.dnn.NMSBoxes(xywh.tolist(), scores.tolist(), min_score, nms_iou)
    idx = np.asarray(idx, dtype=int).reshape(-1)
    idx = idx[np.argsort(-scores[idx], kind="stable")]
    return boxes[idx], scores[idx]


# The ONNX file's declared shapes, rewritten on the protobuf wire format (no onnx package needed):
# ModelProto.graph = 7; GraphProto.input = 11, output = 12, value_info = 13; ValueInfoProto.type = 2;
# TypeProto.tensor_type = 1; TypeProto.Tensor.shape = 2; TensorShapeProto.dim = 1; Dimension.dim_value = 1.


def _varint(data: bytes, i: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        byte = data[i]
        i += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if byte < 0x80:
            return value, i


def _encode_varint(value: int) -> bytes:
    out = bytearray()
    while True:
        low, value = value & 0x7F, value >> 7
        out.append(low | (0x80 if value else 0))
        if not value:
            return bytes(out)


def _fields(data: bytes) -> list[tuple[int, int, bytes]]:
    """A protobuf message's fields in order: (number, wire type, raw payload)."""
    out, i = [], 0
    while i < len(data):
        tag, i = _varint(data, i)
        number, wire = tag >> 3, tag & 7
        if wire == 0:
            _, j = _varint(data, i)
        elif wire == 1:
            j = i + 8
        elif wire == 5:
            j = i + 4
        elif wire == 2:
            size, i = _varint(data, i)
            j = i + size
        else:
            raise ValueError(f"unsupported protobuf wire type {wire}")
        if j > len(data):
            raise ValueError("truncated protobuf message")
        out.append((number, wire, data[i:j]))
        i = j
    return out


def _join(fields: list[tuple[int, int, bytes]]) -> bytes:
    out = bytearray()
    for number, wire, raw in fields:
        out += _encode_varint(number << 3 | wire)
        if wire == 2:
            out += _encode_varint(len(raw))
        out += raw
    return bytes(out)


def _with_dims(value_info: bytes, dims: list[int]) -> bytes:
    """A ValueInfoProto with its tensor's shape replaced by ``dims``."""
    shape = _join([(1, 2, _join([(1, 0, _encode_varint(d))])) for d in dims])

    def tensor(raw: bytes) -> bytes:
        return _join([f for f in _fields(raw) if f[0] != 2] + [(2, 2, shape)])

    def typ(raw: bytes) -> bytes:
        return _join([(n, w, tensor(r) if n == 1 else r) for n, w, r in _fields(raw)])

    return _join([(n, w, typ(r) if n == 2 else r) for n, w, r in _fields(value_info)])


def with_input_shape(model: bytes, rows: int, cols: int) -> bytes:
    """The YOLOX ONNX model ``model`` (bytes) declared for a 1 x 3 x rows x cols input: the input's and
    output's shapes rewritten (the output 1 x A x 85, A the anchors of strides 8, 16, 32) and the stored
    intermediate shapes dropped (onnxruntime infers them). The weights and operators are untouched."""
    if rows % 32 or cols % 32:
        raise ValueError(f"the detector's input must be a multiple of 32 each way, got {rows} x {cols}")
    anchors = sum((rows // s) * (cols // s) for s in STRIDES)
    top = _fields(model)
    graphs = [raw for number, wire, raw in top if number == 7 and wire == 2]
    if len(graphs) != 1:
        raise ValueError("not an ONNX model with one graph")
    graph = []
    for number, wire, raw in _fields(graphs[0]):
        if number == 13:
            continue
        if number == 11:
            raw = _with_dims(raw, [1, 3, rows, cols])
        elif number == 12:
            raw = _with_dims(raw, [1, anchors, 85])
        graph.append((number, wire, raw))
    return _join([(n, w, _join(graph) if n == 7 else r) for n, w, r in top])
