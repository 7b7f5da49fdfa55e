"""A composed member's Twists for many robots, filed and applied whole (plant/intake.py,
plant/command_rows.py), have the effects of the same answers filed message by message and
applied robot by robot: tick by tick the same commands driven and the same protocol errors,
and at the end the same command book and ledger, through answers that go whole and ones
that cannot (a refused value, a member silent past the command timeout, a second member
for a robot, a process member's command, an answer twice, ticks filed with none applied
past the book's memory), under both couplings. No processes, no Zenoh."""
from __future__ import annotations

import math
import random

import pytest

from bus.controller import Twist
from plant.commands import Command

from .test_intake import ROBOTS, T, answer, effects, plant


def _driven_at_once(p) -> None:
    """The plant's tick with the core's one-assignment hand-over, recorded robot by robot
    (a robot told to stand still is a zero Twist, as :meth:`plant.tick.Tick.drive` files
    None)."""
    def drive_twists(names, values):
        p.whole = getattr(p, "whole", 0) + 1
        p.driven.extend((n, Twist(*v)) for n, v in zip(names, values.tolist()))
    p.tick.drive_twists = drive_twists


def _standing(driven: list) -> list:
    """What acts: each robot's last command filed in the tick (None: a zero Twist)."""
    return sorted((n, v if v is not None else Twist(0.0, 0.0))
                  for n, v in dict(driven).items())


def _script(seed: int, ticks: int) -> list[tuple[int, list]]:
    """Per tick: the answers ((member, stamp, [(robot, linear, angular)]) or a process
    member's single command (robot, linear, angular, member)), and whether it is applied."""
    rng = random.Random(seed)
    out = []
    for k in range(ticks):
        t = k * T
        plan = []
        for member, robots in (("a", ROBOTS[:2]), ("b", ROBOTS[2:])):
            if 10 <= k < 50 and member == "b":
                continue                      # silent past cmd_timeout, and past 32 ticks
            cmds = [(r, round(rng.uniform(-0.5, 0.5), 3), round(rng.uniform(-2, 2), 3))
                    for r in robots]
            roll = rng.random()
            if roll < 0.05:
                cmds[0] = (cmds[0][0], math.nan, 0.0)      # refused
            elif roll < 0.1:
                cmds[-1] = (cmds[-1][0], 9.0, 0.0)         # absurd
            stamp = t - T if roll > 0.97 and k else t      # an old tick's stamp
            plan.append((member, stamp, cmds))
            if rng.random() < 0.05:
                plan.append((member, stamp, cmds))         # the same answer twice
        if rng.random() < 0.08:                            # a second member for r1
            plan.append(("c", t, [("r1", 0.1, 0.1)]))
        if rng.random() < 0.08:                            # a process member's command
            plan.append(("r3", 0.2, -0.1, "d"))
        out.append((t, plan, not 70 <= k < 110))           # 40 ticks filed, none applied
    return out


@pytest.mark.parametrize("coupling", ["sequential", "pipelined"])
@pytest.mark.parametrize("seed", [1, 2])
def test_twists_filed_and_applied_whole_have_the_effects_of_one_by_one(coupling, seed):
    rows, one = plant(coupling, 0), plant(coupling, 0)
    _driven_at_once(rows)
    for p in (rows, one):
        for m in ("a", "b", "c", "d"):
            p.ledger.join(m)
    for t, plan, applied in _script(seed, 160):
        for p in (rows, one):
            p.sim.time_ns = p.time_ns = t
            p.ledger.begin_tick(t)
        for item in plan:
            if item[-1] == "d":
                robot, a, b, member = item
                msgs = answer(member, t, [(robot, a, b)])
                for p in (rows, one):
                    for key, payload, att, parsed, twist in msgs:
                        p.intake.output(key, payload, att, parsed, twist)
                continue
            member, stamp, cmds = item
            msgs = answer(member, stamp, cmds)
            rows.intake.answer(msgs, ([m[0] for m in msgs], stamp, [float(c[1]) for c in cmds],
                                      [float(c[2]) for c in cmds]))
            one.intake.answer(msgs)
        if applied:
            for p in (rows, one):
                p.intake.apply()
        assert _standing(rows.driven) == _standing(one.driven), t
        assert rows.protocol_errors.said == one.protocol_errors.said, t
        assert rows.rejects.said == one.rejects.said, t
        rows.driven.clear()
        one.driven.clear()
    assert one.protocol_errors.said and one.rejects.said     # the script said something
    assert effects(rows) == effects(one)
    assert rows.whole >= 50               # (of the 120 ticks applied: the rest robot by robot)


def test_a_member_s_twists_are_taken_whole():
    """The usual answer is filed whole, and picked and handed over in one assignment;
    each command is then the one the book gives robot by robot."""
    p = plant("pipelined", 0)
    _driven_at_once(p)
    calls = []
    p.tick.drive = lambda r, v: calls.append(r)           # (robot by robot: not used)
    p.ledger.join("a")
    for k in range(3):
        t = k * T
        p.sim.time_ns = p.time_ns = t
        p.ledger.begin_tick(t)
        cmds = [(r, 0.1 * k, -0.1 * i) for i, r in enumerate(ROBOTS)]
        msgs = answer("a", t, cmds)
        p.intake.answer(msgs, ([m[0] for m in msgs], t, [c[1] for c in cmds],
                               [c[2] for c in cmds]))
        p.intake.apply()
    assert calls == [] and not p.commands.rows.apart
    assert p.driven[-4:] == [(r, Twist(0.1, -0.1 * i)) for i, r in enumerate(ROBOTS)]
    assert p.protocol_errors.said == []
    assert p.commands.for_tick("r2", 2 * T) == Command(Twist(0.2, -0.2), 2 * T,
                                                       p.commands.by_tick["r2"][2 * T].wall,
                                                       "a")
