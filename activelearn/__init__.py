"""activelearn: active learning of a calibrated Bayesian surrogate of vehicle dynamics.

The package has three rooms (see docs/design/index.md):

- `activelearn.loop`: the active-learning loop (pool, collection, acquisition, campaign);
- `activelearn.studies`: what is built on it (strategy comparisons, tuning, MLflow tracking);
- `activelearn.numerics`: models, training, uncertainty, the surrogate and its compiled kernels;

plus the shared ground floor: `config`, `names` (strategies, metrics, log columns), `errors`, `data`,
`plots`, `terminal` (exit statuses, red lines); and the command line on top (`cli`, one module per
command, and `console`, the console script's entry point).
The names users reach for most are importable from the package itself (loaded on first use, so
`import activelearn` stays cheap):

    from activelearn import Campaign, compare, load_config, tune
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

# Public name -> module that defines it.
_API: dict[str, str] = {
    "Campaign": "activelearn.loop.campaign",
    "CampaignResult": "activelearn.loop.campaign",
    "CampaignConfig": "activelearn.config",
    "load_config": "activelearn.config",
    "compare": "activelearn.studies.compare",
    "tune": "activelearn.studies.tuning",
    "build_model": "activelearn.numerics.models",
    "load_model": "activelearn.numerics.models",
    "save_model": "activelearn.numerics.models",
    "fit": "activelearn.numerics.training",
    "simulate": "activelearn.numerics.surrogate",
}

__all__ = ["__version__", *sorted(_API)]


def __getattr__(name: str) -> Any:
    if name in _API:
        return getattr(importlib.import_module(_API[name]), name)
    raise AttributeError(f"module 'activelearn' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_API])
