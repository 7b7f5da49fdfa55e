"""docs/PROTOCOL.md is the contract: the code agrees with it, a client written from it alone
holds lockstep byte-identically to bus.node, and the plant says what is wrong."""
from __future__ import annotations

import json
import os
import queue
import re
import signal
import struct
import subprocess
import sys
import textwrap

import pytest

from bus import codec
from bus.keys import TOPICS, Keys, check_name
from bus.protocol import (COUPLINGS, END_SEEN_S, PACE_TICKS, PLANT_READS, PROTOCOL_MINOR,
                          PROTOCOL_VERSION, max_hold,
                          REPUBLISH_TICKS, SEEN_EVERY_TICKS)

from ..conftest import ROOT, wait_for

DOC = os.path.join(ROOT, "docs", "PROTOCOL.md")
K = Keys()


def doc() -> str:
    with open(DOC, encoding="utf-8") as f:
        return f.read()


# ---------------------------------------------------------------- the document and the code
def test_version_in_the_document_is_the_code_s():
    text = doc()
    assert re.search(r"^# .*protocol, version (\d+)$", text, re.M).group(1) == \
        str(PROTOCOL_VERSION)
    assert f'"protocol": {PROTOCOL_VERSION}' in text
    # the additions within the version: sim/info's protocol_minor and section 8's list
    assert f"| `protocol_minor` | the additions within the version this plant has (section 8, " \
           f'"Added within 5"): {PROTOCOL_MINOR};' in text
    assert f"\n- {PROTOCOL_MINOR}: " in text and f"\n- {PROTOCOL_MINOR + 1}: " not in text
    # holding's bound, as the page's worked example gives it (bus.protocol.max_hold)
    assert "allow h = 25 under sequential coupling and h = 24 under pipelined" in text
    assert (max_hold(20_000_000, 0.5, 0), max_hold(20_000_000, 0.5, 1)) == (25, 24)
    # the ticks the plant keeps to re-publish, as sections 4 and 8 give them
    assert text.count(f"last {REPUBLISH_TICKS} ticks") == 3
    assert f"its last {REPUBLISH_TICKS}," in text
    # how far lockstep runs ahead of a watcher that keeps up, and how often it reports
    assert f"at least t - {PACE_TICKS} ticks" in text
    assert re.search(rf"within {PACE_TICKS}\s+ticks of it", text)
    assert f"every {SEEN_EVERY_TICKS} new clocks" in text
    assert re.search(rf"or later, up to {END_SEEN_S:g} s \(then it logs", text)
    assert PACE_TICKS < REPUBLISH_TICKS


def test_every_key_is_in_the_document():
    text = doc()
    table = {m.group(1) for m in re.finditer(r"^\| `([^`]+)` \|", text, re.M)}
    wanted = {f"<robot>/{t.suffix}" for t in TOPICS.values()}
    wanted |= {"sim/clock", "sim/poses", "sim/end", "sim/info", "sim/reset", "sim/alive/<node>",
               "sim/sync/<node>", "sim/ack/<node>", "sim/seen/<node>"}
    assert wanted <= table, f"missing from PROTOCOL.md: {sorted(wanted - table)}"
    for name, t in TOPICS.items():
        row = next(ln for ln in text.splitlines() if ln.startswith(f"| `<robot>/{t.suffix}` |"))
        assert t.msgtype in row, f"{name}: PROTOCOL.md does not give type {t.msgtype}"
    for topic in PLANT_READS:
        assert f"`<robot>/{topic}`" in text.split("The **keys the plant reads**")[1][:300]
    for c in COUPLINGS:
        assert c in text


