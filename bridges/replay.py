"""Play a recording back onto the bus: ``diffbot replay FILE.mcap [--rate R | --fast]``.

The replayer stands in for the plant: it listens on the endpoint (nodes connect to
it as they would to the plant), declares ``sim/alive/plant``, answers ``sim/info``
and ends with ``sim/end``, so an unchanged ``diffbot controller ...`` runs against
recorded sensors. Each message goes out on its recorded key with the recorded CDR
bytes, encoding ``application/cdr`` and the attachment (sequence, sim-time stamp)
rebuilt from the MCAP message (``sequence``, ``log_time``).

* **order and timing** — messages go out in file order, which is the order the
  recorder received them (the plant's sensors of a tick, then ``sim/clock``, then the
  nodes' outputs), spaced by their sim-time stamps divided by ``--rate`` (default 1),
  or back to back with ``--fast``.
* **sim/info** — the plant's ``sim/info`` stored in the recording, with ``mode`` set to
  ``realtime`` (``--rate``) or ``fast`` so nodes do not wait for lockstep; a recording
  without it gets one made up from its topics (robots, control tick).
* **what is replayed** — every recorded key, or only ``--keys``, minus ``--exclude``
  (key expressions such as ``robot1/odom`` or ``'robot1/camera/**'``): exclude the
  topics the nodes under test will publish themselves.
* **start** — ``--expect NODES`` waits for those nodes' ``sim/alive/<node>`` tokens
  (a node API node declares its token once subscribed), so nothing is missed.
  After the last message the replayer publishes ``sim/end`` and stays up until the
  expected nodes have left (at most ``--linger`` s), so their last outputs still
  reach other subscribers through it.

A recording left unclosed by a SIGKILL replays up to its last flushed chunk.
"""
from __future__ import annotations

import argparse
import logging
import math
import sys
import threading
import time

import zenoh

from bus import codec, jsonio
from bus.cliargs import ArgumentParser, nonneg_float, positive_float
from bus.keys import Keys
from bus.process import EXIT_BAD_CONFIG as EXIT_BAD_INPUT, EXIT_FAILED, EXIT_OK, Exit, Process
from bus.process import process_main
from bus.session import add_process_args

from .mcapfile import Recorded, RecordError, iter_recording, layout

PROGRESS_EVERY_S = 5.0


def scan(path: str) -> tuple[Recorded, dict]:
    """Channels, metadata and a few facts of a recording without replaying it:
    ``{"first_ns", "last_ns", "count", "clock_dt_ns", "counts": {key: n}}``.

    Uses the summary of a complete file; reads a truncated one through.
    """
    file, _ = layout(path)
    try:
        from mcap.reader import make_reader
        with open(file, "rb") as f:
            r = make_reader(f)
            summary = r.get_summary()
            if summary is None or summary.statistics is None:
                raise ValueError("no summary")
            rec = Recorded(file, channels=dict(summary.channels), schemas=dict(summary.schemas),
                           complete=True)
            for m in r.iter_metadata():
                rec.metadata[m.name] = dict(m.metadata)
            st = summary.statistics
            counts = {rec.key_of(cid): n for cid, n in st.channel_message_counts.items()
                      if cid in rec.channels}
            clock_dt = None
            clocks = [c for c in rec.channels.values() if c.topic.endswith("/sim/clock")
                      or c.topic == "/sim/clock"]
            if clocks:
                ts = []
                for _, _, m in r.iter_messages(topics=[clocks[0].topic]):
                    ts.append(m.log_time)
                    if len(ts) == 2:
                        break
                clock_dt = ts[1] - ts[0] if len(ts) == 2 else None
            return rec, {"first_ns": st.message_start_time, "last_ns": st.message_end_time,
                         "count": st.message_count, "clock_dt_ns": clock_dt, "counts": counts}
    except RecordError:
        raise
    except Exception:
        pass
    rec = Recorded(file)
    first = last = None
    counts: dict[str, int] = {}
    clock_ts: list[int] = []
    for m in iter_recording(path, rec):
        key = rec.key_of(m.channel_id)
        counts[key] = counts.get(key, 0) + 1
        first = m.log_time if first is None else min(first, m.log_time)
        last = m.log_time if last is None else max(last, m.log_time)
        if key.endswith("sim/clock") and len(clock_ts) < 2:
            clock_ts.append(m.log_time)
    return rec, {"first_ns": first or 0, "last_ns": last or 0, "count": sum(counts.values()),
                 "clock_dt_ns": clock_ts[1] - clock_ts[0] if len(clock_ts) == 2 else None,
                 "counts": counts}


