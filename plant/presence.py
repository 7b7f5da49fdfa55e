"""Who is on the bus, as the plant sees it: the ``sim/alive`` tokens of processes and the
``sim/sync`` tokens of lockstep members, what the plant does when one comes or goes, and
what the watchers that keep up (a recorder) say they have taken in (``sim/seen``).

The ledger (:class:`bus.lockstep.AckLedger`) keeps who time is held for: lockstep members
lost and rejoined, and processes away with the plant's router link (docs/PROTOCOL.md
section 4, "Lost members"). This module keeps only what the tokens say and when: which
processes are here now, which went and when, and when time goes on for a held process
that is back. The plant calls it from its main thread only (:mod:`bus.inbox`).
"""
from __future__ import annotations

import time

from bus.inbox import Event
from bus.protocol import END_SEEN_S, decode_seen

#: the name of the plant's own sim/alive token
PLANT_TOKEN = "plant"
#: a process whose sim/alive token went within this long (wall s) of the plant losing its
#: link to its router went with it (its token and the plant's own vanish together)
LINK_WINDOW_S = 1.0
#: (wall s) how long time stays held after such a process is back: its token may reach the
#: plant before its subscriptions reach the router (a CI run lost 41 ticks of a recorder
#: that way); the plant re-publishes its last ticks again when this has passed
SETTLE_S = 0.5


