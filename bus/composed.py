"""Members composed into the plant's process: :class:`Composed`, the host.

Where a member runs is a deployment choice, not a second API (ROS 2 component containers,
dora-rs operators): a controller object, the FMU node, a policy, built by its own command
line (:func:`bus.node.capture_member`), runs here with the same rules as over Zenoh. Each
composed member is a :class:`bus.member.MemberTick`, exactly as a process member's; only
the wire differs: the plant hands it the messages it publishes directly (made from the
tick's values where it keeps them as the wire carries them, :mod:`plant.handover`; else
their bytes, and the bytes other members send it, decoded as a process would decode them),
and takes what it sends back as bytes with the same attachment, a tick's answer in one
call, with the effects its messages would have one by one from Zenoh (the ACK ledger, the
command checks). The host also puts those outputs on the bus and holds each member's
liveliness tokens (``sim/alive/<node>``, ``sim/sync/<node>``) on the plant's session, so a
recorder, a live view, a ROS 2 bridge or process members beside composed ones see the same
bus as when every member is a process. A composed run's recording equals the all-process
run's, byte for byte (docs/scenarios.md, "Composed members").

A composed member must not block in ``step`` (it holds the plant's tick) nor keep threads
of its own; one whose ``step`` raises is stopped and leaves as a crashed process would.
"""
from __future__ import annotations

import functools
import logging
from typing import Callable

import zenoh

from . import codec
from . import controller as hooks
from .jsonio import write_stats
from .keys import TOPICS, Keys
from .log import RejectCounter
from .many import ManyTick, answer_attachments
from .member import MemberTick, Sent, make_slots, with_own_stats
from .node import MemberSpec
from .one import OneTick
from .rows import ROW

#: emit([(key, payload, attachment, the attachment as parse_attachment reads it, a command's
#: (stamp, linear, angular) the payload was packed from or None), ...], twists): a composed
#: member's messages for one tick, in order, handed to the plant in one call; ``twists``:
#: where they are one Twist per robot, (their keys, stamp, linear, angular values), else None
#: (:meth:`bus.many.ManyTick.twists_of`)
Emit = Callable[[list[tuple[str, bytes, bytes, codec.Attachment | None, tuple | None]],
                 tuple | None], None]


class _Hosted:
    """One composed member: its MemberTick, tokens, counters."""

    def __init__(self, spec: MemberSpec, keys: Keys) -> None:
        self.spec = spec
        self.name = spec.name
        self.log = logging.getLogger(spec.name)
        self.log.setLevel(getattr(logging, spec.log_level.upper(), logging.INFO))
        self.topics = dict(TOPICS)
        slots = make_slots(spec.controller, spec.robots, self.topics)
        # (a topic's key asked once: a member asks for its robots' keys every tick)
        self.member = MemberTick(spec.name, 0, slots=slots, topics=self.topics,
                                 key=functools.lru_cache(maxsize=None)(keys.topic),
                                 ack_key=keys.ack(spec.name), log=self.log)
        # (a member of many robots on one step_many controller, or of one robot answering
        # a Twist, answers in one pass)
        self.many = ManyTick.of(self.member) or OneTick.of(self.member)
        self.rejects = RejectCounter(self.log)
        self.published: dict[str, int] = {}
        self.seq = 0
        self.exit_code = 0
        self.tokens: list = []
        self.gone = False                 # finished and left, or failed

    def leave(self) -> None:
        for tok in self.tokens:
            tok.undeclare()
        self.tokens = []
        self.gone = True

    def stats(self) -> dict:
        return with_own_stats({
            "node": self.name, "robot": self.spec.robots[0], "robots": self.spec.robots,
            "ticks": self.member.ticks, "published": self.published,
            "rejected": dict(self.rejects.counts), "plant_lost": 0,
            "exit_code": self.exit_code, "composed": True},
            [s.controller for s in self.member.slots])


