"""How long a process waits for a plant it lost before it ends by itself.

A member (:mod:`bus.runtime`) or a recorder (:mod:`bridges.record`) that took part in a run and
loses its plant cannot tell a killed plant from a lost router or link: in both it sees
``sim/alive/plant`` vanish, and no ``sim/end`` may ever come. The plant itself holds time for
lost members up to its ``--rejoin-timeout`` and then ends the run (exit 1), but its
``sim/end`` then reaches nobody if the router is what went. So a process that has been
without its plant for longer than the run's rejoin timeout (``sim/info``
``rejoin_timeout_s``, docs/PROTOCOL.md section 5) plus :data:`GONE_GRACE_S` knows the run is
over and ends (exit :data:`EXIT_PLANT_GONE`), whether or not it waits (``--wait``).
"""
from __future__ import annotations

#: the exit code of a process whose plant went away and did not come back in time
EXIT_PLANT_GONE = 3
#: beyond the rejoin timeout: the plant notices a lost router within its 1 s lease, and a
#: router back just in time must still reach this process
GONE_GRACE_S = 2.0


class PlantWatch:
    """The plant's presence as one process saw it: :meth:`here` / :meth:`gone` on its
    ``sim/alive/plant`` token, :meth:`expired` once it has been gone too long."""

    def __init__(self) -> None:
        self.seen = False               # a plant was there once (this process took part)
        self.gone_since: float | None = None
        self.rejoin_timeout_s = 0.0

    def learn(self, info: dict | None) -> None:
        """The run's rejoin timeout from the plant's ``sim/info`` (0 if it gives none)."""
        try:
            self.rejoin_timeout_s = max(0.0, float((info or {}).get("rejoin_timeout_s") or 0))
        except (TypeError, ValueError):
            self.rejoin_timeout_s = 0.0

    def here(self) -> None:
        self.seen = True
        self.gone_since = None

    def gone(self, now: float) -> None:
        if self.seen and self.gone_since is None:
            self.gone_since = now

    @property
    def limit_s(self) -> float:
        return self.rejoin_timeout_s + GONE_GRACE_S

    def expired(self, now: float) -> bool:
        """The plant has been gone longer than the run's rejoin timeout (and the grace)."""
        return self.gone_since is not None and now - self.gone_since > self.limit_s

    def why(self, now: float) -> str:
        gone = now - (self.gone_since if self.gone_since is not None else now)
        return (f"the plant has been gone for {gone:.1f} s, longer than the run's rejoin "
                f"timeout ({self.rejoin_timeout_s:g} s, sim/info rejoin_timeout_s) + "
                f"{GONE_GRACE_S:g} s: the run is over (a lost plant, or a lost router whose "
                "sim/end could not reach this process)")
