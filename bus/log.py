"""Logging helpers: one format for every process, and rate-limited warnings for bad input."""
from __future__ import annotations

import logging
import sys
import time
from collections import Counter


def setup_logging(name: str, level: str = "INFO") -> logging.Logger:
    logging.basicConfig(stream=sys.stderr, level=getattr(logging, level.upper(), logging.INFO),
                        format=f"%(asctime)s {name} %(levelname)s %(message)s",
                        datefmt="%H:%M:%S")
    return logging.getLogger(name)


class RejectCounter:
    """Counts rejected inputs per reason and logs them at most once per ``period_s`` per reason."""

    def __init__(self, log: logging.Logger, period_s: float = 2.0, verb: str = "rejected") -> None:
        self.log = log
        self.verb = verb
        self.period_s = period_s
        self.counts: Counter[str] = Counter()
        self._last: dict[str, float] = {}
        self._since: Counter[str] = Counter()

    def reject(self, reason: str, detail: str = "") -> None:
        self.counts[reason] += 1
        self._since[reason] += 1
        now = time.monotonic()
        if now - self._last.get(reason, -1e9) >= self.period_s:
            n = self._since.pop(reason)
            self._last[reason] = now
            more = f" ({n} since last report)" if n > 1 else ""
            self.log.warning("%s %s%s%s", self.verb, reason, f": {detail}" if detail else "", more)

    @property
    def total(self) -> int:
        return sum(self.counts.values())
