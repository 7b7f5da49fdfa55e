"""Holding at its bound, over processes (docs/PROTOCOL.md section 4, "Holding"): a client
written from the page (tests/support/conformance_client.py) drives a plant for 20 episodes at each
hold around the bound (bound - 1, the bound, bound + 1) and unheld, resetting the world between
episodes, frozen once past the lease in the middle of it. Every episode of a hold must give one
ground truth, byte for byte; within the bound it is the unheld one's; past it the robot stops
where its command expires, the same tick every episode, and the plant names the rule."""
from __future__ import annotations

import collections
import json
import os
import signal
import subprocess
import sys
import time

import pytest

from bus import codec
from bus.keys import Keys
from bus.lockstep import HOLD_PAST
from bus.protocol import COUPLINGS, PROTOCOL_MINOR, max_hold

from ..conftest import ROOT, wait_for

#: no wall-clock promise: runs beside the serial tests, at a low CPU priority (conftest.py)
pytestmark = pytest.mark.background

K = Keys()
CLIENT = os.path.join(ROOT, "tests", "support", "conformance_client.py")
EPISODES = 20               # per hold value
TICKS = 40                  # per episode: 0.8 s at 0.2 m/s, a hold of the bound and more
TICK_NS = 20_000_000        # the empty world's control tick
TIMEOUT_S = 0.5             # and its robot's cmd_timeout_s


def _holds_sent(hold: int) -> list[int]:
    """The holds the client's answers of one episode carry: from tick 0, each held up to
    the tick before the last (tests/support/conformance_client.py)."""
    out, n = [], 0
    while n < TICKS - 1:
        out.append(max(0, min(hold, TICKS - 2 - n)))
        n += out[-1] + 1
    return out


@pytest.mark.slow
@pytest.mark.parametrize("coupling", COUPLINGS)
def test_soak_20_episodes_per_hold_at_the_bound_give_one_recording_each(procs, endpoint,
                                                                         tmp_path, coupling):
    bound = max_hold(TICK_NS, TIMEOUT_S, 1 if coupling == "pipelined" else 0)
    assert bound == {"sequential": 25, "pipelined": 24}[coupling]     # the page's example
    holds = [0, bound - 1, bound, bound + 1]
    stats = tmp_path / "plant.json"
    plant = procs.diffbot("plant", "--world", "empty", "--seed", "0", "--coupling", coupling,
                          "--expect", "conformance", "--end-with", "conformance",
                          "--rejoin-timeout", "20", "--endpoint", endpoint,
                          "--stats", str(stats), name="plant")
    from bus.session import open_session, query_info
    s = open_session("test", endpoint)
    truth: dict[tuple[int, int], bytes] = {}

    def on_truth(smp):
        a = codec.parse_attachment(smp.attachment.to_bytes())
        truth.setdefault((a.epoch, a.t_ns), smp.payload.to_bytes())
    try:
        sub = s.declare_subscriber(K.topic("robot1", "ground_truth"), on_truth)
        info = query_info(s, K, 30.0)
        assert info["protocol_minor"] == PROTOCOL_MINOR          # the bound is enforced
        log = open(tmp_path / "client.log", "wb")
        client = subprocess.Popen(
            [sys.executable, CLIENT, "--endpoint", endpoint, "--ticks", str(TICKS),
             "--speed", "0.2", "--episodes", str(EPISODES * len(holds)),
             "--hold", ",".join(map(str, holds))],
            env=dict(os.environ, PYTHONPATH=ROOT), stdout=log, stderr=subprocess.STDOUT,
            start_new_session=True)
        client.log_path = log.name
        procs.procs.append(client)
        # A freeze past the 1 s lease in the middle: the plant holds time for the member,
        # re-publishes its last ticks when it is back, and it answers them as it did.
        wait_for(lambda: len({e for e, _ in truth}) >= 2 * len(holds), 60, what="8 episodes")
        client.send_signal(signal.SIGSTOP)
        time.sleep(2.0)
        client.send_signal(signal.SIGCONT)
        assert procs.wait(client, 120, "the client") == 0, procs.log(client)
        assert procs.wait(plant, 30, "the plant") == 0, procs.log(plant)
        assert "lockstep member rejoined: conformance" in procs.log(plant)
        sub.undeclare()
    finally:
        s.close()
    st = json.loads(stats.read_text())
    assert st["stale_commands"] == 0 and st["rejected"] == {}, st
    # each episode past the bound holds past it as often as its answers hold bound + 1 ticks
    n_past = EPISODES * sum(h > bound for h in _holds_sent(bound + 1))
    assert n_past >= EPISODES
    assert st["protocol_errors"] == {HOLD_PAST: n_past}, st
    assert st["holds_past_timeout"] == n_past
    episodes = collections.defaultdict(dict)
    for (epoch, t), payload in truth.items():
        if t < TICKS * TICK_NS:                 # the last episode ends at its FINAL tick
            episodes[epoch][t] = payload
    assert sorted(episodes) == list(range(EPISODES * len(holds)))
    runs = {h: {b"".join(episodes[e][t] for t in sorted(episodes[e]))
                for e in episodes if holds[e % len(holds)] == h} for h in holds}
    assert {h: len(r) for h, r in runs.items()} == {h: 1 for h in holds}   # one recording each
    unheld = runs[0].pop()
    assert runs[bound - 1].pop() == unheld and runs[bound].pop() == unheld
    past = runs[bound + 1].pop()
    assert past != unheld                       # stopped where its command expired
    x = [codec.decode(episodes[len(holds) - 1][t], "nav_msgs/msg/Odometry").pose.pose.position.x
         for t in sorted(episodes[len(holds) - 1])]
    assert x[-1] < x[0] + 0.2 * (TICKS - 1) * TICK_NS * 1e-9 - 0.005     # it stood, for a tick
