"""Refactors change no arithmetic: small campaigns of the loop's main paths learn what they learnt
when their fingerprints were stored (`python -m tests.fingerprint --write` stores them anew, for a
change meant to alter what is learnt; say so in its commit)."""

from __future__ import annotations

import json

import pytest

from tests.fingerprint import SETTINGS, STORED, run


@pytest.mark.parametrize("name", [s[0] for s in SETTINGS])
def test_a_small_campaign_learns_what_its_stored_fingerprint_says(name):
    stored = json.loads(STORED.read_text())[name]
    now = run(name)
    assert now["batches"] == stored["batches"]
    assert now["cuts"] == stored["cuts"]
    assert (now["n_rows"], now["samples_sha256"]) == (stored["n_rows"], stored["samples_sha256"])
    for index, (got, want) in enumerate(zip(now["rounds"], stored["rounds"], strict=True)):
        differ = [f"{k} {got.get(k)} != {want.get(k)}" for k in sorted(set(got) | set(want))
                  if got.get(k) != want.get(k)]  # fmt: skip
        assert not differ, f"round {index}: " + ", ".join(differ)
