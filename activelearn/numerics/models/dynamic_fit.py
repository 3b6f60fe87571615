"""The dynamic core's scales (`dynamic_scales.parameters_of`: five, nine with the kinematic core) identified
from logs (`identify_dynamic`), its misfit of them in and out of sample, and each log's Fisher
information about the scales: output error of the core's free
runs (`dynamic_track.rate_runs`), restarted from the recorded rates every `horizon` s, MAP under the
file's prior (`single_track._map_fit`) with the cluster-robust covariance, each log a cluster."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from activelearn.numerics.models.dynamic_scales import dynamic_bounds, parameters_of, scaled
from activelearn.numerics.models.dynamic_track import DynamicCar, quasi_static_lateral, rate_runs
from activelearn.numerics.models.single_track import (
    Identified,
    _map_fit,
    cross_validated_rms,
    rms_of,
    stacked_logs,
    usable_logs,
)


def _restart_errors(
    logs: list[tuple[np.ndarray, np.ndarray]], car: DynamicCar, dt: float, every: int, horizon: float | None,
    implicit: bool,
) -> tuple[Callable[[np.ndarray], np.ndarray], np.ndarray, np.ndarray]:  # fmt: skip
    """An identification's free runs of `logs` (see `identify_dynamic`): `errors_of(sets (P, scales))` → rate
    errors (P, n, 2) at the compared steps, the error rows' clusters (their log) and the rates' spread."""
    owners, wheels = list(range(len(logs))), [u[0, 1] for u, _ in logs]
    if horizon is not None:
        steps = max(2, round(horizon / dt))
        cut = [(i, u[k : k + steps + 1], y[k : k + steps + 1], u[max(k - 1, 0), 1])
               for i, (u, y) in enumerate(logs) for k in range(0, len(u) - 1, steps)]  # fmt: skip
        cut = [piece for piece in cut if len(piece[1]) > 1]
        owners, wheels = [i for i, *_ in cut], [wheel for *_, wheel in cut]
        logs = [(u, y) for _, u, y, _ in cut]
    controls, rates, valid, keep = stacked_logs(logs, every)

    def errors_of(sets: np.ndarray) -> np.ndarray:  # (P, n, 2)
        cars = scaled(car, sets)
        # each run starts at its recorded rates, v_y of a steady turn there, the wheels at the command
        # before its first step (where the log has one)
        v, r = rates[:, 0, 0], rates[:, 0, 1]
        lateral = quasi_static_lateral(cars, v, r)  # (P, M)
        start = np.stack(np.broadcast_arrays(v, lateral, r, np.asarray(wheels)), axis=-1)
        predicted = rate_runs(cars, controls, start, dt, implicit)
        return np.nan_to_num(predicted - rates, nan=1e3, posinf=1e3, neginf=-1e3)[:, keep]

    clusters = np.asarray(owners)[np.nonzero(keep)[0]]  # a log's windows share its cluster
    return errors_of, clusters, rates[valid].std(axis=0)


def identify_dynamic(
    logs: list[tuple[np.ndarray, np.ndarray]], car: DynamicCar, dt: float, every: int = 3,
    horizon: float | None = None, search_from: np.ndarray | None = None, implicit: bool = False,
    prior: Identified | None = None, loss: str = "squares", also_from_prior: bool = False,
) -> Identified:
    """Output-error MAP of the car's scales (`parameters_of`: of the file's figures, the file as the
    prior) from logs, (controls (T, 2), rates (T, 2) = speed, yaw rate), as the kinematic core's
    `identify_from_logs` does: free runs from each log's first recorded rates (lateral speed: a steady
    turn's there, `quasi_static_lateral`; the wheels at the command before), every `every`-th step
    compared, each log a cluster of the covariance. `horizon` (s): free runs restart
    from the recorded rates every `horizon` s instead (a spinning car's 30 s are chaotic in the
    parameters; a few seconds are not). `search_from`: where the search begins (default the file);
    `implicit`: free runs by the step with implicit tyre damping (the physics kind's); `prior`: the
    Gaussian prior instead of the file's (another car's estimate, `single_track.widened`); `loss`:
    `single_track._map_fit`'s ("cauchy": rows no parameter set fits weigh less); `also_from_prior`: with
    `search_from`, the search also starts from the prior's centre, the lower objective kept (`_map_fit`)."""
    logs = usable_logs(logs)
    bounds = dynamic_bounds(car)
    prior = prior or bounds.prior
    if not logs:
        return Identified(prior.values.copy(), prior.covariance.copy())
    errors_of, clusters, spread = _restart_errors(logs, car, dt, every, horizon, implicit)
    return _map_fit(errors_of, spread, clusters, prior, search_from, bounds, loss, also_from_prior)