def replay_info(rec: Recorded, facts: dict, keys: Keys, mode: str, rate: float) -> dict:
    """The ``sim/info`` to serve: the recorded one, or one made up from the topics."""
    info = rec.sim_info()
    recorded_mode = None
    if info is None:
        robots: dict[str, dict] = {}
        for key in facts["counts"]:
            rt = keys.robot_topic_of(key)
            if rt is not None:
                robots.setdefault(rt[0], {"topics": {}})
        dt = facts.get("clock_dt_ns")
        info = {"robots": robots, "control_tick_s": dt * 1e-9 if dt else 0.02,
                "seed": None, "synthesized": True}
    else:
        recorded_mode = info.get("mode")
    info = dict(info)
    info.update(mode=mode, rate=rate, namespace=keys.namespace,
                replay={"file": rec.file, "recorded_mode": recorded_mode,
                        "first_ns": facts["first_ns"], "last_ns": facts["last_ns"]})
    return info


class Replayer:
    def __init__(self, session: zenoh.Session, keys: Keys, path: str, log: logging.Logger,
                 rate: float | None, include: list[str], exclude: list[str],
                 remap: tuple[str, str] = ("", ""),
                 scanned: tuple[Recorded, dict] | None = None) -> None:
        self.session = session
        self.keys = keys
        self.path = path
        self.log = log
        self.rate = rate                      # None: as fast as possible
        self.include = [zenoh.KeyExpr(k) for k in include]
        self.exclude = [zenoh.KeyExpr(k) for k in exclude]
        self.remap = remap
        self.stop_event = threading.Event()
        self.rec, self.facts = scanned if scanned is not None else scan(path)
        self.info = replay_info(self.rec, self.facts, keys,
                                "fast" if rate is None else "realtime", rate or 0.0)
        self.published: dict[str, int] = {}
        self.sim_ns = self.facts["first_ns"]
        self._pubs: dict[str, zenoh.Publisher] = {}
        self._wanted: dict[str, str | None] = {}     # recorded key -> bus key or None
        self.alive: set[str] = set()
        self._alive_cv = threading.Condition()
        self._queryable = session.declare_queryable(keys.info, self._on_info)
        self._alive_sub = session.liveliness().declare_subscriber(
            keys.alive(), self._on_alive, history=True)
        self._token = session.liveliness().declare_token(keys.alive("plant"))
        self.wall_start = 0.0
        self.wall_end = 0.0
        self.end_reason = "replay finished"

    # ------------------------------------------------------------------ bus side
    def _on_info(self, query: zenoh.Query) -> None:
        d = dict(self.info)
        d["time_ns"] = self.sim_ns
        query.reply(self.keys.info, jsonio.dumps(d))

    def _on_alive(self, sample: zenoh.Sample) -> None:
        node = self.keys.node_of(str(sample.key_expr))
        with self._alive_cv:
            (self.alive.add if sample.kind == zenoh.SampleKind.PUT else self.alive.discard)(node)
            self._alive_cv.notify_all()

    def wait_for(self, want: set[str], present: bool, timeout_s: float) -> bool:
        """Wait until every node in ``want`` is alive (``present``) or gone (not ``present``)."""
        deadline = time.monotonic() + timeout_s
        with self._alive_cv:
            while not self.stop_event.is_set():
                ok = want <= self.alive if present else not (want & self.alive)
                if ok:
                    return True
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._alive_cv.wait(min(left, 0.1))
        return False

    def bus_key(self, key: str) -> str | None:
        """The key to publish a recorded key on, or None if it is not replayed."""
        if key in self._wanted:
            return self._wanted[key]
        ke = zenoh.KeyExpr(key)
        ok = ((not self.include or any(k.intersects(ke) for k in self.include))
              and not any(k.intersects(ke) for k in self.exclude))
        out = None
        if ok:
            old, new = self.remap
            out = new + key[len(old):] if old != new and key.startswith(old) else key
        self._wanted[key] = out
        return out

    def _publisher(self, key: str) -> zenoh.Publisher:
        pub = self._pubs.get(key)
        if pub is None:
            pub = self._pubs[key] = self.session.declare_publisher(
                key, encoding=zenoh.Encoding.APPLICATION_CDR,
                congestion_control=zenoh.CongestionControl.BLOCK)
        return pub

    # ------------------------------------------------------------------ loop
    def run(self) -> int:
        t0 = self.facts["first_ns"]
        self.wall_start = w0 = time.monotonic()
        last_progress = w0
        total_s = (self.facts["last_ns"] - t0) * 1e-9
        self.log.info("replaying %d messages, %.2f s of sim time, %s", self.facts["count"],
                      total_s, "as fast as possible" if self.rate is None
                      else f"at {self.rate:g}x real time")
        for m in iter_recording(self.path, self.rec):
            if self.stop_event.is_set():
                self.end_reason = "replay stopped"
                break
            key = self.bus_key(self.rec.key_of(m.channel_id))
            if key is None:
                continue
            if self.rate is not None:
                due = w0 + (m.log_time - t0) * 1e-9 / self.rate
                while (left := due - time.monotonic()) > 0 and not self.stop_event.is_set():
                    time.sleep(min(left, 0.05))
                if self.stop_event.is_set():
                    self.end_reason = "replay stopped"
                    break
            self.sim_ns = m.log_time
            self._publisher(key).put(m.data, attachment=codec.attachment(m.sequence, m.log_time))
            self.published[key] = self.published.get(key, 0) + 1
            now = time.monotonic()
            if now - last_progress >= PROGRESS_EVERY_S:
                last_progress = now
                self.log.info("t=%.2f s of %.2f s", (m.log_time - t0) * 1e-9, total_s)
        if not self.rec.complete and self.rec.error:
            self.log.warning("the recording ends early (never closed? %s); replayed what "
                             "it has", self.rec.error)
        self.wall_end = time.monotonic()
        return EXIT_OK

    def close(self, expect: set[str], linger_s: float) -> None:
        """``sim/end``; stay up until the expected nodes left (their last outputs pass
        through us); then leave."""
        try:
            self.session.put(self.keys.end, self.end_reason.encode())
        except Exception:
            pass
        if expect and linger_s > 0:
            if self.stop_event.is_set():          # interrupted: do not keep the user waiting
                linger_s = min(linger_s, 1.0)
            self.stop_event.clear()
            if not self.wait_for(expect, present=False, timeout_s=linger_s):
                self.log.warning("still alive %.0f s after sim/end: %s", linger_s,
                                 ", ".join(sorted(expect & self.alive)))
            time.sleep(0.2)      # let their last samples leave our queues
        self._token.undeclare()
        self._alive_sub.undeclare()
        self._queryable.undeclare()
        for p in self._pubs.values():
            p.undeclare()

    def stats(self) -> dict:
        wall = self.wall_end - self.wall_start if self.wall_end else 0.0
        sim = (self.sim_ns - self.facts["first_ns"]) * 1e-9
        return {"node": "replay", "file": self.rec.file, "published": self.published,
                "messages": sum(self.published.values()), "sim_time_s": sim,
                "wall_time_s": wall, "real_time_factor": sim / wall if wall > 0 else None,
                "complete_file": self.rec.complete, "end_reason": self.end_reason}


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(
        prog="diffbot replay",
        description="Publish a recording back onto the bus, standing in for the plant "
                    "(sim/info, sim/alive/plant, sim/end): controllers run against it unchanged.")
    p.add_argument("path", metavar="FILE.mcap", help="recording (file or rosbag2 bag directory)")
    speed = p.add_mutually_exclusive_group()
    speed.add_argument("--rate", type=positive_float, default=1.0, metavar="R",
                       help="sim seconds per wall second (default 1: recorded spacing)")
    speed.add_argument("--fast", action="store_true", help="as fast as possible")
    p.add_argument("--keys", nargs="+", default=[], metavar="KEY",
                   help="replay only these keys / key expressions (as recorded, no leading /)")
    p.add_argument("--exclude", nargs="+", default=[], metavar="KEY",
                   help="do not replay these, e.g. the outputs of the node under test")
    p.add_argument("--expect", default="", metavar="NODES",
                   help="comma-separated nodes (sim/alive/<node>) to wait for before starting")
    p.add_argument("--join-timeout", type=positive_float, default=30.0, metavar="S")
    p.add_argument("--linger", type=nonneg_float, default=10.0, metavar="S",
                   help="after sim/end, wait up to S s for the expected nodes to leave")
    add_process_args(p)
    return p


