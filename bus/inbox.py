"""One queue for everything a process receives, in arrival order.

Zenoh delivers samples from one peer in the order they were sent; direct callback
subscribers that all feed one queue keep that order across keys. The lockstep
protocol does not depend on it (nodes check stamps), but it saves waiting.

The thread rule of the plant and the nodes: Zenoh's callbacks (subscribers, liveliness,
queryables) only put events here; the process's main thread takes them and alone touches
its state.
"""
from __future__ import annotations

import queue
from dataclasses import dataclass

import zenoh

from .session import undeclare_all, wake_on_stop


@dataclass(slots=True)
class Event:
    tag: str             # what the subscriber was declared for
    key: str             # the concrete key
    payload: bytes
    attachment: bytes | None
    alive: bool = True   # liveliness: token appeared (True) or vanished (False)
    query: zenoh.Query | None = None   # a query to answer (:meth:`Inbox.serve`)


#: put by :meth:`Inbox.wake`; :meth:`Inbox.get` gives None for it, as for nothing
WAKE = Event("wake", "", b"", None)


class Inbox:
    def __init__(self, session: zenoh.Session) -> None:
        self.session = session
        self.queue: queue.SimpleQueue[Event] = queue.SimpleQueue()
        self._handles: list = []
        wake_on_stop(self)

    def wake(self) -> None:
        """Ends a wait in :meth:`get` now (a stop signal: bus.session.wake_on_stop)."""
        self.queue.put(WAKE)

    def subscribe(self, key: str, tag: str, remote_only: bool = False) -> None:
        """Samples on ``key`` become events tagged ``tag``; ``remote_only``: not this
        session's own puts (the plant's, of the members composed into it)."""
        q = self.queue

        def cb(sample: zenoh.Sample) -> None:
            att = sample.attachment
            q.put(Event(tag, str(sample.key_expr), sample.payload.to_bytes(),
                        att.to_bytes() if att is not None else None))

        # indirect=False: run in Zenoh's receive thread, so samples of different keys
        # reach the queue in the order they arrived (the default hands every
        # subscriber its own Python thread, which reorders them).
        self._handles.append(self.session.declare_subscriber(
            key, zenoh.handlers.Callback(cb, indirect=False),
            allowed_origin=zenoh.Locality.REMOTE if remote_only else zenoh.Locality.ANY))

    def watch_liveliness(self, key: str, tag: str) -> None:
        """Events for tokens on ``key`` appearing (alive=True) and vanishing (alive=False),
        including the ones already there."""
        q = self.queue

        def cb(sample: zenoh.Sample) -> None:
            q.put(Event(tag, str(sample.key_expr), b"", None,
                        sample.kind == zenoh.SampleKind.PUT))

        self._handles.append(self.session.liveliness().declare_subscriber(
            key, zenoh.handlers.Callback(cb, indirect=False), history=True))

    def serve(self, key: str, tag: str) -> None:
        """Queries on ``key`` become events (``ev.query``) that the main thread answers."""
        self._handles.append(self.session.declare_queryable(
            key, lambda query: self.put_query(tag, query)))

    def put_query(self, tag: str, query: zenoh.Query) -> None:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        self.queue.put(Event(tag, str(query.key_expr), payload, None, query=query))

    def get_nowait(self) -> Event | None:
        """The next event, or None if there is none (nothing else is caught)."""
        try:
            ev = self.queue.get_nowait()
        except queue.Empty:
            return None
        return None if ev is WAKE else ev

    def get(self, timeout: float | None = None) -> Event | None:
        """The next event within ``timeout`` s, or None (none came, or :meth:`wake`)."""
        try:
            ev = self.queue.get(timeout=timeout)
        except queue.Empty:
            return None
        return None if ev is WAKE else ev

    def close(self) -> None:
        undeclare_all(self._handles)
        self._handles.clear()
