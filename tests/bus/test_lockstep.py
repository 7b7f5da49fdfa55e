"""The lockstep rules of docs/PROTOCOL.md section 4, each side on its own, without processes:
the plant's ACK ledger and a member's tick (bus/lockstep.py)."""
from __future__ import annotations

import pytest

from bus import codec
from bus.lockstep import AckLedger
from bus.member import MemberTick, Output

T = 20_000_000          # one control tick, ns
CMD = "robot1/cmd_vel"


def ledger(end_with=(), expect=()):
    errors: list[tuple[str, str]] = []
    led = AckLedger(T, lambda kind, text: errors.append((kind, text)), end_with, expect)
    return led, errors


def att(node, t, flags=0, n_plant=0, seq=1):
    raw = codec.attachment(seq, t, flags, n_plant, node)
    return codec.parse_attachment(raw), raw


def send(led, node, t, flags=0, n_plant=0, key=CMD, topic="cmd_vel", now=10 * T):
    a, raw = att(node, t, flags, n_plant)
    return led.file(key, topic, a, raw, now)


# ---------------------------------------------------------------- the plant's ledger
def test_a_member_is_done_with_a_tick_once_its_ack_and_all_its_messages_are_in():
    led, errors = ledger()
    led.join("a")
    led.begin_tick(0)
    assert led.waiting_for(0) == ["a"]
    send(led, "a", 0, key="robot1/odom", topic="odom")      # 1 of 2, no ACK
    assert led.waiting_for(0) == ["a"]
    send(led, "a", 0, codec.ACK, n_plant=2)                  # 2 of 2, with the ACK
    assert led.waiting_for(0) == [] and led.done("a", 0)
    assert errors == []


def test_an_ack_whose_messages_did_not_all_come_is_reported_as_missing_outputs():
    led, errors = ledger()
    led.join("a")
    led.begin_tick(0)
    send(led, "a", 0, codec.ACK, n_plant=3)
    assert led.missing_outputs("a", 0) == (3, 1)
    assert led.waiting_for(0) == ["a"]
    assert led.describe_wait(0, ["a"]) == ["a (ACKed with n_plant=3, 1 arrived)"]
    assert not errors or errors[-1][0] != "missing outputs"     # describing counts nothing
    led.report_missing(0, ["a"])
    assert errors[-1][0] == "missing outputs" and "n_plant=3 but 1" in errors[-1][1]


def test_a_tick_is_owed_by_the_members_present_when_it_began():
    """Pipelined: the ACKs of t_{k-1} are looked at during tick k; a member that joined
    since tick k-1 began may never have seen its clock."""
    led, _ = ledger()
    led.join("a")
    led.begin_tick(0)
    led.join("late")
    led.begin_tick(T)
    send(led, "a", 0, codec.ACK, n_plant=1)
    assert led.waiting_for(0) == []                 # late not owed t0
    assert led.waiting_for(T) == ["a", "late"]      # but t1


def test_a_member_that_leaves_is_not_waited_for_but_its_final_is_kept():
    led, _ = ledger(end_with=("a",))
    led.join("a")
    led.join("b")
    led.begin_tick(T)
    send(led, "a", T, codec.ACK | codec.FINAL, n_plant=1)
    led.leave("a")
    assert led.ended(T) == ["a"] and led.ended(0) == []
    assert led.waiting_for(T) == ["b"]
    led.leave("b")
    assert led.waiting_for(T) == []


def test_nobody_is_waited_for_after_their_final():
    led, _ = ledger()
    led.join("a")
    send(led, "a", T, codec.ACK | codec.FINAL, n_plant=1)
    led.begin_tick(2 * T)
    assert led.waiting_for(2 * T) == []


def test_an_end_with_member_gone_before_its_final_gets_its_grace_once():
    led, _ = ledger(end_with=("a",))
    led.join("a")
    led.leave("a")
    assert led.left_before_final() == ["a"]
    assert led.left_before_final() == []
    led.join("a")                                   # back: it may be given it again
    led.leave("a")
    assert led.left_before_final() == ["a"]


