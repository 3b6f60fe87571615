"""Where the campaigns of a comparison run: local processes, or tasks on a Ray cluster.

Every executor runs the same job function on the same arguments and hands each job's result back as
it finishes, so a comparison's per-round metrics do not depend on where it ran. A Ray task that loses
its worker (node gone, process killed) is retried by Ray (`max_retries`); its campaign then resumes
from its last checkpoint in the shared output directory, so a lost worker costs at most one round.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any

from activelearn.errors import InputError
from activelearn.studies.processes import with_environment, worker_context

EXECUTORS = ("process", "ray")
# Ray retries a task whose worker died this many times (the campaign resumes each time).
RAY_MAX_RETRIES = 3


def check_executor(executor: str, ray_address: str | None) -> None:
    """Reject an unknown executor, a Ray address without Ray, or Ray missing, before anything runs."""
    if executor not in EXECUTORS:
        raise InputError("--executor", executor, f"choose from {', '.join(EXECUTORS)}")
    if executor != "ray":
        if ray_address is not None:
            raise InputError("--ray-address", ray_address, "applies to --executor ray only")
        return
    try:
        import ray  # noqa: F401
    except ImportError:
        raise InputError(
            "--executor", executor, "Ray is not installed: pip install 'activelearn[cluster]'"
        ) from None


def run_jobs(
    job: Callable[..., Any],
    jobs: Sequence[tuple[Any, tuple]],
    *,
    executor: str = "process",
    workers: int = 1,
    ray_address: str | None = None,
    on_start: Callable[[dict[str, Any]], None] | None = None,
) -> Iterator[tuple[Any, Any]]:
    """Run `job(*args)` for every (key, args) of `jobs`; yield (key, result) as each finishes.

    "process": `workers` local processes (`studies.processes`; 1: in this process). "ray": one task per
    job on the cluster at `ray_address` ("auto", "HOST:PORT", or None/"local" for an in-process cluster of
    `workers` CPUs), one CPU each; `on_start` gets {"event": "dashboard", "url": ...} when the
    cluster has a dashboard.
    """
    if executor == "ray":
        yield from _ray_jobs(job, jobs, workers=workers, address=ray_address, on_start=on_start)
    elif workers == 1:  # no process pool: simpler to debug, no start-up cost
        for key, args in jobs:
            yield key, job(*args)
    else:
        with ProcessPoolExecutor(max_workers=workers, mp_context=worker_context()) as pool:
            environment = dict(os.environ)
            futures = {pool.submit(with_environment, environment, job, *args): key for key, args in jobs}
            for future in as_completed(futures):
                yield futures[future], future.result()


def _auth_error_text(exc: BaseException) -> str | None:
    """The text of Ray's token-authentication error in `exc` or what caused it; None if there is none."""
    seen: BaseException | None = exc
    while seen is not None:
        text = str(seen)
        if type(seen).__name__ == "AuthenticationError" or "InvalidAuthToken" in text:
            return text
        seen = seen.__cause__ or seen.__context__
    return None


def join_error(exc: BaseException) -> str:
    """Why `ray.init` could not join a cluster, in one line; a head that wants a token says how to give one.

    A Ray >= 2.59 head started with RAY_AUTH_MODE=token refuses clients without its token; Ray then says
    only "Failed to connect to Ray cluster at <address>", and its token error is in what caused that.
    """
    text = _auth_error_text(exc)
    if text is None:
        return " ".join(str(exc).split()) or type(exc).__name__
    how = (
        "export RAY_AUTH_MODE=token and RAY_AUTH_TOKEN=<the cluster's token> (`ray get-auth-token` on the "
        "head prints it) where you run this command"
    )
    if "no authentication token was found" in text:
        return f"the head wants an auth token and none was found: {how}"
    if "RAY_AUTH_MODE is currently" in text:  # Ray's note when this process is not in token mode
        return f"the head wants an auth token (Ray >= 2.59) and this command sent none: {how}"
    return f"the head wants an auth token and refused this one: {how}"


def _ray_jobs(
    job: Callable[..., Any],
    jobs: Sequence[tuple[Any, tuple]],
    *,
    workers: int,
    address: str | None,
    on_start: Callable[[dict[str, Any]], None] | None,
) -> Iterator[tuple[Any, Any]]:
    import ray

    local = address in (None, "local")
    try:
        context = ray.init(
            address=None if local else address,
            num_cpus=workers if local else None,
            include_dashboard=False if local else None,
            log_to_driver=False,
            configure_logging=False,
        )
    except (ConnectionError, RuntimeError, ValueError, ray.exceptions.RayError) as exc:
        reason = f"cannot join the Ray cluster: {join_error(exc)}"
        raise InputError("--ray-address", address, reason) from None
    try:
        if on_start is not None and getattr(context, "dashboard_url", None):
            on_start({"event": "dashboard", "url": f"http://{context.dashboard_url}"})
        # One CPU per campaign: the job limits itself to one torch thread when it shares a node.
        task = ray.remote(num_cpus=1, max_retries=RAY_MAX_RETRIES)(job)
        pending = {task.remote(*args): key for key, args in jobs}
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            key = pending.pop(done[0])
            yield key, ray.get(done[0])
    finally:
        ray.shutdown()
