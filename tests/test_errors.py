"""User-mistake errors cross process boundaries whole (compare's and tune's workers raise them)."""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor

import pytest

from activelearn.errors import ConfigError, InputError


def _raise(kind: type[InputError]) -> None:
    raise kind("model.core", "dynamic", "a reason")


@pytest.mark.parametrize("kind", [InputError, ConfigError])
def test_an_error_raised_in_a_worker_process_reaches_the_caller_with_its_field(kind: type[InputError]):
    with ProcessPoolExecutor(max_workers=1) as pool:
        with pytest.raises(kind) as caught:
            pool.submit(_raise, kind).result()
    error = caught.value
    assert (error.field, error.value, error.reason) == ("model.core", "dynamic", "a reason")
    assert str(caught.value) == "model.core: a reason (got 'dynamic')"
