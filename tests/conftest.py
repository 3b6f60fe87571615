"""Shared fixtures."""

from __future__ import annotations

import os

import pytest

POSTGRES_ENV = "ACTIVELEARN_TEST_POSTGRES_URL"


@pytest.fixture(scope="session")
def postgres_url() -> str:
    """URL of a PostgreSQL database the tests may write to (set up by .ci/run).

    Without it the test is skipped on a developer machine, but fails in CI (`CI` set): there the
    server is part of the job, and a silently skipped test would hide that it did not start.
    """
    url = os.environ.get(POSTGRES_ENV)
    if not url:
        message = f"{POSTGRES_ENV} is not set: run the suite through .ci/run, which starts PostgreSQL"
        if os.environ.get("CI"):
            pytest.fail(message)
        pytest.skip(message)
    return url
