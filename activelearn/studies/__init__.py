"""Studies built on the loop: strategy comparisons, hyperparameter tuning and MLflow tracking.

`tracking` is the only MLflow importer and `tuning` the only Optuna importer of the project.
"""
