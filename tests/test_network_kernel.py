"""The compiled network kernel computes what the torch path computes, for every model kind and layer kind."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from activelearn.config import ModelConfig
from activelearn.errors import InputError
from activelearn.numerics import native
from activelearn.numerics.arch import ACTIVATIONS
from activelearn.numerics.models import build_model

# Every kind, every activation, a full-covariance posterior, the reference preset (sigmoid first,
# a variational layer first), a sampled layer between dense ones, and a Markov-state model.
CASES = {
    "hybrid default": dict(kind="hybrid"),
    "hybrid reference": dict(kind="hybrid", arch="reference"),
    "hybrid full-cov": dict(kind="hybrid", arch="D8-V6-D5-V", posterior="full_cov"),
    "pbnn": dict(kind="pbnn", arch="D8-D8-V"),
    "pnn": dict(kind="pnn", arch="D8-D8-V"),
    "bnn": dict(kind="bnn", arch="D8-D8-V"),
    "dnn": dict(kind="dnn", arch="D8-D8-V"),
    "ensemble": dict(kind="ensemble", arch="D8-D8-V", ensemble_size=3),
    "markov": dict(kind="hybrid", arch="D16-V7-V", n_inputs=4),
    **{f"activation {a}": dict(kind="hybrid", arch="D9-V6-V", activation=a) for a in ACTIVATIONS},
}


pytestmark = pytest.mark.usefixtures("c_kernels")  # every test here compares or runs the C kernels


def _model(config: dict, seed: int = 0):
    """A model with scrambled weights, scalers and posterior scales, so nothing is at its default."""
    model = build_model(ModelConfig(**config), seed=seed)
    gen = torch.Generator().manual_seed(seed + 1)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.3 * torch.randn(p.shape, generator=gen))
        d, o = model.n_inputs, model.n_outputs
        model.x_mean.copy_(torch.randn(d, generator=gen))
        model.x_std.copy_(0.5 + torch.rand(d, generator=gen))
        model.y_mean.copy_(torch.randn(o, generator=gen))
        model.y_std.copy_(0.2 + torch.rand(o, generator=gen))
    return model


def _inputs(n_rows: int, n_inputs: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-2.0, 2.0, (n_rows, n_inputs)).astype(np.float32)


@pytest.mark.parametrize("case", list(CASES))
def test_draws_match_torch(case):
    model = _model(CASES[case])
    # 150 rows: two full tiles of 64 and a partial one; S = 5 is odd and not a vector width.
    x = _inputs(150, model.n_inputs)
    native_draw, torch_draw = (model.draw(5, seed=3, backend=b) for b in ("native", "reference"))
    assert native_draw.kernel is not None and torch_draw.kernel is None
    got, want = native_draw(x), torch_draw(x)
    assert np.abs(want[0]).max() > 0.0  # means (a DNN's variances are zeros)
    for name, g, w in zip(("means", "variances"), got, want, strict=True):
        np.testing.assert_allclose(g, w, rtol=2e-5, atol=2e-6, err_msg=name)
    # One input set per draw (the Markov rollout feeds each trajectory's own rates back in).
    per_draw = np.stack([_inputs(150, model.n_inputs, seed=s) for s in range(5)])
    for got, want in zip(native_draw(per_draw), torch_draw(per_draw), strict=True):
        np.testing.assert_allclose(got, want, rtol=2e-5, atol=2e-6)


@pytest.mark.parametrize("case", ["hybrid default", "hybrid reference", "ensemble", "bnn", "dnn"])
def test_predict_matches_torch_and_honours_the_epistemic_scale(case):
    model = _model(CASES[case])
    with torch.no_grad():
        model.epistemic_scale.fill_(2.5)
    x = _inputs(700, model.n_inputs)
    got, want = (model.predict(x, 9, seed=1, backend=b) for b in ("native", "reference"))
    for name in ("mean", "aleatoric_var", "epistemic_var", "total_var"):
        g, w = getattr(got, name), getattr(want, name)
        # float32 rounding: relative to each array's scale (means cross zero)
        np.testing.assert_allclose(g, w, rtol=5e-5, atol=2e-6 * np.abs(w).max(), err_msg=name)
    draws_native, draws_torch = (model.draw(9, seed=1, backend=b)(x)[0] for b in ("native", "reference"))
    np.testing.assert_allclose(draws_native, draws_torch, rtol=2e-5, atol=2e-6)


def test_kernel_results_do_not_depend_on_threads_or_blocks():
    model = _model(CASES["hybrid default"])
    x = _inputs(40_000, 2)  # several kernel tasks per thread
    old = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        one = model.predict(x, 8, seed=2)
        torch.set_num_threads(2)
        two = model.predict(x, 8, seed=2)
    finally:
        torch.set_num_threads(old)
    for name in ("mean", "aleatoric_var", "epistemic_var"):
        np.testing.assert_array_equal(getattr(one, name), getattr(two, name), err_msg=name)
    # A row's values do not depend on where its tile starts.
    part = model.predict(x[37:101], 8, seed=2)
    np.testing.assert_array_equal(part.mean, one.mean[37:101])


def test_a_wrong_activation_would_be_caught():
    """The comparison above can fail: a kernel told relu where the model has tanh disagrees."""
    model = _model(CASES["activation tanh"])
    sampled = model.draw(4, seed=0, backend="native")
    layers = []
    for (w, b), act in zip(sampled._params, model.activations, strict=True):
        per_sample = w.dim() == 3
        layers.append((w.numpy(), b.reshape(*w.shape[:-2], -1).numpy(), per_sample, "relu" if act else None))
    wrong = native.NetworkKernel(
        native.library(),
        layers,
        n_samples=4,
        x_mean=model.x_mean.numpy(),
        x_std=model.x_std.numpy(),
        min_std=model.config.min_std,
        head_var=None,
    )
    x = _inputs(64, 2).T.copy()
    right_means, wrong_means = (np.empty((4, 2, 64), np.float32) for _ in range(2))
    sampled.kernel.forward(x, draws=(right_means, np.empty_like(right_means)))
    wrong.forward(x, draws=(wrong_means, np.empty_like(wrong_means)))
    assert np.abs(right_means - wrong_means).max() > 1e-2


def test_native_backend_without_a_compiler_is_a_clear_error(monkeypatch, tmp_path):
    monkeypatch.setattr(native, "CACHE_DIR", tmp_path)
    monkeypatch.setattr(native, "COMPILERS", ("false",))
    native.library.cache_clear()
    model = _model(CASES["hybrid default"])
    x = _inputs(10, 2)
    try:
        with pytest.warns(RuntimeWarning, match="kernel unavailable"):
            fallback = model.predict(x, 4)  # "auto" falls back to torch
        with pytest.raises(InputError, match="backend"):
            model.predict(x, 4, backend="native")
    finally:
        monkeypatch.undo()
        native.library.cache_clear()
    np.testing.assert_allclose(fallback.mean, model.predict(x, 4).mean, rtol=2e-5, atol=2e-6)
    with pytest.raises(InputError, match="backend"):
        model.draw(4, backend="gpu")
