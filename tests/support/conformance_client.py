"""A lockstep client written from docs/PROTOCOL.md alone.

It imports nothing of diffbot-cosim: only ``zenoh``, ``rosbags`` and the standard
library. It joins a plant's lockstep, drives a robot forward on ground truth until it has
covered ``--distance`` metres (or for ``--ticks`` ticks), sends its last command with
FINAL, waits until the plant has moved past that tick and leaves.

    python tests/support/conformance_client.py --endpoint unixsock-stream/... [--robot robot1]

For the protocol's fixed points: ``--quit-at N`` leaves at tick N without answering it
(a member that gives up: the plant ends the run naming it), ``--duplicates N`` sends a
second, different command for some ticks, sooner or later, carrying the ACK again (the
plant must ignore them, ACK included, whenever they come), ``--future N`` sends N commands
stamped for a tick the plant has not published yet (ignored, counted as protocol errors),
``--reset-at N`` drives backwards until tick N, then resets the world (``sim/reset``) instead
of answering it and drives the new world from its tick 0 (told from a re-publish by the
epoch of the plant's attachment: N may be below 26). A clock for a tick it answered already,
in the same epoch, is answered again byte for byte (a re-publish after a rejoin). ``--hold H``
(with ``--ticks``) answers a tick with ``hold`` = H whenever its next H commands are the same
(section 4, "Holding") and answers the held ticks with nothing, before the FINAL tick.
``--episodes N`` drives N times ``--ticks`` ticks, resetting the world (``sim/reset`` without
a seed: the same world again) at the tick after each but the last; ``--hold H1,H2,...``
then holds H1 in the first episode, H2 in the second, and so on, cycling.

Exit codes: 0 done, 2 a plant of another protocol version, 3 the plant went away.
"""
from __future__ import annotations

import argparse
import json
import queue
import struct
import sys
import time

import zenoh
from rosbags.typesys import Stores, get_typestore

PROTOCOL = 5                                   # section "The diffbot-cosim bus protocol, version 5"
ACK, FINAL = 1, 2                              # section 3: flags
HOLD_SHIFT, HOLD_MAX = 2, 63                   # section 3: flags bits 2-7
KEEP_TICKS = 26                                # section 4, "Lost members": answers kept
TS = get_typestore(Stores.ROS2_JAZZY)
T = TS.types


def attachment(seq: int, stamp_ns: int, flags: int, n_plant: int, name: str) -> bytes:
    """Section 3: u64 seq, u64 stamp_ns, u8 flags, u16 n_plant, u8 name_len, name."""
    raw = name.encode("utf-8")
    return struct.pack("<QQBHB", seq, stamp_ns, flags, n_plant, len(raw)) + raw


def plant_epoch(att: bytes | None) -> int:
    """Section 3: the plant's attachment is u64 seq, u64 stamp_ns, u32 epoch (20 bytes)."""
    return struct.unpack_from("<I", att, 16)[0] if att is not None and len(att) == 20 else 0


def twist_stamped(stamp_ns: int, linear_mps: float) -> bytes:
    """Section 2: geometry_msgs/msg/TwistStamped in frame base_link, CDR."""
    msg = T["geometry_msgs/msg/TwistStamped"](
        header=T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9,
                                                   nanosec=stamp_ns % 10**9),
            frame_id="base_link"),
        twist=T["geometry_msgs/msg/Twist"](
            linear=T["geometry_msgs/msg/Vector3"](x=linear_mps, y=0.0, z=0.0),
            angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)))
    return bytes(TS.serialize_cdr(msg, "geometry_msgs/msg/TwistStamped"))


def stamp_of(payload: bytes, msgtype: str) -> tuple[int, object]:
    msg = TS.deserialize_cdr(payload, msgtype)
    st = msg.clock if msgtype == "rosgraph_msgs/msg/Clock" else msg.header.stamp
    return st.sec * 10**9 + st.nanosec, msg


def client_config(endpoint: str) -> zenoh.Config:
    """Section 1: a client session to the plant's endpoint, no scouting."""
    conf = zenoh.Config()
    for key, value in (("mode", "client"), ("connect/endpoints", [endpoint]),
                       ("transport/link/tx/lease", 1000),
                       ("listen/endpoints", []), ("scouting/multicast/enabled", False),
                       ("scouting/gossip/enabled", False)):
        conf.insert_json5(key, json.dumps(value))
    return conf


