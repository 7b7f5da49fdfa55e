"""--end-with is exact under pipelined coupling even when the finishing member leaves as
soon as the plant publishes the next tick (under load its token's withdrawal can reach the
plant together with the FINAL ack, before the plant has looked for it)."""
from __future__ import annotations

import json
import queue
import time

import pytest
import zenoh

from bus import codec
from bus.keys import Keys

from ..support import patience

#: background: no wall-clock bound here; runs beside the serial tests, its processes at the
#: low CPU priority (tests/conftest.py)
pytestmark = pytest.mark.background

K = Keys()
TICK_NS = 20_000_000


def member_ends(s):
    """What a hand-driven member needs: the ``sim/clock`` stamps it sees (a queue, in order),
    their subscriber, and robot1's cmd_vel publisher."""
    clocks: queue.SimpleQueue = queue.SimpleQueue()
    sub = s.declare_subscriber(K.clock, lambda smp: clocks.put(codec.msg_stamp_ns(
        codec.decode(smp.payload.to_bytes(), "rosgraph_msgs/msg/Clock"))))
    pub = s.declare_publisher(K.topic("robot1", "cmd_vel"),
                              encoding=zenoh.Encoding.APPLICATION_CDR,
                              congestion_control=zenoh.CongestionControl.BLOCK)
    return clocks, sub, pub


@pytest.mark.slow
@pytest.mark.parametrize("coupling", ["sequential", "pipelined"])
def test_a_member_that_leaves_at_the_next_tick_after_final_still_ends_the_run(procs, endpoint, bus,
                                                                    tmp_path, coupling):
    stats = tmp_path / "plant.json"
    plant = procs.diffbot("plant", "--world", "empty", "--coupling", coupling, "--expect",
                          "quitter", "--end-with", "quitter", "--endpoint", endpoint,
                          "--stats", str(stats), name="plant")
    s = bus()
    clocks, sub, pub = member_ends(s)
    tok = s.liveliness().declare_token(K.sync("quitter"))
    last = 10 * TICK_NS
    seq = 0
    try:
        while True:
            t = patience.get(clocks, 20, plant.pid, what="sim/clock")
            seq += 1
            final = codec.FINAL if t == last else 0
            pub.put(codec.encode(codec.twist_stamped(t, 0.1, 0.0)),
                    attachment=codec.attachment(seq, t, codec.ACK | final, 1, "quitter"))
            if final:
                break
        # Leave as soon as the plant publishes a later tick (or ends): pipelined, the plant
        # publishes last + 1 tick before it looks at the acks of `last`, so the token's
        # withdrawal can reach it with the FINAL (what the node did before lingering longer).
        while plant.poll() is None:
            try:
                if clocks.get(timeout=0.05) > last:
                    break
            except queue.Empty:
                pass
    finally:
        tok.undeclare()
        pub.undeclare()
        sub.undeclare()
    patience.wait_until(lambda: plant.poll() is not None, 30, plant.pid, what="the plant's end")
    assert plant.wait() == 0, procs.log(plant)
    st = json.loads(stats.read_text())
    assert st["end_reason"] == "quitter finished", procs.log(plant)
    # the plant stops at the tick it has published when it takes the FINAL
    assert st["sim_time_s"] == pytest.approx((last + (TICK_NS if coupling == "pipelined"
                                                       else 0)) * 1e-9)


