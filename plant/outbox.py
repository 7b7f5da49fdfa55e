"""The plant's publishers: CDR bytes out with their attachment, and who reads what.

One Zenoh publisher per key, declared on first use. :meth:`Outbox.reads` is Zenoh's
matching status of a key's publisher: whether any subscriber (a node, the recorder, the
launcher's observer, ``diffbot echo``...) would get a put on it now. The plant builds only
the topics someone reads (:meth:`plant.sensors.RobotSensors.messages`'s ``wanted``): a
``square`` run has nobody on its lidar, a swarm's controllers read one topic of four.
The matching status comes from the same routing tables a put goes by, so a subscriber
declared before a member's ``sim/sync`` token is always counted by the time the plant
sees the member. Asking costs a walk of those tables, so the answers are kept until
something may have changed them: the plant calls :meth:`Outbox.changed` whenever a node
comes or goes (its liveliness), before it publishes again, and a matching listener on
each publisher says when any other subscriber (a recorder, ``diffbot echo``) appears or
leaves (those callbacks come late and in no particular order, so they alone could not
be trusted with a member's inputs). That holds where the plant's session is the router every node connects
to (its own configuration, the default): the routing tables are its own and a member's
declarations reach it in order. A key once read stays read for the rest of the run (even
after its reader has gone): a reader whose link blips, or a member lost and back, finds
every tick it missed built, whatever the order in which its subscriptions and its
liveliness went and came, and a topic's bytes never depend on when a reader's
subscription was seen to go. Behind a user's Zenoh configuration (a separate router,
peers) a newly declared publisher learns of the subscribers only some time later, so there
the outbox says everything is read (``skip_unread=False``) and the plant builds it all, as
before. Attachment sequence numbers count every due message, put or not, so a message's
attachment is the same whoever listens.
"""
from __future__ import annotations

import struct

import zenoh

from bus import codec
from bus.protocol import REPUBLISH_TICKS

#: the plant's attachment (:func:`bus.codec.attachment` with an ``epoch``: seq, t_ns, then
#: the epoch) packed in one call
_PLANT_ATTACHMENT = struct.Struct(codec.ATTACHMENT.format + codec.EPOCH.format[1:]).pack
_U64, _U32 = 0xFFFFFFFFFFFFFFFF, 0xFFFFFFFF


class Reads(dict):
    """topic -> whether anyone reads it (``ask(topic)``), asked once per topic."""
    __slots__ = ("ask",)

    def __init__(self, ask) -> None:
        super().__init__()
        self.ask = ask

    def __missing__(self, topic: str) -> bool:
        answer = self[topic] = bool(self.ask(topic))
        return answer


