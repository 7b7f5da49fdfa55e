"""A passive bus listener for the launcher: keeps the messages the analysis needs.

It never takes part in lockstep; it only listens to the keys it keeps, so the plant
does not build messages nobody else reads. Message counts come from each
process's own stats. It is a watcher that keeps up (docs/PROTOCOL.md section 4): it says
on ``sim/seen/observer`` the latest clock it has received, so a lockstep plant runs at
most a few ticks ahead of it, and at a run's end it answers the plant's get on
``sim/seen/*`` with that clock, so the plant leaves only once the last tick is here
("End"). Paced, a launcher that stops reading for a while (suspended, swapped out) pauses
the run: the plant waits rather than filling its router's queue towards the launcher,
where a reliable put blocks the router's receiving threads, and the lockstep members'
links, unread for longer than their lease, would be dropped. Where it keeps
``sim/poses``, which the plant puts every tick just before that tick's ``sim/clock``, the
latest pose's stamp is that clock, so it does not subscribe to ``sim/clock`` (the plant
then need not put it for nobody).
"""
from __future__ import annotations

import threading
import time

import zenoh

from bridges.seen import SeenReporter
from bus import codec
from bus.keys import Keys
from bus.session import undeclare_all


#: samples Zenoh may hold per key between two drains; a full channel makes the sender
#: wait (nothing is lost), which at this size and DRAIN_S never happens in practice
CHANNEL_CAPACITY = 1 << 16
#: how often the drain thread empties the channels (s)
DRAIN_S = 0.05


#: the observer's node name: its ``sim/alive/observer`` token says it listens (a plant that
#: hosts its members waits for it before the first tick: ``diffbot plant --wait-for``)
OBSERVER = "observer"
#: (ms) the lease the launcher's session announces: the plant's router drops a launcher
#: frozen this long (one killed at once), so one suspended for a few seconds is kept, and
#: the run, paced to it, waits (module docstring)
OBSERVER_LEASE_MS = 5000


class Observer:
    def __init__(self, session: zenoh.Session, keys: Keys, keep: dict[str, str]) -> None:
        """``keep`` maps concrete keys to message types whose decoded messages are stored.

        Samples wait in Zenoh's own FIFO channels and a thread empties them in batches every
        ``DRAIN_S``: the observer costs the running simulation no Python callback (and no
        GIL hand-over) per message, only a few wake-ups per second.
        """
        self.keys = keys
        self.keep = keep
        self.samples: dict[str, list[tuple[int, bytes]]] = {k: [] for k in keep}
        #: key -> (samples decoded, their decoded messages in stamp order)
        self._decoded: dict[str, tuple[int, list]] = {}
        self.lock = threading.Lock()
        self._subs = {k: session.declare_subscriber(k, zenoh.handlers.FifoChannel(CHANNEL_CAPACITY))
                      for k in keep}
        # the clock taken in, said on sim/seen/observer as it comes and answered at a run's
        # end: each tick's sim/poses where those are kept, its sim/clock otherwise (module
        # docstring). On Zenoh's thread, one small callback a tick: said from the drain
        # thread instead, every DRAIN_S, the plant would wait at each drain for it.
        self._seen = SeenReporter(session, keys, OBSERVER)
        self._seen.declare()
        self._ticks = session.declare_subscriber(
            keys.poses if keys.poses in keep else keys.clock, self._took_in)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._drain_loop, name="observer", daemon=True)
        self._thread.start()
        self._token = session.liveliness().declare_token(keys.alive(OBSERVER))

    def _drain_loop(self) -> None:
        while not self._stop.wait(DRAIN_S):
            self.drain()

    def _took_in(self, sample: zenoh.Sample) -> None:
        """Zenoh's thread: a tick's clock (or poses) has come; what has come is kept."""
        if sample.attachment is not None:
            self._seen.took_in_clock(sample.attachment.to_bytes())

    def drain(self) -> None:
        """Move what the channels hold into ``samples``."""
        with self.lock:
            for key, sub in self._subs.items():
                out = self.samples[key]
                while (sample := sub.try_recv()) is not None:
                    att = sample.attachment
                    att = codec.parse_attachment(att.to_bytes() if att is not None else None)
                    out.append((att[1] if att else -1, sample.payload.to_bytes()))

    def settle(self, expected: dict[str, int], timeout_s: float = 2.0) -> None:
        """Wait, up to ``timeout_s``, until every kept key holds as many samples as its
        publishers say they put (``expected``, their --stats): the last messages of a
        node that has just exited may still be on their way here (a loaded machine's
        square once lost its last three commands, and three rows of trajectory.csv)."""
        deadline = time.monotonic() + timeout_s
        while True:
            self.drain()
            with self.lock:
                behind = [k for k, got in self.samples.items() if len(got) < expected.get(k, 0)]
            if not behind or time.monotonic() >= deadline:
                return
            time.sleep(0.02)

    def stamped(self, key: str) -> list[tuple[int, object]]:
        """(sim-time stamp from the attachment, decoded message) on ``key``, in stamp
        order (undecodable ones skipped). Works for messages without a header too."""
        self.drain()
        with self.lock:
            raw = list(self.samples.get(key, ()))
        # decoded once per key while nothing new has come (the analyses after a run, the
        # paths among them, read the same ground truth several times); a new list each call
        done = self._decoded.get(key)
        if done is not None and done[0] == len(raw):
            return list(done[1])
        out = []
        for t, payload in raw:
            try:
                out.append((t, codec.decode(payload, self.keep[key])))
            except codec.CodecError:
                continue
        out.sort(key=lambda item: item[0])
        self._decoded[key] = (len(raw), out)
        return list(out)

    def messages(self, key: str) -> list:
        """Decoded messages on ``key`` in stamp order."""
        return [m for _, m in self.stamped(key)]

    def close(self) -> None:
        if self._token is not None:
            self._token.undeclare()
            self._token = None
        self._stop.set()
        self._thread.join()
        self.drain()                      # what arrived before the close is kept
        subs, self._subs = self._subs, {}
        undeclare_all([*subs.values(), self._ticks])
        self._seen.undeclare()