class Composed:
    """The members composed into this plant (module docstring). The plant calls
    :meth:`start` once it can answer ``sim/info``, :meth:`deliver` for every message a
    member may read, :meth:`clock` once a tick's sensors and clock are out, :meth:`run`
    whenever something came, and :meth:`close` at the end."""

    def __init__(self, specs: list[MemberSpec], keys: Keys, session: zenoh.Session) -> None:
        names = [s.name for s in specs]
        if len(set(names)) != len(names):
            raise ValueError(f"a composed member is named twice in {', '.join(names)}")
        self.keys = keys
        self.session = session
        self.hosted = [_Hosted(s, keys) for s in specs]
        self._names = frozenset(names)
        self._readers: dict[str, list[_Hosted]] = {}
        #: key -> (the payload a member last sent on it, its Encoded), for a key another
        #: member composed here reads: :meth:`deliver` hands that the message built from
        #: the values the payload was packed from (bus.made), not the payload decoded
        self._made: dict[str, tuple[bytes, object]] = {}
        self._any: dict[int, tuple[list, bool]] = {}     # reads_any's answers
        self._rows: list[_Hosted] = []    # members that take their scans as one array
        for h in self.hosted:
            for key in h.member.slot_of:
                self._readers.setdefault(key, []).append(h)
        #: key -> the members that read it message by message (:meth:`deliver`): those
        #: that take their scans as one array (:meth:`deliver_scans`) are not among them
        self._each = {key: list(hs) for key, hs in self._readers.items()}

    @property
    def names(self) -> list[str]:
        return [h.name for h in self.hosted]

    def hosts(self, nodes: set[str]) -> bool:
        """Whether every node of ``nodes`` is a member composed here."""
        return nodes <= self._names

    def start(self, info: dict) -> None:
        """Configure every member from the plant's ``sim/info`` and let it join: its
        controllers' ``configure``/``on_session`` hooks, then its liveliness tokens."""
        liveliness = self.session.liveliness()
        for h in self.hosted:
            h.member.configure(info)
            for slot in h.member.slots:
                hooks.configure(slot.controller, info, slot.robot)
            for ctrl in hooks.distinct(s.controller for s in h.member.slots):
                hooks.on_session(ctrl, self.session, self.keys)
            if h.many is not None and h.many.take_rows():
                # (its scans come as one array a tick: deliver_scans, not message by message)
                for key in h.many.rows.keys:
                    readers = self._each.get(key, [])
                    if h in readers:
                        readers.remove(h)
                    if not readers:
                        self._each.pop(key, None)
                self._rows.append(h)
            h.tokens.append(liveliness.declare_token(self.keys.alive(h.name)))
            if h.member.sync:
                h.tokens.append(liveliness.declare_token(self.keys.sync(h.name)))
            h.log.info("%s composed into the plant on robot%s %s: inputs %s%s", h.name,
                       "s" if len(h.spec.robots) > 1 else "", ", ".join(h.spec.robots),
                       ", ".join(h.member.slots[0].inputs) or "none",
                       ", lockstep member" if h.member.sync else "")

    def foreign_input_keys(self) -> set[str]:
        """The keys a composed member reads that the plant does not publish itself (another
        node's outputs): the plant's own sensors reach its members directly, and a
        subscription of the plant's on one would count as a reader of its bytes on the bus."""
        return {key for h in self.hosted for key, (_, topic) in h.member.slot_of.items()
                if h.topics[topic].source != "plant"}

    def reads(self, key: str) -> bool:
        """Whether a composed member reads ``key``."""
        return key in self._readers

    def delivers(self, key: str) -> bool:
        """Whether a composed member reads ``key`` message by message (:meth:`deliver`)."""
        return key in self._each

    def reads_any(self, keys: list[str]) -> bool:
        """Whether a composed member reads any of ``keys`` (a member's cmd_vel keys: asked
        once per list, which stays the member's own)."""
        got = self._any.get(id(keys))
        if got is None or got[0] is not keys:
            got = self._any[id(keys)] = (keys, any(k in self._readers for k in keys))
        return got[1]

    def deliver(self, key: str, payload: bytes, att: bytes | None, msg=None) -> None:
        """Section 4, step 2: a message on ``key`` reaches the members that read it, decoded
        once, filed by stamp (docs/PROTOCOL.md). ``msg``: the message the plant made of the
        values ``payload`` carries (:mod:`plant.handover`: the object decoding would give),
        taken as it is; None: ``payload`` is decoded."""
        readers = self._each.get(key)
        if not readers:
            return
        if msg is None and (got := self._made.get(key)) is not None and got[0] is payload:
            msg = got[1].made()
        # (decoded at most once for every member that reads it)
        for h in readers:
            if not h.gone:
                topic, problem, msg = h.member.receive(key, payload, att, msg)
                if problem is not None:
                    h.rejects.reject(topic, problem)

    @property
    def takes_scans(self) -> bool:
        """Whether a member composed here takes its scans as one array (:meth:`deliver_scans`)."""
        return bool(self._rows)

    def deliver_scans(self, t_ns: int, groups, index: dict) -> None:
        """Section 4, step 2, for the members that take their scans as one array
        (:class:`bus.rows.ScanRows`): the plant's scans of tick ``t_ns``, ``groups`` as
        [(the LaserScan's fields angle_min .. range_max, the plant's robot rows, float32
        (rows, rays))], ``index``: robot -> plant row. (The others get them by
        :meth:`deliver`, message by message.)"""
        for h in list(self._rows):
            if h.gone:
                continue
            if not any(h.many.rows.file(t_ns, plant_rows, ranges, head, index)
                       for head, plant_rows, ranges in groups):
                self._rows_off(h)       # (its robots' scans are not rows of one group)

    def _rows_off(self, h: _Hosted) -> None:
        """Member ``h`` takes its scans message by message again, from this tick on (the
        plant delivers them after :meth:`deliver_scans`): its batches' marks go."""
        rows, h.many.rows = h.many.rows, None
        self._rows.remove(h)
        for key in rows.keys:
            buf = h.member.buf.get(key)
            for s in [s for s, m in (buf or {}).items() if m is ROW]:
                del buf[s]
            self._each.setdefault(key, []).append(h)

    def clock(self, t_ns: int, emit: Emit, epoch: int | None = None) -> None:
        """The plant published tick ``t_ns``'s sensors and clock (of its world ``epoch``):
        members that are not in lockstep act now; a finished member leaves once the plant
        took its FINAL."""
        for h in self.hosted:
            if h.gone:
                continue
            m = h.member
            if m.final_tick is not None:
                if m.may_leave(m.final_tick, t_ns):
                    h.leave()
                continue
            _, problem = m.clock(t_ns, 0.0, epoch)   # (a re-published tick: the plant keeps our
            if problem:                     #  answers and re-publishes them itself)
                h.rejects.reject("clock", problem)
            if not m.sync:
                self._act(h, t_ns, emit)

    def run(self, emit: Emit) -> None:
        """Every member acts on every tick it has all inputs for, in order, until none can:
        a member's output may complete another's tick (``emit`` delivers it)."""
        acted = True
        while acted:
            acted = False
            for h in self.hosted:
                if h.gone or not h.member.sync or h.member.final_tick is not None:
                    continue
                while (t_ns := h.member.next_due()) is not None:
                    acted = True
                    if self._act(h, t_ns, emit):
                        break

    def _act(self, h: _Hosted, t_ns: int, emit: Emit) -> bool:
        try:
            got = h.many.act(t_ns) if h.many is not None else None
            sent, finished = got if got is not None else h.member.act(t_ns)
        except Exception:
            h.log.exception("%s failed at t=%.3f s; it leaves the simulation", h.name,
                            t_ns * 1e-9)
            h.exit_code = 1
            h.leave()
            return True
        self._send(h, sent, t_ns, emit)
        return finished

    def _send(self, h: _Hosted, sent: Sent, t_ns: int, emit: Emit) -> None:
        if not sent:
            return
        name = h.name if h.member.sync else None
        published, twists, encoded = h.published, h.member.twists, h.member.encoded
        seq = h.seq
        many = h.many.twists_of(sent) if h.many is not None else None
        if many is not None:           # (one Twist per robot: their values, as lists too)
            atts = answer_attachments(seq, t_ns, len(sent), name)
            msgs = [(key, payload, att, parsed, (t_ns, a, b)) for (key, payload, _, _),
                    (att, parsed), a, b in zip(sent, atts, many[2], many[3])]
            for key in many[0]:
                published[key] = published.get(key, 0) + 1
        else:
            atts = codec.attachments_parsed(seq, t_ns, [(f, n) for _, _, f, n in sent], name)
            msgs = []
            for (key, payload, _, _), (att, parsed) in zip(sent, atts):
                enc = encoded.get(key)      # (these very bytes, with their values)
                if enc is not None and enc.data is payload and key in self._readers:
                    self._made[key] = (payload, enc)
                tw = twists.get(key)        # (the values of these very bytes, if a Twist's)
                msgs.append((key, payload, att, parsed,
                             tw[1:] if tw is not None and tw[0] is payload else None))
                published[key] = published.get(key, 0) + 1
        h.seq = seq + len(sent)
        emit(msgs, many)

    def close(self) -> None:
        """The run ended: every member leaves, its controllers are closed and its
        ``--stats`` written."""
        for h in self.hosted:
            h.leave()
            controllers = hooks.distinct(s.controller for s in h.member.slots)
            stats = h.stats()
            for ctrl in controllers:
                try:
                    hooks.close(ctrl)
                except Exception as exc:
                    h.log.error("closing %s: %s", h.name, exc)
            write_stats(h.spec.stats, stats, h.log)