def test_the_lockstep_sections_name_the_code_that_implements_them():
    """Every `module.Class.method` the page names exists; every rule of bus/lockstep.py is
    named in the page, in a section its docstring cites."""
    import importlib
    import inspect

    from bus import lockstep, member
    named: dict[str, set[int]] = {}
    section = 0
    for line in doc().splitlines():
        if (m := re.match(r"## (\d+)\.", line)):
            section = int(m.group(1))
        for ref in re.findall(r"`((?:bus|plant)\.\w+\.\w+\.\w+)`", line):
            named.setdefault(ref, set()).add(section)
    assert named, "PROTOCOL.md names no code"
    for ref in named:
        mod, cls, meth = ref.rsplit(".", 2)
        assert callable(getattr(getattr(importlib.import_module(mod), cls), meth, None)), ref
    for cls in (lockstep.AckLedger, member.MemberTick):
        for meth, fn in inspect.getmembers(cls, inspect.isfunction):
            if meth.startswith("_"):
                continue
            ref = f"{cls.__module__}.{cls.__name__}.{meth}"
            assert ref in named, f"PROTOCOL.md does not name {ref}"
            cited = {int(n) for n in re.findall(r"[Ss]ection (\d+)", fn.__doc__ or "")}
            assert cited & named[ref], f"{ref} cites sections {cited}, the page names it in " \
                                       f"{named[ref]}"


def test_attachment_layout_in_the_document_is_the_codec_s():
    text = doc()
    rows = re.findall(r"^\| (\d+) \| (u8|u16|u64|bytes) \| `(\w+)` \|", text, re.M)
    layout = [(int(off), typ, name) for off, typ, name in rows]
    assert layout == [(0, "u64", "seq"), (8, "u64", "stamp_ns"), (16, "u8", "flags"),
                      (17, "u16", "n_plant"), (19, "u8", "name_len"), (20, "bytes", "name")]
    assert codec.ATTACHMENT.format == "<QQ" and codec.TRAILER.format == "<BHB"
    assert "| 16 | u32 | `epoch` |" in text and codec.EPOCH.format == "<I"
    assert "bit 0 `ACK`" in text and "bit 1 `FINAL`" in text
    assert (codec.ACK, codec.FINAL) == (1, 2)
    # the worked example is what the codec makes
    example = re.search(r"attachment \(31 bytes\):\n\n```\n(.*?)\n", text, re.S).group(1)
    want = codec.attachment(51, 1_020_000_000, codec.ACK, 1, "go_straight")
    assert bytes.fromhex(example.replace(" ", "")) == want
    payload = re.search(r"payload \(84 bytes\):\n\n```\n(.*?)```", text, re.S).group(1)
    assert bytes.fromhex("".join(payload.split())) == \
        codec.encode(codec.twist_stamped(1_020_000_000, 0.25, 0.0, "robot1/base_link"))
    assert "frame_id `robot1/base_link`" in text


def test_attachments_round_trip_and_malformed_ones_are_refused():
    a = codec.parse_attachment(codec.attachment(9, 40_000_000, codec.ACK | codec.FINAL, 3, "nöde"))
    assert a == (9, 40_000_000, 3, 3, "nöde", None)
    assert codec.parse_attachment(codec.attachment(9, 5)) == (9, 5, 0, 0, None, None)
    plant = codec.attachment(9, 5, epoch=2)                 # the plant's: 20 bytes
    assert len(plant) == 20 and codec.parse_attachment(plant) == (9, 5, 0, 0, None, 2)
    good = codec.attachment(1, 2, codec.ACK, 1, "abc")
    # a hold (flags bits 2-7, section 4 "Holding") round-trips; with FINAL it is malformed
    held = codec.parse_attachment(codec.attachment(1, 2, codec.with_hold(codec.ACK, 63), 1, "abc"))
    assert (held.flags & codec.ACK, codec.hold_of(held.flags)) == (codec.ACK, 63)
    assert codec.hold_of(codec.parse_attachment(good[:16] + b"\x04" + good[17:]).flags) == 1
    with pytest.raises(ValueError, match="0..63"):
        codec.with_hold(codec.ACK, 64)
    for bad in (good[:-1], good + b"x", good[:17], good[:16] + b"\x07" + good[17:],
                good[:19] + b"\x00a", codec.attachment(1, 2)[:15], b"",
                codec.attachment(1, 2, codec.ACK, 1, "n" * 65)):
        assert codec.parse_attachment(bad) is None, bad
    longest = "n" * 64                  # name_len 1..64: a node name's longest (section 3)
    assert codec.parse_attachment(codec.attachment(1, 2, codec.ACK, 1, longest)).node == longest
    assert check_name(longest) and "name_len` | length of the name in bytes, 1..64" in doc()
    with pytest.raises(ValueError, match="at most 64 characters"):
        check_name("n" * 65)


