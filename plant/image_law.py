"""The law of a camera channel's noise, which plant/kernels/noise.c draws from: for a
whole grey level x, ``rint(x + offset + N(0, std)) = x + rint(offset + N(0, std))`` but
on ties (probability 0), so a noisy channel is ``clip(x + D, 0, 255)`` with D an integer
of the law of ``rint(offset + N(0, std))``. :func:`alias_table` is that law as Walker's
alias table (the kernel's input), :func:`image_noise_reference` the kernel in numpy.
:mod:`plant.noise` exports all three.
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

__all__ = ["image_noise_law", "alias_table", "image_noise_reference"]

_GOLDEN = 0x9E3779B97F4A7C15

#: beyond this many std from the offset the law's tails (< 1e-32) are lumped into its ends
_TAIL_SIGMAS = 12.0


def _phi(z: float) -> float:
    return 0.5 * math.erfc(-z / math.sqrt(2.0))


def image_noise_law(std: float, offset: float) -> tuple[int, np.ndarray]:
    """``(lo, p)``: P(D = lo + i) = p[i] for D = rint(offset + N(0, std)) clamped to
    [-255, 255] (past which every level clips alike), its tails beyond 12 std lumped
    into its first and last values."""
    lo = int(min(255, max(-255, math.floor(offset - _TAIL_SIGMAS * std))))
    hi = int(min(255, max(-255, math.ceil(offset + _TAIL_SIGMAS * std))))
    edges = [_phi((k + 0.5 - offset) / std) for k in range(lo, hi)]
    p = np.diff(np.array([0.0, *edges, 1.0]))
    return lo, np.clip(p, 0.0, None) / np.clip(p, 0.0, None).sum()


@lru_cache(maxsize=32)
def alias_table(std: float, offset: float) -> tuple[np.ndarray, np.ndarray]:
    """Walker's alias table of :func:`image_noise_law` (Vose's construction): ``(thresholds
    uint32 (K,), values uint16 (K, 2))``, values holding (alias, own) + 255. A 32-bit
    uniform u with u K = j 2**32 + f gives values[j, 1] - 255 if f < thresholds[j], else
    values[j, 0] - 255."""
    lo, p = image_noise_law(std, offset)
    k = p.size
    q = list(p * k)
    prob, alias = [1.0] * k, list(range(lo, lo + k))
    small = [j for j in range(k) if q[j] < 1.0]
    large = [j for j in range(k) if q[j] >= 1.0]
    while small and large:
        a, b = small.pop(), large.pop()
        prob[a], alias[a] = q[a], lo + b
        q[b] = (q[b] + q[a]) - 1.0
        (small if q[b] < 1.0 else large).append(b)
    thr = np.empty(k, dtype=np.uint32)
    for j in range(k):
        if prob[j] >= 1.0:                  # the whole column (the last 2**-32 included)
            thr[j], alias[j] = 0xFFFFFFFF, lo + j
        else:
            thr[j] = min(0xFFFFFFFF, max(0, round(prob[j] * 2.0 ** 32)))
    vals = np.stack([np.array(alias), np.arange(lo, lo + k)], axis=1) + 255
    vals = np.ascontiguousarray(vals, dtype=np.uint16)
    thr.flags.writeable = vals.flags.writeable = False
    return thr, vals


def image_noise_reference(img: np.ndarray, seed: int, std: float, offset: float) -> np.ndarray:
    """plant/kernels/noise.c in numpy (the tests compare the bytes): the noisy image of
    ``img`` (uint8) for the frame seed ``seed``."""
    thr, vals = alias_table(float(std), float(offset))
    x = np.ascontiguousarray(img).ravel()
    i = np.arange(1, (x.size + 1) // 2 + 1, dtype=np.uint64)
    with np.errstate(over="ignore"):
        z = np.uint64(seed) + i * np.uint64(_GOLDEN)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        z = z ^ (z >> np.uint64(31))
    u = np.ascontiguousarray(z).view(np.uint32)[:x.size].astype(np.uint64)  # low, high halves
    uk = u * np.uint64(thr.size)
    j = (uk >> np.uint64(32)).astype(np.intp)
    own = (uk & np.uint64(0xFFFFFFFF)).astype(np.uint32) < thr[j]
    d = vals[j, own.astype(np.intp)].astype(np.intp) - 255
    return np.clip(x.astype(np.intp) + d, 0, 255).astype(np.uint8).reshape(img.shape)
