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
  recorder adds what :mod:`bus.scene` derives (the live view sends the same): ``/scene``
  (``visualization_msgs/msg/MarkerArray``: every world object and robot part),
  ``/tf_static`` (``world -> <robot>/odom``, sensor mounts) and
  ``/<robot>/robot_description`` (the URDF, :mod:`bus.urdf`) once, when ``sim/info``
  arrives, and ``/tf`` (``tf2_msgs/msg/TFMessage``: ``world -> <robot>/base_link``) with
  every ground truth; ``--no-scene`` leaves them out. They are ordinary ROS 2 messages
  (``ros2 bag play`` publishes them; ``diffbot replay`` skips them, they are no bus keys).
  Frames and topic names are the bus's, as in the live view and over ROS 2.
* **skipped** — keys that carry no message type (``sim/ack/*``, ``sim/end``,
  anything unknown) and payloads that do not decode as their key's type (counted,
  logged at a limited rate); liveliness tokens never reach a subscriber.

Crash safety: chunks are closed and flushed to the OS at least every ``--flush``
seconds of wall time (default 1 s) and whenever they reach ``--chunk-size``.
SIGINT, SIGTERM and ``sim/end`` close the file properly (summary, index, footer).
After a **SIGKILL** (or a power cut after the OS wrote it) the file has everything up
to the last flushed chunk — at most about one flush period is lost — but no summary
or footer: ``diffbot replay`` reads such a file as it is, and
``diffbot record --recover FILE`` rewrites it into a complete file (and writes the
bag directory's ``metadata.yaml``) for tools that need the footer.
"""
from __future__ import annotations

import argparse
import io
import json
import logging
import os
import queue
import socket
import sys
import threading
import time
from dataclasses import dataclass, field

import zenoh
from mcap.records import Attachment, Channel, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from . import codec, jsonio, scene, urdf
from .cliargs import ArgumentParser, positive_float, positive_int
from .keys import Keys
from .log import RejectCounter, setup_logging
from .session import BusConfigError, add_bus_args, open_session
from .topics import FmuTypes

PROFILE = "ros2"
MESSAGE_ENCODING = "cdr"
SCHEMA_ENCODING = "ros2msg"
#: Name of the MCAP metadata record with the plant's ``sim/info`` and the recorder settings.
INFO_METADATA = "diffbot"
ROSBAG2_VERSION = 9
#: Channel metadata ``offered_qos_profiles``, YAML as rosbag2 writes it: none offered, so
#: ROS 2 tools use their defaults.
QOS_NONE = "[]"
#: stamps per key remembered to drop a message re-sent after a lockstep rejoin (more than
#: the plant re-publishes, plant.node.REPUBLISH_TICKS)
REPEAT_WINDOW = 64
#: After ``sim/end``, keep listening until the bus has been quiet this long (the last
#: outputs of other nodes) and no lockstep member is left, but no longer than END_MAX_S.
END_GRACE_S = 0.3
END_MAX_S = 5.0

EXIT_OK = 0
EXIT_WRITE_FAILED = 1
EXIT_BAD_INPUT = 2


class RecordError(Exception):
    """A recording that cannot be created or read."""


# ====================================================================== file side
def layout(path: str) -> tuple[str, str | None]:
    """(MCAP file, bag directory or None) for a recording path.

    ``x.mcap`` is a single file; anything else is a rosbag2 bag directory holding
    ``<dir>_0.mcap`` and ``metadata.yaml``. An existing bag directory is found by
    its ``metadata.yaml`` (or its only ``.mcap`` file, e.g. one never closed).
    """
    if os.path.isfile(path) or (path.endswith(".mcap") and not os.path.isdir(path)):
        return path, None
    d = path.rstrip("/") or "/"
    meta = os.path.join(d, "metadata.yaml")
    if os.path.isfile(meta):
        try:
            from ruamel.yaml import YAML
            with open(meta) as f:
                info = YAML(typ="safe").load(f)["rosbag2_bagfile_information"]
            return os.path.join(d, os.path.basename(info["relative_file_paths"][0])), d
        except Exception:
            pass
    if os.path.isdir(d):
        found = sorted(f for f in os.listdir(d) if f.endswith(".mcap"))
        if found:
            return os.path.join(d, found[0]), d
    return os.path.join(d, f"{os.path.basename(os.path.abspath(d))}_0.mcap"), d


class McapRecording:
    """The writing side: schemas, channels, messages, metadata; no Zenoh.

    Only one thread may call it. ``flush_s`` bounds how much a SIGKILL can lose.
    """

    def __init__(self, path: str, *, chunk_size: int = 1 << 20, compression: str = "zstd",
                 flush_s: float = 1.0, library: str = "diffbot-cosim record") -> None:
        self.path = path
        self.file, self.bag_dir = layout(path)
        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "none": CompressionType.NONE}.get(compression)
        if comp is None:
            raise RecordError(f"unknown compression {compression!r} (zstd, lz4, none)")
        if self.bag_dir is not None and os.path.exists(self.bag_dir):
            raise RecordError(f"{self.bag_dir}: exists already, not overwriting")
        if self.bag_dir is None and os.path.exists(self.file):
            raise RecordError(f"{self.file}: exists already, not overwriting")
        try:
            if self.bag_dir is not None:
                os.makedirs(self.bag_dir)
            else:
                os.makedirs(os.path.dirname(os.path.abspath(self.file)), exist_ok=True)
            self.stream = open(self.file, "xb")
        except OSError as exc:
            raise RecordError(f"{self.file}: cannot create: {exc.strerror or exc}") from None
        self.writer = Writer(self.stream, chunk_size=chunk_size, compression=comp)
        self.writer.start(profile=PROFILE, library=library)
        self.stream.flush()
        self.flush_s = flush_s
        self.schemas: dict[str, int] = {}
        self.channels: dict[str, tuple[int, str]] = {}     # key -> (channel id, msgtype)
        self.counts: dict[str, int] = {}
        self.first_ns: int | None = None
        self.last_ns = 0
        self._dirty = False
        self._last_flush = time.monotonic()
        self.closed = False

    def _schema(self, msgtype: str) -> int:
        sid = self.schemas.get(msgtype)
        if sid is None:
            msgdef, _ = codec.TYPESTORE.generate_msgdef(msgtype, ros_version=2)
            sid = self.schemas[msgtype] = self.writer.register_schema(
                msgtype, SCHEMA_ENCODING, msgdef.encode())
        return sid

    def channel(self, key: str, msgtype: str) -> int:
        ch = self.channels.get(key)
        if ch is None:
            cid = self.writer.register_channel(
                "/" + key, MESSAGE_ENCODING, self._schema(msgtype),
                {"offered_qos_profiles": QOS_NONE,
                 "topic_type_hash": codec.TYPESTORE.hash_rihs01(msgtype)})
            ch = self.channels[key] = (cid, msgtype)
            self.counts[key] = 0
        return ch[0]

    def write(self, key: str, msgtype: str, data: bytes, log_time: int, publish_time: int,
              sequence: int = 0) -> None:
        self.writer.add_message(self.channel(key, msgtype), log_time=log_time, data=data,
                                publish_time=publish_time, sequence=sequence & 0xFFFFFFFF)
        self.counts[key] += 1
        if self.first_ns is None:
            self.first_ns = log_time
        self.first_ns = min(self.first_ns, log_time)
        self.last_ns = max(self.last_ns, log_time)
        self._dirty = True

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        self.writer.add_metadata(name, data)
        self.stream.flush()

    def maybe_flush(self, now: float | None = None) -> None:
        """Close the chunk in progress and hand it to the OS if ``flush_s`` has passed."""
        now = time.monotonic() if now is None else now
        if self._dirty and now - self._last_flush >= self.flush_s:
            self.flush()

    def flush(self) -> None:
        self.writer.flush()
        self._dirty = False
        self._last_flush = time.monotonic()

    def rosbag2_metadata(self) -> dict:
        """rosbag2 ``metadata.yaml`` content (version 9) for what was written."""
        n = sum(self.counts.values())
        start = self.first_ns if (n and self.first_ns is not None) else 0
        duration = self.last_ns - start if n else 0
        return {"rosbag2_bagfile_information": {
            "version": ROSBAG2_VERSION,
            "storage_identifier": "mcap",
            "relative_file_paths": [os.path.basename(self.file)],
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": n,
            "topics_with_message_count": [
                {"topic_metadata": {"name": "/" + key, "type": msgtype,
                                    "serialization_format": MESSAGE_ENCODING,
                                    "offered_qos_profiles": [],
                                    "type_description_hash": codec.TYPESTORE.hash_rihs01(msgtype)},
                 "message_count": self.counts[key]}
                for key, (_, msgtype) in self.channels.items()],
            "compression_format": "",
            "compression_mode": "",
            "files": [{"path": os.path.basename(self.file),
                       "starting_time": {"nanoseconds_since_epoch": start},
                       "duration": {"nanoseconds": duration}, "message_count": n}],
            "custom_data": None,
            "ros_distro": "jazzy",
        }}

    def close(self) -> None:
        """Write the summary, index and footer (and the bag's metadata.yaml)."""
        if self.closed:
            return
        self.closed = True
        meta = self.rosbag2_metadata()
        self.writer.add_metadata("rosbag2", {
            "serialized_metadata": _yaml(meta["rosbag2_bagfile_information"])})
        self.writer.finish()
        self.stream.flush()
        os.fsync(self.stream.fileno())
        self.stream.close()
        if self.bag_dir is not None:
            _write_text_atomic(os.path.join(self.bag_dir, "metadata.yaml"), _yaml(meta))

    def discard(self) -> None:
        """Remove a recording that never started (nothing to keep)."""
        self.closed = True
        self.stream.close()
        try:
            os.remove(self.file)
        except OSError:
            pass
        if self.bag_dir is not None:
            try:
                os.rmdir(self.bag_dir)
            except OSError:
                pass

    @property
    def size_bytes(self) -> int:
        try:
            return os.path.getsize(self.file)
        except OSError:
            return 0


def _yaml(data: dict) -> str:
    from ruamel.yaml import YAML
    y = YAML(typ="safe")
    y.default_flow_style = False
    s = io.StringIO()
    y.dump(data, s)
    return s.getvalue()


def _write_text_atomic(path: str, text: str) -> None:
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "w") as f:
        f.write(text)
    os.replace(tmp, path)


# ====================================================================== reading
@dataclass
class Recorded:
    """What :func:`read_recording` found: channels by id and the metadata records."""
    file: str
    channels: dict[int, Channel] = field(default_factory=dict)
    schemas: dict[int, Schema] = field(default_factory=dict)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    attachments: list[Attachment] = field(default_factory=list)
    complete: bool = False       # the footer was reached
    error: str = ""              # why reading stopped early (truncated file)

    def sim_info(self) -> dict | None:
        raw = self.metadata.get(INFO_METADATA, {}).get("sim_info")
        try:
            return json.loads(raw) if raw else None
        except ValueError:
            return None

    def key_of(self, channel_id: int) -> str:
        return self.channels[channel_id].topic.lstrip("/")


def iter_recording(path: str, rec: Recorded | None = None):
    """Yield every :class:`mcap.records.Message` of a recording in file (arrival) order.

    Tolerates a file that was never closed (SIGKILL): reading stops at the first
    incomplete record, with ``rec.complete`` False and ``rec.error`` saying why.
    Channels, schemas and metadata records fill ``rec`` as they are met.
    """
    file, _ = layout(path)
    rec = rec if rec is not None else Recorded(file)
    try:
        f = open(file, "rb")
    except OSError as exc:
        raise RecordError(f"{file}: cannot open: {exc.strerror or exc}") from None
    with f:
        reader = StreamReader(f, record_size_limit=1 << 31)
        try:
            for r in reader.records:
                if isinstance(r, Message):
                    if r.channel_id in rec.channels:
                        yield r
                elif isinstance(r, Channel):
                    rec.channels[r.id] = r
                elif isinstance(r, Schema):
                    rec.schemas[r.id] = r
                elif isinstance(r, Metadata):
                    rec.metadata[r.name] = dict(r.metadata)
                elif isinstance(r, Attachment):
                    rec.attachments.append(r)
            rec.complete = True
        except GeneratorExit:
            raise
        except Exception as exc:  # truncated record, partial chunk, bad magic...
            if not rec.channels and not rec.metadata:
                raise RecordError(f"{file}: not a readable MCAP file "
                                  f"({type(exc).__name__}: {exc})") from None
            rec.error = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__


def recover(path: str, log: logging.Logger | None = None) -> dict[str, int]:
    """Rewrite a recording that was never closed (SIGKILL) into a complete one, in place.

    Keeps every message that was flushed before the kill; returns counts per key.
    A complete file is rewritten unchanged in content.
    """
    file, bag_dir = layout(path)
    rec = Recorded(file)
    tmp_dir = f"{file}.recover{os.getpid()}"
    out = McapRecording(os.path.join(tmp_dir, "r.mcap"), library="diffbot-cosim record --recover")
    try:
        for m in iter_recording(file, rec):
            ch = rec.channels[m.channel_id]
            schema = rec.schemas.get(ch.schema_id)
            msgtype = schema.name if schema is not None else ""
            if msgtype not in codec.TYPESTORE.types:
                continue
            out.write(ch.topic.lstrip("/"), msgtype, m.data, m.log_time, m.publish_time,
                      m.sequence)
        for name, data in rec.metadata.items():
            if name != "rosbag2":
                out.add_metadata(name, data)
        for a in rec.attachments:
            out.writer.add_attachment(a.create_time, a.log_time, a.name, a.media_type, a.data)
        out.close()
        os.replace(out.file, file)
    finally:
        try:
            os.rmdir(tmp_dir)
        except OSError:
            pass
    if bag_dir is not None:
        meta = out.rosbag2_metadata()
        meta["rosbag2_bagfile_information"]["relative_file_paths"] = [os.path.basename(file)]
        meta["rosbag2_bagfile_information"]["files"][0]["path"] = os.path.basename(file)
        _write_text_atomic(os.path.join(bag_dir, "metadata.yaml"), _yaml(meta))
    if log is not None:
        log.info("%s: %s; %d messages kept%s", file,
                 "was complete" if rec.complete else "recovered",
                 sum(out.counts.values()), f" (stopped at: {rec.error})" if rec.error else "")
    return dict(out.counts)


# ====================================================================== bus side
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
        self.wall_start = time.monotonic()
        self.wall_end = 0.0

    def subscribe(self) -> None:
        q = self.queue

        def cb(sample: zenoh.Sample) -> None:
            att = sample.attachment
            q.put((str(sample.key_expr), sample.payload.to_bytes(),
                   att.to_bytes() if att is not None else None, time.time_ns()))

        for expr in _distinct([*self.exprs, self.keys.end]):
            # Direct callbacks (Zenoh's receive thread) keep the arrival order across keys.
            self._subs.append(self.session.declare_subscriber(
                expr, zenoh.handlers.Callback(cb, indirect=False)))

    def fetch_info(self, timeout_s: float) -> None:
        """The plant's ``sim/info``, stored as MCAP metadata (once)."""
        if self.info is not None:
            return
        from .session import query_info
        try:
            self.info = query_info(self.session, self.keys, timeout_s)
        except (TimeoutError, ValueError) as exc:
            self.log.warning("no sim/info (%s); recording without it", exc)
            return
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
        self._token = self.session.liveliness().declare_token(self.keys.alive(self.name))

    def handle(self, item) -> None:
        key, payload, att, recv_ns = item
        if key == self.keys.end:
            if self.end_reason is None:
                self.end_reason = payload.decode("utf-8", "replace") or "sim/end"
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
        for s in self._subs:
            try:
                s.undeclare()
            except Exception:
                pass
        self._subs.clear()
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
                   help="keep recording after sim/end (until Ctrl-C)")
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
    p.add_argument("--stats", metavar="FILE", help="write counters as JSON at exit")
    p.add_argument("--log-level", default="INFO")
    add_bus_args(p)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    log = setup_logging(args.name if not args.recover else "recover", args.log_level)
    if args.recover:
        try:
            counts = recover(args.path, log)
        except (RecordError, OSError) as exc:
            log.error("%s", exc)
            return EXIT_BAD_INPUT
        report(counts)
        return EXIT_OK
    if args.flush <= 0 or args.chunk_size <= 0:
        log.error("--flush and --chunk-size must be > 0")
        return EXIT_BAD_INPUT
    try:
        keys = Keys(args.namespace)
        prefix = f"{keys.namespace}/" if keys.namespace else ""
        exprs = [prefix + k.strip("/") for k in args.keys] or [keys.all]
        for e in exprs:
            zenoh.KeyExpr(e)
    except Exception as exc:
        log.error("bad key: %s", exc)
        return EXIT_BAD_INPUT
    try:
        out = McapRecording(args.path, chunk_size=args.chunk_size, compression=args.compression,
                            flush_s=args.flush)
    except RecordError as exc:
        log.error("%s", exc)
        return EXIT_BAD_INPUT
    try:
        session = open_session("node", args.endpoint, args.zenoh_config)
    except BusConfigError as exc:
        log.error("%s", exc)
        out.discard()
        return EXIT_BAD_INPUT
    from .jsonio import write_json
    from .session import install_stop_signals
    rec = Recorder(session, keys, out, exprs, log, args.name)
    rec.with_scene = args.scene
    install_stop_signals(rec.stop_event)
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
        session.close()
        st = rec.stats()
        if args.stats:
            write_json(args.stats, st)
        log.info("wrote %s: %d messages, %.1f MB, %d skipped, %d rejected", out.file,
                 st["messages"], st["bytes"] / 1e6, sum(rec.skipped.values()),
                 rec.rejects.total)
        report(out.counts)
    return code


if __name__ == "__main__":
    sys.exit(main())
