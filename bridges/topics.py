"""Look at a live bus: ``diffbot topics`` (keys, types, rates) and ``diffbot echo KEY``.

Like ``ros2 topic list -t`` + ``ros2 topic hz`` and ``ros2 topic echo``. Both only
listen (a client session, no liveliness token), so they never hold up lockstep.
Rates are measured twice: per wall-clock second (what the bus carries now) and per
simulated second (from the attachments' stamps: the sensor's configured rate,
whatever the real-time factor).
"""
from __future__ import annotations

import json
import math
import queue
import sys
import threading
import time

import zenoh

from bus import codec, jsonio
from bus.cliargs import ArgumentParser, nonneg_float, positive_float, positive_int
from bus.keys import Keys, is_fmu_topic
from bus.session import BusConfigError, add_bus_args, open_session

EXIT_OK = 0
EXIT_NOTHING = 1
EXIT_BAD_INPUT = 2
#: echo gives up when nothing came for this long (wall s), saying what the plant publishes
ECHO_TIMEOUT_S = 10.0


# ---------------------------------------------------------------- topics
class RateMeter:
    """Counts samples per key with their wall arrival times and sim stamps."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.seen: dict[str, list] = {}   # key -> [n, first wall, last wall, first sim, last sim]

    def __call__(self, sample: zenoh.Sample) -> None:
        now = time.monotonic()
        att = sample.attachment
        a = codec.parse_attachment(att.to_bytes() if att is not None else None)
        t = a[1] if a else None
        key = str(sample.key_expr)
        with self.lock:
            s = self.seen.get(key)
            if s is None:
                self.seen[key] = [1, now, now, t, t]
            else:
                s[0] += 1
                s[2] = now
                if t is not None:
                    s[3] = t if s[3] is None else min(s[3], t)
                    s[4] = t if s[4] is None else max(s[4], t)

    def table(self, keys: Keys, types: dict[str, str] | None = None) -> list[dict]:
        rows = []
        with self.lock:
            items = sorted(self.seen.items())
        for key, (n, w0, w1, s0, s1) in items:
            hz = (n - 1) / (w1 - w0) if n > 1 and w1 > w0 else None
            sim_hz = ((n - 1) / ((s1 - s0) * 1e-9)
                      if n > 1 and s0 is not None and s1 is not None and s1 > s0 else None)
            kind = _msgtype(keys, key) or (types or {}).get(key) or "-"
            rows.append({"key": key, "type": kind, "count": n,
                         "hz": hz, "sim_hz": sim_hz})
        return rows


def _msgtype(keys: Keys, key: str) -> str | None:
    """The message type on ``key``. Without --namespace the listing covers every key, so a
    namespaced run's ``<ns>/robot1/odom`` is typed too (a namespace is one segment)."""
    kind = keys.msgtype_of(key)
    if kind is None and not keys.namespace and "/" in key:
        try:
            kind = Keys(key.split("/", 1)[0]).msgtype_of(key)
        except ValueError:             # not a name a namespace could have
            pass
    return kind


def alive_nodes(session: zenoh.Session, keys: Keys, timeout_s: float = 1.0) -> list[str]:
    """Names behind the ``sim/alive/<node>`` liveliness tokens."""
    names = []
    for reply in session.liveliness().get(keys.alive(), timeout=timeout_s):
        if reply.ok is not None:
            names.append(keys.node_of(str(reply.ok.key_expr)))
    return sorted(set(names))


def fmu_nodes(session: zenoh.Session, keys: Keys, timeout_s: float = 1.0) -> list[dict]:
    """What the FMU nodes answer on ``fmu/<instance>/info`` (docs/fmu.md)."""
    out = []
    for reply in session.get(keys.fmu_info("*"), target=zenoh.QueryTarget.ALL,
                             consolidation=zenoh.ConsolidationMode.NONE,
                             timeout=timeout_s):
        if reply.ok is not None:
            try:
                out.append(json.loads(reply.ok.payload.to_bytes()))
            except ValueError:
                continue
    return sorted(out, key=lambda i: str(i.get("instance")))


def _fmu_types(infos: list[dict]) -> dict[str, str]:
    """key -> message type of every FMU node's variables."""
    return {v["key"]: v["type"] for i in infos for v in i.get("variables", ())
            if isinstance(v, dict) and v.get("key") and v.get("type")}


class FmuTypes:
    """The message types of fmu/ keys, asked from the FMU nodes' info when a key is first
    seen (at most once per second while a key stays unknown)."""

    def __init__(self, session: zenoh.Session, keys: Keys) -> None:
        self.session, self.keys = session, keys
        self.types: dict[str, str] = {}
        self._asked = -math.inf

    def __call__(self, key: str) -> str | None:
        kind = self.types.get(key)
        if kind is None and is_fmu_topic(key[len(self.keys.namespace) + 1:]
                                         if self.keys.namespace else key) \
                and time.monotonic() - self._asked > 1.0:
            self._asked = time.monotonic()
            self.types.update(_fmu_types(fmu_nodes(self.session, self.keys, 0.5)))
            kind = self.types.get(key)
        return kind


