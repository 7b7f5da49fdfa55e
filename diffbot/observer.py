"""A passive bus listener for the launcher: keeps the messages the analysis needs.

It never takes part in lockstep; it only listens to the keys it keeps, so the plant
does not build messages nobody else reads. Message counts come from each
process's own stats.
"""
from __future__ import annotations

import threading

import zenoh

from bus import codec
from bus.keys import Keys


class Observer:
    def __init__(self, session: zenoh.Session, keys: Keys, keep: dict[str, str]) -> None:
        """``keep`` maps concrete keys to message types whose decoded messages are stored."""
        self.keys = keys
        self.keep = keep
        self.samples: dict[str, list[tuple[int, bytes]]] = {k: [] for k in keep}
        self.lock = threading.Lock()
        self._subs = [session.declare_subscriber(k, self._on_sample) for k in keep]

    def _on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        with self.lock:
            if key in self.samples:
                att = codec.parse_attachment(sample.attachment.to_bytes()
                                             if sample.attachment is not None else None)
                self.samples[key].append((att[1] if att else -1, sample.payload.to_bytes()))

    def stamped(self, key: str) -> list[tuple[int, object]]:
        """(sim-time stamp from the attachment, decoded message) on ``key``, in stamp
        order (undecodable ones skipped). Works for messages without a header too."""
        with self.lock:
            raw = list(self.samples.get(key, ()))
        out = []
        for t, payload in raw:
            try:
                out.append((t, codec.decode(payload, self.keep[key])))
            except codec.CodecError:
                continue
        out.sort(key=lambda item: item[0])
        return out

    def messages(self, key: str) -> list:
        """Decoded messages on ``key`` in stamp order."""
        return [m for _, m in self.stamped(key)]

    def close(self) -> None:
        for sub in self._subs:
            try:
                sub.undeclare()
            except Exception:
                pass
