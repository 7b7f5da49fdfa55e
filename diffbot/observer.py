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

    def messages(self, key: str) -> list:
        """Decoded messages on ``key`` sorted by sim-time stamp (undecodable ones skipped)."""
        with self.lock:
            raw = list(self.samples.get(key, ()))
        out = []
        for _, payload in raw:
            try:
                out.append(codec.decode(payload, self.keep[key]))
            except codec.CodecError:
                continue
        out.sort(key=codec.msg_stamp_ns)
        return out

    def close(self) -> None:
        for sub in self._subs:
            try:
                sub.undeclare()
            except Exception:
                pass
