"""The numerics: Bayesian models, training, uncertainty metrics, the surrogate and its compiled kernels.

Knows nothing of campaigns, strategies or tracking; depends only on `activelearn.config` (the model
and training sections), `activelearn.errors` and the scientific stack.
"""
