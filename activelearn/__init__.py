"""activelearn: active learning of a calibrated Bayesian surrogate of vehicle dynamics.

The package has three rooms (see docs/design/index.md):

- `activelearn.loop`: the active-learning loop (pool, collection, acquisition, campaign);
- `activelearn.studies`: what is built on it (strategy comparisons, tuning, MLflow tracking);
- `activelearn.numerics`: models, training, uncertainty, the surrogate and its compiled kernels;

plus the shared ground floor: `config`, `names` (strategies, metrics, log columns), `errors`, `data`,
`plots`; and the command line on top (`cli`, one module per command).
The names users reach for most are importable from the package itself (loaded on first use, so
`import activelearn` stays cheap):

    from activelearn import Campaign, compare, load_config, tune
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings
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

# Modules that moved when the package was split into rooms: the old import paths keep working (with a
# DeprecationWarning), and so do models pickled under the old paths (e.g. by `mlflow.pytorch`).
MOVED_MODULES: dict[str, str] = {
    **{f"activelearn.{name}": f"activelearn.loop.{name}" for name in ("campaign", "pool", "collection")},
    "activelearn.acquisition": "activelearn.loop.acquisition",
    **{f"activelearn.{name}": f"activelearn.studies.{name}" for name in ("compare", "tracking", "tuning")},
    **{
        f"activelearn.{name}": f"activelearn.numerics.{name}"
        for name in (
            "training",
            "uncertainty",
            "surrogate",
            "buffers",
            "counter_noise",
            "threads",
            "synthetic",
            "models",
            "native",
        )
    },
    **{
        f"activelearn.models.{name}": f"activelearn.numerics.models.{name}"
        for name in ("base", "layers", "networks", "persistence")
    },
    "activelearn.models.spec": "activelearn.numerics.arch",
}


class _MovedModules(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Serve an old module path with the module object at its new path (one module, two names)."""

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> Any:
        if fullname not in MOVED_MODULES:
            return None
        return importlib.util.spec_from_loader(fullname, self)

    def create_module(self, spec: Any) -> Any:
        new = MOVED_MODULES[spec.name]
        warnings.warn(
            f"{spec.name} moved to {new}; import it from there", DeprecationWarning, stacklevel=2
        )
        return importlib.import_module(new)

    def exec_module(self, module: Any) -> None:
        """The module is already executed under its new name."""


if not any(isinstance(finder, _MovedModules) for finder in sys.meta_path):
    # First in line: the path finder would otherwise load a moved submodule a second time, under
    # its old name, through the new package's __path__.
    sys.meta_path.insert(0, _MovedModules())


def __getattr__(name: str) -> Any:
    if name in _API:
        return getattr(importlib.import_module(_API[name]), name)
    raise AttributeError(f"module 'activelearn' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_API])
