"""Bayesian linear layer: KL (closed form vs Monte Carlo), full covariance vs mean-field, sampling."""

from __future__ import annotations

import math

import pytest
import torch

from activelearn.numerics.models.layers import BayesianLinear, DenseLinear, inverse_softplus


def _randomise(layer: BayesianLinear, seed: int = 0) -> None:
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in layer.parameters():
            p.copy_(torch.randn(p.shape, generator=g) * 0.5)
        if layer.posterior == "mean_field":
            layer.weight_rho.copy_(torch.rand(layer.weight_rho.shape, generator=g) * 2 - 3)
            layer.bias_rho.copy_(torch.rand(layer.bias_rho.shape, generator=g) * 2 - 3)
        else:
            layer.scale_rho.copy_(torch.rand(layer.scale_rho.shape, generator=g) * 2 - 3)
            layer.scale_offdiag.mul_(0.05)


def _mf_to_fc(mf: BayesianLinear, **kw) -> BayesianLinear:
    """A full-covariance layer with mf's means and diagonal, zero off-diagonal."""
    fc = BayesianLinear(mf.n_in, mf.n_out, posterior="full_cov", **kw)
    with torch.no_grad():
        fc.weight_mu.copy_(mf.weight_mu)
        fc.bias_mu.copy_(mf.bias_mu)
        fc.scale_rho.copy_(torch.cat([mf.weight_rho.reshape(-1), mf.bias_rho]))
        fc.scale_offdiag.zero_()
    return fc


@pytest.mark.parametrize("posterior", ["mean_field", "full_cov"])
@pytest.mark.parametrize("prior_scale", [1.0, 0.3])
def test_kl_closed_form_matches_monte_carlo(posterior, prior_scale):
    """Test 4: the closed-form KL matches a many-sample Monte Carlo estimate."""
    layer = BayesianLinear(3, 4, posterior=posterior, prior_scale=prior_scale)
    _randomise(layer)
    with torch.no_grad():
        exact = layer.kl_exact().item()
        g = torch.Generator().manual_seed(1)
        mc = layer.kl_mc(200_000, generator=g).item()
    assert exact > 0
    assert mc == pytest.approx(exact, rel=0.01)


def test_kl_is_zero_at_the_prior_and_mc_mode_is_used():
    layer = BayesianLinear(2, 3, prior_scale=0.5, kl="mc", kl_samples=4)
    with torch.no_grad():
        layer.weight_mu.zero_()
        layer.bias_mu.zero_()
        layer.weight_rho.fill_(inverse_softplus(0.5))
        layer.bias_rho.fill_(inverse_softplus(0.5))
    assert layer.kl_exact().item() == pytest.approx(0.0, abs=1e-5)
    assert layer.kl_divergence().item() == pytest.approx(0.0, abs=1e-4)  # q == p: every draw gives 0


def test_kl_mc_gradient_flows_to_posterior_and_trainable_prior():
    layer = BayesianLinear(2, 2, kl="mc", prior_trainable=True)
    layer.kl_divergence().backward()
    assert layer.weight_rho.grad is not None and layer.weight_rho.grad.abs().sum() > 0
    assert isinstance(layer.prior_log_scale, torch.nn.Parameter)
    assert layer.prior_log_scale.grad is not None
    fixed = BayesianLinear(2, 2)
    assert not isinstance(fixed.prior_log_scale, torch.nn.Parameter)
    assert "prior_log_scale" in fixed.state_dict()


def test_full_covariance_with_zero_off_diagonal_equals_mean_field():
    """Test 5: a full-covariance posterior with zero off-diagonal is the mean-field posterior."""
    mf = BayesianLinear(3, 2, prior_scale=0.7)
    _randomise(mf)
    fc = _mf_to_fc(mf, prior_scale=0.7)
    torch.testing.assert_close(fc.scale_tril(), mf.scale_tril())
    torch.testing.assert_close(fc.std_vector(), mf.std_vector())
    torch.testing.assert_close(fc.kl_exact(), mf.kl_exact())
    g1, g2 = torch.Generator().manual_seed(3), torch.Generator().manual_seed(3)
    torch.testing.assert_close(fc.kl_mc(16, generator=g1), mf.kl_mc(16, generator=g2))
    g1, g2 = torch.Generator().manual_seed(4), torch.Generator().manual_seed(4)
    for a, b in zip(fc.sample(8, g1), mf.sample(8, g2), strict=True):
        torch.testing.assert_close(a, b)
    x = torch.randn(5, 3)
    for a, b in zip(fc.output_moments(x), mf.output_moments(x), strict=True):
        torch.testing.assert_close(a, b)
    # Off-diagonal terms do change the posterior (so the comparison above can fail).
    with torch.no_grad():
        fc.scale_offdiag.fill_(0.3)
    assert not torch.allclose(fc.kl_exact(), mf.kl_exact())


@pytest.mark.parametrize("posterior", ["mean_field", "full_cov"])
def test_training_forward_has_the_posterior_moments(posterior):
    """Local reparameterisation / per-row draws: output mean and variance match the closed form."""
    layer = BayesianLinear(3, 2, posterior=posterior)
    _randomise(layer)
    x = torch.randn(4, 3)
    torch.manual_seed(0)
    with torch.no_grad():
        draws = torch.stack([layer(x) for _ in range(20_000)])
        mean, var = layer.output_moments(x)
    torch.testing.assert_close(draws.mean(0), mean, atol=4 * math.sqrt(var.max() / 20_000), rtol=0)
    torch.testing.assert_close(draws.var(0), var, rtol=0.05, atol=0)


def test_mean_field_moments_closed_form():
    layer = BayesianLinear(3, 2)
    _randomise(layer)
    x = torch.randn(6, 3)
    mean, var = layer.output_moments(x)
    sw = torch.nn.functional.softplus(layer.weight_rho)
    sb = torch.nn.functional.softplus(layer.bias_rho)
    torch.testing.assert_close(mean, x @ layer.weight_mu + layer.bias_mu)
    torch.testing.assert_close(var, x.square() @ sw.square() + sb.square())


def test_sample_shapes_and_shared_weights():
    layer = BayesianLinear(3, 2)
    w, b = layer.sample(5, torch.Generator().manual_seed(0))
    assert w.shape == (5, 3, 2) and b.shape == (5, 1, 2)
    w2, _ = layer.sample(5, torch.Generator().manual_seed(0))
    torch.testing.assert_close(w, w2)
    # The sample spread matches the posterior std.
    w, b = layer.sample(40_000, torch.Generator().manual_seed(1))
    std = torch.nn.functional.softplus(layer.weight_rho)
    torch.testing.assert_close(w.std(0), std, rtol=0.03, atol=0)


def test_dense_members_are_independent():
    layer = DenseLinear(3, 4, members=5)
    x = torch.randn(5, 7, 3)
    out = layer(x)
    assert out.shape == (5, 7, 4)
    torch.testing.assert_close(out[2], x[2] @ layer.weight[2] + layer.bias[2])
    assert not torch.allclose(layer.weight[0], layer.weight[1])