# ---------------------------------------------------------------- a client from the document
GO_STRAIGHT = textwrap.dedent('''
    import sys
    from bus.controller import Twist
    from bus.node import run_node

    class GoStraight:
        inputs = ["ground_truth"]
        done = False
        def step(self, obs):
            x = obs["ground_truth"].pose.pose.position.x
            self.x0 = getattr(self, "x0", x)
            self.done = x - self.x0 >= 1.0
            return Twist(linear=0.25, angular=0.0)

    sys.exit(run_node(GoStraight(), robot="robot1"))
''')


def _drive(procs, endpoint, tmp_path, coupling, client_argv) -> dict[int, bytes]:
    """One plant run in lockstep ended by member ``conformance``; ground truth by stamp."""
    stats = tmp_path / f"plant-{len(procs.procs)}.json"
    plant = procs.diffbot("plant", "--world", "empty", "--coupling", coupling, "--expect",
                          "conformance", "--end-with", "conformance", "--endpoint", endpoint,
                          "--stats", str(stats), name="plant")
    from bus.session import open_session
    s = open_session("test", endpoint)
    truth: dict[int, bytes] = {}
    try:
        sub = s.declare_subscriber(K.topic("robot1", "ground_truth"),
                                   lambda smp: truth.setdefault(
                                       codec.parse_attachment(smp.attachment.to_bytes()).t_ns,
                                       smp.payload.to_bytes()))
        r = subprocess.run([*client_argv, "--endpoint", endpoint], cwd=str(tmp_path),
                           env=dict(os.environ, PYTHONPATH=ROOT), capture_output=True,
                           text=True, timeout=120)
        assert r.returncode == 0, r.stderr
        assert plant.wait(30) == 0, procs.log(plant)
        sub.undeclare()
    finally:
        s.close()
    st = json.loads(stats.read_text())
    assert st["end_reason"] == "conformance finished" and st["coupling"] == coupling
    assert st["protocol_errors"] == {} and st["rejected"] == {}, st
    assert st["stale_commands"] == 0, st          # every tick's command was the rule's
    return truth


@pytest.mark.slow
@pytest.mark.parametrize("coupling", COUPLINGS)
def test_a_client_written_from_the_document_drives_like_bus_node(procs, endpoint, tmp_path,
                                                                coupling):
    script = tmp_path / "go_straight.py"
    script.write_text(GO_STRAIGHT)
    ours = _drive(procs, endpoint, tmp_path, coupling,
                  [sys.executable, str(script), "--name", "conformance"])
    theirs = _drive(procs, endpoint.replace("bus.sock", "bus2.sock"), tmp_path, coupling,
                    [sys.executable, os.path.join(ROOT, "tests", "support", "conformance_client.py")])
    assert len(ours) > 150                       # ~4 s at 0.25 m/s, 20 ms ticks
    xs = [codec.decode(ours[t], "nav_msgs/msg/Odometry").pose.pose.position.x
          for t in sorted(ours)]
    assert xs[-1] - xs[0] >= 1.0
    assert sorted(ours) == sorted(theirs)
    assert ours == theirs                        # byte for byte, every tick


def _poses_from_the_page(data: bytes) -> list[tuple[int, str, str, tuple]]:
    """sim/poses read as section 2 and the CDR rules give it (struct only): (stamp ns,
    frame_id, child_frame_id, (x, y, z, qx, qy, qz, qw)) per transform."""
    assert data[:4] == b"\x00\x01\x00\x00"           # CDR, little endian
    at = 4

    def take(fmt: str, align: int):
        nonlocal at
        at += -(at - 4) % align                          # alignment after the header
        got = struct.unpack_from(fmt, data, at)
        at += struct.calcsize(fmt)
        return got

    def string() -> str:
        (n,) = take("<I", 4)
        (raw,) = take(f"{n}s", 1)
        return raw[:-1].decode()

    out = []
    for _ in range(take("<I", 4)[0]):
        sec, nanosec = take("<iI", 4)
        frame_id, child = string(), string()
        out.append((sec * 1_000_000_000 + nanosec, frame_id, child, take("<7d", 8)))
    assert at == len(data)
    return out


