"""A batch's results as Gymnasium's vector envs give them: a chunk's step (:class:`Out`:
observations, rewards, flags and ``info`` batched with ``_key`` masks), the chunks joined
in env order (:func:`merge`), and the checks of the vector options (``autoreset_mode``,
``reset_mask``)."""
from __future__ import annotations

import numpy as np
from gymnasium.vector import AutoresetMode


class Out:
    """A chunk's step results, env by env (:meth:`put`) or rows at once (:meth:`put_rows`),
    batched as :meth:`gymnasium.vector.VectorEnv._add_info` batches ``info``: each key an
    array typed by its value's type (bool, int, float: that dtype; an ndarray: its shape
    and dtype; else objects) with a ``_key`` mask of the envs that gave it."""

    def __init__(self, n: int, space) -> None:
        self.n = n
        self.obs = ({} if space is None else
                    {k: np.zeros((n, *sp.shape), sp.dtype) for k, sp in space.spaces.items()})
        self.rew = np.zeros(n, np.float64)
        self.term = np.zeros(n, bool)
        self.trunc = np.zeros(n, bool)
        self.infos: dict = {}

    def _array(self, key: str, sample) -> np.ndarray:
        a = self.infos.get(key)
        if a is None:
            if type(sample) in (int, float, bool) or issubclass(type(sample), np.number):
                a = np.zeros(self.n, dtype=type(sample))
            elif isinstance(sample, np.ndarray):
                a = np.zeros((self.n, *sample.shape), dtype=sample.dtype)
            else:
                a = np.full(self.n, None, dtype=object)
            self.infos[key] = a
            self.infos[f"_{key}"] = np.zeros(self.n, dtype=np.bool_)
        return a

    def put(self, i: int, obs: dict, rew: float, term: bool, trunc: bool, info: dict) -> None:
        for k, a in self.obs.items():
            a[i] = obs[k]
        self.rew[i], self.term[i], self.trunc[i] = rew, term, trunc
        self.put_info(i, info)

    def put_info(self, i: int, info: dict) -> None:
        for key, value in info.items():
            self._array(key, value)[i] = value
            self.infos[f"_{key}"][i] = True

    def info_of(self, i: int) -> dict:
        """Env ``i``'s info as the single env gives it (Python scalars, array rows copied)."""
        out = {}
        for key, a in self.infos.items():
            if key.startswith("_") or not self.infos[f"_{key}"][i]:
                continue
            v = a[i]
            out[key] = v.copy() if isinstance(v, np.ndarray) else (
                v.item() if isinstance(v, np.generic) else v)
        return out

    def put_rows(self, rows: np.ndarray, obs: dict, rew, term, trunc, info: dict) -> None:
        """Rows ``rows`` at once; ``info``: key -> one value per row (an array's rows, or a
        list), typed as the single env's values are (float64, bool, ndarray rows)."""
        for k, a in self.obs.items():
            a[rows] = obs[k]
        self.rew[rows], self.term[rows], self.trunc[rows] = rew, term, trunc
        for key, col in info.items():
            first = col[0]
            sample = first.item() if isinstance(first, np.generic) else first
            a = self._array(key, sample)
            if a.dtype == object and not (isinstance(col, np.ndarray) and col.dtype == object):
                for r, v in zip(rows.tolist(), col):
                    a[r] = v
            else:
                a[rows] = col
            self.infos[f"_{key}"][rows] = True


def merge(parts: list[tuple]) -> tuple:
    """Chunks' :meth:`Worlds.step` results, in env order, as one batch's."""
    if len(parts) == 1:
        return parts[0]
    obs = {k: np.concatenate([p[0][k] for p in parts]) for k in parts[0][0]}
    rew, term, trunc = (np.concatenate([p[j] for p in parts]) for j in (1, 2, 3))
    sizes = [len(p[1]) for p in parts]
    return obs, rew, term, trunc, merge_infos([p[4] for p in parts], sizes)


def merge_infos(infos: list[dict], sizes: list[int]) -> dict:
    """Chunks' batched infos (each of ``sizes[j]`` envs) as one batch's: each key's arrays
    joined in env order, a key a chunk lacks filled (and masked out) for its envs; a
    nested info (``final_info``) joined the same way."""
    out: dict = {}
    for key in dict.fromkeys(k for info in infos for k in info):
        like = next(info[key] for info in infos if key in info)
        if isinstance(like, dict):
            out[key] = merge_infos([info.get(key, {}) for info in infos], sizes)
            continue
        cols = []
        for info, n in zip(infos, sizes):
            if key in info:
                cols.append(info[key])
            else:        # a key no env of this chunk gave: empty, masked out
                cols.append(np.zeros((n, *like.shape[1:]), like.dtype) if like.dtype != object
                            else np.full(n, None, dtype=object))
        out[key] = np.concatenate(cols)
    return out


def autoreset_mode(mode) -> AutoresetMode:
    """``mode`` as an :class:`AutoresetMode` (or its value: ``"NextStep"``, ``"SameStep"``,
    ``"Disabled"``; or its name, any case)."""
    if isinstance(mode, AutoresetMode):
        return mode
    for m in AutoresetMode:
        if isinstance(mode, str) and mode.lower() in (m.value.lower(), m.name.lower()):
            return m
    raise ValueError(f"autoreset_mode must be one of {', '.join(m.name for m in AutoresetMode)} "
                     f"(gymnasium.vector.AutoresetMode), got {mode!r}")


def reset_mask(options: dict | None, n: int) -> np.ndarray | None:
    """``options["reset_mask"]`` checked as Gymnasium's vector envs check it (a bool numpy
    array of shape (n,), at least one True), or None."""
    if not options or "reset_mask" not in options:
        return None
    mask = options["reset_mask"]
    if not isinstance(mask, np.ndarray):
        raise TypeError(f"options['reset_mask'] must be a numpy array, got {type(mask)}")
    if mask.shape != (n,):
        raise ValueError(f"options['reset_mask'] must have shape ({n},), got {mask.shape}")
    if mask.dtype != np.bool_:
        raise TypeError(f"options['reset_mask'] must have dtype=np.bool_, got {mask.dtype}")
    if not mask.any():
        raise ValueError("options['reset_mask'] resets no env (all False)")
    return mask
