"""Each lockstep rule a held-out mutation audit could break unnoticed, pinned on its own, without
processes (docs/PROTOCOL.md section 4): the member's epoch, in-order answering, re-send and hold
rules (bus.member.MemberTick), the ledger's n_plant counting (bus.lockstep.AckLedger), the
hold's bound, and what a timed-out command leaves in the plant's book (plant.commands)."""
from __future__ import annotations

import pytest

from bus import codec
from bus.keys import TOPICS
from bus.lockstep import HOLD_PAST, AckLedger
from bus.member import MemberTick, Output, Slot
from bus.protocol import command_expired, info_max_hold, max_hold
from plant.commands import Command, CommandBook

T = 20_000_000          # one control tick, ns
CMD = "robot1/cmd_vel"


def ledger(**kw):
    errors: list[tuple[str, str]] = []
    led = AckLedger(T, lambda kind, text: errors.append((kind, text)), **kw)
    return led, errors


def send(led, node, t, flags=0, n_plant=0, key=CMD, topic="cmd_vel", now=10 * T):
    raw = codec.attachment(1, t, flags, n_plant, node)
    return led.file(key, topic, codec.parse_attachment(raw), raw, now)


def commander() -> MemberTick:
    """A member with no inputs: every tick it is told of is complete at once."""
    return MemberTick("n", T, ack_key="sim/ack/n")


def answer(m: MemberTick, t: int, speed: float = 0.25, hold: int = 0):
    m._out = [Output(CMD, codec.twist_stamped(t, speed, 0.0), True)]
    return m.send_tick(t, hold=hold)


# ---------------------------------------------------------------- the member: epochs
def test_a_clock_of_a_new_epoch_is_a_new_world_never_a_re_publish():
    """"Reset": in the first ticks a reset's stamps are ones the member answered; told by the
    epoch, it steps again instead of re-sending the old world's commands."""
    m = commander()
    sent = {}
    for k in range(3):
        assert m.clock(k * T, 1.0, epoch=0) == (None, None)
        assert m.next_due() == k * T
        sent[k] = answer(m, k * T, speed=0.25)
    assert m.clock(T, 1.0, epoch=0) == (sent[1], None)       # the same epoch: re-sent as it was
    assert m.clock(0, 1.0, epoch=1) == (None, None)          # a new world: nothing re-sent
    assert m.next_due() == 0                                 # its tick 0 is answered afresh
    new = answer(m, 0, speed=-0.25)
    assert new != sent[0]
    assert m.clock(0, 1.0, epoch=1) == (new, None)           # and that answer is what re-sends


def test_a_clock_of_an_older_epoch_is_the_old_world_s_late_and_ignored():
    """"Reset": any member, not only the one that asked: it neither answers nor re-sends it,
    and it does not take it for yet another world."""
    m = commander()
    m.clock(0, 1.0, epoch=3)
    m.next_due()
    sent = answer(m, 0)
    assert m.clock(T, 1.0, epoch=2) == (None, None) and m.next_due() is None
    assert m.clock(0, 1.0, epoch=3) == (sent, None)          # still the same world
    m.reset(epoch=4)                        # asked from inside step: the reply's new epoch
    assert m.clock(T, 1.0, epoch=3) == (None, None) and m.next_due() is None
    assert m.clock(0, 1.0, epoch=4) == (None, None) and m.next_due() == 0
    answer(m, 0)
    m.configure({"mode": "lockstep", "control_tick_s": T * 1e-9, "epoch": 0, "robots": {}})
    assert m.clock(0, 1.0, epoch=0) == (None, None) and m.next_due() == 0   # another run


def test_a_new_epoch_forgets_the_member_s_hold():
    m = commander()
    m.clock(0, 1.0, epoch=0)
    m.next_due()
    answer(m, 0, hold=5)
    assert m.holds(3 * T)
    m.clock(0, 1.0, epoch=1)                                 # a reset: its stamps start again
    assert not m.holds(T) and not m.holds(3 * T)


