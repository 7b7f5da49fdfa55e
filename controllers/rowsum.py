"""Masked row sums equal to the bit to numpy's sum of each row's selected values.

``np.sum(x[mask])`` of one robot's values and a sum over a batch of robots in one call
round differently unless they add the same numbers in the same order: numpy sums a
contiguous run of floats pairwise (blocks of eight partial sums, halves past 128 values;
numpy/_core/src/umath/loops_utils.h.src, ``pairwise_sum``). :func:`masked_row_sums`
follows that order for every row at once, so a controller stepping many robots with numpy
gives the commands its per-robot step gives, byte for byte.
"""
from __future__ import annotations

import numpy as np

#: numpy's pairwise-summation block (PW_BLOCKSIZE): longer runs are split in halves
_BLOCK = 128


def masked_row_sums(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Per row ``i``: ``np.sum(values[i][mask[i]])``, bit for bit (float64)."""
    values = np.asarray(values, dtype=np.float64)
    mask = np.asarray(mask, dtype=bool)
    if values.ndim != 2 or values.shape != mask.shape:
        raise ValueError(f"values {values.shape} and mask {mask.shape}: need the same 2-D shape")
    rows, width = values.shape
    n = mask.sum(axis=1)
    # each row's selected values moved to its front, in order (the rest: zeros, never added)
    packed = np.zeros((rows, width + 8), dtype=np.float64)
    packed[:, :width][np.arange(width)[None, :] < n[:, None]] = values[mask]
    # numpy starts a sum from its identity, 0.0 (so a sum of -0.0 values is +0.0)
    return 0.0 + _pairwise(packed, np.zeros(rows, dtype=np.intp), n)


def _pairwise(a: np.ndarray, start: np.ndarray, n: np.ndarray) -> np.ndarray:
    """The pairwise sum of ``a[i, start[i]:start[i] + n[i]]`` for every row ``i``."""
    out = np.empty(len(n), dtype=np.float64)
    big = n > _BLOCK
    if big.any():
        half = n[big] // 2
        half -= half % 8
        out[big] = (_pairwise(a[big], start[big], half)
                    + _pairwise(a[big], start[big] + half, n[big] - half))
    small = ~big
    if small.any():
        out[small] = _leaf(a[small], start[small], n[small])
    return out


def _leaf(a: np.ndarray, start: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Runs of at most 128 values: a plain loop under 8 values, else eight partial sums over
    whole blocks of eight, combined as a tree, then the rest added one by one."""
    rows = np.arange(len(n))
    res = np.zeros(len(n), dtype=np.float64)
    short = n < 8
    for j in range(7):                        # under 8 values: res += a[i], in order
        take = short & (j < n)
        res[take] = res[take] + a[rows[take], start[take] + j]
    long_ = ~short
    if long_.any():
        r_, s, m = rows[long_], start[long_], n[long_]
        whole = m - m % 8
        part = a[r_[:, None], s[:, None] + np.arange(8)]
        for i in range(8, int(whole.max()), 8):
            more = i < whole
            part[more] = part[more] + a[r_[more, None], s[more, None] + i + np.arange(8)]
        tot = (((part[:, 0] + part[:, 1]) + (part[:, 2] + part[:, 3]))
               + ((part[:, 4] + part[:, 5]) + (part[:, 6] + part[:, 7])))
        for j in range(7):                    # the rest past the last whole block
            more = j < m % 8
            tot[more] = tot[more] + a[r_[more], s[more] + whole[more] + j]
        res[long_] = tot
    return res
