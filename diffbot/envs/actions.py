"""What every environment does with an action, in one place: its space, its check, its
clip, and how many control ticks it is held (the action repeat).

An action is ``[v, w]`` for one robot: in m/s and rad/s within the robot's drive limits
(``[-v_max, v_max] x [-w_max, w_max]``, the default), or with ``normalize_actions=True``
in ``[-1, 1] x [-1, 1]``, scaled by those limits (``v = a[0] * v_max``), the form PPO's and
SAC's default policies expect. Either way:

* an action that is not two finite numbers (a NaN, the wrong shape) is a ``ValueError``
  naming the robot; the environment is still usable after it;
* an action outside the box is clipped to it, as the robot's drive limiter would (no
  error, no warning: exploration noise overshoots all the time);
* the action goes through float32 (the space's type) first, as
  :func:`controllers.learned.as_action`, so a deployed policy commands the very same numbers.
"""
from __future__ import annotations

import numpy as np
from gymnasium import spaces

from controllers.learned import as_action


def check_repeat(action_repeat: int) -> int:
    if int(action_repeat) < 1:
        raise ValueError(f"action_repeat must be >= 1, got {action_repeat!r}")
    return int(action_repeat)


def check_action(action, who: str = "the robot") -> np.ndarray:
    """The action as float32 ``[v, w]``; a ValueError naming ``who`` if it is not two finite
    numbers (module docstring)."""
    a = as_action(action)
    if a.shape != (2,) or not np.all(np.isfinite(a)):
        raise ValueError(f"action for {who} must be 2 finite numbers [v, w], got {action!r}")
    return a


class Drive:
    """One robot's action: space, check and clip, in the robot's units or normalised."""

    def __init__(self, v_max: float, w_max: float, normalize: bool = False) -> None:
        self.v_max, self.w_max = float(v_max), float(w_max)
        self.normalize = bool(normalize)
        hi = np.array([1.0, 1.0] if self.normalize else [self.v_max, self.w_max], np.float32)
        self.space = spaces.Box(-hi, hi, dtype=np.float32)
        self._hi = hi.astype(np.float64)
        self._hi_f = tuple(self._hi.tolist())

    def command(self, action, who: str = "the robot") -> tuple[float, float]:
        """The twist ``(v m/s, w rad/s)`` an action gives (module docstring)."""
        v, w = check_action(action, who).tolist()        # (float32 values, exact as floats)
        hv, hw = self._hi_f
        v, w = min(max(v, -hv), hv), min(max(w, -hw), hw)  # np.clip's values (finite)
        if self.normalize:
            return v * self.v_max, w * self.w_max
        return v, w

    def commands(self, actions) -> np.ndarray:
        """:meth:`command` of each row of ``actions`` (K, 2), checked already (a batch's,
        :func:`check_action` each): (K, 2) float64, the same numbers."""
        a = np.clip(np.asarray(actions, dtype=np.float32).astype(np.float64).reshape(-1, 2),
                    -self._hi, self._hi)
        return a * [self.v_max, self.w_max] if self.normalize else a
