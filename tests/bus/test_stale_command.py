"""A router blip must not make the plant step a held tick with the previous tick's command.

The window, found by experiment: an ``--end-with`` member (the square controller) lost
without its FINAL gets LEFT_FINAL_GRACE_S for its FINAL; if the router comes back within
that grace, both members rejoin during it (owing the held tick again) and the barrier used
to step as soon as nobody was lost, without waiting for the rejoined member's answer: the
robot was driven from t_k by the command of t_(k-1). Here the plant's barrier
(plant.modes.Lockstep) runs against the real ledger with the events of such a blip
scripted in order, no processes, no timing: deterministic. Then the per-tick check
(plant.commands.stale_commands) that counts any such step as a protocol error.
"""
from __future__ import annotations

import threading
import time
from types import SimpleNamespace

from bus import codec
from bus.controller import Twist
from bus.lockstep import AckLedger
from bus.log import RejectCounter
from plant import modes
from plant.commands import Command, CommandBook, stale_commands

T = 20_000_000                     # one control tick, ns
K = 150 * T                        # the held tick (t = 3.000 s)
SQ, ODO = "square_path_robot1", "odometry_robot1"
CMD, ODOM = "robot1/cmd_vel", "robot1/odom"
KEYS = {"robot1": (CMD, "robot1/wheel_cmd")}


class FakePlant:
    """What plant.modes.Lockstep uses of a Plant: the ledger, the commands, and a drain that
    hands over the scripted events one per call (a blip as the plant's inbox saw it)."""

    def __init__(self, events: list) -> None:
        self.log = SimpleNamespace(info=lambda *a: None, warning=lambda *a: None,
                                   error=lambda *a: None)
        self.errors = RejectCounter(self.log, verb="lockstep protocol:")
        self.ledger = AckLedger(T, self.errors.reject, end_with=(SQ,), expect=(SQ, ODO))
        self.commands = CommandBook(lockstep=True)
        self.sim = SimpleNamespace(time_ns=K)
        self.time_ns = K
        self.tick_ns = T
        self.events = list(events)
        self.last = time.monotonic()
        self.stop_event = threading.Event()
        self.reset_in_tick = False
        self.rejoin_timeout_s = 30.0
        self.exit_code = 0

    def drain(self, timeout=0.0) -> bool:
        """The next event; a number in the script is a gap: nothing comes until that many
        wall seconds after the event before it."""
        if self.events and not callable(self.events[0]):
            left = self.last + self.events[0] - time.monotonic()
            if left > 0:
                time.sleep(min(left, timeout or 0.0))
                return False
            self.events.pop(0)
        if not self.events:
            return False
        self.events.pop(0)(self)
        self.last = time.monotonic()
        return True

    def publish_pending(self) -> None:
        pass

    # what Plant._on_output does with a member's message: file it, then the command
    def output(self, member: str, t: int, key: str, value=None) -> None:
        raw = codec.attachment(1, t, codec.ACK, 1, member)
        if self.ledger.file(key, key.split("/")[-1], codec.parse_attachment(raw), raw,
                            self.sim.time_ns) and value is not None:
            self.commands.file("robot1", Command(value, t, 0.0, member))


def up_to_the_blip(p: FakePlant) -> None:
    """Both members answered every tick before K; at K the odometry answered, the square's
    command is in flight when the router goes."""
    p.ledger.join(ODO)
    p.ledger.join(SQ)
    for t in range(K - 5 * T, K + T, T):
        p.ledger.begin_tick(t)
        p.output(ODO, t, ODOM)
        if t < K:
            p.output(SQ, t, CMD, Twist(0.2, t * 1e-12))


def blip(p: FakePlant) -> None:             # the router goes: both tokens vanish
    for m in (SQ, ODO):
        p.ledger.leave(m, link_lost=True)


def back(p: FakePlant) -> None:             # it is back within the grace: both rejoin
    for m in (SQ, ODO):
        assert p.ledger.join(m, K)


def resent(p: FakePlant) -> None:           # the square answers the re-published tick K
    p.output(SQ, K, CMD, Twist(0.2, K * 1e-12))


def test_a_member_back_during_the_grace_for_its_final_is_waited_for_at_the_held_tick(
        monkeypatch):
    # the rejoin comes within the grace, the re-sent answer only after it has run out
    monkeypatch.setattr(modes, "LEFT_FINAL_GRACE_S", 0.05)
    p = FakePlant([blip, back, 4 * modes.LEFT_FINAL_GRACE_S, resent])
    up_to_the_blip(p)
    assert p.ledger.waiting_for(K) == [SQ]
    assert modes.Lockstep(p, "sequential").barrier(K) is None
    # stepped only once the square's answer to K was in: its command of K drives the robot
    assert p.events == [] and p.ledger.waiting_for(K) == []
    assert p.commands.for_tick("robot1", K).t_ns == K


def check(p: FakePlant, due: int = K) -> int:
    picked = {"robot1": p.commands.for_tick("robot1", due)}
    return stale_commands(p.ledger, p.commands, due, picked, KEYS.get, p.errors.reject)


def test_stepping_a_tick_with_an_older_command_while_its_member_owes_it_is_counted():
    """The case the barrier above now prevents, forced: the counter sees it."""
    p = FakePlant([])
    up_to_the_blip(p)
    blip(p)
    back(p)
    assert check(p) == 1
    assert p.errors.counts == {"stale command": 1}
    resent(p)
    assert check(p) == 0 and p.errors.total == 1


def test_the_command_of_the_tick_or_the_documented_fallback_is_not_stale():
    p = FakePlant([])
    up_to_the_blip(p)
    resent(p)
    assert check(p) == 0                    # the command stamped t_k
    # a member that finished (its FINAL) before the tick: its last command acts on
    p = FakePlant([])
    up_to_the_blip(p)
    p.ledger.finished[SQ] = K - T
    assert check(p) == 0
    # a member the others go on without (dropped): its last command acts until cmd_timeout
    p = FakePlant([])
    p.ledger.expected = set()
    up_to_the_blip(p)
    p.ledger.join("other")
    p.ledger.leave(SQ)
    assert check(p) == 0
    # a member that answered the tick without a command for the robot
    p = FakePlant([])
    up_to_the_blip(p)
    p.output(SQ, K, "sim/ack/" + SQ)
    assert check(p) == 0
    # a command for the tick that was rejected (bad values): counted in `rejected`, not here
    p = FakePlant([])
    up_to_the_blip(p)
    p.output(SQ, K, CMD)                    # the ledger took it; the plant refused it
    p.commands.refuse("robot1", K)
    assert check(p) == 0
    assert p.errors.total == 0


def test_a_command_the_ledger_took_but_that_is_not_the_one_applied_is_counted():
    """The ACK counted from a message whose command was then lost on the way to the
    commands (the other path a stale command could take): never silent."""
    p = FakePlant([])
    up_to_the_blip(p)
    p.output(SQ, K, CMD)                    # taken by the ledger, never filed as a command
    assert p.ledger.waiting_for(K) == []
    assert check(p) == 1 and p.errors.counts == {"stale command": 1}
