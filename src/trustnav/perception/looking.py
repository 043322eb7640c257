"""Eye-contact confidence C_eye (`eye_score`) from 17 COCO keypoints: the LOOKING model in numpy.

The pretrained weights (Belkada et al., 2021, file ``LookingModel_LOOK+PIE.p``) are a PyTorch
state_dict; they are read here without torch by a restricted unpickler that only rebuilds
tensors from the zip's storages and refuses every other class. Inference in eval mode:
y = relu(bn1(w1 x)); per stage y = y + relu(bn2(l2 relu(bn1(l1 y)))); C = sigmoid(w2 y).
"""

from __future__ import annotations

import os
import pickle
import zipfile
from collections import OrderedDict
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from trustnav.perception import model_files

__all__ = ["LOOKING_URL", "LookingModel", "load_torch_state_dict", "normalise_keypoints", "resolve_weights"]

LOOKING_URL = "https://github.com/vita-epfl/looking/raw/main/models/predictor/LookingModel_LOOK%2BPIE.p"
WEIGHTS_NAME = "LookingModel_LOOK+PIE.p"
WEIGHTS_HINT = "pass --looking-weights FILE (Python: LookingModel.from_file(FILE)) or set TRUSTNAV_LOOKING_WEIGHTS"
_DTYPES = {"FloatStorage": np.float32, "DoubleStorage": np.float64, "LongStorage": np.int64, "IntStorage": np.int32}
BN_EPS = 1e-5  # torch.nn.BatchNorm1d default


class _StorageType:
    def __init__(self, name: str) -> None:
        if name not in _DTYPES:
            raise pickle.UnpicklingError(f"unsupported tensor storage type torch.{name}")
        self.dtype = _DTYPES[name]


def _rebuild_tensor(storage, offset, size, stride, *_):
    itemsize = storage.itemsize
    return np.lib.stride_tricks.as_strided(
        storage[offset:], shape=tuple(size), strides=tuple(s * itemsize for s in stride)
    ).copy()


class _StateDictUnpickler(pickle.Unpickler):
    def __init__(self, file, archive: zipfile.ZipFile, prefix: str) -> None:
        super().__init__(file)
        self._archive = archive
        self._prefix = prefix

    def find_class(self, module: str, name: str):
        if (module, name) == ("collections", "OrderedDict"):
            return OrderedDict
        if (module, name) == ("torch._utils", "_rebuild_tensor_v2"):
            return _rebuild_tensor
        if module == "torch" and name.endswith("Storage"):
            return _StorageType(name)
        raise pickle.UnpicklingError(f"refusing to load {module}.{name}: only tensors are allowed in a weights file")

    def persistent_load(self, pid):
        kind, storage_type, key, _location, _numel = pid
        if kind != "storage":
            raise pickle.UnpicklingError(f"unexpected persistent id {kind!r}")
        raw = self._archive.read(f"{self._prefix}data/{key}")
        return np.frombuffer(raw, dtype=storage_type.dtype)


def load_torch_state_dict(path: str | Path) -> dict[str, NDArray]:
    """Read a zip-format torch state_dict into numpy arrays, without torch."""
    path = Path(path)
    try:
        archive = zipfile.ZipFile(path)
    except (OSError, zipfile.BadZipFile) as exc:
        raise ValueError(
            f"LOOKING weights {path}: not a readable zip-format torch weights file ({exc}); {WEIGHTS_HINT}"
        ) from None
    with archive:
        pkl = [n for n in archive.namelist() if n.endswith("data.pkl")]
        if len(pkl) != 1:
            raise ValueError(f"{path}: expected one data.pkl in the archive, found {len(pkl)}")
        prefix = pkl[0][: -len("data.pkl")]
        with archive.open(pkl[0]) as fh:
            state = _StateDictUnpickler(fh, archive, prefix).load()
    if not isinstance(state, dict):
        raise ValueError(f"{path}: the pickle holds a {type(state).__name__}, not a state_dict")
    return dict(state)


def _candidates() -> tuple[list[Path], Path]:
    """Where the weights are looked for, in order, and the cache they are downloaded to."""
    env = [Path(os.environ["TRUSTNAV_LOOKING_WEIGHTS"])] if os.environ.get("TRUSTNAV_LOOKING_WEIGHTS") else []
    cache = model_files.cache_path(WEIGHTS_NAME)
    return [*env, *model_files.checkout_paths("looking", WEIGHTS_NAME), cache], cache


