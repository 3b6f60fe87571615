"""Every random stream a campaign derives from its seed, by name: one recipe each, written once.

A campaign's seed (or its pool's seed) feeds several independent streams: each round's training and
fan, the prior's training, each maneuver's sensor noise, the first batch, each round's picks, the
test split of recorded logs, each family's pool draw. Every site asks this module for its stream
(`derived_seed` for an integer seed, `derived_rng` for a generator) instead of writing a recipe by
hand, so two sites that must share a stream (a round's model and the safety figure's fan) cannot
drift apart. The recipes are the ones campaigns have always used, so the same seeds keep giving the
same campaigns bit for bit (tests/test_fingerprint.py).

It imports nothing of the project (numpy and the standard library only).
"""

from __future__ import annotations

import zlib
from enum import Enum

import numpy as np

# The multiplier that spreads campaign seeds apart before a round index or tag is added.
_SPREAD = 10_007


class Stream(Enum):
    """A stream derived from a seed; its key (a round index, a name) says which draw of the stream."""

    ROUND = "round"  # a round's model: its training and the fan drawn from it (key: the round index)
    PRIOR = "prior"  # the prior model trained on the prior's rows (no key)
    NOISE = "noise"  # one maneuver's sensor noise, whoever collects it and when (key: its name)
    INITIAL = "initial"  # the first batch's greedy maximin (no key)
    PICKS = "picks"  # a round's acquisition (key: the round index)
    TEST_SPLIT = "test_split"  # which recorded logs are held out as the test set (seed: the pool's)
    FAMILY = "family"  # one maneuver family's pool draw (seed: the pool's; key: the family's name)
    # NOISE and FAMILY share a recipe (seed, crc32 of a name); a maneuver's name is never a family's.


# The tag each stream mixes in (after the seed; PICKS after the seed and the round index).
_TAGS: dict[Stream, int] = {
    Stream.PRIOR: 0x9210,
    Stream.INITIAL: 0x1D,
    Stream.PICKS: 0x5E1,
    Stream.TEST_SPLIT: 0x7E57,
}


def _name_key(key: int | str | None) -> int:
    if not isinstance(key, str):
        raise TypeError(f"this stream's key is a name, not {key!r}")
    return zlib.crc32(key.encode())


def _int_key(key: int | str | None) -> int:
    if isinstance(key, str) or key is None:
        raise TypeError(f"this stream's key is an integer, not {key!r}")
    return int(key)


def _entropy(seed: int, stream: Stream, key: int | str | None) -> list[int]:
    """The entropy a generator of `stream` is seeded with."""
    if stream in (Stream.INITIAL, Stream.TEST_SPLIT):
        return [seed, _TAGS[stream]]
    if stream is Stream.PICKS:
        return [seed, _int_key(key), _TAGS[stream]]
    if stream in (Stream.NOISE, Stream.FAMILY):
        return [seed, _name_key(key)]
    raise ValueError(f"{stream} is an integer seed: use derived_seed")


def derived_seed(seed: int, stream: Stream, key: int | str | None = None) -> int:
    """The integer seed of one draw of `stream` (the seed a model's `fit` or a fan takes)."""
    if stream is Stream.ROUND:
        return seed * _SPREAD + _int_key(key)
    if stream is Stream.PRIOR:
        return seed * _SPREAD + _TAGS[stream]
    return int(np.random.SeedSequence(_entropy(seed, stream, key)).generate_state(1)[0])


def derived_rng(seed: int, stream: Stream, key: int | str | None = None) -> np.random.Generator:
    """A generator for one draw of `stream` (a batch's picks, a split, a family's pool)."""
    if stream in (Stream.ROUND, Stream.PRIOR):
        return np.random.default_rng(derived_seed(seed, stream, key))
    return np.random.default_rng(_entropy(seed, stream, key))