class Outbox:
    """``keep``: the messages of the last REPUBLISH_TICKS ticks are kept to re-publish
    (lockstep, docs/PROTOCOL.md section 4, "Lost members")."""

    def __init__(self, session: zenoh.Session, congestion: zenoh.CongestionControl,
                 skip_unread: bool = True, keep: bool = False) -> None:
        self.session = session
        self.keep = keep
        #: the last ticks' messages as published: stamp -> [(key, payload, a composed
        #: member's attachment or None)]
        self.recent: dict[int, list[tuple[str, bytes, bytes | None]]] = {}
        self.skip_unread = skip_unread
        self.congestion = congestion
        self.seq = 0
        self.published: dict[str, int] = {}
        self._pubs: dict[str, zenoh.Publisher] = {}
        self._listeners: list = []
        self._reads: dict[str, bool] = {}      # matching status, asked since the last change
        self._ever: set[str] = set()            # keys someone has read: read from then on
        self._held: list | None = None          # puts held back (:meth:`hold`), in order

    def publisher(self, key: str, remote: bool = False) -> zenoh.Publisher:
        """``key``'s publisher, declared on first use: ``remote`` (asked first for the key) to
        other sessions only, so its matching status leaves out this session's subscribers."""
        pub = self._pubs.get(key)
        if pub is None:
            pub = self._pubs[key] = self.session.declare_publisher(
                key, encoding=zenoh.Encoding.APPLICATION_CDR,
                congestion_control=self.congestion,
                allowed_destination=zenoh.Locality.REMOTE if remote else None)
            if self.skip_unread:
                self._listeners.append(pub.declare_matching_listener(self._on_matching))
        return pub

    def _on_matching(self, status) -> None:
        self._reads = {}                        # (Zenoh's thread: a new dict, not a clear)

    def changed(self) -> None:
        """Subscribers may have come or gone (a node joined or left): ask again."""
        self._reads = {}

    def readers(self) -> object:
        """What :meth:`reads` answers from: a new object whenever subscribers may have come
        or gone, so an answer kept beside the same object is still the answer."""
        return self._reads

    def reads(self, key: str, remote: bool = False) -> bool:
        """Whether anyone subscribes to ``key`` (Zenoh's matching status) or has since the
        run began; always True without ``skip_unread``. ``remote``: anyone but this
        session (:meth:`relay`'s keys)."""
        if not self.skip_unread or key in self._ever:
            return True
        reads = self._reads
        known = reads.get(key)
        if known is None:
            known = reads[key] = self.publisher(key, remote).matching_status.matching
            if known:
                self._ever.add(key)
        return known

    def put(self, key: str, data: bytes, t_ns: int, epoch: int) -> None:
        """``data`` (CDR bytes) on ``key`` stamped ``t_ns``, with the next sequence number
        and the plant's world ``epoch`` (docs/PROTOCOL.md section 3)."""
        self.seq = seq = self.seq + 1
        att = _PLANT_ATTACHMENT(seq & _U64, t_ns, epoch & _U32)
        pub = self._pubs.get(key) or self.publisher(key)
        if self._held is None:
            pub.put(data, attachment=att)
        else:
            self._held.append((pub, data, att))
        published = self.published
        published[key] = published.get(key, 0) + 1
        if self.keep:
            self._kept(t_ns, key, data, None)

    def relay(self, key: str, data: bytes, t_ns: int, att: bytes) -> None:
        """A composed member's message stamped ``t_ns`` on the bus, with its own attachment
        (its counts are the member's, not the plant's), if another session reads it. The
        plant's own subscription to members' outputs (a process member's command) is not
        a reader of it: the plant and its other composed members have it already
        (bus/composed.py), so a composed member's command nobody else reads stays off the
        bus, as a due sensor nobody reads does. It is kept to re-publish either way."""
        if self.reads(key, remote=True):
            if self._held is None:
                self.publisher(key, remote=True).put(data, attachment=att)
            else:
                self._held.append((self.publisher(key, remote=True), data, att))
        self._kept(t_ns, key, data, att)

    def hold(self) -> None:
        """Hold the puts back until :meth:`flush` (the plant does for a tick whose lockstep
        members are all composed into it: no process waits on the tick's messages while
        those members answer). Zenoh's transmit task writes what it finds queued as one
        batch, so messages put back to back share writes and wake the transmit task and a
        reading process less often than puts spread over the tick. The bytes, attachments
        and their order on every key stay the same; only when they leave changes."""
        if self._held:
            self.flush()
        self._held = []

    def flush(self) -> None:
        """The puts held back since :meth:`hold`, in their order; puts go out at once again."""
        held, self._held = self._held, None
        for pub, data, att in held or ():
            pub.put(data, attachment=att)

    def _kept(self, t_ns: int, key: str, data: bytes, att: bytes | None) -> None:
        if self.keep:
            recent = self.recent
            kept = recent.get(t_ns)
            if kept is None:                    # (a new tick: only then can one be too many)
                kept = recent[t_ns] = []
                while len(recent) > REPUBLISH_TICKS:
                    del recent[min(recent)]
            kept.append((key, data, att))

    def republish(self, upto_ns: int, epoch: int) -> list[int]:
        """The kept messages of the ticks up to ``upto_ns`` (of the world ``epoch``: the
        plant clears :attr:`recent` at a new one) again, as they were (new sequence
        numbers; a composed member's with its attachment); the ticks."""
        self.flush()                            # (what was held goes first)
        ticks = sorted(t for t in self.recent if t <= upto_ns)
        for t in ticks:
            for key, data, att in self.recent[t]:
                if att is None:
                    self.seq += 1
                    self.publisher(key).put(data, attachment=codec.attachment(
                        self.seq, t, epoch=epoch))
                    self.published[key] = self.published.get(key, 0) + 1
                else:
                    self.publisher(key).put(data, attachment=att)
        return ticks

    def skip(self, n: int = 1) -> None:
        """``n`` due messages nobody reads: their sequence numbers go unused."""
        self.seq += n

    def undeclare(self) -> None:
        for listener in self._listeners:
            listener.undeclare()
        self._listeners.clear()
        for pub in self._pubs.values():
            pub.undeclare()
        self._pubs.clear()