def _squared_misfit(
    logs: list[tuple[np.ndarray, np.ndarray]], car: DynamicCar, dt: float, theta: np.ndarray, every: int,
    horizon: float | None, implicit: bool,
) -> tuple[np.ndarray, int]:  # fmt: skip
    """The summed squared rate errors (2,) of `identify_dynamic`'s free runs at scales `theta`, and their
    number."""
    errors_of, _, _ = _restart_errors(logs, car, dt, every, horizon, implicit)
    errors = errors_of(np.asarray(theta, np.float64)[None])[0]
    return (errors**2).sum(axis=0), len(errors)


def misfit(
    logs: list[tuple[np.ndarray, np.ndarray]], car: DynamicCar, dt: float, theta: np.ndarray, every: int = 3,
    horizon: float | None = None, implicit: bool = False,
) -> np.ndarray:  # fmt: skip
    """(2,) the rms rate errors (v m/s, r rad/s) of `identify_dynamic`'s free runs at scales `theta`:
    what the core, so identified, still misses of its own logs (the sensors' noise included); zeros
    without logs."""
    logs = usable_logs(logs)
    if not logs:
        return np.zeros(2)
    return rms_of(*_squared_misfit(logs, car, dt, theta, every, horizon, implicit))


def cross_validated_misfit(
    logs: list[tuple[np.ndarray, np.ndarray]], car: DynamicCar, dt: float, theta: np.ndarray, folds: int = 4,
    every: int = 3, horizon: float | None = None, implicit: bool = False, loss: str = "squares",
) -> np.ndarray:  # fmt: skip
    """(2,) `misfit` out of sample: the logs in min(`folds`, logs) folds (in their order), each fold's
    errors at the scales identified on the others (by `loss`, searched from `theta`, the fit on all). A
    core fitted to a few logs misses maneuvers unlike them by more than its own (after a 1:10 cold
    start's 4 signals: 0.12 m/s against 0.028). One log: the in-sample misfit."""
    logs = usable_logs(logs)
    if not logs:
        return np.zeros(2)

    def squared(some: list[tuple[np.ndarray, np.ndarray]], at: np.ndarray) -> tuple[np.ndarray, int]:
        return _squared_misfit(some, car, dt, at, every, horizon, implicit)

    def refit(rest: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
        return identify_dynamic(rest, car, dt, every, horizon, theta, implicit, loss=loss).values

    return cross_validated_rms(logs, theta, refit, squared, folds)


def log_information(
    logs: list[tuple[np.ndarray, np.ndarray]], car: DynamicCar, dt: float, theta: np.ndarray,
    noise: np.ndarray, every: int = 3, horizon: float | None = None, implicit: bool = False,
    step: float = 1e-5,
) -> np.ndarray:  # fmt: skip
    """(L, P, P) each log's Fisher information about the car's P scales at `theta`: Σ Jᵀ diag(noise⁻²) J over
    the rows of `identify_dynamic`'s free runs of it (the same restarts and spacing), J the rates'
    forward differences in the scales (`step` × each parameter's prior width, inwards at an upper
    bound, as the identification's Jacobian). `noise` (2,): the rates' error sizes (v m/s, r rad/s).
    Every log needs at least two steps."""
    if any(len(u) < 2 for u, _ in logs):
        raise ValueError("every log needs at least two steps")
    count = len(parameters_of(car))
    info = np.zeros((len(logs), count, count))
    if not logs:
        return info
    bounds = dynamic_bounds(car)
    errors_of, clusters, _ = _restart_errors(usable_logs(logs), car, dt, every, horizon, implicit)
    theta = np.clip(np.asarray(theta, np.float64), bounds.low, bounds.high)
    h = step * bounds.width
    h = np.where(theta + h > bounds.high, -h, h)
    errors = errors_of(np.vstack([theta, theta + np.diag(h)]))  # (1 + count, n, 2)
    weighted = (errors[1:] - errors[0]) / h[:, None, None] / np.asarray(noise, np.float64)  # (count, n, 2)
    np.add.at(info, clusters, np.einsum("inr,jnr->nij", weighted, weighted))
    return info
