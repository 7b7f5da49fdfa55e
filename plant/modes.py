"""What the plant waits for between publishing a tick and stepping, one strategy per mode.

* :class:`Lockstep` — the tick's barrier: the members' ACKs (sequential: of this tick;
  pipelined: of the one before), a recorder that says what it has taken in kept within
  ``PACE_TICKS``, and the end of the run when an ``--end-with`` member has finished
  (docs/PROTOCOL.md section 4; the ledger is :class:`bus.lockstep.AckLedger`).
* :class:`Realtime` — paces to the wall clock times ``--rate``; the last command is held
  and one older than ``cmd_timeout_s`` of wall time stops its robot.
* :class:`Fast` — free running: takes what has come, waits for nobody.

Each says whether the physics may step while the tick is published (``overlaps``), which
command acts at a tick, and how old it is, and what its mode asks of the plant (``lockstep``:
members, ACKs, nothing dropped, re-publishing; ``check_age``; the coupling's ``delays``).
:func:`make` picks one by name: the plant never branches on a mode's name. A strategy sees
the plant only through :class:`Host`.
"""
from __future__ import annotations

import threading
import time
from typing import Callable, Protocol

from bus.lockstep import AckLedger
from bus.protocol import command_expired
from bus.protocol import delays as coupling_delays

from .commands import Command, CommandBook

MODES = ("lockstep", "realtime", "fast")


class Host(Protocol):
    """What a mode strategy may use of the plant that runs it."""
    tick_ns: int
    rate: float
    rejoin_timeout_s: float
    exit_code: int
    reset_in_tick: bool
    stop_event: threading.Event
    commands: CommandBook
    ledger: AckLedger
    log: object

    @property
    def time_ns(self) -> int: ...

    def drain(self, timeout: float | None = 0.0) -> bool: ...

    def publish_pending(self) -> None: ...


def make(mode: str, host: Host, coupling: str = "sequential") -> "Mode":
    """The strategy of ``mode`` (one of MODES); the coupling matters in lockstep only."""
    if mode == "lockstep":
        return Lockstep(host, coupling)
    return Realtime(host) if mode == "realtime" else Fast(host)

#: lockstep: waiting this long (wall s) on a tick makes the plant say who it waits for,
#: then again after a gap twice the one before, at most WAIT_REPORT_MAX_S (wait_reports)
WAIT_REPORT_S = 2.0
WAIT_REPORT_MAX_S = 30.0
#: A member's last messages may reach the plant just after its sim/sync token is gone
#: (liveliness and data take different paths): how long, once, the plant waits for the
#: FINAL of an --end-with member that left without one, rather than run past its end.
LEFT_FINAL_GRACE_S = 0.5
#: realtime: falling this far behind the wall clock (s) re-anchors it instead of catching up
STALL_S = 0.25


def wait_reports():
    """Seconds of waiting on one tick after which the plant says whom it waits for
    (docs/PROTOCOL.md section 7): 2, 6, 14, 30, 60, 90, ... (each gap twice the one
    before, at most WAIT_REPORT_MAX_S)."""
    at, gap = WAIT_REPORT_S, WAIT_REPORT_S
    while True:
        yield at
        gap = min(2 * gap, WAIT_REPORT_MAX_S)
        at += gap


class Mode:
    """What every mode shares: free running, nobody waited for (the base of the others)."""
    overlaps = True
    lockstep = False           # members hold the ticks: ACKs, nothing dropped, re-publishing
    check_age = False          # commands older than cmd_timeout_s are rejected on arrival
    stalls = 0                 # times the wall clock was re-anchored (realtime)
    paced_s = 0.0              # wall time waited for watchers to keep up (lockstep)

    def __init__(self, plant: Host) -> None:
        self.plant = plant
        self.delays = coupling_delays("sequential")

    def start(self) -> None:
        """The first tick is about to be published."""

    def restarted(self) -> None:
        """The world restarted at t = 0."""

    def barrier(self, t_ns: int) -> str | None:
        """Between publishing tick ``t_ns`` and stepping: wait for what the mode waits for;
        the reason the run ends here, or None."""
        self.plant.drain(0.0)
        return None

    def at_end(self, t_ns: int) -> None:
        """The run ends at tick ``t_ns`` (its sensors are published)."""

    def command(self, robot: str) -> Command | None:
        return self.plant.commands.latest.get(robot)

    def commands(self, robots: list[str]) -> list[Command | None]:
        """:meth:`command` of each of ``robots``, in order."""
        latest = self.plant.commands.latest
        return [latest.get(r) for r in robots]

    def age_s(self, cmd: Command) -> float:
        return time.monotonic() - cmd.wall

    def expired(self, cmd: Command, timeout_s: float) -> bool:
        """Whether ``cmd`` is past its robot's ``cmd_timeout_s`` (it stops the robot)."""
        return self.age_s(cmd) > timeout_s

    def expired_all(self, cmds: list[Command | None], timeouts_s: list[float]) -> list[bool]:
        """:meth:`expired` of each command (False for None) with its robot's timeout."""
        expired = self.expired
        return [cmd is not None and expired(cmd, t) for cmd, t in zip(cmds, timeouts_s)]


