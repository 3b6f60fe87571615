"""Model interface: every kind predicts, draws, recalibrates, saves and loads the same way."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from pydantic import ValidationError

from activelearn.config import ModelConfig, TrainingConfig
from activelearn.errors import DataFormatError, InputError
from activelearn.numerics import synthetic as syn
from activelearn.numerics.arch import ARCH_PRESETS
from activelearn.numerics.models import (
    BNN,
    DNN,
    PBNN,
    PNN,
    BayesianLinear,
    DeepEnsemble,
    DenseLinear,
    HybridPBNN,
    Model,
    Prediction,
    build_model,
    load_model,
    parse_arch,
    save_model,
)
from activelearn.numerics.models.base import CHUNK_ROWS
from activelearn.numerics.training import fit
from activelearn.numerics.training_data import TrainingData
from activelearn.studies.tracking import model_packages

KINDS = ["hybrid", "pbnn", "pnn", "bnn", "dnn", "ensemble"]
SMALL = {"arch": "D8-V8-V", "ensemble_size": 3}


@pytest.fixture(scope="module")
def data():
    x, y = syn.uniform_rows(400, seed=0)
    return x, y


@pytest.fixture(scope="module")
def trained(data):
    """One briefly trained model of each kind (shared by the read-only tests)."""
    x, y = data
    models = {}
    for kind in KINDS:
        m = build_model(ModelConfig(kind=kind, **SMALL))
        fit(m, TrainingData(x, y), TrainingConfig(epochs=3, batch_size=64, patience=None))
        models[kind] = m
    return models


def test_build_model_classes():
    classes = {
        "hybrid": HybridPBNN,
        "pbnn": PBNN,
        "pnn": PNN,
        "bnn": BNN,
        "dnn": DNN,
        "ensemble": DeepEnsemble,
    }
    for kind, cls in classes.items():
        m = build_model(ModelConfig(kind=kind, **SMALL))
        assert isinstance(m, cls) and isinstance(m, Model) and m.kind == kind
    hybrid = build_model(ModelConfig(kind="hybrid", arch="D8-V8-V"))
    assert [type(layer) for layer in hybrid.layers] == [DenseLinear, BayesianLinear, BayesianLinear]
    assert not any(isinstance(layer, BayesianLinear) for layer in build_model(ModelConfig(kind="pnn")).layers)
    assert all(isinstance(layer, BayesianLinear) for layer in build_model(ModelConfig(kind="pbnn")).layers)


def test_reference_preset_layers_and_activations():
    m = build_model(ModelConfig(arch="reference"))
    assert [isinstance(layer, BayesianLinear) for layer in m.layers] == [True, False, False, False, True]
    assert m.activations == ["sigmoid", "relu", "relu", "relu", None]
    assert [layer.n_out for layer in m.layers] == [8, 32, 32, 8, 4]  # head: mean + scale for 2 outputs
    assert "default" in ARCH_PRESETS and parse_arch("default")


def test_build_model_is_seeded():
    a = build_model(ModelConfig(), seed=1)
    b = build_model(ModelConfig(), seed=1)
    c = build_model(ModelConfig(), seed=2)
    for pa, pb in zip(a.parameters(), b.parameters(), strict=True):
        torch.testing.assert_close(pa, pb)
    assert not all(torch.equal(pa, pc) for pa, pc in zip(a.parameters(), c.parameters(), strict=True))


@pytest.mark.parametrize(
    ("field", "value", "needle"),
    [
        ("arch", "V8-X3-V", "arch"),
        ("arch", "V8-D32", "arch"),
        ("arch", "V8:swish-V", "arch"),
        ("prior_scale", 0.0, "prior_scale"),
        ("min_std", -1.0, "min_std"),
        ("ensemble_size", 1, "ensemble_size"),
        ("kind", "gp", "kind"),
        ("n_inputs", 0, "n_inputs"),
    ],
)
def test_model_config_errors_name_the_field(field, value, needle):
    with pytest.raises(ValidationError) as info:
        ModelConfig(**{field: value})
    assert needle in str(info.value)


def test_config_rejects_unknown_keys():
    with pytest.raises(ValidationError, match="prior_sigma"):
        ModelConfig(prior_sigma=1.0)
    with pytest.raises(ValidationError, match="learning_rate"):
        TrainingConfig(learning_rate=1.0)
    for field, value in [("lr", 0.0), ("kl_count", -3), ("kl_count", "weeks"), ("batch_size", 0)]:
        with pytest.raises(ValidationError, match=field):
            TrainingConfig(**{field: value})
    assert TrainingConfig(kl_count=100).kl_count == 100.0


@pytest.mark.parametrize("kind", KINDS)
def test_predict_shapes_units_and_flags(trained, data, kind):
    m = trained[kind]
    x, y = data
    p = m.predict(x[:50], n_samples=8, seed=0)
    assert isinstance(p, Prediction)
    for arr in (p.mean, p.aleatoric_var, p.epistemic_var, p.total_var):
        assert arr.shape == (50, 2) and np.isfinite(arr).all()
    assert (p.aleatoric_var >= 0).all() and (p.epistemic_var >= 0).all()
    np.testing.assert_allclose(p.total_var, p.aleatoric_var + p.epistemic_var)
    # Physical units: the mean is on the scale of the targets, not standardised.
    assert abs(p.mean[:, 0].mean() - y[:, 0].mean()) < 0.5 * y[:, 0].std() + 0.05
    assert p.has_epistemic == (kind in ("hybrid", "pbnn", "bnn", "ensemble"))
    assert p.has_aleatoric == (kind != "dnn")
    if not p.has_epistemic:
        assert (p.epistemic_var == 0).all()
    else:
        assert (p.epistemic_var > 0).all()
    if kind == "dnn":
        assert (p.aleatoric_var == 0).all()
    if kind == "bnn":  # homoscedastic: the same aleatoric variance everywhere
        np.testing.assert_allclose(
            p.aleatoric_var, np.broadcast_to(p.aleatoric_var[0], p.aleatoric_var.shape)
        )


@pytest.mark.parametrize("kind", KINDS)
def test_predict_is_deterministic_per_seed(trained, data, kind):
    m = trained[kind]
    x = data[0][:20]
    a, b = m.predict(x, 8, seed=3), m.predict(x, 8, seed=3)
    np.testing.assert_array_equal(a.mean, b.mean)
    np.testing.assert_array_equal(a.epistemic_var, b.epistemic_var)
    if kind in ("hybrid", "pbnn", "bnn"):
        assert not np.array_equal(a.mean, m.predict(x, 8, seed=4).mean)


@pytest.mark.parametrize("kind", KINDS)
def test_draw_shares_weights_across_rows_and_calls(trained, data, kind):
    m = trained[kind]
    x = data[0][:30]
    sampled = m.draw(6, seed=1)
    means, var = sampled(x)
    assert isinstance(means, np.ndarray) and means.shape == (6, 30, 2) and var.shape == (6, 30, 2)
    # Same weights for every row: evaluating one row alone gives that row's values.
    one_m, one_v = sampled(x[7:8])
    np.testing.assert_allclose(one_m[:, 0], means[:, 7], rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(one_v[:, 0], var[:, 7], rtol=1e-5, atol=1e-9)
    # ... and every call: a second call (and a redraw with the same seed) agree.
    np.testing.assert_array_equal(sampled(x)[0], means)
    np.testing.assert_array_equal(m.draw(6, seed=1)(x)[0], means)
    # (S, N, d) input, torch in → torch out.
    xs = torch.as_tensor(np.broadcast_to(x, (6, 30, 2)).copy(), dtype=torch.float32)
    t_means, _ = sampled(xs)
    assert isinstance(t_means, torch.Tensor)
    np.testing.assert_allclose(t_means.numpy(), means, rtol=1e-5, atol=1e-7)
    with pytest.raises(InputError):
        sampled(np.zeros((3, 30, 2)))
    with pytest.raises(InputError):
        sampled(np.zeros((30, 3)))


def test_draw_samples_distinct_for_variational_and_member_cycle_for_ensemble(trained, data):
    x = data[0][:10]
    means, _ = trained["hybrid"].draw(4, seed=0)(x)
    assert not np.allclose(means[0], means[1])
    ens = trained["ensemble"]
    means, _ = ens.draw(7, seed=0)(x)  # K = 3: sample s is member s mod 3
    np.testing.assert_array_equal(means[0], means[3])
    np.testing.assert_array_equal(means[1], means[4])
    assert not np.allclose(means[0], means[1])
    for kind in ("dnn", "pnn"):
        means, _ = trained[kind].draw(3, seed=0)(x)
        np.testing.assert_array_equal(means[0], means[2])


def test_predict_agrees_with_draw(trained, data):
    m = trained["hybrid"]
    x = data[0][:25]
    p = m.predict(x, 16, seed=5, return_samples=True)
    means, var = m.draw(16, seed=5)(x)
    assert p.sample_means is not None and p.sample_means.shape == (16, 25, 2)
    np.testing.assert_allclose(p.mean, means.mean(0), rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(p.epistemic_var, means.var(0), rtol=1e-4, atol=1e-12)
    np.testing.assert_allclose(p.aleatoric_var, var.mean(0), rtol=1e-5, atol=1e-12)
    ens = trained["ensemble"].predict(x, 32, return_samples=True)
    assert ens.sample_means.shape == (3, 25, 2)  # moments over the K members


def test_epistemic_scale_applies_to_predict_and_draw(data):
    x, y = data
    m = build_model(ModelConfig(**SMALL))
    fit(m, TrainingData(x, y), TrainingConfig(epochs=2, batch_size=64, patience=None))
    base = m.predict(x[:20], 8)
    base_draw, _ = m.draw(8)(x[:20])
    with torch.no_grad():
        m.epistemic_scale.fill_(4.0)
    scaled = m.predict(x[:20], 8)
    np.testing.assert_allclose(scaled.epistemic_var, 4 * base.epistemic_var, rtol=1e-4)
    np.testing.assert_allclose(scaled.mean, base.mean, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(scaled.aleatoric_var, base.aleatoric_var, rtol=1e-5)
    draw, _ = m.draw(8)(x[:20])
    centre = base_draw.mean(0)
    np.testing.assert_allclose(draw - centre, 2 * (base_draw - centre), rtol=1e-4, atol=1e-6)
    assert "epistemic_scale" in m.state_dict()


@pytest.mark.parametrize("kind", KINDS)
def test_save_and_load_round_trip(trained, data, tmp_path, kind):
    m = trained[kind]
    with torch.no_grad():
        m.epistemic_scale.fill_(2.5)
    path = tmp_path / "sub" / f"{kind}.pt"
    save_model(m, path)
    loaded = load_model(path)
    assert type(loaded) is type(m) and loaded.config == m.config
    torch.testing.assert_close(loaded.y_std, m.y_std)
    assert float(loaded.epistemic_scale) == 2.5
    x = data[0][:15]
    a, b = m.predict(x, 8, seed=2), loaded.predict(x, 8, seed=2)
    np.testing.assert_array_equal(a.mean, b.mean)
    np.testing.assert_array_equal(a.epistemic_var, b.epistemic_var)
    with torch.no_grad():
        m.epistemic_scale.fill_(1.0)
    assert not list(path.parent.glob(".*"))  # no temporary file left behind


def test_load_model_rejects_garbage(tmp_path):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a model")
    with pytest.raises(DataFormatError):
        load_model(bad)


def test_forward_is_the_posterior_mean_network(trained, data):
    m = trained["hybrid"]
    out = m(torch.as_tensor(data[0][:5], dtype=torch.float32))
    assert out.shape == (5, 4)
    assert (out[:, 2:] > 0).all()


def test_full_cov_and_mc_kl_models_train(data):
    x, y = data
    for extra in ({"posterior": "full_cov"}, {"kl": "mc", "kl_samples": 2}, {"prior_trainable": True}):
        m = build_model(ModelConfig(arch="D8-V4-V", **extra))
        h = fit(m, TrainingData(x, y), TrainingConfig(epochs=2, batch_size=64, patience=None))
        assert np.isfinite(h.train_loss).all()
        assert m.predict(x[:5], 4).epistemic_var.shape == (5, 2)


def test_markov_state_inputs():
    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, (300, 4))
    y = np.stack([x[:, 0] + 0.5 * x[:, 2], x[:, 1] * x[:, 3]], 1) + 0.01 * rng.standard_normal((300, 2))
    m = build_model(ModelConfig(n_inputs=4, arch="D8-V8-V"))
    fit(m, TrainingData(x, y), TrainingConfig(epochs=2, batch_size=64, patience=None))
    assert m.predict(x[:7], 4).mean.shape == (7, 2)
    assert m.draw(3)(np.zeros((3, 7, 4)))[0].shape == (3, 7, 2)


@pytest.mark.slow
def test_mlflow_pytorch_round_trip(trained, data, tmp_path, monkeypatch):
    """The module logs and loads through mlflow.pytorch with a real SQLite store (pickle format), and
    MLflow's own inference of its requirements finds the packages `Tracker.log_model` names itself."""
    mlflow_pytorch = pytest.importorskip("mlflow.pytorch")
    import mlflow

    monkeypatch.chdir(tmp_path)
    mlflow.set_tracking_uri(f"sqlite:///{tmp_path}/mlflow.db")
    exp = mlflow.create_experiment("compat", artifact_location=(tmp_path / "artifacts").as_uri())
    m = trained["hybrid"]
    try:
        with mlflow.start_run(experiment_id=exp):
            info = mlflow_pytorch.log_model(m, name="model", serialization_format="pickle")
        loaded = mlflow_pytorch.load_model(info.model_uri)
    finally:
        mlflow.set_tracking_uri(None)
    assert isinstance(loaded, HybridPBNN)
    [requirements] = (tmp_path / "artifacts").rglob("requirements.txt")
    inferred = {line.split("==")[0] for line in requirements.read_text().split()}
    assert inferred == set(model_packages())
    x = data[0][:10]
    np.testing.assert_array_equal(loaded.predict(x, 8, seed=1).mean, m.predict(x, 8, seed=1).mean)


def test_predict_in_blocks_equals_predict_on_each_part(trained):
    """Inputs longer than one block of rows give the same moments as the rows evaluated apart."""
    m = trained["hybrid"]
    x = np.random.default_rng(0).uniform([-1, -0.5], [1, 0.5], (CHUNK_ROWS + 300, 2))
    whole = m.predict(x, 8, seed=2)
    for rows in (slice(0, 10), slice(CHUNK_ROWS - 5, CHUNK_ROWS + 5), slice(CHUNK_ROWS + 290, None)):
        part = m.predict(x[rows], 8, seed=2)
        for name in ("mean", "aleatoric_var", "epistemic_var"):
            np.testing.assert_allclose(getattr(part, name), getattr(whole, name)[rows], rtol=1e-5, atol=1e-9)
