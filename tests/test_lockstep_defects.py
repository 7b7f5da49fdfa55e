"""Three defects that hid in the lockstep code before it had a home (issue 28), each pinned
by what a user sees: a member joining between two pipelined ticks does not stall the
plant; a node meeting a plant of another protocol version exits 2 also after --wait; a
world rebuilt after the physics diverged waits for the new world's ACKs."""
from __future__ import annotations

import json
import logging
import queue
import threading
import time

import pytest

from bus import codec
from bus.keys import Keys
from bus.protocol import PROTOCOL_VERSION

from .conftest import wait_for
from .test_pipelined_end import TICK_NS, member_ends

K = Keys()


@pytest.mark.slow
def test_a_member_joining_between_pipelined_ticks_is_not_waited_for_the_tick_before(
        procs, endpoint, bus):
    """Pipelined, the plant looks at tick k-1's ACKs during tick k: it must wait for the
    members present when tick k-1 began (PROTOCOL.md section 4, step 4), not for one that
    joined since, whose first clock may be t_k (it would never answer t_{k-1})."""
    plant = procs.diffbot("plant", "--world", "empty", "--coupling", "pipelined", "--expect",
                          "early", "--endpoint", endpoint, name="plant")
    s = bus()
    clocks, sub, pub = member_ends(s)
    tokens = [s.liveliness().declare_token(K.sync("early"))]
    seq = 0

    def ack(t: int) -> None:
        nonlocal seq
        seq += 1
        pub.put(codec.encode(codec.twist_stamped(t, 0.0, 0.0)),
                attachment=codec.attachment(seq, t, codec.ACK, 1, "early"))

    try:
        assert clocks.get(timeout=60) == 0
        assert clocks.get(timeout=20) == TICK_NS     # pipelined: no wait at tick 0
        # the plant now waits for early's ACK of t0; "late" joins, and sees no clock
        # before t2 (it is not subscribed yet)
        tokens.append(s.liveliness().declare_token(K.sync("late")))
        wait_for(lambda: "member joined: late" in procs.log(plant), 10, what="late seen")
        ack(0)
        assert clocks.get(timeout=20) == 2 * TICK_NS
        ack(TICK_NS)                                  # late was not there when t1 began
        try:
            t3 = clocks.get(timeout=10)
        except queue.Empty:
            pytest.fail("the plant waits for late's ACK of a tick that began before late "
                        "joined:\n" + procs.log(plant))
        assert t3 == 3 * TICK_NS
    finally:
        for tok in tokens:
            tok.undeclare()
        pub.undeclare()
        sub.undeclare()
    plant.terminate()
    assert plant.wait(20) == 0, procs.log(plant)


@pytest.mark.slow
def test_a_waiting_node_exits_2_when_the_plant_comes_back_speaking_another_version(
        procs, endpoint):
    """PROTOCOL.md: a node that finds another version must not join; this project's nodes
    exit 2. That holds for the plant that comes back while the node waits (--wait) too."""
    from bus.session import open_session
    s = open_session("plant", endpoint)
    info = {"protocol": PROTOCOL_VERSION, "mode": "lockstep", "control_tick_s": 0.02,
            "robots": {"robot1": {"topics": {"joint_states": 1}}}}
    served = {"info": info}
    q = s.declare_queryable(K.info, lambda query: query.reply(
        K.info, json.dumps(served["info"])))
    alive = s.liveliness().declare_token(K.alive("plant"))
    node = None
    try:
        node = procs.diffbot("controller", "square_path", "--wait", "--endpoint", endpoint,
                             name="node")
        wait_for(lambda: "lockstep member" in procs.log(node), 60, what="the node to join")
        time.sleep(0.5)                                # (its liveliness watch sees the plant)
        alive.undeclare()                              # the plant goes ...
        wait_for(lambda: "waiting for it to come back" in procs.log(node), 20,
                 what="the node to wait")
        served["info"] = dict(info, protocol=PROTOCOL_VERSION - 1)   # ... another comes back
        alive = s.liveliness().declare_token(K.alive("plant"))
        assert node.wait(60) == 2, procs.log(node)
        log = procs.log(node)
        assert (f"the plant speaks bus protocol {PROTOCOL_VERSION - 1}; "
                f"this node speaks bus protocol {PROTOCOL_VERSION}") in log
        assert "Traceback" not in log
    finally:
        q.undeclare()
        s.close()                                      # (with the token, if still declared)


@pytest.mark.slow
def test_a_world_rebuilt_after_divergence_waits_for_the_new_world_s_acks(endpoint, bus,
                                                                         monkeypatch):
    """A diverged world is rebuilt at t = 0 like a reset: the old world's ACKs of the same
    stamps must not let the new world step without its members."""
    from bus.session import open_session
    from plant import sim as plant_sim
    from plant.node import Plant
    from plant.world import load_world

    diverge_at = 3 * TICK_NS
    real_is_finite = plant_sim.Simulation.is_finite
    once = []

    def is_finite(self):
        if self.time_ns == diverge_at and not once:
            once.append(True)
            return False
        return real_is_finite(self)
    monkeypatch.setattr(plant_sim.Simulation, "is_finite", is_finite)

    ps = open_session("plant", endpoint)
    plant = Plant(load_world("empty"), ps, K, "lockstep", logging.getLogger("plant"),
                  expect=("m",))
    runner = threading.Thread(target=plant.run, daemon=True)
    s = bus()
    clocks, sub, pub = member_ends(s)
    tok = s.liveliness().declare_token(K.sync("m"))
    seq = 0

    def ack(t: int) -> None:
        nonlocal seq
        seq += 1
        pub.put(codec.encode(codec.twist_stamped(t, 0.1, 0.0)),
                attachment=codec.attachment(seq, t, codec.ACK, 1, "m"))

    runner.start()
    try:
        seen = []
        while True:                          # the old world, until it restarts at t = 0
            t = clocks.get(timeout=30)
            if seen and t == 0:
                break
            seen.append(t)
            ack(t)
        assert seen == [0, TICK_NS, 2 * TICK_NS]
        with pytest.raises(queue.Empty):     # it waits for m's ACK of the new world's t0
            pytest.fail(f"the rebuilt world stepped on the old world's ACK: "
                        f"t={clocks.get(timeout=1.5)}")
        ack(0)
        assert clocks.get(timeout=10) == TICK_NS
    finally:
        plant.stop_event.set()
        runner.join(10)
        tok.undeclare()
        pub.undeclare()
        sub.undeclare()
        plant.close()
        ps.close()
