"""Defects that hid in the lockstep code, each pinned by what a user sees: a member joining
between two pipelined ticks does not stall the plant; a node meeting a plant of another
protocol version exits 2 also after --wait; a world rebuilt after the physics diverged
waits for the new world's ACKs; a member whose next tick's
inputs are late answers it before a later tick that is complete (a router blip)."""
from __future__ import annotations

import json
import logging
import queue
import threading
import time

import pytest

from bus import codec
from bus.keys import Keys
from bus.protocol import PROTOCOL_VERSION, REPUBLISH_TICKS

from ..conftest import wait_for
from ..bus.test_pipelined_end import TICK_NS, member_ends

#: background: no wall-clock bound here; runs beside the serial tests, its processes at the
#: low CPU priority (tests/conftest.py)
pytestmark = pytest.mark.background

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
        # stopped while its members are still there: were "early" (expected, no rejoin
        # timeout) gone first, it would end the run with exit 1 before the SIGTERM came
        plant.terminate()
        assert plant.wait(20) == 0, procs.log(plant)
    finally:
        for tok in tokens:
            tok.undeclare()
        pub.undeclare()
        sub.undeclare()


@pytest.mark.slow
def test_a_waiting_node_exits_2_when_the_plant_comes_back_speaking_another_version(
        procs, endpoint):
    """PROTOCOL.md: a node that finds another version must not join; this project's nodes
    exit 2. That holds for the plant that comes back while the node waits (--wait) too."""
    from bus.session import open_session
    s = open_session("plant", endpoint)
    info = {"protocol": PROTOCOL_VERSION, "mode": "lockstep", "control_tick_s": 0.02,
            "rejoin_timeout_s": 30,          # how long a --wait node waits for it to come back
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
    from plant.process import Plant
    from plant.world import load_world

    diverge_at = 3 * TICK_NS
    real_read_state = plant_sim.Simulation.read_state
    once = []

    def read_state(self, *args, **kwargs):   # (the plant's finite check reads it with the state)
        rows, finite = real_read_state(self, *args, **kwargs)
        if self.time_ns == diverge_at and not once:
            once.append(True)
            return rows, False
        return rows, finite
    monkeypatch.setattr(plant_sim.Simulation, "read_state", read_state)

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


def test_a_member_answers_its_ticks_in_order_when_the_next_one_s_input_is_late(endpoint, bus):
    """After a router blip a member may hold tick k without its sensors and tick k+1 in
    full; the plant re-publishes what was lost. Acting on k+1 first made the re-published
    k look like a world gone back: the FMU node re-initialised its FMU and the run left the
    undisturbed one's bytes (a fresh-clone CI run). A member answers every tick in order,
    also when the blip swallowed tick k's clock and k+1 came whole (another fresh-clone CI
    run: the FMU node stepped k+1, then took the re-published k for a reset), unless k lies
    beyond the ticks the plant keeps to re-publish."""
    from bus.controller import Twist
    from bus.runtime import NodeRunner
    from bus.session import open_session

    class Recorder:
        inputs = ["joint_states"]

        def __init__(self):
            self.stepped: list[int] = []

        def step(self, obs):
            self.stepped.append(obs.t_ns)
            return Twist(linear=0.1, angular=0.0)

    ps = open_session("plant", endpoint)
    info = {"protocol": PROTOCOL_VERSION, "mode": "lockstep", "coupling": "sequential",
            "control_tick_s": TICK_NS * 1e-9,
            "robots": {"robot1": {"topics": {"joint_states": 1}}}}
    q = ps.declare_queryable(K.info, lambda query: query.reply(K.info, json.dumps(info)))
    alive = ps.liveliness().declare_token(K.alive("plant"))
    clock_pub = ps.declare_publisher(K.clock)
    js_pub = ps.declare_publisher(K.topic("robot1", "joint_states"))
    acks: queue.SimpleQueue = queue.SimpleQueue()
    ack_sub = ps.declare_subscriber(K.topic("robot1", "cmd_vel"), lambda smp: acks.put(
        codec.parse_attachment(smp.attachment.to_bytes()).t_ns))
    ctrl = Recorder()
    runner = NodeRunner(ctrl, "robot1", "m", bus(), K, logging.getLogger("m"))
    thread = threading.Thread(target=runner.run, daemon=True)

    def clock(t):
        clock_pub.put(codec.encode(codec.clock(t)))

    def js(t):
        js_pub.put(codec.encode(codec.joint_state(t, ["left_wheel_joint", "right_wheel_joint"],
                                                  [0.0, 0.0], [0.0, 0.0])))

    def member_joined():
        return any(r.ok is not None for r in ps.liveliness().get(K.sync("m"), timeout=1.0))

    thread.start()
    try:
        wait_for(member_joined, 20, what="the member to join")
        js(0)
        clock(0)
        assert acks.get(timeout=10) == 0
        clock(TICK_NS)                     # t1's sensors lost in the blip ...
        js(2 * TICK_NS)                    # ... t2 arrives whole
        clock(2 * TICK_NS)
        with pytest.raises(queue.Empty):
            pytest.fail(f"answered t={acks.get(timeout=1.0)} before t1's inputs came")
        js(TICK_NS)                        # re-published after the rejoin
        assert [acks.get(timeout=10), acks.get(timeout=10)] == [TICK_NS, 2 * TICK_NS]
        clock(TICK_NS)                     # re-published again: re-sent, not stepped
        assert acks.get(timeout=10) == TICK_NS
        js(3 * TICK_NS)
        clock(3 * TICK_NS)
        assert acks.get(timeout=10) == 3 * TICK_NS
        js(4 * TICK_NS)                    # t4's clock lost in a blip, its sensors not ...
        js(5 * TICK_NS)                    # ... and t5 arrives whole
        clock(5 * TICK_NS)
        with pytest.raises(queue.Empty):
            pytest.fail(f"answered t={acks.get(timeout=1.0)} before t4's clock came")
        clock(4 * TICK_NS)                 # re-published after the rejoin
        assert [acks.get(timeout=10), acks.get(timeout=10)] == [4 * TICK_NS, 5 * TICK_NS]
        far = 5 * TICK_NS + REPUBLISH_TICKS * TICK_NS   # t6 lost past what the plant keeps:
        for t in (far, far + TICK_NS):                  # it never comes, the member goes on
            js(t)
            clock(t)
        assert [acks.get(timeout=10), acks.get(timeout=10)] == [far, far + TICK_NS]
        assert ctrl.stepped == [0, TICK_NS, 2 * TICK_NS, 3 * TICK_NS, 4 * TICK_NS,
                                5 * TICK_NS, far, far + TICK_NS]
        assert runner.rejects.counts == {}
    finally:
        runner.stop_event.set()
        thread.join(10)
        for ent in (ack_sub, js_pub, clock_pub, alive, q):
            ent.undeclare()
        ps.close()
