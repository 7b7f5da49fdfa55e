"""Several robots from one node process: one controller object per robot, one lockstep
member acking each tick once (n_plant = its commands), inputs awaited per robot."""
from __future__ import annotations

import json
import threading

import pytest

from bus import codec
from bus.keys import Keys
from bus.controller import Twist, make_controllers
from bus.node import node_arg_parser

#: background: no wall-clock bound here; runs beside the serial tests, its processes at the
#: low CPU priority (tests/conftest.py)
pytestmark = pytest.mark.background

K = Keys()


class _Ctl:
    inputs = ["ground_truth"]

    def __init__(self, robot: str | None = None) -> None:
        self.robot = robot

    def step(self, obs):
        return Twist(0.1, 0.0)


def test_one_controller_object_per_robot():
    """A factory is called per robot (with the name if it takes one); an object is copied."""
    made = make_controllers(_Ctl, ["a", "b"])
    assert [c.robot for c in made] == ["a", "b"] and made[0] is not made[1]
    made = make_controllers(lambda: _Ctl("x"), ["a", "b"])
    assert [c.robot for c in made] == ["x", "x"] and made[0] is not made[1]
    one = _Ctl("solo")
    assert make_controllers(one, ["a"]) == [one]
    two = make_controllers(one, ["a", "b"])
    assert one not in two and len({id(c) for c in two}) == 2
    args = node_arg_parser("t").parse_args(["--robots", "r0,r1"])
    assert (args.robot, args.robots) == ("r0", ["r0", "r1"])
    assert node_arg_parser("t").parse_args([]).robots is None


@pytest.mark.parametrize("bad", ["r0,r0", ",", "r0,a/b", "r0,*"])
def test_bad_robot_lists_are_refused(bad, capsys):
    with pytest.raises(SystemExit) as e:
        node_arg_parser("t").parse_args(["--robots", bad])
    assert e.value.code == 2 and "--robots" in capsys.readouterr().err


class AttTap:
    """(key, Attachment) of every message on some keys."""

    def __init__(self, session, keys):
        self.lock = threading.Lock()
        self.seen: list[tuple[str, codec.Attachment]] = []
        self.subs = [session.declare_subscriber(k, self._on) for k in keys]

    def _on(self, s):
        a = codec.parse_attachment(s.attachment.to_bytes() if s.attachment else None)
        with self.lock:
            self.seen.append((str(s.key_expr), a))


@pytest.mark.slow
@pytest.mark.parametrize("coupling", ["sequential", "pipelined"])
def test_one_process_drives_two_robots_in_lockstep(procs, endpoint, bus, tmp_path, coupling):
    """``--robots leader,follower``: one process and one lockstep member; each tick one
    wheel command per robot, the ACK with n_plant 2 on the last; both robots move."""
    stats, node_stats = tmp_path / "plant.json", tmp_path / "node.json"
    plant = procs.diffbot("plant", "--world", "living_room_follow", "--disable", "camera,lidar",
                          "--coupling", coupling, "--duration", "1.0", "--expect", "pair",
                          "--endpoint", endpoint, "--stats", str(stats), name="plant")
    s = bus()
    robots = ("leader", "follower")
    tap = AttTap(s, [K.topic(r, t) for r in robots for t in ("cmd_vel", "wheel_cmd")]
                 + [K.ack()])
    gt: dict[str, list] = {r: [] for r in robots}
    subs = [s.declare_subscriber(K.topic(r, "ground_truth"), lambda smp, r=r: gt[r].append(
        codec.decode(smp.payload.to_bytes(), "nav_msgs/msg/Odometry"))) for r in robots]
    node = procs.diffbot("controller", "wheel_schedule", "--schedule", "10:2,2",
                         "--robots", "leader,follower", "--name", "pair", "--endpoint",
                         endpoint, "--stats", str(node_stats), name="pair")
    assert plant.wait(60) == 0, procs.log(plant)
    assert node.wait(10) == 0, procs.log(node)
    for sub in tap.subs + subs:
        sub.undeclare()
    st = json.loads(stats.read_text())
    assert st["members_seen"] == ["pair"] and st["coupling"] == coupling
    assert st["rejected"] == {} and st.get("protocol_errors", {}) == {}, st
    assert st["stale_commands"] == 0, st          # each robot, every tick: the rule's command
    ns = json.loads(node_stats.read_text())
    assert ns["robots"] == ["leader", "follower"] and ns["ticks"] >= 50
    assert ns["published"] == {K.topic("leader", "wheel_cmd"): ns["ticks"],
                               K.topic("follower", "wheel_cmd"): ns["ticks"]}
    with tap.lock:
        seen = list(tap.seen)
    by_tick: dict[int, list] = {}
    for key, a in seen:
        by_tick.setdefault(a.t_ns, []).append((key, a.flags, a.n_plant, a.node))
    assert len(by_tick) == ns["ticks"]
    for t, msgs in by_tick.items():
        # (the tap's callbacks may reorder keys; the node puts leader, then follower)
        assert sorted(msgs) == [(K.topic("follower", "wheel_cmd"), codec.ACK, 2, "pair"),
                                (K.topic("leader", "wheel_cmd"), 0, 0, "pair")], (t, msgs)
    for r in robots:       # 2 rad/s on both wheels: both drive forward, about alike
        v = [m.twist.twist.linear.x for m in gt[r][-10:]]
        assert min(v) > 0.1, (r, v)
