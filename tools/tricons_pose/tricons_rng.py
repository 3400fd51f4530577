"""The runtime's random number generator and point sampler, in Python.

A port of ``src/rng.rs`` (SplitMix64 seeding xoshiro256**, ``mix_seed``)
and of ``sample_indices`` in ``src/pose/preprocess.rs``, so that the PyTorch
evaluation can draw exactly the points ``tricons replay`` draws
(``python -m tricons_pose.predict --sampler tricons``) and the two runtimes
can be compared on identical inputs. Pure integer arithmetic, bit-exact;
tests/fixtures/rng/sequences.json pins the sequences on both sides.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

MASK64 = (1 << 64) - 1
GOLDEN_GAMMA = 0x9E3779B97F4A7C15
MIX_SEED_INIT = 0x5EED5EED5EED5EED


def _rotl(x: int, k: int) -> int:
    return ((x << k) | (x >> (64 - k))) & MASK64


def splitmix64(state: int) -> tuple[int, int]:
    """One SplitMix64 step: ``(new_state, output)``."""
    state = (state + GOLDEN_GAMMA) & MASK64
    z = state
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & MASK64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK64
    return state, z ^ (z >> 31)


def mix_seed(words: Sequence[int]) -> int:
    """Mixes several 64-bit words into one seed (``tricons::rng::mix_seed``)."""
    state, acc = MIX_SEED_INIT, 0
    for w in words:
        state ^= w & MASK64
        state, out = splitmix64(state)
        acc = out ^ _rotl(acc, 17)
    return acc


class TriconsRng:
    """xoshiro256** seeded by SplitMix64 (``tricons::rng::Rng``)."""

    def __init__(self, seed: int):
        st, s = seed & MASK64, []
        for _ in range(4):
            st, out = splitmix64(st)
            s.append(out)
        if s == [0, 0, 0, 0]:
            s[0] = 1
        self.s = s

    @classmethod
    def from_words(cls, words: Sequence[int]) -> "TriconsRng":
        """The generator of the stream identified by ``words`` (``Rng::from_words``)."""
        return cls(mix_seed(words))

    def next_u64(self) -> int:
        """The next 64 random bits."""
        s = self.s
        result = (_rotl((s[1] * 5) & MASK64, 7) * 9) & MASK64
        t = (s[1] << 17) & MASK64
        s[2] ^= s[0]
        s[3] ^= s[1]
        s[1] ^= s[2]
        s[0] ^= s[3]
        s[2] ^= t
        s[3] = _rotl(s[3], 45)
        return result

    def below(self, n: int) -> int:
        """Uniform integer in [0, n) by multiply-shift (``Rng::below``)."""
        return (self.next_u64() * n) >> 64

    def sample_indices(self, n_valid: int, n: int) -> np.ndarray:
        """``n`` indices into ``n_valid`` points: a partial Fisher-Yates shuffle without
        replacement when ``n_valid >= n``, else ``n`` independent draws (``sample_indices``)."""
        if n_valid >= n:
            perm = list(range(n_valid))
            for i in range(n):
                j = i + self.below(n_valid - i)
                perm[i], perm[j] = perm[j], perm[i]
            return np.asarray(perm[:n], dtype=np.int64)
        return np.asarray([self.below(n_valid) for _ in range(n)], dtype=np.int64)


def instance_rng(seed: int, frame_index: int, instance_index: int) -> TriconsRng:
    """The stream ``tricons replay --seed seed`` samples instance ``instance_index`` (position
    in the frame's annotation list) of frame ``frame_index`` with."""
    return TriconsRng.from_words([mix_seed([seed, frame_index]), instance_index])


__all__ = ["TriconsRng", "instance_rng", "mix_seed", "splitmix64"]
