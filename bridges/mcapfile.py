"""The MCAP file of a recording, without the bus: :class:`McapRecording` writes one (rosbag2
layout, schemas, channels, crash-safe flushing), :func:`iter_recording` reads one, even a
file never closed, and :func:`recover` completes such a file. The format and its choices
are described in :mod:`bridges.record`, the ``diffbot record`` command that uses them.
"""
from __future__ import annotations

import io
import json
import logging
import os
import time
from dataclasses import dataclass, field

from mcap.records import Attachment, Channel, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from bus import codec

PROFILE = "ros2"
MESSAGE_ENCODING = "cdr"
SCHEMA_ENCODING = "ros2msg"
#: Name of the MCAP metadata record with the plant's ``sim/info`` and the recorder settings.
INFO_METADATA = "diffbot"
ROSBAG2_VERSION = 9
#: Channel metadata ``offered_qos_profiles``, YAML as rosbag2 writes it: none offered, so
#: ROS 2 tools use their defaults.
QOS_NONE = "[]"

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
