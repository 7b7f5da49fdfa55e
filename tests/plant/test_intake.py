"""A composed member's answer to a tick, filed at once, has the effects of its messages filed
one by one (plant/intake.py): the ledger's filing and protocol errors, the commands and
their rejections; and the tick's commands are handed over as the rule says robot by robot.
No processes, no Zenoh: the plant's intake on its real ledger, command book and mode."""
from __future__ import annotations

import math
import threading
from types import SimpleNamespace

import pytest

from bus import codec
from bus.controller import Twist
from bus.keys import NAME_MAX
from bus.lockstep import AckLedger
from plant import modes
from plant.commands import CommandBook
from plant.intake import Intake

T = 20_000_000
NOW = 50 * T
ROBOTS = ("r0", "r1", "r2", "r3")
DRIVE = SimpleNamespace(max_linear_mps=0.5, max_angular_radps=2.0, max_wheel_speed_radps=10.0,
                        cmd_timeout_s=0.5)


class Said:
    """A RejectCounter's interface that keeps every (reason, detail)."""

    def __init__(self) -> None:
        self.said: list[tuple[str, str]] = []

    def reject(self, reason: str, detail: str = "") -> None:
        self.said.append((reason, detail))


def plant(coupling: str = "sequential", now: int = NOW) -> SimpleNamespace:
    quiet = SimpleNamespace(warning=lambda *a: None, info=lambda *a: None)
    p = SimpleNamespace(
        tick_ns=T, log=quiet, rejects=Said(), protocol_errors=Said(),
        commands=CommandBook(lockstep=True), stop_event=threading.Event(),
        sim=SimpleNamespace(time_ns=now, robots={r: SimpleNamespace(
            spec=SimpleNamespace(drive=DRIVE)) for r in ROBOTS}),
        _robot_of_key={f"{r}/{t}": (r, t) for r in ROBOTS for t in ("cmd_vel", "wheel_cmd")},
        _ack_prefix="sim/ack/", _key=lambda r, t: f"{r}/{t}", driven=[])
    p.time_ns = now
    p.ledger = AckLedger(T, p.protocol_errors.reject)
    p.strategy = modes.Lockstep(p, coupling)
    p.tick = SimpleNamespace(drive=lambda r, v: p.driven.append((r, v)))
    p.intake = Intake(p)
    return p


def answer(member: str, t: int, cmds: list, acked: bool = True) -> list:
    """A member's messages for tick ``t`` as Composed._send hands them over: each command
    (robot, linear, angular) as a cmd_vel with its values, or (robot, left, right, "wheels")
    as a wheel_cmd; the ACK with n_plant on the last."""
    sent = []
    for c in cmds:
        if c[-1] == "wheels":
            payload = codec.encode(codec.joint_state(t, [], velocity=c[1:3]))
            sent.append((f"{c[0]}/wheel_cmd", payload, None))
        else:
            sent.append((f"{c[0]}/cmd_vel", codec.twist_stamped_bytes(t, c[1], c[2]),
                         (t, float(c[1]), float(c[2]))))
    flags = [codec.ACK if acked and i == len(sent) - 1 else 0 for i in range(len(sent))]
    n_plant = [len(sent) if f else 0 for f in flags]
    atts = codec.attachments_parsed(7, t, list(zip(flags, n_plant)), member)
    return [(k, p, a, parsed, tw) for (k, p, tw), (a, parsed) in zip(sent, atts)]


def effects(p) -> tuple:
    book = p.commands
    cmds = {r: {t: (c.value, c.t_ns, c.member) for t, c in ticks.items()}
            for r, ticks in book.by_tick.items()}
    latest = {r: (c.value, c.t_ns, c.member) for r, c in book.latest.items()}
    led = p.ledger
    return (cmds, latest, dict(book.refused), p.rejects.said, p.protocol_errors.said,
            led.acks, led.member_msgs, led.finished)