def resolve_weights(path: str | Path | None = None, *, download: bool = True) -> Path:
    """Find the LOOKING weights: ``path``; $TRUSTNAV_LOOKING_WEIGHTS; ``../shared/models/looking/``
    (development checkout); the user cache (~/.cache/trustnav). If none has the file and
    ``download`` is true, fetch it once from its public URL into the cache, saying so.
    Raises FileNotFoundError with a one-line hint when the file cannot be had."""
    if path is not None:
        p = Path(path)
        if not p.is_file():
            what = "a folder, not a file" if p.is_dir() else "no such file"
            raise FileNotFoundError(f"LOOKING weights not found at {p} ({what}; expected the file {WEIGHTS_NAME})")
        return p
    candidates, cache = _candidates()
    return model_files.find_or_download(
        candidates, cache, allow=download, url=LOOKING_URL, hint=WEIGHTS_HINT, timeout=30.0,
        missing=f"LOOKING weights not found (looked in {', '.join(str(c) for c in candidates[:2])}, ..., {cache}); "
        f"{WEIGHTS_HINT}, or allow the download from {LOOKING_URL}",
        notice=f"trustnav: downloading the LOOKING eye-contact weights (1.7 MB) once to {cache}",
        what="LOOKING eye-contact weights",
    )  # fmt: skip


def normalise_keypoints(keypoints: ArrayLike, confidences: ArrayLike, image_width: float) -> NDArray[np.float64]:
    """The input normalisation used with these weights (see ../shared/README.md):
    hips centre (cx, cy) = integer midpoint of keypoints 11 and 12, w, h = extent of X and Y,
    X_n = X / W + (X - cx) / w, Y_n = (Y - cy) / h; input = [X_n, Y_n, C] (51)."""
    kp = np.asarray(keypoints, dtype=float)
    c = np.asarray(confidences, dtype=float).reshape(-1)
    if kp.shape != (17, 2) or c.shape != (17,):
        raise ValueError(f"need keypoints (17, 2) and confidences (17,), got {kp.shape} and {c.shape}")
    if not image_width > 0:
        raise ValueError(f"image_width must be > 0 pixels, got {image_width!r}")
    x, y = kp[:, 0], kp[:, 1]
    cx = int((x[11] + x[12]) / 2)
    cy = int((y[11] + y[12]) / 2)
    w = max(float(x.max() - x.min()), 1e-6)
    h = max(float(y.max() - y.min()), 1e-6)
    return np.concatenate([x / image_width + (x - cx) / w, (y - cy) / h, c])


class LookingModel:
    """The LOOKING MLP (51 -> 256 -> 2 residual stages -> 1) in numpy, eval mode."""

    def __init__(self, state: dict[str, NDArray]) -> None:
        def lin(name: str) -> tuple[NDArray, NDArray]:
            return state[f"{name}.weight"].astype(np.float64), state[f"{name}.bias"].astype(np.float64)

        def bn(name: str) -> tuple[NDArray, NDArray]:
            scale = state[f"{name}.weight"] / np.sqrt(state[f"{name}.running_var"].astype(np.float64) + BN_EPS)
            return scale, state[f"{name}.bias"] - state[f"{name}.running_mean"] * scale

        try:
            self.w1, self.bn1 = lin("w1"), bn("batch_norm1")
            n_stages = len({k.split(".")[1] for k in state if k.startswith("linear_stages.")})
            self.stages = [
                tuple(f(f"linear_stages.{i}.{n}") for f, n in ((lin, "l1"), (bn, "bn1"), (lin, "l2"), (bn, "bn2")))
                for i in range(n_stages)
            ]
            self.w2 = lin("w2")
        except KeyError as exc:
            raise ValueError(f"not a LOOKING state_dict: missing {exc}") from exc
        if self.w1[0].shape != (256, 51):
            raise ValueError(f"LOOKING w1 must be 256 x 51, got {self.w1[0].shape}")

    @classmethod
    def from_file(cls, path: str | Path | None = None, *, download: bool = True) -> LookingModel:
        return cls(load_torch_state_dict(resolve_weights(path, download=download)))

    def predict(self, inputs: ArrayLike) -> NDArray[np.float64]:
        """Eye-contact probability for normalised inputs (B, 51) (or one (51,))."""
        x = np.atleast_2d(np.asarray(inputs, dtype=np.float64))
        if x.shape[1] != 51:
            raise ValueError(f"LOOKING inputs must have 51 columns, got {x.shape}")
        y = np.maximum((x @ self.w1[0].T + self.w1[1]) * self.bn1[0] + self.bn1[1], 0.0)
        for (w_a, b_a), (s_a, t_a), (w_b, b_b), (s_b, t_b) in self.stages:
            z = np.maximum((y @ w_a.T + b_a) * s_a + t_a, 0.0)
            y = y + np.maximum((z @ w_b.T + b_b) * s_b + t_b, 0.0)
        logit = y @ self.w2[0].T + self.w2[1]
        return (1.0 / (1.0 + np.exp(-logit))).reshape(-1)
