"""The active-learning loop: candidate pools, collection, acquisition strategies and the campaign.

Reads config objects and drives the numerics (models, training, uncertainty) and the simulator; never
imports MLflow or Optuna (a tracker is handed in by the studies on top).
"""