@pytest.mark.slow
def test_a_client_written_from_the_document_reads_sim_poses(procs, endpoint, tmp_path):
    """sim/poses, read by a subscriber with the page's rules alone: every tick, a transform
    per robot in the world's order, world -> <robot>/base_link stamped with the tick, the
    doubles of the robot's ground_truth pose at that tick."""
    from bus.session import open_session
    from plant.swarm_world import write_swarm_world
    world = write_swarm_world(str(tmp_path / "w.toml"), 3, seed=1, mode="kinematic")
    names = ["r0", "r1", "r2"]
    got: dict[str, list] = {}

    def keep(smp):
        got.setdefault(str(smp.key_expr), []).append(smp.payload.to_bytes())
    plant = procs.diffbot("plant", "--world", world, "--mode", "fast", "--duration", "0.2",
                          "--wait-for", "reader", "--endpoint", endpoint, name="plant")
    s = open_session("test", endpoint)
    try:
        subs = [s.declare_subscriber(k, keep)
                for k in [K.poses, *(K.topic(r, "ground_truth") for r in names)]]
        token = s.liveliness().declare_token(K.alive("reader"))
        assert plant.wait(60) == 0, procs.log(plant)
        token.undeclare()
        for sub in subs:
            sub.undeclare()
    finally:
        s.close()
    poses = [_poses_from_the_page(m) for m in got[K.poses]]
    assert [p[0][0] for p in poses] == [k * 20_000_000 for k in range(11)]
    for msg in poses:
        assert [(f, c) for _, f, c, _ in msg] == [("world", f"{r}/base_link") for r in names]
        assert len({t for t, *_ in msg}) == 1
    for r, i in zip(names, range(3)):
        truth = [codec.decode(m, "nav_msgs/msg/Odometry") for m in got[K.topic(r, "ground_truth")]]
        assert [codec.msg_stamp_ns(m) for m in truth] == [p[0][0] for p in poses]
        for m, msg in zip(truth, poses):
            p, q = m.pose.pose.position, m.pose.pose.orientation
            assert struct.pack("<7d", p.x, p.y, p.z, q.x, q.y, q.z, q.w) == \
                struct.pack("<7d", *msg[i][3])
    assert len({t[3] for t in poses[-1]}) == 3            # (each robot its own pose)


# ---------------------------------------------------------------- versions and errors
@pytest.mark.slow
def test_a_node_exits_2_on_a_plant_of_another_protocol_version(procs, endpoint, tmp_path):
    from bus.session import open_session
    s = open_session("plant", endpoint)
    info = {"protocol": 1, "mode": "lockstep", "control_tick_s": 0.02,
            "robots": {"robot1": {"topics": {"joint_states": 1}}}}
    q = s.declare_queryable(K.info, lambda query: query.reply(K.info, json.dumps(info)))
    try:
        node = procs.diffbot("controller", "square_path", "--endpoint", endpoint, name="node")
        assert node.wait(60) == 2
        log = procs.log(node)
        assert ("the plant speaks bus protocol 1; this node speaks bus protocol "
                f"{PROTOCOL_VERSION}") in log
        assert "Traceback" not in log
    finally:
        q.undeclare()
        s.close()