def get_info(session: zenoh.Session, timeout_s: float = 15.0) -> dict:
    """Section 5: ask sim/info until the plant answers."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for reply in session.get("sim/info", timeout=1.0):
            if reply.ok is not None:
                return json.loads(reply.ok.payload.to_bytes())
        time.sleep(0.1)
    raise TimeoutError("no plant answered sim/info")


def reset_world(session: zenoh.Session, epoch: int) -> bool:
    """Section 6: reset the world (the same seed and poses again); whether it was. A reply
    lost on the way (this process frozen past the lease, say) is told from a refusal by the
    plant's epoch (section 5): a new one means the reset was done."""
    for _ in range(3):
        replies = list(session.get("sim/reset", payload=b"{}", timeout=10.0))
        if replies:
            if replies[0].ok is None:
                return False
            said = json.loads(replies[0].ok.payload.to_bytes())
            return said.get("epoch", epoch + 1) > epoch      # the new world's (5.2)
        if get_info(session).get("epoch", epoch) > epoch:
            return True
    return False


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--endpoint", required=True)
    p.add_argument("--robot", default="robot1")
    p.add_argument("--name", default="conformance")
    p.add_argument("--distance", type=float, default=1.0, help="m (default 1)")
    p.add_argument("--speed", type=float, default=0.25, help="m/s (default 0.25)")
    p.add_argument("--ticks", type=int, default=None, help="drive this many ticks instead")
    p.add_argument("--quit-at", type=int, default=None, metavar="N")
    p.add_argument("--duplicates", type=int, default=0, metavar="N",
                   help="at ticks 5, 10, ... 5N send a second, different command with the ACK "
                        "again, 0 to 40 ms after the first (before and after the plant applies "
                        "it)")
    p.add_argument("--future", type=int, default=0, metavar="N",
                   help="at ticks 7, 14, ... 7N also send a command stamped 10 ticks ahead")
    p.add_argument("--reset-at", type=int, default=None, metavar="N",
                   help="drive backwards until tick N, then reset the world instead of "
                        "answering it, and drive the new world from its tick 0")
    p.add_argument("--hold", default="0", metavar="H[,H...]",
                   help="with --ticks: answer with hold H (at most up to the FINAL tick) and "
                        "send nothing for the held ticks; a list: one per episode, cycling")
    p.add_argument("--episodes", type=int, default=1, metavar="N",
                   help="with --ticks: drive N episodes, resetting the world between them")
    a = p.parse_args(argv)
    holds = [int(h) for h in a.hold.split(",")]
    if (any(holds) or a.episodes > 1) and a.ticks is None:
        p.error("--hold and --episodes need --ticks (the commands ahead must be known)")
    with zenoh.open(client_config(a.endpoint)) as s:
        info = get_info(s)
        if info.get("protocol") != PROTOCOL or info.get("mode") != "lockstep":
            print(f"conformance client: plant speaks protocol {info.get('protocol')} in "
                  f"{info.get('mode')} mode; this client speaks {PROTOCOL}, lockstep",
                  file=sys.stderr)
            return 2
        tick_ns = round(info["control_tick_s"] * 1e9)
        events: queue.SimpleQueue = queue.SimpleQueue()

        def on(tag):
            return lambda sample: events.put((
                tag, sample.payload.to_bytes(), sample.kind,
                sample.attachment.to_bytes() if sample.attachment is not None else None))
        # Section 4, joining: subscribe first, then declare the tokens.
        subs = [s.declare_subscriber("sim/clock", on("clock")),
                s.declare_subscriber(f"{a.robot}/ground_truth", on("truth")),
                s.declare_subscriber("sim/end", on("end")),
                s.liveliness().declare_subscriber("sim/alive/plant", on("plant"))]
        pub = s.declare_publisher(f"{a.robot}/cmd_vel", encoding=zenoh.Encoding.APPLICATION_CDR,
                                  congestion_control=zenoh.CongestionControl.BLOCK)
        tokens = [s.liveliness().declare_token(f"sim/alive/{a.name}"),
                  s.liveliness().declare_token(f"sim/sync/{a.name}")]
        clocks: list[int] = []
        x_of: dict[tuple[int, int], float] = {}    # ground truth x by (epoch, stamp)
        sent: dict[int, list[tuple[bytes, int]]] = {}   # tick -> (payload, flags) answered
        held: set[int] = set()                     # ticks held: answered with nothing
        hold_until = -1                            # the stamp of the last tick held
        epoch = None                               # of the world the clocks are of
        x0 = None
        seq = 0
        n = 0                                      # ticks answered (in this world)
        final_tick = None
        resetting = a.reset_at is not None         # drives backwards until the reset
        episode = 0
        reset_from = -1                            # the epoch this client reset away from
        code = 3

        def put(t: int, payload: bytes, flags: int) -> None:
            nonlocal seq
            seq += 1
            pub.put(payload, attachment=attachment(seq, t, flags, 1, a.name))
        try:
            while True:
                tag, payload, kind, att = events.get(timeout=30)
                if tag == "end":
                    code = 0
                    break
                if tag == "plant":
                    if kind == zenoh.SampleKind.DELETE:
                        break                      # the plant went away without an end
                    continue
                if tag == "truth":
                    t, msg = stamp_of(payload, "nav_msgs/msg/Odometry")
                    x_of[plant_epoch(att), t] = msg.pose.pose.position.x
                elif tag == "clock":
                    t, _ = stamp_of(payload, "rosgraph_msgs/msg/Clock")
                    e = plant_epoch(att)
                    if epoch is not None and e < epoch or e <= reset_from:
                        continue                   # the old world's, late
                    if e != epoch:                 # a new world (section 4, "Reset")
                        epoch, clocks, x0, n, hold_until = e, [], None, 0, -1
                        sent.clear()
                        held.clear()                # a reset forgets every hold
                    if final_tick is not None:
                        if t > final_tick:         # the plant moved past our last tick
                            code = 0
                            break
                        continue
                    if t in sent:                  # a re-publish: the same answer again
                        for data, flags in sent[t]:
                            put(t, data, flags)
                        continue
                    if t in held or t in clocks:   # held, or still to answer: once only
                        continue
                    clocks.append(t)
                # Section 4, step 2: act on a tick once its clock and every input due are in
                # (ground truth is published every tick).
                while clocks and (epoch, clocks[0]) in x_of and final_tick is None:
                    t = clocks.pop(0)
                    x = x_of.pop((epoch, t))
                    x0 = x if x0 is None else x0
                    k = t // tick_ns               # the tick's number in this world
                    if t <= hold_until:            # "Holding": observed, not answered (by
                        held.add(t)                # stamp: a held tick's clock may be lost)
                        n = k + 1
                        continue
                    if k == a.quit_at:
                        print(f"conformance client: giving up at tick {k}", file=sys.stderr)
                        return 1
                    last = episode + 1 >= a.episodes
                    if resetting and k == a.reset_at or not last and k == a.ticks:
                        # Section 6: the world restarts at t = 0 instead of this tick
                        if not reset_world(s, epoch):
                            print("conformance client: sim/reset refused", file=sys.stderr)
                            return 1
                        if resetting:
                            resetting = False
                        else:
                            episode += 1
                        reset_from = epoch         # its clocks still on their way: not ours
                        clocks.clear()
                        break
                    done = (last and k + 1 >= a.ticks if a.ticks is not None
                            else x - x0 >= a.distance)
                    # --ticks: the FINAL tick's command is the last of the drive (applied
                    # without --end-with, section 4 "Finishing"); else it stops the robot
                    speed = a.speed if not done or a.ticks is not None else 0.0
                    flags = ACK | (FINAL if done else 0)
                    hold = holds[episode % len(holds)]
                    if hold and not done:          # the held ticks come before the FINAL one
                        h = max(0, min(hold, HOLD_MAX, a.ticks - 2 - k))
                        flags |= h << HOLD_SHIFT
                        hold_until = t + h * tick_ns
                    data = twist_stamped(t, -speed if resetting else speed)
                    # Step 3: one command, the last plant-read output, so it carries the ACK.
                    put(t, data, flags)
                    sent[t] = [(data, flags)]
                    while len(sent) > KEEP_TICKS:
                        del sent[min(sent)]
                    while len(held) > 2 * HOLD_MAX:
                        held.discard(min(held))
                    n = k + 1
                    i, r = divmod(n - 1, 5)
                    if not r and 1 <= i <= a.duplicates:
                        # Section 7: a second message on the key for the same tick is
                        # ignored, however late it comes, and so is the ACK it carries.
                        time.sleep(0.01 * (i % 5) ** 2 / 4)
                        put(t, twist_stamped(t, -a.speed), ACK)
                    i, r = divmod(n, 7)
                    if not r and 1 <= i <= a.future:
                        # Section 7: a stamp for a tick not published yet is ignored.
                        put(t + 10 * tick_ns, twist_stamped(t + 10 * tick_ns, -a.speed), 0)
                    if done:
                        final_tick = t             # finishing: keep the tokens until then
        except queue.Empty:
            print(f"conformance client: nothing from the plant for 30 s (epoch {epoch}, "
                  f"{n} ticks answered or held, waiting for the ticks {clocks[:3]} of "
                  f"{len(clocks)}, ground truth of {sorted(t for _, t in x_of)[-3:]})",
                  file=sys.stderr)
        finally:
            for tok in tokens:
                tok.undeclare()
            for sub in subs:
                sub.undeclare()
    print(f"conformance client: {'done' if final_tick is not None else 'stopped'} "
          f"after {n} ticks", file=sys.stderr)
    return code if final_tick is not None or code else 1


if __name__ == "__main__":
    sys.exit(main())
