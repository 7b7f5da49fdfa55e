"""The plant's watch on its own router (docs/PROTOCOL.md section 1): a plant that is a
client of a router notices losing it, as nodes notice losing the plant."""
from __future__ import annotations

import time

import zenoh


class RouterWatch:
    """A plant that is a client of a router (a user's Zenoh config) notices losing it, as
    nodes notice losing the plant (docs/PROTOCOL.md section 1): lockstep holds time (every
    member is then lost, section 4), realtime and fast say they run on without the bus."""

    CHECK_S = 0.25

    def __init__(self, session: zenoh.Session, log, mode: str, on_lost=None) -> None:
        self.session = session
        self.on_lost = on_lost            # called when it finds the router gone
        self.log = log
        self.mode = mode
        # a session connected to a router watches it; the router itself has none to lose
        self.watching = bool(list(session.info.routers_zid()))
        self.gone = False
        self._checked = 0.0

    def lost(self) -> bool:
        """No router now (asked of the session's transport, not remembered)."""
        return self.watching and not list(self.session.info.routers_zid())

    def check(self, t_ns: int, now: bool = False) -> None:
        """Ask the session at most every CHECK_S, or at once with ``now`` (a liveliness
        token came or went: the router may have gone or come back, and a blip shorter
        than CHECK_S would otherwise be missed)."""
        t = time.monotonic()
        if not self.watching or (not now and t - self._checked < self.CHECK_S):
            return
        self._checked = t
        gone = self.lost()
        if gone and not self.gone:
            self.log.warning("lost the router at t=%.3f s: %s", t_ns * 1e-9,
                             "simulated time is held until the members are back"
                             if self.mode == "lockstep"
                             else "running on; nothing published reaches anyone")
            if self.on_lost is not None:
                self.on_lost()
        elif self.gone and not gone:
            self.log.warning("the router is back at t=%.3f s", t_ns * 1e-9)
        self.gone = gone