def main(argv: list[str] | None = None) -> int:
    return process_main(_run, build_parser(), argv, "replay")


def _run(proc: Process) -> int:
    args, log = proc.args, proc.log
    if not args.fast and not (args.rate > 0 and math.isfinite(args.rate)):
        raise Exit(EXIT_BAD_INPUT, f"--rate must be > 0, got {args.rate}")
    try:
        keys = proc.keys
        expect = {n for n in args.expect.split(",") if n}
        for e in [*args.keys, *args.exclude]:
            zenoh.KeyExpr(e.strip("/"))
    except Exception as exc:
        raise Exit(EXIT_BAD_INPUT, exc) from None
    try:
        scanned = scan(args.path)
    except (RecordError, OSError) as exc:
        raise Exit(EXIT_BAD_INPUT, exc) from None
    rec0 = scanned[0]
    old_ns = (rec0.sim_info() or {}).get("namespace", "") or ""
    remap = (f"{old_ns}/" if old_ns else "", f"{keys.namespace}/" if keys.namespace else "")
    session = proc.open("plant")
    rp = None
    code = EXIT_OK
    try:
        rp = Replayer(session, keys, args.path, log, None if args.fast else args.rate,
                      [k.strip("/") for k in args.keys], [k.strip("/") for k in args.exclude],
                      remap, scanned)
        proc.stats = rp.stats
        proc.stop_on_signals(rp.stop_event)
        if expect:
            log.info("waiting for nodes: %s", ", ".join(sorted(expect)))
            if not rp.wait_for(expect, present=True, timeout_s=args.join_timeout):
                if not rp.stop_event.is_set():
                    log.error("nodes did not join within %.0f s: %s", args.join_timeout,
                              ", ".join(sorted(expect - rp.alive)))
                    code = EXIT_FAILED
                rp.end_reason = "replay stopped"
        if code == EXIT_OK and not rp.stop_event.is_set():
            code = rp.run()
        st = rp.stats()
        log.info("%s: %d messages, %.2f s sim in %.2f s wall", rp.end_reason, st["messages"],
                 st["sim_time_s"], st["wall_time_s"])
    except (RecordError, OSError) as exc:
        log.error("%s", exc)
        code = EXIT_BAD_INPUT
    finally:
        if rp is not None:
            rp.close(expect, args.linger)
    return code


if __name__ == "__main__":
    sys.exit(main())
