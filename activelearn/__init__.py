"""activelearn: active learning of a calibrated Bayesian surrogate of vehicle dynamics."""

__version__ = "0.1.0"
