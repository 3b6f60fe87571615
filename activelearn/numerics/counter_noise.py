"""Counter-based Gaussian noise for surrogate rollouts: Philox4x32-10 and Box-Muller, in NumPy.

The noise of step t of maneuver m in the trajectory keyed `key` is a pure function of (key, m, t).
So a maneuver's noise does not depend on the other maneuvers in the batch, on padding, or on which
thread computes it, and the compiled kernel (`activelearn/numerics/native/static_rollout.c`) and this
reference draw the same numbers, up to the last bit of log/sin/cos.

Layout (mirrored in the C kernel): steps go in tiles of TILE; Philox counter
(tile · HALF + p, m, 0, 0) gives 4 words: words 0, 1 make the (v, ω) noise of step p of the tile,
words 2, 3 that of step HALF + p. Each pair of words is one Box-Muller draw on 24-bit uniforms: the
radius's uniform lies in (0, 1], so the largest |z| is √(-2 ln 2⁻²⁴) ≈ 5.8.
"""

from __future__ import annotations

import numpy as np

TILE = 512
HALF = TILE // 2
_M0, _M1 = np.uint64(0xD2511F53), np.uint64(0xCD9E8D57)
_W0, _W1 = 0x9E3779B9, 0xBB67AE85
_MASK = np.uint64(0xFFFFFFFF)
_TWO_POW_M24 = np.float32(2.0**-24)
_ANGLE_SCALE = np.float32(2.0 * np.pi) * _TWO_POW_M24


def philox4x32_10(counter: tuple, key: tuple[int, int]) -> tuple[np.ndarray, ...]:
    """Philox4x32-10 (Salmon et al. 2011) of counter words (each an int or array, broadcast) under a key.

    Returns the 4 random words as uint32 arrays of the broadcast shape.
    """
    c0, c1, c2, c3 = np.broadcast_arrays(*(np.asarray(c, dtype=np.uint64) for c in counter))
    k0, k1 = int(key[0]) & 0xFFFFFFFF, int(key[1]) & 0xFFFFFFFF
    for _ in range(10):
        p0, p1 = _M0 * c0, _M1 * c2  # < 2⁶⁴: exact in uint64
        c0, c1, c2, c3 = (
            (p1 >> 32) ^ c1 ^ np.uint64(k0),
            p1 & _MASK,
            (p0 >> 32) ^ c3 ^ np.uint64(k1),
            p0 & _MASK,
        )
        k0, k1 = (k0 + _W0) & 0xFFFFFFFF, (k1 + _W1) & 0xFFFFFFFF
    return tuple(c.astype(np.uint32) for c in (c0, c1, c2, c3))


def _box_muller(radius_word: np.ndarray, angle_word: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    uniform = ((radius_word >> 8) + 1).astype(np.float32) * _TWO_POW_M24
    radius = np.sqrt(np.float32(-2.0) * np.log(uniform))
    angle = (angle_word >> 8).astype(np.float32) * _ANGLE_SCALE
    return radius * np.cos(angle), radius * np.sin(angle)


def step_noise(key: int, n_maneuvers: int, n_steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Standard normal (v, ω) noise of one trajectory: two float32 arrays of shape (M, T)."""
    n_tiles = -(-n_steps // TILE)
    pair = np.arange(n_tiles * HALF, dtype=np.uint64)[None, :]
    maneuver = np.arange(n_maneuvers, dtype=np.uint64)[:, None]
    words = philox4x32_10((pair, maneuver, 0, 0), (key & 0xFFFFFFFF, key >> 32))
    first, second = _box_muller(words[0], words[1]), _box_muller(words[2], words[3])

    def steps(half_a: np.ndarray, half_b: np.ndarray) -> np.ndarray:
        tiles = np.stack([h.reshape(n_maneuvers, n_tiles, HALF) for h in (half_a, half_b)], axis=2)
        return tiles.reshape(n_maneuvers, n_tiles * TILE)[:, :n_steps]

    return steps(first[0], second[0]), steps(first[1], second[1])
