"""The seed streams keep the recipes campaigns were recorded with (the same seeds, the same campaigns)."""

from __future__ import annotations

import zlib

import numpy as np
import pytest

from activelearn.seeds import Stream, derived_rng, derived_seed


@pytest.mark.parametrize("seed", [0, 7, 123456])
def test_each_stream_keeps_its_recipe(seed):
    assert derived_seed(seed, Stream.ROUND, 3) == seed * 10_007 + 3
    assert derived_seed(seed, Stream.PRIOR) == seed * 10_007 + 0x9210
    name = "step_0.50_+0.20_4.0s"
    noise = np.random.SeedSequence([seed, zlib.crc32(name.encode())]).generate_state(1)[0]
    assert derived_seed(seed, Stream.NOISE, name) == int(noise)
    cases = [
        (derived_rng(seed, Stream.INITIAL), [seed, 0x1D]),
        (derived_rng(seed, Stream.PICKS, 4), [seed, 4, 0x5E1]),
        (derived_rng(seed, Stream.TEST_SPLIT), [seed, 0x7E57]),
        (derived_rng(seed, Stream.FAMILY, "chirp"), [seed, zlib.crc32(b"chirp")]),
    ]
    for rng, entropy in cases:
        expected = np.random.default_rng(entropy).integers(0, 2**32, 4)
        assert rng.integers(0, 2**32, 4).tolist() == expected.tolist()


def test_streams_differ_and_keys_are_checked():
    # NOISE and FAMILY share a recipe (seed, crc32 of a name): a maneuver's name and a family's differ.
    keys = {Stream.NOISE: "step_0.50_+0.20_4.0s", Stream.FAMILY: "chirp"}
    draws = {s: derived_rng(1, s, keys.get(s, 0)).random() for s in Stream}
    assert len(set(draws.values())) == len(Stream)
    with pytest.raises(TypeError):
        derived_seed(1, Stream.ROUND, "a")
    with pytest.raises(TypeError):
        derived_seed(1, Stream.NOISE, 2)
