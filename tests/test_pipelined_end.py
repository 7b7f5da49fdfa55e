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
            t = clocks.get(timeout=20)
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
    assert plant.wait(30) == 0, procs.log(plant)
    st = json.loads(stats.read_text())
    assert st["end_reason"] == "quitter finished", procs.log(plant)
    # the plant stops at the tick it has published when it takes the FINAL
    assert st["sim_time_s"] == pytest.approx((last + (TICK_NS if coupling == "pipelined"
                                                       else 0)) * 1e-9)


@pytest.mark.slow
def test_a_member_joining_after_every_member_left_is_waited_for(procs, endpoint, bus, tmp_path):
    """With every member gone the plant runs on by itself; one that joins then is seen and
    waited for again (it used to stay unseen: nothing drained the plant's inbox)."""
    from .conftest import wait_for
    stats = tmp_path / "plant.json"
    plant = procs.diffbot("plant", "--world", "empty", "--expect", "first", "--endpoint",
                          endpoint, "--stats", str(stats), name="plant")
    s = bus()
    clocks, sub, pub = member_ends(s)
    seq = 0

    def answer(name: str, ticks: int, speed: float) -> int:
        nonlocal seq
        t = -1
        for _ in range(ticks):
            t = clocks.get(timeout=20)
            seq += 1
            pub.put(codec.encode(codec.twist_stamped(t, speed, 0.0)),
                    attachment=codec.attachment(seq, t, codec.ACK, 1, name))
        return t

    try:
        tok = s.liveliness().declare_token(K.sync("first"))
        answer("first", 5, 0.0)
        tok.undeclare()                       # the plant now runs on by itself
        wait_for(lambda: "member left: first" in procs.log(plant), 10, what="first gone")
        while not clocks.empty():
            clocks.get()
        tok = s.liveliness().declare_token(K.sync("second"))   # answers from now on
        wait_for(lambda: "member joined: second" in procs.log(plant), 10,
                 what="the plant to see the new member")
        t = answer("second", 20, 0.3)
        while not clocks.empty():             # ticks it ran alone before it saw us
            t = answer("second", 1, 0.3)
        t = answer("second", 10, 0.3)
        time.sleep(0.5)                       # the plant now waits for our next answer:
        later = []                            # at most the one tick it published
        while not clocks.empty():
            later.append(clocks.get())
        assert later in ([], [t + TICK_NS]), f"the plant ran on: {len(later)} ticks"
        tok.undeclare()
    finally:
        pub.undeclare()
        sub.undeclare()
    plant.terminate()
    assert plant.wait(20) == 0, procs.log(plant)
    st = json.loads(stats.read_text())
    assert st["members_seen"] == ["first", "second"]