class Fast(Mode):
    """Free running: nobody is waited for."""


class Realtime(Mode):
    """Paced to the wall clock times ``rate``."""
    overlaps = False
    check_age = True

    def __init__(self, plant: Host) -> None:
        super().__init__(plant)
        self.pace0 = 0.0                 # wall time of sim time 0
        self.stalls = 0                  # times the wall clock was re-anchored
        self._stall_logged = -1e9

    def start(self) -> None:
        self.pace0 = time.monotonic()

    def restarted(self) -> None:
        self.pace0 = time.monotonic() - self.plant.time_ns * 1e-9 / self.plant.rate

    def barrier(self, t_ns: int) -> str | None:
        p = self.plant
        p.drain(0.0)
        due = self.pace0 + (t_ns + p.tick_ns) * 1e-9 / p.rate
        behind = time.monotonic() - due
        if behind > max(STALL_S, 5 * p.tick_ns * 1e-9 / p.rate):
            # Stopped (SIGSTOP, debugger) or starved: do not race to catch up, which would
            # replay the missed wall time at full speed.
            self.stalls += 1
            self.pace0 += behind
            due -= behind
            if time.monotonic() - self._stall_logged > 5.0:
                self._stall_logged = time.monotonic()
                p.log.warning("realtime: %.2f s behind the wall clock at t=%.3f s (stopped "
                              "or overloaded); carrying on from now", behind, t_ns * 1e-9)
        while (left := due - time.monotonic()) > 0 and not p.stop_event.is_set():
            p.drain(min(left, 0.05))
        return None


