"""A member's per-tick bookkeeping is made once per configuration (bus/member.py): the
inputs a tick waits for follow the configuration in force, and a sample's attachment
covers later ticks exactly when it carries a hold."""
from __future__ import annotations

from bus import codec
from bus.keys import TOPICS
from bus.member import MemberTick, Slot

T = 20_000_000


class _Reads:
    inputs = ["joint_states", "gps", "odom"]

    def step(self, obs):
        return None


def _member(periods: dict, lag_ticks: int) -> MemberTick:
    m = MemberTick("m", T, slots=[Slot("robot1", _Reads(), list(_Reads.inputs), True)],
                   topics=dict(TOPICS))
    m.configure({"control_tick_s": T * 1e-9, "node_input_delay_ticks": lag_ticks,
                 "robots": {"robot1": {"topics": periods}}})
    return m


def _reference(m: MemberTick, t_ns: int) -> list:
    """needs() by its rule, input by input (input_stamp)."""
    slot = m.slots[0]
    out = []
    for t in slot.awaited:
        s = m.input_stamp(t_ns, slot.periods.get(t, 1), m.lag_ns[t])
        if s is not None:
            out.append((m.key(slot.robot, t), t, s))
    return out


def test_the_inputs_a_tick_waits_for_follow_each_configuration():
    m = _member({"joint_states": 1, "gps": 5}, 0)
    seen = []
    for periods, lag in (({"joint_states": 1, "gps": 5}, 0), ({"joint_states": 2, "gps": 3}, 1),
                         ({"joint_states": 1}, 2)):
        m.configure({"control_tick_s": T * 1e-9, "node_input_delay_ticks": lag,
                     "robots": {"robot1": {"topics": periods}}})
        for k in range(12):
            got = m.needs(m.slots[0], k * T)
            assert got == _reference(m, k * T), (periods, lag, k)
            seen.append(len(got))
    assert len(set(seen)) >= 3          # (the configurations differ in what a tick waits for)
    # a robot whose gps is not published any more waits for no gps
    assert all(t != "gps" for _, t, _ in m.needs(m.slots[0], 15 * T))


def test_a_sample_covers_later_ticks_only_when_its_attachment_holds():
    key = "robot1/odom"
    odom = codec.odometry(4 * T, 1.0, 2.0, 0.5, 0.1, 0.0)
    cases = [(codec.attachment(7, 4 * T, codec.with_hold(0, 3), 0, "odo"), (4 * T, 7 * T)),
             (codec.attachment(7, 4 * T, 0, 0, "odo"), None),
             (codec.attachment(7, 4 * T, epoch=12), None),                # the plant's
             (codec.attachment(7, 4 * T), None),
             (codec.attachment(7, 4 * T, codec.with_hold(codec.FINAL, 2), 0, "odo"), None)]
    for att, covered in cases:
        m = _member({"joint_states": 1}, 0)
        m.clock(4 * T)
        assert m.file_input(key, odom, att) is None
        assert m.covered.get(key) == covered, att


def test_a_tick_is_complete_exactly_by_needs_has_and_used():
    """_complete reads needs()' kept plan in place; it answers as needs(), _has() and the
    used marks say, robot by robot, whatever is filed, held, covered, used or done."""
    import random
    rnd = random.Random(5)
    robots = ["a", "b", "c"]
    answers = set()
    for case in range(300):
        m = MemberTick("m", T, slots=[Slot(r, _Reads(), list(_Reads.inputs), True)
                                      for r in robots], topics=dict(TOPICS))
        periods = rnd.choice(({"joint_states": 1, "gps": 5}, {"joint_states": 2, "gps": 3},
                              {"joint_states": 1}))
        m.configure({"control_tick_s": T * 1e-9, "node_input_delay_ticks": rnd.randint(0, 2),
                     "robots": {r: {"topics": periods} for r in robots}})
        t_ns = rnd.randint(0, 12) * T
        for slot in m.slots:
            slot.done = rnd.random() < 0.2
            for key, _, s in m.needs(slot, t_ns):
                roll = rnd.random()
                if roll < 0.8:
                    m.buf.setdefault(key, {})[s] = object()
                elif roll < 0.9:                  # an earlier sample whose producer holds
                    m.buf.setdefault(key, {})[s - T] = object()
                    m.covered[key] = (s - T, s + rnd.choice((-T, 0, T)))
                if rnd.random() < 0.1:
                    m.used.add((key, s))
        want = all(m._has(key, s) and (key, s) not in m.used
                   for slot in m.slots if not slot.done
                   for key, _, s in m.needs(slot, t_ns))
        assert m._complete(t_ns) is want, case
        answers.add(want)
    assert answers == {True, False}