def test_a_member_that_resets_inside_its_step_answers_that_step_but_keeps_and_holds_nothing():
    """"Reset": the answer of the old world's last tick goes out (the plant ignores it as not
    due in the new world) but is no answer of the new world's: neither re-sent nor held."""
    m = commander()
    m.clock(0, 1.0, epoch=0)
    m.next_due()
    answer(m, 0)
    m.clock(T, 1.0, epoch=0)
    m.next_due()
    m.reset()                                                 # sim/reset asked from step()
    sent = answer(m, T, hold=3)
    assert sent and codec.hold_of(sent[-1][2]) == 3           # sent as the step made it
    assert T not in m.sent and not m.holds(2 * T)
    assert m.clock(0, 1.0, epoch=1) == (None, None) and m.next_due() == 0


# ---------------------------------------------------------------- the member: order
class _Reads:
    inputs = ["ground_truth"]

    def step(self, obs):
        return None


def test_a_member_answers_ticks_in_order_a_later_complete_one_waits_for_the_next():
    m = MemberTick("reader", T, slots=[Slot("robot1", _Reads(), ["ground_truth"], False)],
                   topics=dict(TOPICS), ack_key="sim/ack/reader")
    m.configure({"mode": "lockstep", "control_tick_s": T * 1e-9,
                 "robots": {"robot1": {"topics": {"ground_truth": 1}}}})

    def truth(k):
        m.file_input("robot1/ground_truth",
                     codec.odometry(k * T, 0.1 * k, 0.0, 0.0, 0.0, 0.0, "world", "robot1/base_link"),
                     codec.attachment(k + 1, k * T))
    m.clock(0, 1.0)
    truth(0)
    assert m.next_due() == 0
    m.clock(T, 1.0)
    m.clock(2 * T, 1.0)
    truth(2)                                 # tick 2 is complete, tick 1 (its input late) not
    assert m.next_due() is None
    truth(1)
    assert [m.next_due(), m.next_due(), m.next_due()] == [T, 2 * T, None]


# ---------------------------------------------------------------- the member: holding
def test_held_ticks_re_published_are_answered_with_nothing_and_the_next_one_in_full():
    m = commander()
    m.clock(0, 1.0, epoch=0)
    m.next_due()
    first = answer(m, 0, hold=2)
    assert all(codec.hold_of(f) == 2 for _, _, f, _ in first)
    for k in (1, 2):
        m.clock(k * T, 1.0, epoch=0)
        assert m.next_due() == k * T and m.holds(k * T)
        assert m.skip(k * T) == []
    m.clock(3 * T, 1.0, epoch=0)
    assert m.next_due() == 3 * T and not m.holds(3 * T)
    third = answer(m, 3 * T)
    # a blip: the plant re-publishes; each tick gets what it got, byte for byte
    assert [m.clock(k * T, 1.0, epoch=0)[0] for k in range(4)] == [first, [], [], third]


# ---------------------------------------------------------------- the ledger: n_plant
def test_n_plant_counts_the_member_s_messages_on_plant_read_keys_whatever_their_order():
    led, errors = ledger()
    led.join("a")
    led.begin_tick(0)
    # the ACK (on robot2's command, counted itself) comes before robot1's command
    send(led, "a", 0, codec.ACK, n_plant=2, key="robot2/cmd_vel")
    assert not led.done("a", 0) and led.waiting_for(0) == ["a"]
    send(led, "a", 0, key=CMD)                               # a second message on robot2's key
    assert led.done("a", 0)
    led.begin_tick(T)
    send(led, "a", T, codec.ACK, n_plant=2, key="robot2/cmd_vel")
    send(led, "a", T, key="robot2/cmd_vel")                  # the same key again: not counted
    assert not led.done("a", T)
    assert led.missing_outputs("a", T) == (2, 1)
    led.begin_tick(2 * T)
    send(led, "a", 2 * T, codec.ACK, n_plant=0, key="sim/ack/a", topic="ack")   # nothing to wait
    assert led.done("a", 2 * T)
    # a second ACK for a tick keeps the smaller n_plant: no stray ACK holds the run for ever
    led.begin_tick(3 * T)
    send(led, "a", 3 * T, codec.ACK, n_plant=1, key="robot2/cmd_vel")
    send(led, "a", 3 * T, codec.ACK, n_plant=3, key=CMD)
    assert led.done("a", 3 * T)
    assert [k for k, _ in errors] == ["robot2/cmd_vel: a second message from a for one tick",
                                      f"{CMD}: a second ACK from a"]