def test_a_second_ack_is_an_error_and_the_smaller_count_is_kept():
    led, errors = ledger()
    led.join("a")
    led.begin_tick(0)
    send(led, "a", 0, codec.ACK, n_plant=5)
    send(led, "a", 0, codec.ACK, n_plant=1, key="robot1/odom", topic="odom")
    assert errors[-1][0] == "robot1/odom: a second ACK from a"
    assert led.missing_outputs("a", 0) == (1, 2) and led.done("a", 0)


def test_bad_member_messages_are_counted_and_ignored_or_applied_as_the_page_says():
    led, errors = ledger()
    led.join("a")
    # no attachment: a command from a non-member, applied, never waited for
    assert led.file(CMD, "cmd_vel", None, None, 0) is True
    # an odometry node of realtime style: not ours, no error
    assert led.file("robot1/odom", "odom", None, None, 0) is False
    # an empty ACK without a trailer: ignored
    plain = codec.attachment(1, 0)
    assert led.file("sim/ack/a", "ack", codec.parse_attachment(plain), plain, 0) is False
    assert send(led, "a", T + 1) is False                     # off the tick grid
    assert send(led, "a", 11 * T, now=10 * T) is False        # not due yet
    assert send(led, "stranger", 0) is True                   # used, not waited for
    kinds = [k for k, _ in errors]
    assert kinds == [f"{CMD}: no attachment", "sim/ack/a: a plain 16-byte attachment "
                     "(no member trailer)", f"{CMD}: stamp off the tick grid",
                     f"{CMD}: stamped for a tick not due",
                     f"{CMD}: from 'stranger', not a lockstep member"]


def test_a_restart_forgets_the_old_world_s_acks():
    led, _ = ledger(end_with=("a",))
    led.join("a")
    led.begin_tick(0)
    send(led, "a", 0, codec.ACK | codec.FINAL, n_plant=1)
    led.restart()
    led.begin_tick(0)
    assert led.waiting_for(0) == ["a"] and led.ended(0) == []


def test_the_ledger_remembers_a_bounded_number_of_ticks():
    led, _ = ledger()
    led.join("a")
    for k in range(200):
        led.begin_tick(k * T)
        send(led, "a", k * T, codec.ACK, n_plant=1, now=k * T)
    assert len(led.acks["a"]) <= 32 and len(led.owed_by) <= 32
    assert len(led.member_msgs) <= 4 * 32


def test_the_first_message_per_key_per_tick_wins_and_a_second_is_an_error():
    """A second cmd_vel for the same tick is an error, never applied or not by timing."""
    led, errors = ledger()
    led.join("a")
    led.begin_tick(0)
    assert send(led, "a", 0, codec.ACK, n_plant=1) is True
    assert send(led, "a", 0, codec.ACK, n_plant=1) is False          # never applied
    assert errors == [(f"{CMD}: a second message from a for one tick",
                       "t=0.000 s; the first is kept, this one ignored")]
    # a duplicate is not one of the n_plant messages of the tick either
    led.begin_tick(T)
    send(led, "a", T, key="robot1/odom", topic="odom")
    send(led, "a", T, key="robot1/odom", topic="odom")
    assert led.waiting_for(T) == ["a"]
    send(led, "a", T, codec.ACK, n_plant=2)
    assert led.waiting_for(T) == []


def test_an_expected_member_gone_without_final_is_lost_and_held_for():
    led, _ = ledger(expect=("a",))
    led.join("a")
    led.join("b")
    led.begin_tick(0)
    assert led.leave("a") == "lost" and led.held_for() == ["a"]
    assert led.leave("b") == "lost"                    # the last member: never run alone
    assert led.held_for() == ["a", "b"]


def test_an_unexpected_member_is_dropped_unless_last_or_the_link_is_lost():
    led, _ = ledger()
    for m in "abc":
        led.join(m)
    assert led.leave("a") == "dropped" and led.held_for() == []
    assert led.leave("b", link_lost=True) == "lost"
    assert led.leave("c") == "lost"