@pytest.mark.slow
def test_the_plant_says_what_is_wrong_with_a_member_s_outputs(procs, endpoint, bus, tmp_path):
    stats = tmp_path / "plant.json"
    plant = procs.diffbot("plant", "--world", "empty", "--expect", "rogue", "--endpoint",
                          endpoint, "--stats", str(stats), name="plant")
    s = bus()
    clocks: queue.Queue = queue.Queue()
    sub = s.declare_subscriber(K.clock, lambda smp: clocks.put(
        codec.parse_attachment(smp.attachment.to_bytes()).t_ns))
    token = s.liveliness().declare_token(K.sync("rogue"))
    key = K.topic("robot1", "cmd_vel")
    cmd = codec.encode(codec.twist_stamped(0, 0.1, 0.0))
    try:
        assert clocks.get(timeout=60) == 0
        s.put(key, cmd)                                           # no attachment at all
        s.put(key, codec.encode(codec.twist_stamped(200_000_000, 0.1, 0.0)),
              attachment=codec.attachment(1, 200_000_000, codec.ACK, 1, "rogue"))  # not due
        s.put(key, cmd, attachment=codec.attachment(2, 0, codec.ACK, 2, "rogue"))  # 1 of 2
        wait_for(lambda: "lockstep: waited" in procs.log(plant), 15, what="the wait report")
        assert clocks.empty(), "the plant stepped without the member's second message"
        # 2 of 2, on another plant-read key (a second on cmd_vel would be a duplicate)
        s.put(K.topic("robot1", "odom"), cmd, attachment=codec.attachment(3, 0, 0, 0, "rogue"))
        assert clocks.get(timeout=15) == 20_000_000
        # Ctrl-C while the member is still there: with its token gone first, the plant may
        # see a member lost (exit 1) before the signal (a race a CI run met)
        plant.send_signal(signal.SIGINT)
        assert procs.wait(plant, 20, "the plant to stop on Ctrl-C") == 0
    finally:
        token.undeclare()
        sub.undeclare()
    log = procs.log(plant)
    assert "robot1/cmd_vel: no attachment" in log and "docs/PROTOCOL.md" in log
    assert "stamped for a tick not due" in log
    assert "rogue (ACKed with n_plant=2, 1 arrived)" in log
    errors = json.loads(stats.read_text())["protocol_errors"]
    assert errors["robot1/cmd_vel: no attachment"] == 1
    assert errors["robot1/cmd_vel: stamped for a tick not due"] == 1
    assert errors["missing outputs"] >= 1


def test_a_recorder_says_the_clocks_it_receives_the_first_at_once_then_every_few(endpoint,
                                                                                tmp_path):
    """The plant paces no watcher it has not heard from (section 4, "Watchers that keep
    up"), so the recorder says a world's first clock at once, then every SEEN_EVERY_TICKS
    new clocks, and a clock seen before (re-published) at once; all as they are received,
    not once written (its writing thread may lag: here it is not even running). A plant
    once ran 48 ticks past a recorder whose writer was busy with a run's first messages,
    and a blip then lost what it did not re-publish. A get on sim/seen/* is answered with
    the latest clock received."""
    import logging

    from bridges.mcapfile import McapRecording
    from bridges.record import Recorder
    from bus.protocol import decode_seen
    from bus.session import open_session
    keys = Keys()
    s = open_session("plant", endpoint)
    said: queue.SimpleQueue = queue.SimpleQueue()
    sub = s.declare_subscriber(keys.seen("recorder"),
                               lambda smp: said.put(decode_seen(smp.payload.to_bytes())))
    rec = Recorder(s, keys, McapRecording(str(tmp_path / "r.mcap")), ["robot1/**"],
                   logging.getLogger("test"))
    clock = s.declare_publisher(keys.clock)
    tick = 20_000_000

    def publish(k: int, epoch: int) -> None:
        clock.put(codec.encode(codec.clock(k * tick)),
                  attachment=codec.attachment(k, k * tick, epoch=epoch))
    try:
        rec.subscribe()
        rec.announce()
        for k in range(11):
            publish(k, epoch=0)
        publish(7, epoch=0)                  # re-published after a blip
        publish(0, epoch=1)                  # a reset: a new world
        wait_for(lambda: said.qsize() >= 5, 10, what="the recorder's reports")
        assert [said.get() for _ in range(5)] == [0, 5 * tick, 10 * tick, 10 * tick, 0]
        assert said.empty()
        (reply,) = s.get(keys.seen("*"), timeout=5.0)
        assert decode_seen(reply.ok.payload.to_bytes()) == 0
    finally:
        rec.close()
        clock.undeclare()
        sub.undeclare()
        s.close()


