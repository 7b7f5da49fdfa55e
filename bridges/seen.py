"""What a watcher that keeps up (a recorder) says it has taken in: ``sim/seen/<name>``.

docs/PROTOCOL.md section 4, "Watchers that keep up": the plant paces a lockstep run to
the processes that report on ``sim/seen/<name>`` the latest ``sim/clock`` stamp they have
received, and at a run's end asks them (a get on ``sim/seen/*``) whether they have its
last tick ("End"). Received is taken in: what came is queued and will be written, however
far the writing lags, so the report goes out as clocks arrive, on Zenoh's thread.
"""
from __future__ import annotations

import zenoh

from bus import codec
from bus.keys import Keys
from bus.protocol import SEEN_EVERY_TICKS, encode_seen
from bus.session import undeclare_all


class SeenReporter:
    """The ``sim/seen/<name>`` half of a watcher: :meth:`took_in_clock` for each clock
    received (Zenoh's receive thread), :meth:`declare` once it listens, :meth:`undeclare`
    when it stops."""

    def __init__(self, session: zenoh.Session, keys: Keys, name: str) -> None:
        self.session, self.keys, self.name = session, keys, name
        self._pub = None
        self._queryable = None
        self._clock_max = -1             # the latest clock stamp of the world's epoch
        self._unsaid = 0                 # clocks taken in since it was last said
        self._epoch = 0
        self.received_ns: int | None = None     # the stamp of the latest clock received

    def declare(self) -> None:
        """Start saying (and answering a get with) what has come."""
        self._pub = self.session.declare_publisher(
            self.keys.seen(self.name), congestion_control=zenoh.CongestionControl.BLOCK)
        self._queryable = self.session.declare_queryable(self.keys.seen(self.name),
                                                         self._answer)

    def undeclare(self) -> None:
        undeclare_all([h for h in (self._pub, self._queryable) if h is not None])
        self._pub = self._queryable = None

    def took_in_clock(self, att: bytes) -> None:
        """Zenoh's receive thread: a clock has come, and what has come is taken in (queued,
        it is written however far the writing lags). It is what the plant's get on
        sim/seen/* is answered with, and said on sim/seen/<name> as it comes, not once
        written: a run's first clocks are said while the writing thread may still be busy
        with the first messages (a plant unpaced for those ~0.1 s ran 48 ticks past what
        the recorder had, and a blip then lost what it had not re-published)."""
        a = codec.parse_attachment(att)
        self.received_ns = a.t_ns if a is not None else None
        if a is None:
            return
        if a.epoch is not None and a.epoch != self._epoch:     # a reset: a new world
            self._epoch = a.epoch
            self._clock_max = -1
        self._keep_up(a.t_ns)

    def _keep_up(self, t_ns: int) -> None:
        """Zenoh's receive thread: a clock taken in (docs/PROTOCOL.md section 4, "Watchers
        that keep up"): say the latest stamp every SEEN_EVERY_TICKS new clocks, and at once
        for the first of a world (the plant paces no one it has not heard from) and for one
        seen before (re-published: the plant held time for this watcher and waits to hear
        from it)."""
        if t_ns > self._clock_max:
            first = self._clock_max < 0
            self._clock_max = t_ns
            self._unsaid += 1
            if self._unsaid < SEEN_EVERY_TICKS and not first:
                return
        if self._pub is not None:
            self._pub.put(encode_seen(self._clock_max))
            self._unsaid = 0

    def _answer(self, query: zenoh.Query) -> None:
        """Zenoh's thread: the plant asks at a run's end what has come (docs/PROTOCOL.md
        section 4, "End"): the latest clock received (queued is taken in: it is written)."""
        t_ns = self.received_ns
        if t_ns is not None:
            query.reply(self.keys.seen(self.name), encode_seen(t_ns))