def test_a_process_gone_with_the_link_is_held_for_until_back_or_given_up():
    """A recorder (a sim/alive token, no membership) gone with the plant's link: time is
    held for it after the members, not for a member through this path, and until it is
    back or the plant gives up on it (the rejoin timeout); no step, no end meanwhile."""
    led, _ = ledger()
    led.join("a")
    led.begin_tick(0)
    send(led, "a", 0, codec.ACK, n_plant=1)
    assert led.gone_with_link("recorder")
    assert not led.gone_with_link("recorder")      # held for already
    assert not led.gone_with_link("a")             # a member: the ledger's own rules
    assert led.held_for() == ["recorder"] and not led.may_step(0)
    assert led.leave("a", link_lost=True) == "lost"
    assert led.held_for() == ["a", "recorder"]
    assert led.join("a") and led.held_for() == ["recorder"]
    send(led, "a", T, codec.ACK | codec.FINAL, n_plant=1)
    assert not led.all_finished(2 * T)             # the recorder would miss the end
    assert led.back("recorder") and not led.back("recorder")
    assert led.held_for() == [] and led.may_step(0) and led.all_finished(2 * T)
    led.gone_with_link("view")
    led.gone_with_link("recorder")
    assert led.give_up_away() == ["recorder", "view"] and led.held_for() == []


def test_a_watcher_that_says_what_it_took_in_is_kept_within_pace_ticks():
    """Section 4, "Watchers that keep up": a tick is not published while a reporting
    process is PACE_TICKS behind it; the latest report counts; a member's report is
    ignored; one held for is the hold's until back; gone, given up or a reset: forgotten."""
    from bus.lockstep import UNPACED_NS
    from bus.protocol import PACE_TICKS
    led, _ = ledger()
    led.join("a")
    assert led.behind(1000 * T) == []                       # nobody reports: no pacing
    led.saw("a", 0)                                          # a member: its ACKs pace it
    assert led.behind(1000 * T) == []
    led.saw("recorder", 5 * T)
    assert led.pace_ns == (5 + PACE_TICKS) * T               # the plant's check a tick
    assert led.behind((5 + PACE_TICKS) * T) == []
    assert led.behind((6 + PACE_TICKS) * T) == ["recorder"]
    led.saw("recorder", 6 * T)
    assert led.behind((6 + PACE_TICKS) * T) == []
    led.saw("recorder", 0)                                   # the latest counts (a reset's)
    assert led.behind((1 + PACE_TICKS) * T) == ["recorder"]
    assert led.gone_with_link("recorder")
    assert led.behind(1000 * T) == [] and led.held_for() == ["recorder"]   # the hold's
    assert led.pace_ns == UNPACED_NS
    led.back("recorder")
    assert led.behind(1000 * T) == ["recorder"]              # back: kept up with again
    assert led.pace_ns == PACE_TICKS * T
    led.gone_with_link("recorder")
    led.give_up_away()
    led.back("recorder")
    assert led.behind(1000 * T) == [] and led.pace_ns == UNPACED_NS   # given up: forgotten
    led.saw("view", 0)
    assert led.pace_ns == PACE_TICKS * T
    led.unseen("view")
    assert led.behind(1000 * T) == [] and led.pace_ns == UNPACED_NS   # its token went
    led.saw("view", 0)
    led.restart()
    assert led.behind(1000 * T) == []                        # the old world's stamps


def test_a_member_that_finished_is_not_lost_and_the_run_ends_when_all_have():
    led, _ = ledger(expect=("a",))
    led.join("a")
    led.join("b")
    send(led, "a", T, codec.ACK | codec.FINAL, n_plant=1)
    assert led.leave("a") == "finished" and led.held_for() == []
    assert not led.all_finished(2 * T)                   # b is still there
    send(led, "b", 2 * T, codec.ACK | codec.FINAL, n_plant=1)
    assert not led.all_finished(2 * T)                   # its FINAL command not acted yet
    assert led.all_finished(3 * T)


def test_a_rejoining_member_is_owed_every_tick_it_has_not_answered_none_it_has():
    """After a blip the plant waits for no tick older than the member's last ACK: a
    rejoin re-owes the ticks without its answer, and answers re-sent for ticks the plant
    has are dropped silently."""
    led, errors = ledger(expect=("a",))
    led.join("a")
    led.begin_tick(0)
    send(led, "a", 0, codec.ACK, n_plant=1, now=T)
    led.begin_tick(T)                                    # its answer to t1 is lost
    assert led.leave("a") == "lost"
    assert led.waiting_for(T) == []                      # gone: held for, not waited for
    assert led.join("a", now_ns=T) is True and led.held_for() == []
    assert led.waiting_for(0) == [] and led.waiting_for(T) == ["a"]
    send(led, "a", 0, codec.ACK, n_plant=1, now=T)      # re-sent: already had it
    send(led, "a", T, codec.ACK, n_plant=1, now=T)
    assert led.waiting_for(T) == [] and errors == []
    assert led.join("b") is False                        # a first join is no rejoin