class Presence:
    """The tokens' view of one plant (:class:`plant.process.Plant`: its ledger, outbox,
    router watch, log and re-publishing)."""

    def __init__(self, plant) -> None:
        self.plant = plant
        self.alive: set[str] = set()             # processes whose sim/alive token is here
        self.went: dict[str, float] = {}         # processes whose sim/alive token went, and
                                                 # when (monotonic s), while away
        self.link_lost_at = -LINK_WINDOW_S       # when the plant last lost its router link
        self.settling: dict[str, float] = {}     # held process back -> when time goes on

    # ------------------------------------------------------------------ sim/alive
    def on_alive(self, ev: Event) -> None:
        """A process's ``sim/alive`` token came or went."""
        p = self.plant
        p.outbox.changed()          # its subscribers are in the tables by now
        node = p.keys.node_of(ev.key)
        if not ev.alive:
            self.alive.discard(node)
            self.settling.pop(node, None)
            now = self.went[node] = time.monotonic()
            if node == PLANT_TOKEN:      # its own token, seen through the router: gone
                self.link_lost()
            elif p.router.gone or now - self.link_lost_at <= LINK_WINDOW_S:
                self._hold_for(node)
            if node not in p.ledger.away:      # gone for good: not kept up with
                p.ledger.unseen(node)
            return
        self.alive.add(node)
        was_away = self.went.pop(node, None) is not None
        held = node in p.ledger.away        # (time goes on SETTLE_S from now)
        if held:
            self.settling[node] = time.monotonic() + SETTLE_S
        if was_away and p.strategy.lockstep:
            # back after a blip (a recorder, say): what it missed of the last ticks,
            # tick 0 included (a blip before the first step: nothing stepped yet, but the
            # members' answers to t=0 went out while it was away)
            p.log.info("%s is back%s", node, f": time goes on in {SETTLE_S:g} s" if held else "")
            p.republish()

    def link_lost(self) -> None:
        """The plant lost its link to its router (its own ``sim/alive`` token went from its
        view, or the router is gone): the processes that went with it are held for."""
        now = self.link_lost_at = time.monotonic()
        for node, went in list(self.went.items()):
            if now - went <= LINK_WINDOW_S:
                self._hold_for(node)

    def settle(self) -> None:
        """Held processes back for SETTLE_S: the last ticks once more (what went out before
        their subscriptions were in place reaches them now), then time goes on."""
        if not self.settling:
            return
        now = time.monotonic()
        done = [n for n, t in self.settling.items() if t <= now]
        for node in done:
            del self.settling[node]
            if self.plant.ledger.back(node):
                self.plant.log.info("%s: time goes on", node)
                self.plant.republish()

    def _hold_for(self, node: str) -> None:
        """docs/PROTOCOL.md section 4, "Lost members": a process that is not a member (a
        recorder, a view), gone with the plant's link, would miss what the plant publishes
        before it is back; in lockstep with a rejoin timeout, time is held for it too (the
        ledger leaves members to their own rules)."""
        p = self.plant
        if (node == PLANT_TOKEN or node in self.alive or not p.strategy.lockstep
                or p.rejoin_timeout_s <= 0 or not p.ledger.gone_with_link(node)):
            return
        p.log.warning("%s went with the router at t=%.3f s: time is held for it too, up to "
                      "--rejoin-timeout %g s", node, p.sim.time_ns * 1e-9, p.rejoin_timeout_s)

    # ------------------------------------------------------------------ sim/sync
    def on_member(self, ev: Event) -> None:
        """A lockstep member's ``sim/sync`` token came or went: the ledger's join or leave."""
        p = self.plant
        p.outbox.changed()
        node = p.keys.node_of(ev.key)
        t_ns = p.sim.time_ns
        if ev.alive:
            if p.ledger.join(node, t_ns):
                p.log.warning("lockstep member rejoined: %s (at t=%.3f s)", node, t_ns * 1e-9)
                p.republish()
            else:
                p.log.info("lockstep member joined: %s", node)
            return
        how = p.ledger.leave(node, p.router.lost())
        if how == "finished":
            p.log.info("lockstep member finished and left: %s", node)
        else:
            p.log.warning("lockstep member lost: %s (gone without its FINAL at t=%.3f s; %s)",
                          node, t_ns * 1e-9, lost_note(how, p.rejoin_timeout_s))

    # ------------------------------------------------------------------ sim/seen
    def on_seen(self, ev: Event) -> None:
        """docs/PROTOCOL.md section 4, "Watchers that keep up": a process that is not a
        member says what it has taken in (only while its sim/alive token is here: a late
        one of a process gone would hold time for nobody)."""
        p = self.plant
        node = p.keys.node_of(ev.key)
        try:
            t_ns = decode_seen(ev.payload)
        except ValueError as exc:
            p.rejects.reject(f"sim/seen/{node}", str(exc))
            return
        if node in self.alive or node in p.ledger.away:
            p.ledger.saw(node, t_ns)

    def last_tick_taken_in(self, t_ns: int) -> None:
        """docs/PROTOCOL.md section 4, "End": the run ended at tick ``t_ns``; the processes
        that answer a get on ``sim/seen/*`` (a recorder, the launcher's observer) get up to
        END_SEEN_S to have taken that tick in before the plant says sim/end and closes its
        session: what is still on its way then is lost (a loaded machine's run summary once
        lacked its last 20 ticks). The get also goes after the last messages, on the same
        links."""
        p = self.plant
        deadline = time.monotonic() + END_SEEN_S
        while not p.stop_event.is_set():
            left = deadline - time.monotonic()
            short = {n: t for n, t in self._ask_seen(max(left, 0.05)).items() if t < t_ns}
            if not short:
                return
            if left <= 0:
                p.log.warning("%s had not taken in the last tick (t=%.3f s) %.0f s after it; "
                              "ending all the same", ", ".join(
                                  f"{n} (t={t * 1e-9:.3f} s)" for n, t in sorted(short.items())),
                              t_ns * 1e-9, END_SEEN_S)
                return
            p.drain(0.02)

    def _ask_seen(self, timeout_s: float) -> dict[str, int]:
        """What each process answering ``sim/seen/*`` says it has taken in (a malformed
        answer is counted and left out)."""
        p = self.plant
        out = {}
        try:
            replies = p.session.get(p.keys.seen(), timeout=min(timeout_s, 1.0))
            for reply in replies:
                if reply.ok is None:
                    continue
                node = p.keys.node_of(str(reply.ok.key_expr))
                try:
                    out[node] = decode_seen(reply.ok.payload.to_bytes())
                except ValueError as exc:
                    p.rejects.reject(f"sim/seen/{node}", str(exc))
        except Exception as exc:         # (the session closing under a stop signal)
            p.log.debug("sim/seen: %s", exc)
        return out


def lost_note(how: str, rejoin_timeout_s: float) -> str:
    """What happens to a lockstep member that left without its FINAL (``AckLedger.leave``
    said ``how``), as the plant's warning says it."""
    if how != "lost":
        return "the others go on without it"
    if rejoin_timeout_s > 0:
        return f"time is held for it, up to --rejoin-timeout {rejoin_timeout_s:g} s"
    return "the run ends at this tick: --rejoin-timeout is 0, so time is not held for it"
