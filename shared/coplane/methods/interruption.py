"""Ranging interruption (paper Sec. 5.3): which inter-vehicle ranges an experiment removes.

"Randomly remove 20 %, 40 %, ... of inter-node ranging measurements between each pair": decided per
(pair, epoch index) from (seed, pair) alone, so an offline run and a streaming server drop exactly
the same ranges. Epoch indices are cut into blocks of `block` epochs; each (pair, block) gets a
seeded random permutation of its epochs and the first round(rate * block) of them are dropped. So
per pair the removed share is exactly `rate` over every full block (of epochs where the pair had a
range at all: close to `rate`), at random epochs.
"""

from __future__ import annotations

import functools
import zlib

import numpy as np

from coplane.errors import ConfigError

INTERRUPTION_BLOCK = 100


def _check_rate(rate: float) -> float:
    r = float(rate)
    if not 0.0 <= r <= 1.0:
        raise ConfigError(f"interruption rate must be in [0, 1], got {rate!r}")
    return r


@functools.lru_cache(maxsize=4096)
def _block_ranks(seed: int, a: str, b: str, block_index: int, block: int) -> np.ndarray:
    """Rank of each epoch of one (pair, block) in a seeded random permutation."""
    rng = np.random.default_rng(
        [seed & 0xFFFFFFFF, zlib.crc32(a.encode()), zlib.crc32(b.encode()), block_index]
    )
    ranks = np.empty(block, dtype=np.int64)
    ranks[rng.permutation(block)] = np.arange(block)
    ranks.setflags(write=False)
    return ranks


def interrupt_range(
    pair: tuple[str, str], epoch_index: int, rate: float, seed: int = 0, *, block: int = INTERRUPTION_BLOCK
) -> bool:
    """True when the range of `pair` at `epoch_index` is removed (order of the pair irrelevant)."""
    r = _check_rate(rate)
    if r <= 0.0:
        return False
    if r >= 1.0:
        return True
    if epoch_index < 0:
        raise ConfigError(f"epoch index must be >= 0, got {epoch_index}")
    a, b = sorted(pair)
    bi, pos = divmod(int(epoch_index), block)
    return bool(_block_ranks(int(seed), a, b, bi, block)[pos] < round(r * block))