def test_the_wait_reports_come_at_2_6_14_30_then_every_30_s():
    from itertools import islice

    from plant.modes import wait_reports
    assert list(islice(wait_reports(), 7)) == [2, 6, 14, 30, 60, 90, 120]


def test_one_command_per_robot_per_tick_whatever_the_arrival_order():
    from plant.commands import Command, CommandBook
    for order in ([("b", 1.0), ("a", 2.0), ("b", 3.0)], [("b", 3.0), ("a", 2.0), ("b", 1.0)]):
        book = CommandBook(lockstep=True)
        problems = [book.file("robot1", Command(v, T, 0.0, m)) for m, v in order]
        assert book.for_tick("robot1", T).value == 2.0             # a's: sorts first
        assert problems[1] is not None and "a's applied" in problems[1]
        book = CommandBook(lockstep=True)
        for m, v in order:
            if m == "b":
                book.file("robot1", Command(v, T, 0.0, m))
        assert book.for_tick("robot1", T).value == order[0][1]     # b's first stays


def test_the_command_for_a_tick_is_the_latest_at_or_before_it_and_older_ones_go():
    """for_tick: the command of the latest tick at or before the one asked (that very
    tick's, or an earlier one where none came for it); every older one is dropped, a later
    one waits for its turn."""
    from plant.commands import Command, CommandBook
    book = CommandBook(lockstep=True)
    for k in (0, 1, 2, 4, 5):
        book.file("robot1", Command(float(k), k * T, 0.0, "m"))
    assert book.for_tick("robot1", 2 * T).value == 2.0                  # its own tick's
    assert sorted(book.by_tick["robot1"]) == [2 * T, 4 * T, 5 * T]
    assert book.for_tick("robot1", 3 * T).value == 2.0                  # none for 3T: 2T's
    assert sorted(book.by_tick["robot1"]) == [2 * T, 4 * T, 5 * T]
    assert book.for_tick("robot1", 5 * T).value == 5.0
    assert sorted(book.by_tick["robot1"]) == [5 * T]
    assert book.for_tick("robot1", -T) is None and book.for_tick("robot2", T) is None


# ---------------------------------------------------------------- the member's tick
def test_a_member_sends_plant_read_outputs_last_and_acks_on_the_very_last():
    m = MemberTick("n", T)
    sent = m.owed([Output("robot1/cmd_vel", "c", True), Output("robot1/debug", "d", False),
                   Output("robot2/cmd_vel", "c2", True)], "sim/ack/n")
    assert [(k, f, n) for k, _, f, n in sent] == [("robot1/debug", 0, 0),
                                                  ("robot1/cmd_vel", 0, 0),
                                                  ("robot2/cmd_vel", codec.ACK, 2)]


def test_a_member_keeps_the_values_each_command_it_sends_was_packed_from():
    """What a composed member's plant takes instead of parsing the command back: for each
    cmd_vel sent, the values of those very bytes (the later of two queued on one key)."""
    from bus.controller import Twist
    m = MemberTick("n", T)
    m.queue_output(Twist(0.2, -0.1), 3 * T, "robot1")
    m.queue_output(Twist(0.0, 0.0), 3 * T, "robot1")           # a stop after the step's
    m.queue_output({"cmd_vel": Twist(1, 2)}, 3 * T, "robot2")  # ints, as a controller may
    sent = m.send_tick(3 * T)
    assert [k for k, *_ in sent] == ["robot1/cmd_vel", "robot2/cmd_vel"]
    for key, payload, _, _ in sent:
        data, *values = m.twists[key]
        assert data is payload and payload == codec.twist_stamped_bytes(*values)
        msg = codec.decode(payload, "geometry_msgs/msg/TwistStamped")
        assert values == [3 * T, msg.twist.linear.x, msg.twist.angular.z]
    assert m.twists["robot1/cmd_vel"][2:] == (0.0, 0.0)
    assert [type(v) for v in m.twists["robot2/cmd_vel"][2:]] == [float, float]