def _fmt_hz(v) -> str:
    return f"{v:9.1f}" if v is not None else f"{'-':>9s}"


def topics_main(argv: list[str] | None = None) -> int:
    p = ArgumentParser(prog="diffbot topics",
                                description="List the live keys with message type and rate.")
    p.add_argument("--duration", type=positive_float, default=2.0, metavar="S",
                   help="listen this many wall seconds (default 2)")
    p.add_argument("--json", action="store_true", help="print the table as JSON")
    add_bus_args(p)
    args = p.parse_args(argv)
    if not args.duration > 0:
        print("diffbot topics: --duration must be > 0", file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        keys = Keys(args.namespace)
        session = open_session("observer", args.endpoint, args.zenoh_config)
    except (BusConfigError, ValueError) as exc:
        print(f"diffbot topics: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    meter = RateMeter()
    try:
        sub = session.declare_subscriber(keys.all, zenoh.handlers.Callback(meter, indirect=False))
        try:
            time.sleep(args.duration)
        except KeyboardInterrupt:
            pass
        sub.undeclare()
        nodes = alive_nodes(session, keys)
        fmus = fmu_nodes(session, keys)
    finally:
        session.close()
    rows = meter.table(keys, _fmu_types(fmus))
    if args.json:
        print(jsonio.dumps({"topics": rows, "nodes": nodes, "fmus": fmus}, indent=2))
        return EXIT_OK
    if not rows:
        print(f"no messages in {args.duration:g} s on {args.endpoint or args.zenoh_config} "
              "(is a plant running? same --endpoint / --namespace?)", file=sys.stderr)
    w = max([len(r["key"]) for r in rows] + [3])
    tw = max([len(r["type"]) for r in rows] + [4])
    if rows:
        print(f"{'key':{w}s}  {'type':{tw}s}  {'Hz(wall)':>9s}  {'Hz(sim)':>9s}  {'count':>7s}")
    for r in rows:
        print(f"{r['key']:{w}s}  {r['type']:{tw}s}  {_fmt_hz(r['hz'])}  "
              f"{_fmt_hz(r['sim_hz'])}  {r['count']:7d}")
    print(f"nodes alive: {', '.join(nodes) or 'none'}")
    for i in fmus:
        step = f"own step {i['step_size_s']:g} s" if i.get("step_size_s") else "step per tick"
        print(f"FMU {i.get('instance')} ({i.get('fmu')}, FMI {i.get('fmi_version')}, {step}, "
              f"start at {i.get('start')}): fmu/{i.get('instance')}/info")
    return EXIT_OK if rows else EXIT_NOTHING


# ---------------------------------------------------------------- echo
def _scalar(v) -> str:
    if isinstance(v, str):
        return json.dumps(v) if (not v or v.strip() != v or ":" in v) else v
    if isinstance(v, float):
        return repr(v)
    if hasattr(v, "item"):          # numpy scalar
        return repr(v.item())
    return str(v)


def _flow(v) -> str:
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k}: {_flow(x)}" for k, x in v.items()) + "}"
    if isinstance(v, list):
        return "[" + ", ".join(_flow(x) for x in v) + "]"
    return _scalar(v)


def _flat(v) -> bool:
    if isinstance(v, dict):
        return all(not isinstance(x, (dict, list)) or _flat(x) for x in v.values())
    if isinstance(v, list):
        return all(not isinstance(x, (dict, list)) for x in v)
    return True


def to_text(obj, indent: int = 0, width: int = 88) -> list[str]:
    """YAML-like lines of a :func:`codec.summarize` dict (short parts on one line)."""
    pad = "  " * indent
    lines = []
    for k, v in obj.items():
        one = f"{pad}{k}: {_flow(v)}"
        if not isinstance(v, (dict, list)) or (_flat(v) and len(one) <= width):
            lines.append(one)
        elif isinstance(v, dict):
            lines.append(f"{pad}{k}:")
            lines += to_text(v, indent + 1, width)
        else:
            lines.append(f"{pad}{k}:")
            for x in v:
                if isinstance(x, dict):
                    sub = to_text(x, indent + 2, width)
                    lines.append(f"{pad}  - {sub[0].lstrip()}" if sub else f"{pad}  - {{}}")
                    lines += sub[1:]
                else:
                    lines.append(f"{pad}  - {_flow(x)}")
    return lines


