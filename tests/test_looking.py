"""LOOKING eye-contact model in numpy: loader, normalisation, agreement with a hand evaluation."""

from __future__ import annotations

import io
import math
import pickle
import zipfile

import numpy as np
import pytest

from trustnav.perception.looking import LookingModel, load_torch_state_dict, normalise_keypoints, resolve_weights


def _hand_eval(state, x):
    """Independent scalar evaluation of the README's inference formula (no matrix products)."""

    def linear(name, v):
        w, b = state[f"{name}.weight"], state[f"{name}.bias"]
        return [math.fsum(float(w[i, j]) * v[j] for j in range(len(v))) + float(b[i]) for i in range(w.shape[0])]

    def batchnorm(name, v):
        g, b = state[f"{name}.weight"], state[f"{name}.bias"]
        m, var = state[f"{name}.running_mean"], state[f"{name}.running_var"]
        return [
            (v[i] - float(m[i])) / math.sqrt(float(var[i]) + 1e-5) * float(g[i]) + float(b[i]) for i in range(len(v))
        ]

    def relu(v):
        return [max(0.0, a) for a in v]

    y = relu(batchnorm("batch_norm1", linear("w1", list(x))))
    for s in range(3):  # linear_stages.{0,1,2} (shared README)
        z = relu(batchnorm(f"linear_stages.{s}.bn1", linear(f"linear_stages.{s}.l1", y)))
        z = relu(batchnorm(f"linear_stages.{s}.bn2", linear(f"linear_stages.{s}.l2", z)))
        y = [a + b for a, b in zip(y, z, strict=True)]
    return 1.0 / (1.0 + math.exp(-linear("w2", y)[0]))


def test_numpy_model_matches_hand_evaluation_to_1e6(looking_weights):
    state = load_torch_state_dict(looking_weights)
    assert state["w1.weight"].shape == (256, 51)
    assert state["linear_stages.1.l2.weight"].shape == (256, 256)
    model = LookingModel(state)
    rng = np.random.default_rng(0)
    kps = rng.uniform([200, 100], [260, 300], size=(4, 17, 2))
    conf = rng.uniform(0, 1, size=(4, 17))
    x = np.stack([normalise_keypoints(k, c, 640) for k, c in zip(kps, conf, strict=True)])
    out = model.predict(x)
    assert out.shape == (4,) and np.all((out > 0) & (out < 1))
    for i in range(4):
        assert out[i] == pytest.approx(_hand_eval(state, x[i]), abs=1e-6)
    assert resolve_weights(looking_weights) == looking_weights


def test_normalisation_follows_the_shared_readme():
    kp = np.column_stack([np.linspace(100, 140, 17), np.linspace(50, 250, 17)])
    c = np.linspace(0, 1, 17)
    x = normalise_keypoints(kp, c, 640)
    cx, cy = int((kp[11, 0] + kp[12, 0]) / 2), int((kp[11, 1] + kp[12, 1]) / 2)
    np.testing.assert_allclose(x[:17], kp[:, 0] / 640 + (kp[:, 0] - cx) / 40)
    np.testing.assert_allclose(x[17:34], (kp[:, 1] - cy) / 200)
    np.testing.assert_allclose(x[34:], c)
    with pytest.raises(ValueError, match=r"need keypoints \(17, 2\)"):
        normalise_keypoints(kp[:5], c, 640)


def test_loader_refuses_anything_but_tensors(tmp_path):
    class Evil:
        def __reduce__(self):
            return (print, ("owned",))

    buf = io.BytesIO()
    pickle.dump({"w": Evil()}, buf, protocol=2)
    bad = tmp_path / "evil.p"
    with zipfile.ZipFile(bad, "w") as z:
        z.writestr("archive/data.pkl", buf.getvalue())
    with pytest.raises(pickle.UnpicklingError, match=r"refusing to load .*print: only tensors"):
        load_torch_state_dict(bad)
    (tmp_path / "junk.p").write_text("not a zip")
    with pytest.raises(ValueError, match="not a readable zip-format torch weights file"):
        load_torch_state_dict(tmp_path / "junk.p")
    with pytest.raises(FileNotFoundError, match="LOOKING weights not found at"):
        resolve_weights(tmp_path / "missing.p")
    with pytest.raises(ValueError, match="not a LOOKING state_dict"):
        LookingModel({"w1.weight": np.zeros((256, 51))})
