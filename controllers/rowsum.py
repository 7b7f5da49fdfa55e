"""Masked row sums equal to the bit to numpy's sum of each row's selected values.

``np.sum(x[mask])`` of one robot's values and a sum over a batch of robots in one call
round differently unless they add the same numbers in the same order: numpy sums a
contiguous run of floats pairwise (eight partial sums over blocks of eight, combined as a
tree, the rest added one by one; a run longer than 128 values is split in halves whose
length is a multiple of eight; numpy/_core/src/umath/loops_utils.h.src, ``pairwise_sum``).
:func:`masked_row_sums` follows that order for every row at once, in a fixed number of
numpy calls whatever the number of rows, so a controller stepping many robots with numpy
gives the commands its per-robot step gives, byte for byte. It runs as one call of the
controllers' C kernels (controllers/kernels/rowsum.c: the same additions in the same
order, ~10x cheaper than the numpy formulation on a swarm's scans);
:func:`masked_row_sums_numpy` is that formulation, the reference the tests compare the
kernel with.
"""
from __future__ import annotations

import numpy as np

from controllers.kernels import function

#: numpy's pairwise-summation block (PW_BLOCKSIZE): longer runs are split in halves
_BLOCK = 128
#: padding: x + (-0.0) == x for every x (-0.0 included): it never changes a partial sum
_NOTHING = -0.0


def _checked(values, mask) -> tuple[np.ndarray, np.ndarray]:
    values = np.asarray(values, dtype=np.float64)
    mask = np.asarray(mask, dtype=bool)
    if values.ndim != 2 or values.shape != mask.shape:
        raise ValueError(f"values {values.shape} and mask {mask.shape}: need the same 2-D shape")
    return values, mask


def masked_row_sums(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Per row ``i``: ``np.sum(values[i][mask[i]])``, bit for bit (float64), in one kernel
    call."""
    values, mask = _checked(values, mask)
    values = np.ascontiguousarray(values)
    mask = np.ascontiguousarray(mask)
    rows, width = values.shape
    got = np.empty(rows + width)           # the sums, then the kernel's scratch row
    if rows:
        function("controller_masked_row_sums", ("controller_rowsum_abi", 1), 6)(
            rows, width, values.ctypes.data, mask.ctypes.data, got.ctypes.data + 8 * rows,
            got.ctypes.data)
    return got[:rows]


def masked_row_sums_numpy(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """:func:`masked_row_sums` in numpy calls (the reference): each row's selected values
    moved to its front, summed in numpy's pairwise order for every row at once."""
    values, mask = _checked(values, mask)
    rows, width = values.shape
    n = mask.sum(axis=1)
    # each row's selected values moved to its front, in order, the rest padding (eight
    # columns of it: a run's rest is read past its last value)
    packed = np.full((rows, width + 8), _NOTHING)
    packed[np.arange(width + 8)[None, :] < n[:, None]] = values[mask]
    if width <= _BLOCK:                       # (one run a row: a lidar's rays)
        return 0.0 + _front_sums(packed, n)
    # runs over _BLOCK values split in halves as numpy does, level by level: segments
    # (row, start, length); the first `rows` are the whole rows
    seg_row, seg_start, seg_n = np.arange(rows), np.zeros(rows, dtype=np.intp), n.copy()
    levels = []
    split = np.flatnonzero(seg_n > _BLOCK)
    while split.size:
        half = seg_n[split] // 2
        half -= half % 8
        left = len(seg_row) + np.arange(split.size)
        right = left + split.size
        seg_row = np.concatenate([seg_row, seg_row[split], seg_row[split]])
        seg_start = np.concatenate([seg_start, seg_start[split], seg_start[split] + half])
        seg_n = np.concatenate([seg_n, half, seg_n[split] - half])
        levels.append((split, left, right))
        halves = np.concatenate([left, right])
        split = halves[seg_n[halves] > _BLOCK]
    total = np.empty(len(seg_row))
    leaves = np.flatnonzero(seg_n <= _BLOCK)
    total[leaves] = _runs(packed, seg_row[leaves], seg_start[leaves], seg_n[leaves])
    for split, left, right in reversed(levels):
        total[split] = total[left] + total[right]
    # numpy starts a sum from its identity, +0.0 (a run of -0.0 sums to +0.0)
    return 0.0 + total[:rows]


def _runs(packed: np.ndarray, row: np.ndarray, start: np.ndarray, n: np.ndarray) -> np.ndarray:
    """numpy's sum of runs of at most 128 values, ``packed[row, start:start + n]`` each
    (:func:`_front_sums` of them, gathered to the front of rows of their own)."""
    if not len(n):
        return np.zeros(0)
    width = packed.shape[1]
    cols = np.arange(8 * (int(n.max()) // 8 + 2))
    run = packed[row[:, None], np.minimum(start[:, None] + cols, width - 1)]
    run[cols[None, :] >= n[:, None]] = _NOTHING
    return _front_sums(run, n)


def _front_sums(packed: np.ndarray, n: np.ndarray) -> np.ndarray:
    """numpy's sum of each row's first ``n`` values (at most 128: one run), ``packed``
    holding -0.0 past them for eight columns at least: the whole blocks of eight summed in
    order into eight partial sums, combined as numpy's tree, then the rest (under eight
    values) added one by one by a sequential ``cumsum``. A row of fewer than eight values
    has no whole block: its rest added to -0.0 is numpy's loop from 0.0 but for the sign of
    a zero sum, which the caller's final ``0.0 +`` gives as numpy does. About 15 numpy
    calls whatever the rows (and an addition per block of eight)."""
    rows, width = packed.shape
    whole = n & -8                            # the values in whole blocks of eight
    cols = np.arange(width)
    blocks = np.where(cols < whole[:, None], packed, _NOTHING)
    part = blocks[:, :8]
    for b in range(8, width - 7, 8):           # (the blocks in order: numpy's partial sums)
        part = part + blocks[:, b:b + 8]
    pairs = part[:, 0::2] + part[:, 1::2]
    quads = pairs[:, 0::2] + pairs[:, 1::2]
    # (each row: its tree sum, then its rest; padding -0.0 past the rest adds nothing)
    tail = np.empty((rows, 8))
    tail[:, 0] = quads[:, 0] + quads[:, 1]
    tail[:, 1:] = packed[np.arange(rows)[:, None], whole[:, None] + cols[:7]]
    return tail.cumsum(axis=1)[:, -1]
