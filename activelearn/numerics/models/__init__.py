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
)
from activelearn.numerics.models.persistence import load_model, save_model
from activelearn.numerics.models.physics import PhysicsModel
from activelearn.numerics.models.registry import MODEL_CLASSES, build_model, model_class
from activelearn.numerics.models.residual import ResidualModel

__all__ = [
    "BNN",
    "DNN",
    "MODEL_CLASSES",
    "PBNN",
    "PNN",
    "BayesianLinear",
    "DeepEnsemble",
    "DenseLinear",
    "HybridPBNN",
    "LayerSpec",
    "Model",
    "PhysicsModel",
    "Prediction",
    "RecurrentPBNN",
    "ResidualModel",
    "SampledModel",
    "StackModel",
    "build_model",
    "load_model",
    "model_class",
    "parse_arch",
    "resolve_arch",
    "save_model",
]