def test_a_member_sends_one_message_per_key_per_tick_the_last_queued():
    m = MemberTick("n", T)
    sent = m.owed([Output("robot1/cmd_vel", "go", True), Output("robot1/cmd_vel", "stop", True)],
                  "sim/ack/n", final=True)
    assert sent == [("robot1/cmd_vel", "stop", codec.ACK | codec.FINAL, 1)]


def test_a_member_with_no_plant_read_output_sends_an_empty_ack():
    m = MemberTick("n", T)
    sent = m.owed([Output("robot1/debug", "d", False)], "sim/ack/n", final=True)
    assert sent[-1] == ("sim/ack/n", None, codec.ACK | codec.FINAL, 0)
    assert m.owed([], "sim/ack/n") == [("sim/ack/n", None, codec.ACK, 0)]


def test_the_stamp_a_tick_needs_of_an_input():
    m = MemberTick("n", T)
    assert m.input_stamp(4 * T, 1, 0) == 4 * T          # a plant sensor due every tick
    assert m.input_stamp(4 * T, 5, 0) is None           # one due every 5 ticks
    assert m.input_stamp(5 * T, 5, 0) == 5 * T
    assert m.input_stamp(4 * T, 1, T) == 3 * T          # pipelined: another node's, t-1
    assert m.input_stamp(0, 1, T) is None               # none at the first tick


def test_a_member_leaves_after_a_clock_past_its_final_and_the_actuation_delay():
    seq, pipe = MemberTick("n", T, 0), MemberTick("n", T, 1)
    assert not seq.may_leave(5 * T, 5 * T) and seq.may_leave(5 * T, 6 * T)
    assert not pipe.may_leave(5 * T, 6 * T) and pipe.may_leave(5 * T, 7 * T)


def test_the_hold_goes_on_without_a_process_given_up_and_ends_for_a_member():
    """Lockstep.hold (plant/modes.py) past --rejoin-timeout: with only a non-member process
    (a recorder gone with the link) missing, the run goes on without it (None, exit code
    untouched, a warning naming it); with a member missing too, the run ends naming the
    member only (exit 1)."""
    import logging
    import threading
    import time

    from plant.modes import Lockstep

    class Host:
        tick_ns, rate, rejoin_timeout_s, exit_code, reset_in_tick = T, 0.0, 0.05, 0, False
        stop_event = threading.Event()
        time_ns = 0
        log = logging.getLogger("test-hold")

        def drain(self, timeout=0.0):
            time.sleep(timeout or 0.0)
            return False

    host = Host()
    host.ledger, _ = ledger()
    host.ledger.join("a")
    host.ledger.gone_with_link("recorder")
    assert Lockstep(host, "sequential").hold(4 * T) is None
    assert host.exit_code == 0 and host.ledger.held_for() == []
    host.ledger.gone_with_link("recorder")
    assert host.ledger.leave("a", link_lost=True) == "lost"
    why = Lockstep(host, "sequential").hold(4 * T)
    assert why == "lost lockstep member a at t=0.080 s (not back within --rejoin-timeout 0.05 s)"
    assert host.exit_code == 1


# ---------------------------------------------------------------- holding (section 4)
def test_an_ack_with_a_hold_answers_the_held_ticks_and_nothing_may_come_for_them():
    led, errors = ledger(expect=("a",))
    led.join("a")
    led.begin_tick(0)
    assert send(led, "a", 0, codec.with_hold(codec.ACK, 3), n_plant=1, now=0) is True
    for k in range(4):                                   # t0 ACKed, t1..t3 held
        led.begin_tick(k * T)
        assert led.waiting_for(k * T) == [] and led.done("a", k * T)
    assert led.holding("a", 3 * T) == 0 and led.holding("a", 4 * T) is None
    led.begin_tick(4 * T)
    assert led.waiting_for(4 * T) == ["a"]                # the hold is over: waited for again
    # a command for a held tick would act or not by timing: ignored whole, an error
    assert send(led, "a", 2 * T, codec.ACK, n_plant=1, now=4 * T) is False
    assert errors and "a tick it holds" in errors[-1][0]
    assert led.stale_command(2 * T, (CMD,), 0) is None   # t0's command acts at t2: the rule's
    # lost and back: the held ticks are not owed again (it would never answer them)
    assert led.leave("a") == "lost" and led.join("a", now_ns=4 * T) is True
    assert [led.waiting_for(k * T) for k in range(5)] == [[], [], [], [], ["a"]]
    led.restart()                                         # a reset forgets every hold
    assert led.holding("a", 2 * T) is None


