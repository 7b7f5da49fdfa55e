"""Record the bus into an MCAP file that Foxglove, ``ros2 bag`` and ``rosbags`` open.

``diffbot record FILE.mcap [KEYS...]`` subscribes to every key of the simulation
(or the given key expressions) and writes each message as it came off the bus:

* **layout** — ``FILE.mcap`` is one MCAP file. A path without the ``.mcap`` suffix
  is a rosbag2 *bag directory*, the layout ``ros2 bag record -s mcap -o DIR``
  makes: ``DIR/DIR_0.mcap`` plus ``DIR/metadata.yaml`` (``rosbags`` readers need
  the directory; everything else opens the ``.mcap`` alone).
* **content** — MCAP profile ``ros2``; one channel per key, topic ``/<key>``
  (``/robot1/joint_states``, ``/sim/clock``), message encoding ``cdr``, schema
  encoding ``ros2msg`` with the full message definition from the rosbags type store
  (so Foxglove panels decode them natively), channel metadata
  ``offered_qos_profiles`` and ``topic_type_hash`` as rosbag2 writes them.
  The CDR payload bytes are the bus's bytes, unchanged.
* **times** — ``log_time`` is the message's *simulated* time, the ``t_ns`` of its
  bus attachment (a message without one gets the latest sim time seen), so a
  recording plays back on the sim-time axis and two recordings of the same seed
  line up. ``publish_time`` is the wall-clock time (Unix epoch ns) at which the
  recorder received the message; it keeps how the run went in real time (rates,
  stalls). ``sequence`` is the attachment's sequence number (modulo 2^32).
* **metadata** — an MCAP metadata record ``diffbot`` holds the plant's ``sim/info``
  JSON at the start of the recording (``sim_info``: world, robots, tick, mode, seed)
  and the recorder's own settings; ``diffbot replay`` serves it back. At a clean
  close a ``rosbag2`` metadata record (``serialized_metadata``, as rosbag2 writes).
* **scene** — so the file opens in Foxglove's 3-D panel as a room, not only numbers, the
  recorder adds what :mod:`bridges.scene` derives (the live view sends the same): ``/scene``
  (``visualization_msgs/msg/MarkerArray``: every world object and robot part),
  ``/tf_static`` (``world -> <robot>/odom``, sensor mounts) and
  ``/<robot>/robot_description`` (the URDF, :mod:`bridges.urdf`) once, when ``sim/info``
  arrives, and ``/tf`` (``tf2_msgs/msg/TFMessage``: ``world -> <robot>/base_link``) with
  every ground truth; ``--no-scene`` leaves them out. They are ordinary ROS 2 messages
  (``ros2 bag play`` publishes them; ``diffbot replay`` skips them, they are no bus keys).
  Frames and topic names are the bus's, as in the live view and over ROS 2.
* **skipped** — keys that carry no message type (``sim/ack/*``, ``sim/end``,
  anything unknown) and payloads that do not decode as their key's type (counted,
  logged at a limited rate); liveliness tokens never reach a subscriber.

Lockstep: the recorder says what it has taken in (``sim/seen/<name>``, the latest
``sim/clock`` stamp received, the first at once and then every few ticks, however far its
writing lags; docs/PROTOCOL.md section 4, "Watchers that keep up"), so
the plant never runs more ticks ahead of it than it re-publishes after a router blip: a
recording with blips in it has the bytes of one without, however far a loaded machine let
the recorder fall behind. At the end of any run it answers the plant's get on
``sim/seen/*`` with the latest clock it has received, and the plant ends once that is its
last tick (section 4, "End"). (It subscribes to ``sim/clock`` for that even when the given keys
leave the clock out; it is then not recorded.)

Crash safety: chunks are closed and flushed to the OS at least every ``--flush``
seconds of wall time (default 1 s) and whenever they reach ``--chunk-size``.
SIGINT, SIGTERM and ``sim/end`` close the file properly (summary, index, footer), and so
does a plant gone for longer than the run's rejoin timeout + 2 s (its ``sim/end`` may never
come, :mod:`bus.plantwatch`; exit 3).
After a **SIGKILL** (or a power cut after the OS wrote it) the file has everything up
to the last flushed chunk — at most about one flush period is lost — but no summary
or footer: ``diffbot replay`` reads such a file as it is, and
``diffbot record --recover FILE`` rewrites it into a complete file (and writes the
bag directory's ``metadata.yaml``) for tools that need the footer.
"""
from __future__ import annotations