# ---------------------------------------------------------------- the bound
def test_the_hold_bound_is_the_last_tick_whose_command_still_acts():
    """(h + actuation delay) x tick <= cmd_timeout_s: the page's worked example, 0.5 s at 20 ms."""
    assert max_hold(T, 0.5, 0) == 25 and max_hold(T, 0.5, 1) == 24
    assert not command_expired(25 * T, 0.5) and command_expired(25 * T + 1, 0.5)
    assert max_hold(T, 0.3, 0) == 15 and not command_expired(15 * T, 0.3)   # 0.3 s: not 14
    assert max_hold(T, 5.0, 0) == 63 and max_hold(T, 0.01, 1) == 0
    info = {"control_tick_s": 0.02, "actuation_delay_ticks": 1,
            "robots": {"a": {"drive": {"cmd_timeout_s": 0.5}},
                       "b": {"drive": {"cmd_timeout_s": 0.3}}}}
    assert info_max_hold(info) == 14                          # the smallest timeout binds


def test_a_hold_past_the_bound_is_reported_by_name_and_still_answers_its_ticks():
    led, errors = ledger(expect=("a",))
    led.max_hold = 24
    led.join("a")
    led.begin_tick(0)
    send(led, "a", 0, codec.with_hold(codec.ACK, 24), n_plant=1, now=0)
    assert errors == []
    led.begin_tick(25 * T)
    send(led, "a", 25 * T, codec.with_hold(codec.ACK, 25), n_plant=1, now=25 * T)
    assert [k for k, _ in errors] == [HOLD_PAST]
    assert led.done("a", 50 * T) and not led.done("a", 51 * T)


def test_a_message_for_a_held_tick_is_told_as_held_however_far_the_plant_has_got():
    """Ignored either way; which error it counts must not depend on the plant's progress."""
    kinds = []
    for now in (0, 5 * T):
        led, errors = ledger()
        led.join("a")
        send(led, "a", 0, codec.with_hold(codec.ACK, 10), n_plant=1, now=now)
        assert send(led, "a", 3 * T, codec.ACK, n_plant=1, now=now) is False
        kinds.append(errors[-1][0])
    assert kinds == [f"{CMD}: a message from a for a tick it holds"] * 2


# ---------------------------------------------------------------- the plant's book
def test_a_timed_out_command_drops_itself_and_older_ones_never_a_later_one():
    """Pipelined, the member's next answer is often filed before the tick whose held command
    times out is applied: it must still act at its own tick."""
    book = CommandBook(lockstep=True)
    for t in (0, 26 * T):
        book.file("robot1", Command(codec.twist_stamped(t, 0.2, 0.0), t, 0.0, "a"))
    assert book.for_tick("robot1", 25 * T).t_ns == 0          # the held one, about to expire
    book.forget("robot1", 0)
    assert book.for_tick("robot1", 25 * T) is None            # gone: the robot stops
    assert book.for_tick("robot1", 26 * T).t_ns == 26 * T     # the next answer still acts
    assert book.latest["robot1"].t_ns == 26 * T


@pytest.mark.parametrize("delay", [0, 1])
def test_the_plant_applies_the_bound_the_page_states(delay):
    """plant.modes.Lockstep.expired: a command held the bound's ticks still acts on the last
    one, one more tick and it is past cmd_timeout_s."""
    from plant.modes import Lockstep

    class Host:
        tick_ns = T
        time_ns = 0
    host = Host()
    mode = Lockstep(host, "pipelined" if delay else "sequential")
    cmd = Command(None, 40 * T, 0.0, "a")
    h = max_hold(T, 0.5, delay)
    host.time_ns = cmd.t_ns + (h + delay) * T                 # the last held tick's turn
    assert not mode.expired(cmd, 0.5)
    host.time_ns += T
    assert mode.expired(cmd, 0.5)