def format_message(key: str, payload: bytes, attachment: bytes | None, keys: Keys,
                   types: dict[str, str] | None = None) -> str:
    """The message on ``key``, decoded (``types``: the types of FMU nodes' fmu/ keys)."""
    a = codec.parse_attachment(attachment)
    head = f"--- /{key}"
    if a is not None:
        head += f"  seq {a.seq}  t {a.t_ns * 1e-9:.6f} s"
        if a.epoch is not None:         # the plant's: its world's epoch (resets)
            head += f"  epoch {a.epoch}"
        if a.node is not None:          # a lockstep member's trailer (docs/PROTOCOL.md)
            flags = [f for f, bit in (("ACK", codec.ACK), ("FINAL", codec.FINAL))
                     if a.flags & bit]
            head += (f"  member {a.node}  flags {'|'.join(flags) or '-'}"
                     + (f"  n_plant {a.n_plant}" if a.flags & codec.ACK else "")
                     + (f"  hold {h}" if (h := codec.hold_of(a.flags)) else ""))
    elif attachment:
        head += f"  (malformed attachment of {len(attachment)} bytes: {attachment[:24].hex()})"
    msgtype = keys.msgtype_of(key) or (types or {}).get(key)
    if msgtype is None and not payload:
        return f"{head}\n(empty payload)"
    if msgtype is None:
        try:
            body = "data: " + _scalar(payload.decode("utf-8"))
        except UnicodeDecodeError:
            body = f"data: <{len(payload)} bytes> {payload[:32].hex()}"
        return f"{head}\n{body}"
    try:
        msg = codec.decode(payload, msgtype)
    except codec.CodecError as exc:
        return f"{head}  ({msgtype})\n# {exc}"
    return "\n".join([f"{head}  ({msgtype})", *to_text(codec.summarize(msg))])


def _what_is_published(session: zenoh.Session, keys: Keys) -> str:
    """What the plant says it publishes (from ``sim/info``), for a "nothing came" message."""
    from bus.session import query_info
    try:
        info = query_info(session, keys, timeout_s=1.0)
    except (TimeoutError, ValueError):
        return (f"no plant answered {keys.info}: is one running with the same --endpoint "
                "and --namespace?")
    pre = f"{keys.namespace}/" if keys.namespace else ""
    published = [keys.clock[len(pre):]]
    for robot, r in sorted(info.get("robots", {}).items()):
        published += [keys.topic(robot, t)[len(pre):] for t in r.get("topics", {})]
    return f"the plant publishes: {', '.join(published)}"


def echo_main(argv: list[str] | None = None) -> int:
    p = ArgumentParser(prog="diffbot echo",
                                description="Print the messages on a key, decoded, with large "
                                            "arrays summarised.")
    p.add_argument("key", help="key (or key expression) relative to the namespace, "
                               "e.g. robot1/gps or 'robot1/**'")
    p.add_argument("--count", type=positive_int, default=None, metavar="N",
                   help="exit after N messages (default: until Ctrl-C)")
    p.add_argument("--timeout", type=nonneg_float, default=ECHO_TIMEOUT_S, metavar="S",
                   help="give up when no message came for S wall seconds, exit 1 "
                        f"(default {ECHO_TIMEOUT_S:g}; 0 waits forever)")
    add_bus_args(p)
    args = p.parse_args(argv)
    try:
        keys = Keys(args.namespace)
        prefix = f"{keys.namespace}/" if keys.namespace else ""
        expr = prefix + args.key.strip("/")
        zenoh.KeyExpr(expr)
    except Exception as exc:
        print(f"diffbot echo: bad key {args.key!r}: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        session = open_session("observer", args.endpoint, args.zenoh_config)
    except BusConfigError as exc:
        print(f"diffbot echo: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    q: queue.SimpleQueue = queue.SimpleQueue()

    def cb(sample: zenoh.Sample) -> None:
        att = sample.attachment
        q.put((str(sample.key_expr), sample.payload.to_bytes(),
               att.to_bytes() if att is not None else None))

    # the types of fmu/ keys come from the FMU nodes' fmu/<instance>/info
    types = _fmu_types(fmu_nodes(session, keys)) if "fmu" in args.key else {}
    n = 0
    code = EXIT_OK
    idle_s = args.timeout or None
    deadline = time.monotonic() + idle_s if idle_s else None
    try:
        sub = session.declare_subscriber(expr, zenoh.handlers.Callback(cb, indirect=False))
        try:
            while args.count is None or n < args.count:
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    print(f"diffbot echo: no message on {args.key} within {idle_s:g} s"
                          f"{' of the last' if n else ''} ({_what_is_published(session, keys)})",
                          file=sys.stderr)
                    code = EXIT_NOTHING
                    break
                try:
                    key, payload, att = q.get(timeout=min(left, 0.2) if left else 0.2)
                except queue.Empty:
                    continue
                print(format_message(key, payload, att, keys, types), flush=True)
                n += 1
                if idle_s:
                    deadline = time.monotonic() + idle_s
        except KeyboardInterrupt:
            pass
        finally:
            sub.undeclare()
    except BrokenPipeError:        # `diffbot echo ... | head`
        pass
    finally:
        session.close()
    return code


if __name__ == "__main__":
    sys.exit(topics_main())