import argparse
import logging
import queue
import socket
import sys
import threading
import time

import zenoh

from bus import codec, jsonio
from bus.cliargs import ArgumentParser, positive_float, positive_int
from bus.keys import Keys
from bus.log import RejectCounter
from bus.plantwatch import EXIT_PLANT_GONE, PlantWatch
from bus.process import EXIT_BAD_CONFIG as EXIT_BAD_INPUT, EXIT_FAILED as EXIT_WRITE_FAILED
from bus.process import EXIT_OK, Exit, Process, process_main
from bus.session import add_process_args, undeclare_all

from . import scene, urdf
from .mcapfile import INFO_METADATA, McapRecording, RecordError, recover
from .seen import SeenReporter
from .topics import FmuTypes

#: stamps per key remembered to drop a message re-sent after a lockstep rejoin (more than
#: the plant re-publishes, bus.protocol.REPUBLISH_TICKS)
REPEAT_WINDOW = 64
#: After ``sim/end``, keep listening until the bus has been quiet this long (the last
#: outputs of other nodes) and no lockstep member is left, but no longer than END_MAX_S.
END_GRACE_S = 0.3
END_MAX_S = 5.0


class Recorder:
    """Subscribes to key expressions and writes what arrives into a :class:`McapRecording`.

    Zenoh's receive thread only queues ``(key, payload, attachment, wall ns)``; the
    thread calling :meth:`run` decodes, checks and writes, so a slow disk never
    stalls the bus (the queue grows instead; ``queue_max`` tells by how much).
    """

    def __init__(self, session: zenoh.Session, keys: Keys, out: McapRecording,
                 exprs: list[str], log: logging.Logger, name: str = "recorder") -> None:
        self.session = session
        self.keys = keys
        self.out = out
        self.log = log
        self.name = name
        self.exprs = exprs
        self.queue: queue.SimpleQueue = queue.SimpleQueue()
        self.rejects = RejectCounter(log)
        self.skipped: dict[str, int] = {}
        self.repeated: dict[str, int] = {}      # key -> messages received again (re-sent)
        self._recent: dict[str, dict[int, int]] = {}   # key -> {stamp: hash of its bytes}
        self._epoch = 0                                # of the plant's world (its attachment)
        self.stop_event = threading.Event()
        self.end_reason: str | None = None
        self.info: dict | None = None
        #: write /scene, /tf_static once and /tf per ground truth (see the module docstring)
        self.with_scene = True
        self.queue_max = 0
        self.fmu_types = FmuTypes(session, keys)     # fmu/ keys: types from the nodes' info
        self._sim_ns = 0
        self._late_info_tried = False
        self._subs: list = []
        self._token = None
        # what it has taken in, said on sim/seen/<name> (the module docstring)
        self.seen = SeenReporter(session, keys, name)
        self.records_clock = any(zenoh.KeyExpr(e).includes(zenoh.KeyExpr(keys.clock))
                                 for e in exprs)
        #: the plant's sim/alive token: a recorder whose plant is gone for longer than the
        #: run's rejoin timeout ends by itself (its sim/end may never come: bus.plantwatch)
        self.watch = PlantWatch()
        self.wall_start = time.monotonic()
        self.wall_end = 0.0

    def subscribe(self) -> None:
        q = self.queue
        clock_key = self.keys.clock

        def cb(sample: zenoh.Sample) -> None:
            att = sample.attachment
            key = str(sample.key_expr)
            att = att.to_bytes() if att is not None else None
            if key == clock_key and att is not None:
                self.seen.took_in_clock(att)
            q.put((key, sample.payload.to_bytes(), att, time.time_ns()))

        clock = [] if self.records_clock else [clock_key]     # (to keep up only)
        for expr in _distinct([*self.exprs, self.keys.end, *clock]):
            # Direct callbacks (Zenoh's receive thread) keep the arrival order across keys.
            self._subs.append(self.session.declare_subscriber(
                expr, zenoh.handlers.Callback(cb, indirect=False)))
        watch = self.watch

        def on_plant(sample: zenoh.Sample) -> None:     # (Zenoh's thread: two assignments)
            if sample.kind == zenoh.SampleKind.PUT:
                watch.here()
            else:
                watch.gone(time.monotonic())
        self._subs.append(self.session.liveliness().declare_subscriber(
            self.keys.alive("plant"), zenoh.handlers.Callback(on_plant, indirect=False),
            history=True))

    def fetch_info(self, timeout_s: float) -> None:
        """The plant's ``sim/info``, stored as MCAP metadata (once)."""
        if self.info is not None:
            return
        from bus.session import query_info
        try:
            self.info = query_info(self.session, self.keys, timeout_s,
                                   self.log if timeout_s > 1.0 else None)
        except (TimeoutError, ValueError) as exc:
            self.log.warning("no sim/info (%s); recording without it", exc)
            return
        self.watch.learn(self.info)
        self.out.add_metadata(INFO_METADATA, {
            "sim_info": jsonio.dumps(self.info),
            "recorder": jsonio.dumps({"keys": self.exprs, "namespace": self.keys.namespace,
                                    "started_unix_ns": time.time_ns(),
                                    "host": socket.gethostname(),
                                    "log_time": "sim time (attachment t_ns)",
                                    "publish_time": "wall clock at the recorder (Unix ns)"}),
        })
        if self.with_scene:
            t = int(self.info.get("time_ns", 0) or 0)
            now = time.time_ns()
            self.out.write(self._derived(scene.SCENE_TOPIC), scene.SCENE_TYPE,
                           codec.encode(scene.scene(self.info, t)), t, now)
            self.out.write(self._derived(scene.TF_STATIC_TOPIC), scene.TF_TYPE,
                           codec.encode(scene.static_tf(self.info, t)), t, now)
            for r in self.info.get("robots", {}):
                self.out.write(self._derived(f"{r}/{urdf.DESCRIPTION_TOPIC}"),
                               urdf.DESCRIPTION_TYPE,
                               codec.encode(urdf.description_message(self.info, r)), t, now)

    def _derived(self, name: str) -> str:
        return f"{self.keys.namespace}/{name}" if self.keys.namespace else name

    def announce(self) -> None:
        """Liveliness ``sim/alive/<name>`` once subscribed: the launcher and the plant's
        ``--expect`` wait for it, so nothing is published before the recorder listens."""
        self.seen.declare()
        self._token = self.session.liveliness().declare_token(self.keys.alive(self.name))

    def handle(self, item) -> None:
        key, payload, att, recv_ns = item
        if key == self.keys.end:
            if self.end_reason is None:
                self.end_reason = payload.decode("utf-8", "replace") or "sim/end"
            return
        if key == self.keys.clock and not self.records_clock:   # subscribed to keep up only
            return
        msgtype = self.keys.msgtype_of(key) or self.fmu_types(key)
        if msgtype is None:
            self.skipped[key] = self.skipped.get(key, 0) + 1
            return
        try:
            msg = codec.decode(payload, msgtype)
        except codec.CodecError as exc:
            self.rejects.reject(key, str(exc))
            return
        a = codec.parse_attachment(att)
        if a is not None:
            seq, t_ns = a.seq, a.t_ns
            self._new_epoch(a.epoch)
            if self._repeated(key, t_ns, payload):
                return
            self._sim_ns = max(self._sim_ns, t_ns)
        else:
            seq, t_ns = 0, self._sim_ns
        self.out.write(key, msgtype, payload, t_ns, recv_ns, seq)
        if self.with_scene and (robot := scene.robot_of_ground_truth(self.keys, key)):
            self.out.write(self._derived(scene.TF_TOPIC), scene.TF_TYPE,
                           codec.encode(scene.tf([scene.ground_truth_transform(robot, msg, t_ns)])),
                           t_ns, recv_ns)
        if self.info is None and key == self.keys.clock and not self._late_info_tried:
            self._late_info_tried = True      # the plant came after the recorder: ask once
            self.fetch_info(1.0)

    def _new_epoch(self, epoch: int | None) -> None:
        """A reset (the plant's attachment's epoch changed): its stamps are all new again."""
        if epoch is not None and epoch != self._epoch:
            self._epoch = epoch
            self._recent.clear()

    def _repeated(self, key: str, t_ns: int, payload: bytes) -> bool:
        """A message already recorded: the same key, stamp and bytes again, as lockstep
        re-publishes (and members re-send) their last ticks after a rejoin (docs/PROTOCOL.md
        section 4, "Lost members"). Counted in ``repeated``, not recorded twice."""
        seen = self._recent.setdefault(key, {})
        digest = hash(payload)
        if seen.get(t_ns) == digest:
            self.repeated[key] = self.repeated.get(key, 0) + 1
            return True
        seen[t_ns] = digest
        if len(seen) > REPEAT_WINDOW:
            del seen[next(iter(seen))]
        return False

    def run(self, stop_on_end: bool = True) -> int:
        """Record until a stop signal, or ``sim/end`` (``stop_on_end``: then EXIT_OK), or the
        plant gone for longer than the run's rejoin timeout (EXIT_PLANT_GONE)."""
        end_at = None
        quiet_since = time.monotonic()
        get = self.queue.get
        while not self.stop_event.is_set():
            try:
                item = get(timeout=0.05)
            except queue.Empty:
                item = None
            if item is not None:
                quiet_since = None
            n = 0
            while item is not None:
                self.handle(item)
                n += 1
                if n >= 1000:
                    break
                try:
                    item = self.queue.get_nowait()
                except queue.Empty:
                    item = None
            self.queue_max = max(self.queue_max, self.queue.qsize())
            now = time.monotonic()
            if quiet_since is None and item is None:
                quiet_since = now
            self.out.maybe_flush(now)
            if stop_on_end and self.end_reason is None and self.watch.expired(now):
                self.log.error("%s; closing the recording", self.watch.why(now))
                return EXIT_PLANT_GONE
            if self.end_reason is not None and stop_on_end:
                if end_at is None:
                    end_at = now
                    self.log.info("the simulation ended (%s); finishing", self.end_reason)
                elif now - end_at >= END_MAX_S:
                    break
                elif (quiet_since is not None and now - quiet_since >= END_GRACE_S
                      and not self._members_left()):
                    break
        return EXIT_OK

    def _members_left(self) -> bool:
        """Whether a lockstep member (``sim/sync/*``) is still on the bus: its last outputs
        may still be on their way (a node starved of CPU, a slow link), so a quiet bus
        alone does not end the recording while one is there (END_MAX_S still does)."""
        try:
            return any(True for _ in self.session.liveliness().get(self.keys.sync(),
                                                                     timeout=0.2))
        except Exception:
            return False

    def close(self) -> None:
        """Stop listening, write what is still queued, close the file."""
        undeclare_all(self._subs)
        self._subs.clear()
        self.seen.undeclare()
        try:
            while True:
                try:
                    self.handle(self.queue.get_nowait())
                except queue.Empty:
                    break
        finally:
            if self._token is not None:
                try:
                    self._token.undeclare()
                except Exception:
                    pass
                self._token = None
            self.out.close()
            self.wall_end = time.monotonic()

    def stats(self) -> dict:
        return {"node": self.name, "file": self.out.file, "bag_dir": self.out.bag_dir,
                "recorded": dict(sorted(self.out.counts.items())),
                "messages": sum(self.out.counts.values()),
                "bytes": self.out.size_bytes, "published": {},
                "skipped": dict(sorted(self.skipped.items())),
                "repeated": dict(sorted(self.repeated.items())),
                "rejected": dict(self.rejects.counts),
                "queue_max": self.queue_max,
                "wall_time_s": (self.wall_end or time.monotonic()) - self.wall_start,
                "end_reason": self.end_reason}


