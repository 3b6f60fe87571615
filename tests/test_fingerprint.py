"""Refactors change no arithmetic: small campaigns of the loop's main paths learn what they learnt
when their fingerprints were stored (`python -m tests.fingerprint --write` stores them anew, for a
change meant to alter what is learnt; say so in its commit). The maneuvers and rows must agree
exactly; the metrics to `RELATIVE`, since another CPU sums float32 in another order."""

from __future__ import annotations

import json

import pytest

from tests.fingerprint import SETTINGS, STORED, differences, run


@pytest.mark.parametrize("name", [s[0] for s in SETTINGS])
def test_a_small_campaign_learns_what_its_stored_fingerprint_says(name):
    differ = differences(run(name), json.loads(STORED.read_text())[name])
    assert not differ, "; ".join(differ)


def test_the_comparison_takes_another_cpus_float_order_but_not_another_round_or_row():
    stored = json.loads(STORED.read_text())["smoke_uniform"]
    first = stored["rounds"][0]
    float_order = {**stored, "rounds": [{**first, "test_rmse": first["test_rmse"] * (1 + 3e-5)},
                                        *stored["rounds"][1:]]}  # fmt: skip
    assert differences(float_order, stored) == []
    learnt_else = {**stored, "rounds": [{**first, "test_rmse": first["test_rmse"] * 1.001},
                                        *stored["rounds"][1:]]}  # fmt: skip
    assert differences(learnt_else, stored) == [
        f"round 0 test_rmse: {first['test_rmse'] * 1.001} != {first['test_rmse']}"]
    assert differences({**stored, "samples_sha256": "0" * 64}, stored)
    assert differences({**stored, "rounds": stored["rounds"][:-1]}, stored)
    assert differences({**stored, "batches": stored["batches"][::-1]}, stored)
