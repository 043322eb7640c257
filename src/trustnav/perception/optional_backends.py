"""Optional pose backends for users who have them: OpenPifPaf (the paper's) and ultralytics YOLO-pose.

Both are imported only when constructed; a missing package gives an ImportError that says what to
install. Their weights come from the packages' own caches (they may download on first use).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from trustnav.perception.types import Person, check_frame

__all__ = ["OpenPifPafBackend", "UltralyticsPoseBackend", "make_backend"]


def _import(module: str, hint: str) -> Any:
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise ImportError(f"this pose backend needs `{module}`: {hint}") from exc


def _person(box: NDArray, kp: NDArray, conf: NDArray, score: float) -> Person | None:
    box = np.asarray(box, dtype=float)
    if not (box[2] > box[0] and box[3] > box[1]):
        return None
    kp = np.asarray(kp, dtype=float).copy()
    conf = np.clip(np.asarray(conf, dtype=float), 0.0, 1.0)
    kp[conf <= 0] = np.nan
    return Person(bbox=box, keypoints=kp, confidences=conf, score=float(np.clip(score, 0.0, 1.0)))


class OpenPifPafBackend:
    """OpenPifPaf predictor (``pip install openpifpaf``); checkpoint name as OpenPifPaf knows it."""

    def __init__(self, checkpoint: str = "shufflenetv2k16") -> None:
        opp = _import("openpifpaf", "pip install openpifpaf (needs torch)")
        self._predictor = opp.Predictor(checkpoint=checkpoint)

    def __call__(self, frame: NDArray[np.uint8]) -> list[Person]:
        frame = check_frame(frame)
        predictions, _, _ = self._predictor.numpy_image(frame)
        out = []
        for ann in predictions:
            x, y, w, h = ann.bbox()
            p = _person(np.array([x, y, x + w, y + h]), ann.data[:, :2], ann.data[:, 2], ann.score)
            if p is not None:
                out.append(p)
        return out


class UltralyticsPoseBackend:
    """ultralytics YOLO-pose (``pip install ultralytics``); ``weights`` is a local .pt path or model name."""

    def __init__(self, weights: str = "yolo11n-pose.pt", min_score: float = 0.25) -> None:
        ul = _import("ultralytics", "pip install ultralytics (needs torch)")
        self._model = ul.YOLO(weights)
        self.min_score = min_score

    def __call__(self, frame: NDArray[np.uint8]) -> list[Person]:
        frame = check_frame(frame)
        res = self._model(frame[:, :, ::-1], verbose=False)[0]  # ultralytics takes BGR arrays
        if res.keypoints is None or res.boxes is None:
            return []
        boxes = res.boxes.xyxy.cpu().numpy()
        scores = res.boxes.conf.cpu().numpy()
        kps = res.keypoints.xy.cpu().numpy()
        confs = res.keypoints.conf.cpu().numpy() if res.keypoints.conf is not None else np.ones(kps.shape[:2])
        out = []
        for box, s, kp, c in zip(boxes, scores, kps, confs, strict=True):
            if s >= self.min_score and (p := _person(box, kp, c, s)) is not None:
                out.append(p)
        return out


def make_backend(name: str, *, video: bool = False, realtime: bool = False, crop_fits: int = 1, **kwargs: Any) -> Any:
    """Pose backend by name: 'mediapipe' (default, offline), 'openpifpaf' or 'yolo'; ``realtime``
    (mediapipe only): the search for new people beside the frame loop
    (:class:`~trustnav.perception.realtime.RealtimePoseBackend`); ``crop_fits`` > 1 (offline
    mediapipe only): each person's landmarks the median of that many fits on moved crops
    (:class:`~trustnav.perception.crop_ensemble.CropEnsembleBackend`)."""
    if crop_fits != 1 and (realtime or name != "mediapipe"):
        raise ValueError(f"crop_fits applies to the offline mediapipe backend only, got {crop_fits!r} with {name!r}"
                         f"{' in real time' if realtime else ''}")  # fmt: skip
    if realtime:
        if name != "mediapipe":
            raise ValueError(f"real-time perception is built on the mediapipe backend, not {name!r}")
        from trustnav.perception.mediapipe_backend import MediaPipeConfig
        from trustnav.perception.realtime import RealtimePoseBackend

        return RealtimePoseBackend(MediaPipeConfig(**kwargs))
    if name == "mediapipe":
        from trustnav.perception.mediapipe_backend import MediaPipeConfig, MediaPipePoseBackend

        if crop_fits != 1:
            from trustnav.perception.crop_ensemble import CropEnsembleBackend

            return CropEnsembleBackend(MediaPipeConfig(**kwargs), video=video, fits=crop_fits)
        return MediaPipePoseBackend(MediaPipeConfig(**kwargs), video=video)
    if name == "openpifpaf":
        return OpenPifPafBackend(**kwargs)
    if name == "yolo":
        return UltralyticsPoseBackend(**kwargs)
    raise ValueError(f"unknown pose backend {name!r}; expected 'mediapipe', 'openpifpaf' or 'yolo'")