def _distinct(exprs: list[str]) -> list[str]:
    """Key expressions without those another one already covers (a sample matching two
    subscribers of one session would be delivered, and recorded, twice)."""
    out: list[str] = []
    for e in exprs:
        ke = zenoh.KeyExpr(e)
        if any(zenoh.KeyExpr(o).includes(ke) for o in out):
            continue
        out = [o for o in out if not ke.includes(zenoh.KeyExpr(o))] + [e]
    return out


def report(counts: dict[str, int], out=sys.stderr) -> None:
    """Counts per topic, like ``ros2 bag info``."""
    if not counts:
        print("  (no messages)", file=out)
    w = max((len(k) for k in counts), default=0) + 1
    for key, n in sorted(counts.items()):
        print(f"  /{key:{w}s} {n:8d}", file=out)
    print(f"  {'total':{w + 1}s} {sum(counts.values()):8d}", file=out)


# ====================================================================== CLI
def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(
        prog="diffbot record",
        description="Record the bus into an MCAP file (ROS 2 profile; Foxglove opens it). "
                    "Runs until Ctrl-C or the simulation ends (sim/end).")
    p.add_argument("path", metavar="FILE.mcap",
                   help="output file; a path without .mcap is a rosbag2 bag directory "
                        "(DIR/DIR_0.mcap + metadata.yaml) as `ros2 bag record` makes")
    p.add_argument("keys", nargs="*", metavar="KEY",
                   help="key expressions to record, relative to the namespace "
                        "(default: everything, **)")
    p.add_argument("--name", default="recorder",
                   help="node name: liveliness token sim/alive/NAME is declared once "
                        "subscribed (default recorder)")
    p.add_argument("--no-stop-on-end", dest="stop_on_end", action="store_false",
                   help="keep recording after sim/end or a lost plant (until Ctrl-C)")
    p.add_argument("--flush", type=positive_float, default=1.0, metavar="S",
                   help="close and flush a chunk at least every S wall seconds: what a "
                        "SIGKILL can lose (default 1)")
    p.add_argument("--chunk-size", type=positive_int, default=1 << 20, metavar="BYTES")
    p.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd")
    p.add_argument("--info-timeout", type=positive_float, default=15.0, metavar="S",
                   help="wait this long for the plant's sim/info at the start (default 15)")
    p.add_argument("--recover", action="store_true",
                   help="do not record: rewrite FILE, left unclosed by a SIGKILL, "
                        "into a complete file")
    p.add_argument("--no-scene", dest="scene", action="store_false",
                   help="do not add /scene, /tf_static and /tf (the 3-D room for Foxglove)")
    add_process_args(p)
    return p