@pytest.mark.slow
def test_a_lost_member_holds_time_and_is_waited_for_where_it_left(procs, endpoint, bus,
                                                                 tmp_path):
    """A lockstep plant never runs alone: with --rejoin-timeout the plant holds
    the tick its lost member left at, re-publishes it when the member is back, and waits
    for its answer there, not a tick older than its last ACK."""
    stats = tmp_path / "plant.json"
    plant = procs.diffbot("plant", "--world", "empty", "--expect", "first", "--coupling",
                          "pipelined", "--rejoin-timeout", "30", "--endpoint", endpoint,
                          "--stats", str(stats), name="plant")
    s = bus()
    clocks, sub, pub = member_ends(s)
    seq = 0
    answered: list[int] = []

    def answer(ticks: int, speed: float = 0.3) -> None:
        nonlocal seq
        for _ in range(ticks):
            t = patience.get(clocks, 20, plant.pid, what="sim/clock")
            if answered and t <= answered[-1]:
                continue                      # re-published: the plant has our answer
            seq += 1
            pub.put(codec.encode(codec.twist_stamped(t, speed, 0.0)),
                    attachment=codec.attachment(seq, t, codec.ACK, 1, "first"))
            answered.append(t)

    try:
        tok = s.liveliness().declare_token(K.sync("first"))
        answer(5)
        tok.undeclare()                       # lost: the plant holds its tick
        patience.wait_until(lambda: "member lost: first" in procs.log(plant), 10, plant.pid,
                            what="first gone")
        time.sleep(1.0)
        held = []
        while not clocks.empty():
            held.append(clocks.get())
        # pipelined: tick k is published before the ACKs of t(k-1) are waited for, so it had
        # published the tick after our last answer, or (our loss seen after that ACK) the one
        # after it too, and holds there
        assert held in ([], [answered[-1] + TICK_NS],
                        [answered[-1] + TICK_NS, answered[-1] + 2 * TICK_NS]), held
        assert plant.poll() is None
        tok = s.liveliness().declare_token(K.sync("first"))
        patience.wait_until(lambda: "member rejoined: first" in procs.log(plant), 10,
                            plant.pid, what="the plant to see it back")
        answer(12)
        assert answered == [k * TICK_NS for k in range(len(answered))], answered
        tok.undeclare()
    finally:
        pub.undeclare()
        sub.undeclare()
    plant.terminate()
    patience.wait_until(lambda: plant.poll() is not None, 20, plant.pid, what="the plant's exit")
    st = json.loads(stats.read_text())
    assert st["members_seen"] == ["first"] and st["protocol_errors"] == {}, st


@pytest.mark.slow
def test_a_watcher_back_before_the_first_step_gets_tick_0_again(procs, endpoint, bus, tmp_path):
    """A router blip right after the run starts (tests/network/test_router_blip.py met it: its
    recording lacked the t=0 cmd_vel): the recorder comes back after the members answered
    t=0, so the plant re-publishes t=0 for it, as for any tick, and the members re-send
    their answers. Here a hand-driven member withholds t=0 while a watcher's sim/alive
    token goes and comes back; the watcher must see t=0 published again."""
    plant = procs.diffbot("plant", "--world", "empty", "--expect", "first", "--coupling",
                          "sequential", "--rejoin-timeout", "30", "--endpoint", endpoint,
                          name="plant")
    s, w = bus(), bus()
    clocks, sub, pub = member_ends(s)
    seen: queue.SimpleQueue = queue.SimpleQueue()
    wsub = w.declare_subscriber(K.clock, lambda smp: seen.put(codec.msg_stamp_ns(
        codec.decode(smp.payload.to_bytes(), "rosgraph_msgs/msg/Clock"))))
    watcher = w.liveliness().declare_token(K.alive("recorder"))
    tok = s.liveliness().declare_token(K.sync("first"))
    try:
        assert patience.get(clocks, 20, plant.pid, what="sim/clock") == 0
        assert patience.get(seen, 5, plant.pid, what="the watcher's sim/clock") == 0
        again = None
        for away_s in (0.5, 1.0, 2.0):          # (longer if the plant missed it going)
            watcher.undeclare()                 # the recorder is away ...
            time.sleep(away_s)
            watcher = w.liveliness().declare_token(K.alive("recorder"))   # ... and back
            try:
                again = patience.get(seen, 5, plant.pid, what="t=0 again")
                break
            except queue.Empty:
                continue
        assert again == 0, "t=0 not re-published for the watcher back"
        assert "recorder is back" in procs.log(plant)
        pub.put(codec.encode(codec.twist_stamped(0, 0.1, 0.0)),
                attachment=codec.attachment(1, 0, codec.ACK, 1, "first"))
        later = patience.get(seen, 10, plant.pid, what="the next tick")
        while later == 0:                       # (more re-publishes of t=0 may follow)
            later = patience.get(seen, 10, plant.pid, what="the next tick")
        assert later == TICK_NS
    finally:
        for d in (tok, watcher, pub, sub, wsub):
            d.undeclare()
    plant.terminate()
    patience.wait_until(lambda: plant.poll() is not None, 20, plant.pid, what="the plant's exit")
    assert plant.wait() == 0, procs.log(plant)