def test_a_member_that_holds_marks_every_message_and_passes_the_held_ticks_sending_nothing():
    m = MemberTick("n", T, ack_key="sim/ack/n")
    m._out = [Output("robot1/cmd_vel", None, True), Output("robot1/debug", None, False)]
    sent = m.send_tick(0, hold=2)
    assert [(k, f) for k, _, f, _ in sent] == [("robot1/debug", codec.with_hold(0, 2)),
                                              ("robot1/cmd_vel", codec.with_hold(codec.ACK, 2))]
    assert [m.holds(k * T) for k in (1, 2, 3)] == [True, True, False]
    assert m.skip(T) == [] and m.sent[T] == []
    assert m.clock(T, 1.0) == ([], None)                   # re-published: answered with nothing
    m._out = [Output("robot1/cmd_vel", None, True)]
    with pytest.raises(ValueError, match="a tick this member holds"):
        m.skip(2 * T)
    with pytest.raises(ValueError, match="FINAL"):
        m.send_tick(3 * T, final=True, hold=1)


def _odom_reader() -> MemberTick:
    """A lockstep member that reads robot1's odom and commands nothing, configured."""
    from bus.keys import TOPICS
    from bus.member import Slot

    class Reads:
        inputs = ["odom"]

        def step(self, obs):
            return None
    m = MemberTick("reader", T, slots=[Slot("robot1", Reads(), ["odom"], False)],
                   topics=dict(TOPICS), ack_key="sim/ack/reader")
    m.configure({"mode": "lockstep", "control_tick_s": T * 1e-9,
                 "robots": {"robot1": {"topics": {}}}})
    return m


def test_a_reader_takes_a_holding_producer_s_sample_for_the_ticks_it_holds():
    m = _odom_reader()
    odom = codec.odometry(0, 1.0, 2.0, 0.0, 0.0, 0.0, "robot1/odom", "robot1/base_link")
    m.file_input("robot1/odom", odom, codec.attachment(1, 0, codec.with_hold(codec.ACK, 2), 1,
                                                       "odometry"))
    for k in range(4):
        m.clock(k * T, 1.0)
    assert [m.next_due() for _ in range(4)] == [0, T, 2 * T, None]   # t3: not held, not in
    for k in (0, 1, 2):
        assert m.take_observation(m.slots[0], k * T).msgs["odom"] is odom
    assert m.missing(3 * T) == ["odom"]


def test_an_observation_shows_the_latest_good_fresh_sample_and_drops_what_it_passed():
    """take_observation against the rule written out (docs/PROTOCOL.md section 4, step 2),
    over every buffer of one or two samples, good or held, older, at or newer than the tick,
    fresh or stale: what it shows, what it keeps, and the stamp it marks used."""
    import itertools
    from bus.member import _HELD, STALE_S

    m = _odom_reader()
    stale = STALE_S * 1e9
    stamps = [0, T, 5 * T, 30 * T, 60 * T]
    entries = [(s, v) for s in stamps for v in ("msg", _HELD)]
    for n, t in itertools.product((1, 2), stamps):
        for picked in itertools.combinations(entries, n):
            if len({s for s, _ in picked}) < n:
                continue
            buf = {s: (f"m{s}" if v == "msg" else v) for s, v in picked}
            good = [s for s, v in buf.items() if s <= t and v is not _HELD]
            best = max(good, default=None)
            shown = buf[best] if best is not None and t - best <= stale else None
            kept = {s: v for s, v in buf.items() if s > t or s == best}
            m.buf = {"robot1/odom": dict(buf)}
            m.used = set()
            obs = m.take_observation(m.slots[0], t)
            assert (obs["odom"], m.buf["robot1/odom"]) == (shown, kept), (buf, t)
            assert m.used == {("robot1/odom", t)}