def main(argv: list[str] | None = None) -> int:
    return process_main(_run, build_parser(), argv,
                        lambda args: args.name if not args.recover else "recover")


def _run(proc: Process) -> int:
    args, log = proc.args, proc.log
    if args.recover:
        try:
            counts = recover(args.path, log)
        except (RecordError, OSError) as exc:
            raise Exit(EXIT_BAD_INPUT, exc) from None
        report(counts)
        return EXIT_OK
    if args.flush <= 0 or args.chunk_size <= 0:
        raise Exit(EXIT_BAD_INPUT, "--flush and --chunk-size must be > 0")
    try:
        keys = proc.keys
        prefix = f"{keys.namespace}/" if keys.namespace else ""
        exprs = [prefix + k.strip("/") for k in args.keys] or [keys.all]
        for e in exprs:
            zenoh.KeyExpr(e)
    except Exception as exc:
        raise Exit(EXIT_BAD_INPUT, f"bad key: {exc}") from None
    try:
        out = McapRecording(args.path, chunk_size=args.chunk_size, compression=args.compression,
                            flush_s=args.flush)
    except RecordError as exc:
        raise Exit(EXIT_BAD_INPUT, exc) from None
    try:
        session = proc.open("node")
    except Exit:
        out.discard()
        raise
    rec = Recorder(session, keys, out, exprs, log, args.name)
    rec.with_scene = args.scene
    proc.stats = rec.stats
    proc.stop_on_signals(rec.stop_event)
    code = EXIT_OK
    try:
        rec.subscribe()
        rec.fetch_info(args.info_timeout)
        rec.announce()
        log.info("recording %s into %s", ", ".join(exprs), out.file)
        code = rec.run(stop_on_end=args.stop_on_end)
    except OSError as exc:                 # disk full, file system gone...
        log.error("writing %s failed: %s", out.file, exc)
        code = EXIT_WRITE_FAILED
    finally:
        try:
            rec.close()
        except OSError as exc:
            log.error("closing %s failed: %s (`diffbot record --recover` keeps what was "
                      "flushed)", out.file, exc)
            code = EXIT_WRITE_FAILED
        st = rec.stats()
        log.info("wrote %s: %d messages, %.1f MB, %d skipped, %d rejected", out.file,
                 st["messages"], st["bytes"] / 1e6, sum(rec.skipped.values()),
                 rec.rejects.total)
        report(out.counts)
    return code


if __name__ == "__main__":
    sys.exit(main())
