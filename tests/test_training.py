"""fit(): ELBO terms, KL counting, optimizers, early stopping, callbacks, reproducibility, compile."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from activelearn.config import ModelConfig, TrainingConfig
from activelearn.errors import InputError
from activelearn.numerics import synthetic as syn
from activelearn.numerics.models import build_model
from activelearn.numerics.training import History, fit, kl_count_value
from activelearn.numerics.training_data import TrainingData
from activelearn.numerics.uncertainty import recalibrate_epistemic, rmse
from tests.conftest import flat_weights

FAST = {"epochs": 3, "batch_size": 64, "patience": None}


@pytest.fixture(scope="module")
def data():
    x, y, groups = syn.repeated_rows(syn.random_points(12, seed=0), 40, seed=1)
    return x, y, groups


def test_same_seed_same_weights_and_global_rng_untouched(data):
    x, y, _ = data
    cfg = TrainingConfig(**FAST)
    torch.manual_seed(123)
    before = torch.random.get_rng_state()
    a, b, c = (build_model(ModelConfig(arch="D8-V8-V"), seed=s) for s in (0, 1, 2))
    fit(a, TrainingData(x, y), cfg, seed=7)
    fit(b, TrainingData(x, y), cfg, seed=7)  # different initial weights: reinit from the fit seed
    fit(c, TrainingData(x, y), cfg, seed=8)
    torch.testing.assert_close(flat_weights(a), flat_weights(b), rtol=0, atol=0)
    assert not torch.equal(flat_weights(a), flat_weights(c))
    assert torch.equal(torch.random.get_rng_state(), before)


def test_fit_reduces_loss_and_learns_the_map(data):
    x, y, _ = data
    m = build_model(ModelConfig(arch="D16-V16-V"))
    h = fit(m, TrainingData(x, y), TrainingConfig(epochs=25, batch_size=32, patience=None))
    assert isinstance(h, History) and h.n_epochs == 25 and h.best_epoch == 24
    assert h.train_loss[-1] < h.train_loss[0]
    assert len(h.kl) == 25 and all(k > 0 for k in h.kl)
    pts = syn.random_points(50, seed=5)
    assert rmse(syn.steady_state(pts), m.predict(pts)) < 0.05


def test_kl_count_values():
    groups = np.repeat(np.arange(4), 25)
    assert kl_count_value("rows", 100, None) == 100
    assert kl_count_value("maneuvers", 100, groups) == 4
    assert kl_count_value("sqrt", 100, groups) == pytest.approx(20.0)
    assert kl_count_value(12.5, 100, None) == 12.5
    # Without groups each row is its own maneuver.
    assert kl_count_value("maneuvers", 100, None) == kl_count_value("sqrt", 100, None) == 100


def test_kl_count_changes_the_loss(data):
    x, y, groups = data
    losses = {}
    for count in ("rows", "maneuvers"):
        m = build_model(ModelConfig(arch="D8-V8-V"))
        h = fit(
            m,
            TrainingData(x, y, groups=groups),
            TrainingConfig(**{**FAST, "epochs": 1, "kl_count": count}),
        )
        losses[count] = h.train_loss[0] - h.train_data[0]  # the KL/N part
        assert h.kl_count == (len(x) if count == "rows" else 12)
    # Fewer "pieces of evidence" → the KL weighs len(x)/12 = 40x more per row.
    assert losses["maneuvers"] > 20 * losses["rows"]


@pytest.mark.parametrize("loss", ["nll", "mse", "mae"])
@pytest.mark.parametrize("optimizer", ["adam", "rmsprop", "sgd"])
def test_losses_and_optimizers_train(data, loss, optimizer):
    x, y, _ = data
    m = build_model(ModelConfig(arch="D8-V8-V"))
    lr = 1e-2
    h = fit(
        m,
        TrainingData(x, y),
        TrainingConfig(epochs=6, batch_size=32, patience=None, loss=loss, optimizer=optimizer, lr=lr),
    )
    assert all(math.isfinite(v) for v in h.train_loss)
    assert h.train_data[-1] < h.train_data[0]


def test_early_stopping_restores_the_best_epoch(data):
    x, y, _ = data
    xv, yv, _ = syn.repeated_rows(syn.random_points(6, seed=9), 20, seed=2)
    m = build_model(ModelConfig(arch="D16-V16-V"))
    # A large learning rate makes validation NLL bounce, so the last epoch is rarely the best.
    cfg = TrainingConfig(epochs=40, batch_size=16, patience=4, lr=0.05, n_eval_samples=8)
    h = fit(m, TrainingData(x, y), cfg, validation=TrainingData(xv, yv))
    assert len(h.val_nll) == h.n_epochs and len(h.val_rmse) == h.n_epochs
    assert h.best_epoch == int(np.argmin(h.val_nll))
    # These data stop early: the weights restored below are not the last epoch's.
    assert h.stopped_early and h.n_epochs < cfg.epochs
    assert h.n_epochs == h.best_epoch + 1 + cfg.patience
    assert h.best_epoch < h.n_epochs - 1
    from activelearn.numerics.training import _validate

    val_nll, _ = _validate(m, xv, yv, 8, 0)
    assert val_nll == pytest.approx(h.val_nll[h.best_epoch], rel=1e-5)


def test_callback_sees_metrics_and_can_stop(data):
    x, y, _ = data
    xv, yv = x[:50], y[:50]
    seen = []

    def cb(epoch, metrics):
        seen.append((epoch, metrics))
        return epoch == 2

    h = fit(
        build_model(ModelConfig(arch="D8-V8-V")),
        TrainingData(x, y),
        TrainingConfig(**{**FAST, "epochs": 10}),
        validation=TrainingData(xv, yv),
        callback=cb,
    )  # fmt: skip
    assert [e for e, _ in seen] == [0, 1, 2] and h.n_epochs == 3
    assert {"train_loss", "val_nll", "val_rmse", "kl", "epoch_time"} <= set(seen[0][1])


def test_callback_exceptions_propagate(data):
    x, y, _ = data

    class Pruned(Exception):
        pass

    def cb(epoch, metrics):
        raise Pruned

    with pytest.raises(Pruned):
        fit(build_model(ModelConfig(arch="D8-V8-V")), TrainingData(x, y), TrainingConfig(**FAST), callback=cb)


def test_bad_inputs_name_the_field(data):
    x, y, groups = data
    m = build_model(ModelConfig())
    with pytest.raises(InputError, match=r"^x:"):
        fit(m, TrainingData(x[:, :1], y), TrainingConfig(**FAST))
    with pytest.raises(InputError, match=r"^y:"):
        fit(m, TrainingData(x, y[:-1]), TrainingConfig(**FAST))
    with pytest.raises(InputError, match="groups"):
        fit(m, TrainingData(x, y, groups=groups[:-1]), TrainingConfig(**FAST))
    with pytest.raises(InputError, match="recalibrate"):
        fit(m, TrainingData(x, y), TrainingConfig(**FAST, recalibrate="validation"))
    bad = y.copy()
    bad[0, 0] = np.nan
    with pytest.raises(InputError):
        fit(m, TrainingData(x, bad), TrainingConfig(**FAST))


def test_recalibrate_on_validation(data):
    x, y, _ = data
    xv, yv, gv = syn.repeated_rows(syn.random_points(8, seed=3), 30, seed=4)
    m = build_model(ModelConfig(arch="D8-V8-V"))
    h = fit(
        m,
        TrainingData(x, y),
        TrainingConfig(**FAST, recalibrate="validation"),
        validation=TrainingData(xv, yv, groups=gv),
    )
    stored = float(m.epistemic_scale)
    # The scale fitted afresh on the validation rows (recalibrate_epistemic starts from scale 1) is the
    # one fit stored in the model and reported, and it moved away from the default 1.
    refitted = recalibrate_epistemic(m, xv, yv, groups=gv, seed=0)
    assert h.epistemic_scale == pytest.approx(refitted, rel=1e-6)
    assert stored == pytest.approx(refitted, rel=1e-6)
    assert abs(refitted - 1.0) > 0.05


def test_ensemble_members_train_independently(data):
    x, y, _ = data
    m = build_model(ModelConfig(kind="ensemble", arch="D8-D", ensemble_size=3))
    fit(m, TrainingData(x, y), TrainingConfig(**FAST))
    w = m.layers[0].weight
    assert not torch.allclose(w[0], w[1])
    assert m.predict(x[:10]).epistemic_var.min() > 0


@pytest.mark.slow
def test_compiled_step_computes_what_the_eager_step_computes(data):
    """The fused, compiled training step matches torch.optim's update (a deterministic PNN)."""
    x, y, _ = data
    weights = []
    for compiled in (False, True):
        m = build_model(ModelConfig(kind="pnn", arch="D8-D"))
        fit(
            m,
            TrainingData(x, y),
            TrainingConfig(epochs=2, batch_size=100, patience=None, compile=compiled, weight_decay=1e-3),
        )
        weights.append(flat_weights(m))
    torch.testing.assert_close(weights[0], weights[1], rtol=1e-4, atol=1e-5)
    assert not torch.equal(weights[0], flat_weights(build_model(ModelConfig(kind="pnn", arch="D8-D"))))


