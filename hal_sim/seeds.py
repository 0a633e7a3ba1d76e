"""Every trial's seed, from (study seed, condition, trial index) alone (``hal_sim.studies``)."""

from __future__ import annotations

import numpy as np


def trial_seeds(base_seed: int, condition: int, first: int, count: int) -> np.ndarray:
    """One 32-bit seed per trial from (study seed, condition, trial index) only:
    ``np.random.SeedSequence([base_seed, condition, t]).generate_state(1)[0]``, computed for
    the whole range at once (``_seed_sequences``; 52,500 SeedSequence objects cost the
    landmark study's parent half a second)."""
    last = first + count - 1
    if (
        count > 0
        and min(base_seed, condition, first) >= 0
        and max(base_seed, condition, last) < (1 << 32)
    ):
        return _seed_sequences(base_seed, condition, np.arange(first, first + count))
    return np.array(
        [
            np.random.SeedSequence([base_seed, condition, t]).generate_state(1)[0]
            for t in range(first, first + count)
        ],
        dtype=np.int64,
    )


# numpy's SeedSequence (numpy/random/bit_generator.pyx), for entropy of three 32-bit words.
_INIT_A, _MULT_A = np.uint32(0x43B0D7E5), np.uint32(0x931E8875)
_INIT_B, _MULT_B = np.uint32(0x8B51F9DD), np.uint32(0x58F38DED)
_MIX_L, _MIX_R = np.uint32(0xCA01F9DD), np.uint32(0x4973F715)
_POOL = 4


def _seed_sequences(base_seed: int, condition: int, trials: np.ndarray) -> np.ndarray:
    """``SeedSequence([base_seed, condition, t]).generate_state(1)[0]`` for every t of
    ``trials`` (all three below 2^32: one word each), as int64; numpy's hash, vectorised."""
    n = trials.shape[0]
    entropy = [
        np.full(n, base_seed, dtype=np.uint32),
        np.full(n, condition, dtype=np.uint32),
        trials.astype(np.uint32),
    ]
    hash_const = _INIT_A

    def hashmix(value: np.ndarray) -> np.ndarray:
        nonlocal hash_const
        value = value ^ hash_const
        hash_const = np.uint32(hash_const * _MULT_A)
        value = value * hash_const
        return value ^ (value >> np.uint32(16))

    def mix(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        r: np.ndarray = _MIX_L * x - _MIX_R * y
        return r ^ (r >> np.uint32(16))

    with np.errstate(over="ignore"):
        mixer = [
            hashmix(entropy[i] if i < 3 else np.zeros(n, dtype=np.uint32)) for i in range(_POOL)
        ]
        for i_src in range(_POOL):
            for i_dst in range(_POOL):
                if i_src != i_dst:
                    mixer[i_dst] = mix(mixer[i_dst], hashmix(mixer[i_src]))
        value = mixer[0] ^ _INIT_B
        value = value * np.uint32(_INIT_B * _MULT_B)
        value = value ^ (value >> np.uint32(16))
    return value.astype(np.int64)
