"""Bayesian layers, the hybrid PBNN and its baselines, all behind one `Model` interface."""

from activelearn.numerics.arch import LayerSpec, parse_arch, resolve_arch
from activelearn.numerics.models.base import Model, Prediction, SampledModel
from activelearn.numerics.models.layers import BayesianLinear, DenseLinear
from activelearn.numerics.models.networks import (
    BNN,
    DNN,
    PBNN,
    PNN,
    DeepEnsemble,
    HybridPBNN,
    RecurrentPBNN,
    StackModel,
    build_model,
)
from activelearn.numerics.models.persistence import load_model, save_model
from activelearn.numerics.models.residual import ResidualModel

__all__ = [
    "BNN",
    "DNN",
    "PBNN",
    "PNN",
    "BayesianLinear",
    "DeepEnsemble",
    "DenseLinear",
    "HybridPBNN",
    "LayerSpec",
    "Model",
    "Prediction",
    "RecurrentPBNN",
    "ResidualModel",
    "SampledModel",
    "StackModel",
    "build_model",
    "load_model",
    "parse_arch",
    "resolve_arch",
    "save_model",
]