@pytest.mark.slow
def test_lockstep_keeps_within_pace_ticks_of_a_watcher_that_says_what_it_took_in(
        procs, endpoint, bus, tmp_path):
    """Section 4, "Watchers that keep up": the plant publishes no tick more than PACE_TICKS
    after the latest sim/seen of a process whose token it sees, says whom it waits for, and
    forgets it when the token goes; a report of a process without a token, or a malformed
    one, holds nothing. "End": the plant says sim/end only once a process answering a get on
    sim/seen/* has its last tick."""
    import time

    import zenoh

    from bus.protocol import encode_seen
    tick = 20_000_000
    stats = tmp_path / "plant.json"
    plant = procs.diffbot("plant", "--world", "empty", "--expect", "member", "--duration",
                          "1.5", "--endpoint", endpoint, "--stats", str(stats), name="plant")
    s = bus()
    clocks: queue.Queue = queue.Queue()
    sub = s.declare_subscriber(K.clock, lambda smp: clocks.put(
        codec.parse_attachment(smp.attachment.to_bytes()).t_ns))
    watcher = s.liveliness().declare_token(K.alive("slowpoke"))
    seen = s.declare_publisher(K.seen("slowpoke"),
                               congestion_control=zenoh.CongestionControl.BLOCK)
    member = s.liveliness().declare_token(K.sync("member"))
    seq, last = 0, -tick

    def answer_until_quiet(quiet_s: float = 1.0) -> int:
        """ACK every clock (a member with no plant-read output) until none comes for
        ``quiet_s``; the last stamp. Until the plant takes the watcher in, it says it saw
        nothing yet."""
        nonlocal seq, last
        while True:
            try:
                t = clocks.get(timeout=quiet_s if last >= 0 else 60)
            except queue.Empty:
                return last
            assert t == last + tick, (last, t)         # every tick, in order
            last = t
            if t <= tick:
                seen.put(encode_seen(0))
            seq += 1
            s.put(K.ack("member"), b"", attachment=codec.attachment(seq, t, codec.ACK, 0,
                                                                     "member"))
    try:
        assert answer_until_quiet() == PACE_TICKS * tick              # seen 0: up to tick 20
        wait_for(lambda: "for slowpoke to keep up (taken in: t=0.000 s)" in procs.log(plant),
                 15, what="the plant's wait report")
        # (the plant's subscriber is in place now: it took slowpoke's report in)
        s.put(K.seen("ghost"), encode_seen(0))        # no token: ignored (else held at 20)
        s.put(K.seen("slowpoke"), b"\x00" * 4)        # not a u64: rejected, holds nothing
        seen.put(encode_seen(PACE_TICKS * tick))
        assert answer_until_quiet() == 2 * PACE_TICKS * tick          # 40 ticks after 20
        # "End": a process that answers sim/seen/* one tick short of the end holds sim/end
        has = [74 * tick]
        finisher = s.declare_queryable(K.seen("finisher"), lambda q: q.reply(
            K.seen("finisher"), encode_seen(has[0])))
        ends: queue.Queue = queue.Queue()
        end_sub = s.declare_subscriber(K.end, lambda smp: ends.put(time.monotonic()))
        watcher.undeclare()                                           # gone: not waited for
        assert answer_until_quiet(0.5) == 75 * tick                   # on to --duration 1.5
        assert ends.empty(), "sim/end before the finisher had the last tick"
        has[0] = 75 * tick
        ends.get(timeout=10)
        assert procs.wait(plant, 20, "the plant's end") == 0
        finisher.undeclare()
        end_sub.undeclare()
    finally:
        member.undeclare()
        sub.undeclare()
    st = json.loads(stats.read_text())
    assert st["end_reason"] == "duration reached" and st["protocol_errors"] == {}, st
    assert st["rejected"] == {"sim/seen/slowpoke": 1}, st
    assert st["paced_s"] >= 2.0, st                   # waited through the report at 2 s
    assert "had not taken in the last tick" not in procs.log(plant)