NAN = math.nan
CASES = {
    "good": [("a", NOW, [("r0", 0.2, 0.1), ("r1", 0.3, -0.5), ("r2", 0.0, 0.0)])],
    # refused commands among good ones (non-finite, absurd); a wheel command (its bytes)
    "bad among good": [("a", NOW, [("r0", 0.2, 0.1), ("r1", NAN, 0.0), ("r2", 9.0, 0.0),
                                    ("r3", 1.0, 2.0, "wheels")])],
    # stamped for a tick not due, off the grid, from a non-member: reported per message
    "not due": [("a", NOW + T, [("r0", 0.2, 0.1), ("r1", 0.1, 0.1)])],
    "off grid": [("a", NOW - 7, [("r0", 0.2, 0.1), ("r1", 0.1, 0.1)])],
    "stranger": [("zed", NOW, [("r0", 0.2, 0.1), ("r1", 0.1, 0.1)])],
    # a command older than cmd_timeout (refused), then a second answer to the same tick
    "too old": [("a", NOW - 30 * T, [("r0", 0.2, 0.1)])],
    "twice": [("a", NOW, [("r0", 0.2, 0.1), ("r1", 0.1, 0.1)]),
              ("a", NOW, [("r0", 0.4, 0.1), ("r1", 0.3, 0.1)])],
    # two members command one robot: the name that sorts first is applied
    "two members": [("b", NOW, [("r0", 0.2, 0.1)]), ("a", NOW, [("r0", 0.3, 0.1)])],
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_an_answer_filed_at_once_has_the_effects_of_its_messages_one_by_one(case):
    whole, one_by_one = plant(), plant()
    for p in (whole, one_by_one):
        p.ledger.join("a")
        p.ledger.join("b")
        p.ledger.begin_tick(NOW)
    for member, t, cmds in CASES[case]:
        msgs = answer(member, t, cmds)
        whole.intake.answer(msgs)
        for key, payload, att, parsed, twist in msgs:
            one_by_one.intake.output(key, payload, att, parsed, twist)
    assert effects(whole) == effects(one_by_one)
    if case == "bad among good":                       # the good ones filed, the bad counted
        assert set(whole.commands.by_tick) == {"r0", "r3"}
        assert [r for r, _ in whole.rejects.said] == ["r1/cmd_vel", "r2/cmd_vel"]
        assert whole.ledger.waiting_for(NOW) == ["b"]   # a's answer complete all the same


def test_a_member_s_attachments_made_at_once_are_those_made_one_by_one():
    """Also a name too long and a FINAL with a hold, which parse as nothing."""
    sent = [("r0/cmd_vel", b"", 0, 0), ("r1/cmd_vel", b"", 0, 0), ("k", b"", codec.ACK, 2)]
    final = sent[:2] + [("k", b"", codec.with_hold(codec.ACK | codec.FINAL, 2), 2)]
    for node, msgs in (("avoid_g0", sent), (None, sent), ("é" * 3, sent),
                       ("x" * (NAME_MAX + 1), sent), ("avoid_g0", final)):
        got = codec.attachments_parsed(41, NOW, [(f, n) for _, _, f, n in msgs], node)
        want = [codec.attachment(41 + i, NOW, f, n, node)
                for i, (_, _, f, n) in enumerate(msgs, 1)]
        assert got == [(a, codec.parse_attachment(a)) for a in want]


@pytest.mark.parametrize("coupling", ["sequential", "pipelined"])
def test_the_tick_s_commands_are_handed_over_as_the_rule_says_robot_by_robot(coupling):
    """r0 has the tick's command; r1 one older than the tick but within cmd_timeout (stale:
    a protocol error, still applied); r2 one past cmd_timeout (stopped, forgotten); r3 none."""
    p = plant(coupling)
    due = NOW - p.strategy.delay_ns
    p.ledger.join("a")
    for r, t in (("r0", due), ("r1", due - 3 * T), ("r2", due - 40 * T)):
        p.commands.file(r, modes.Command(Twist(0.2, 0.0), t, 0.0, "a"))
    p.intake.apply()
    assert p.driven == [("r0", Twist(0.2, 0.0)), ("r1", Twist(0.2, 0.0)), ("r2", None),
                        ("r3", None)]
    assert [d.split(":")[0] for k, d in p.protocol_errors.said] == ["r1", "r2", "r3"]
    assert {k for k, _ in p.protocol_errors.said} == {"stale command"}
    assert "r2" not in p.commands.by_tick or not p.commands.by_tick["r2"]
    # every robot with the tick's command: nothing stale, nothing said
    p = plant(coupling)
    for r in ROBOTS:
        p.commands.file(r, modes.Command(Twist(0.1, 0.0), due, 0.0, "a"))
    p.intake.apply()
    assert p.protocol_errors.said == [] and [v for _, v in p.driven] == [Twist(0.1, 0.0)] * 4
    # every robot with a command, one of them older than the tick's: stale, said
    p = plant(coupling)
    p.ledger.join("a")
    for r in ROBOTS:
        p.commands.file(r, modes.Command(Twist(0.1, 0.0), due - T * (r == "r2"), 0.0, "a"))
    p.intake.apply()
    assert [d.split(":")[0] for k, d in p.protocol_errors.said] == ["r2"]