@pytest.mark.slow
def test_compiled_hybrid_training_is_reproducible(data):
    """The compiled path draws its training noise from the seeded RNG too: same seed, same weights."""
    x, y, _ = data
    weights = []
    for seed in (0, 0, 1):
        m = build_model(ModelConfig(arch="D8-V8-V"))
        fit(
            m,
            TrainingData(x, y),
            TrainingConfig(epochs=2, batch_size=64, patience=None, compile=True),
            seed=seed,
        )
        weights.append(flat_weights(m))
    assert torch.equal(weights[0], weights[1])
    assert not torch.equal(weights[0], weights[2])


def test_training_data_without_some_maneuvers_keeps_rows_logs_and_flags_together():
    """`TrainingData.without`: the rows, logs, log ids and flags of the other maneuvers, in order."""
    ids = np.array([7, 3, 9, 4])
    x = np.arange(12, dtype=float).reshape(12, 1)
    logs = [(np.full((2, 2), i), np.full((2, 2), -i)) for i in ids]
    flags = [True, False, True, False]
    data = TrainingData(x, -x, np.repeat(ids, 3), logs=logs, log_groups=list(ids), of_another_car=flags)
    kept = data.without(np.array([3, 9]))
    np.testing.assert_array_equal(kept.x[:, 0], [0, 1, 2, 9, 10, 11])
    np.testing.assert_array_equal(kept.y, -kept.x)
    np.testing.assert_array_equal(kept.groups, [7, 7, 7, 4, 4, 4])
    assert kept.log_groups == [7, 4] and kept.of_another_car == [True, False]
    assert [int(u[0, 0]) for u, _ in kept.logs] == [7, 4] and kept.windows is None


def test_a_network_has_no_kind_specific_steps(data):
    """The model hooks' neutral defaults: a network identifies nothing, gates nothing, records nothing
    of its own, and `fit` leaves it exactly as it would without them."""
    x, y, groups = data
    net = build_model(ModelConfig(arch="D8-V8-V"))
    assert not net.identifies_on_logs and net.is_variational()
    assert net.round_metrics() == {} and net.physical_parameters() == {}
    assert not net.gates_correction(TrainingData(x, y, groups, logs=[(x[:, :2], y)], log_groups=[0]))
    h = fit(net, TrainingData(x, y, groups), TrainingConfig(**FAST))
    assert (h.correction_weight, h.gate_errors) == (1.0, {})