class Lockstep(Mode):
    """The tick's barrier under ``coupling`` (its actuation delay: 0 sequential, a tick
    pipelined)."""
    lockstep = True
    check_age = True

    def __init__(self, plant: Host, coupling: str) -> None:
        super().__init__(plant)
        self.delays = coupling_delays(coupling)
        self.delay_ns = self.delays["actuation_delay_ticks"] * plant.tick_ns
        self.overlaps = self.delay_ns > 0   # pipelined: tick k's sensors do not feed this step

    def barrier(self, t_ns: int) -> str | None:
        """Sequential: tick t's ACKs; pipelined: tick t-1's, while the members compute tick
        t's (none before the first tick). Time is held while a member is lost (up to
        --rejoin-timeout), and waited for again once it is back. Then the end, if an
        --end-with member finished, or every member did."""
        p = self.plant
        due = t_ns - self.delay_ns
        while True:
            self.wait_for_watchers(t_ns + p.tick_ns)
            if due >= 0:
                self.wait_for_acks(due)
            if p.reset_in_tick or p.stop_event.is_set():
                return None
            self.await_final_of_leavers()
            # Stepped only if, as it looks now (events were handled since the ACKs came),
            # nobody is lost and nobody owes the tick: a member back within the grace
            # for an --end-with member's FINAL owes it again, and stepping before its
            # answer would act on the previous tick's command.
            if p.ledger.may_step(due):
                break
            if not p.ledger.held_for():
                continue
            lost = self.hold(t_ns)
            if lost or p.reset_in_tick or p.stop_event.is_set():
                return lost
        ended = p.ledger.ended(due)
        if not ended:
            if p.ledger.all_finished(due):
                p.publish_pending()
                p.log.info("every lockstep member finished: stopping at t=%.3f s", t_ns * 1e-9)
                return "every member finished"
            return None
        p.publish_pending()
        if self.delay_ns:           # pipelined: the others' outputs of tick t too, so the
            self.wait_for_acks(t_ns)          # end is exact
        p.log.info("%s finished at t=%.3f s: stopping", ended[0], due * 1e-9)
        return f"{ended[0]} finished"

    def at_end(self, t_ns: int) -> None:
        self.wait_for_acks(t_ns)

    def command(self, robot: str) -> Command | None:
        return self.plant.commands.for_tick(robot, self.plant.time_ns - self.delay_ns)

    def commands(self, robots: list[str]) -> list[Command | None]:
        upto = self.plant.time_ns - self.delay_ns
        for_tick = self.plant.commands.for_tick
        return [for_tick(r, upto) for r in robots]

    def age_s(self, cmd: Command) -> float:
        return (self.plant.time_ns - cmd.t_ns) * 1e-9

    def expired(self, cmd: Command, timeout_s: float) -> bool:
        """Section 4: a command's age is the simulated time of the tick it would act from
        (the plant's, as it applies the commands) minus its stamp, in whole ns."""
        return command_expired(self.plant.time_ns - cmd.t_ns, timeout_s)

    def expired_all(self, cmds: list[Command | None], timeouts_s: list[float]) -> list[bool]:
        now = self.plant.time_ns
        return [cmd is not None and command_expired(now - cmd.t_ns, t)
                for cmd, t in zip(cmds, timeouts_s)]

    def wait_for_acks(self, t_ns: int) -> None:
        """Until every member owed tick ``t_ns`` has answered it in full (AckLedger.
        waiting_for); after WAIT_REPORT_S of wall time, say whom it waits for (then less
        and less often). A sim/reset answered meanwhile ends the wait: the tick is gone."""
        p = self.plant
        # What came meanwhile, even when nobody is to be waited for (every member gone): a
        # member joining, a late FINAL, a sim/reset query would otherwise stay queued.
        p.drain(0.0)

        def say(waited_s: float, waiting: list[str]) -> None:
            p.ledger.report_missing(t_ns, waiting)
            p.log.warning("lockstep: waited %.1f s for tick t=%.3f s: %s", waited_s,
                          t_ns * 1e-9, "; ".join(p.ledger.describe_wait(t_ns, waiting)))
        self._wait_while(lambda: p.ledger.waiting_for(t_ns), say)

    def _wait_while(self, pending: Callable[[], list[str]],
                    say: Callable[[float, list[str]], None]) -> float:
        """Handle events until ``pending()`` is empty, someone is lost (the hold waits then),
        a stop or a sim/reset; ``say(waited_s, pending)`` at :func:`wait_reports`' times.
        The wall time waited."""
        p = self.plant
        since = time.monotonic()
        reports = wait_reports()
        report_at = since + next(reports)
        while not p.stop_event.is_set() and not p.reset_in_tick:
            waiting = pending()
            if not waiting or p.ledger.held_for():
                break
            now = time.monotonic()
            if now >= report_at:
                say(now - since, waiting)
                report_at = since + next(reports)
            p.drain(min(0.5, max(report_at - now, 0.01)))
        return time.monotonic() - since

    def wait_for_watchers(self, t_ns: int) -> None:
        """docs/PROTOCOL.md section 4, "Watchers that keep up": tick ``t_ns`` (the next) is
        not published before every process that says what it has taken in (``sim/seen``: a
        recorder) has taken in the tick PACE_TICKS before it; after WAIT_REPORT_S of wall
        time, say whom it waits for. Its token going ends the wait, and so does anyone
        lost: time is then held (:meth:`hold`, with the rejoin timeout), and this wait
        comes again once they are back."""
        p = self.plant
        if t_ns <= p.ledger.pace_ns:            # (every tick: the usual case first)
            return

        def say(waited_s: float, behind: list[str]) -> None:
            p.log.warning("lockstep: waited %.1f s before tick t=%.3f s for %s to keep up "
                          "(taken in: %s)", waited_s, t_ns * 1e-9, ", ".join(behind),
                          ", ".join(f"t={p.ledger.seen[n] * 1e-9:.3f} s" for n in behind))
        self.paced_s += self._wait_while(lambda: p.ledger.behind(t_ns), say)

    def hold(self, t_ns: int) -> str | None:
        """Members are lost (docs/PROTOCOL.md section 4, "Lost members"): simulated time
        stays at ``t_ns`` until they are back (the plant then re-publishes its last ticks,
        Plant.republish) or ``--rejoin-timeout`` runs out: then the run ends with a reason
        naming them, and the plant exits 1. Processes that are not members, gone with the
        plant's link (a recorder), are held for alike; if only they are missing when the
        timeout runs out, the run goes on without them."""
        p = self.plant
        lost = p.ledger.held_for()
        timeout = p.rejoin_timeout_s
        if timeout > 0:
            p.log.warning("lockstep: holding time at t=%.3f s: %s gone; waiting up to %.0f s "
                          "for %s to rejoin (--rejoin-timeout)", t_ns * 1e-9, ", ".join(lost),
                          timeout, "it" if len(lost) == 1 else "them")
        deadline = time.monotonic() + timeout
        while lost and not p.stop_event.is_set() and not p.reset_in_tick:
            left = deadline - time.monotonic()
            if left <= 0 and not set(lost) - p.ledger.away:
                p.log.warning("lockstep: %s not back within --rejoin-timeout %g s: going on "
                              "without %s at t=%.3f s", ", ".join(p.ledger.give_up_away()),
                              timeout, "it" if len(lost) == 1 else "them", t_ns * 1e-9)
                return None
            if left <= 0:
                lost = [m for m in lost if m not in p.ledger.away]
                p.exit_code = 1
                why = (f"lost lockstep member {', '.join(lost)} at t={t_ns * 1e-9:.3f} s"
                       + (f" (not back within --rejoin-timeout {timeout:g} s)" if timeout
                          else " (gone without its FINAL)"))
                p.log.error("%s: ending the run", why)
                return why
            p.drain(min(left, 0.05))
            lost = p.ledger.held_for()
        return None

    def await_final_of_leavers(self) -> None:
        """An --end-with member that left without its FINAL having come: its last messages
        may still be on their way, so give them LEFT_FINAL_GRACE_S once (a crashed member
        costs the run that much), and the run ends at the member's last tick."""
        p = self.plant
        for m in p.ledger.left_before_final():
            deadline = time.monotonic() + LEFT_FINAL_GRACE_S
            while (m not in p.ledger.finished and not p.stop_event.is_set()
                   and (left := deadline - time.monotonic()) > 0):
                p.drain(min(left, 0.05))
