"""Compare two MCAP recordings topic by topic: the same messages, payload bytes and stamps.

``python tests/support/compare_recordings.py A.mcap B.mcap`` prints, per topic, the message count
and whether every payload and sim-time stamp (``log_time``) is the same in both, in
order; exit 0 when every topic is identical. Wall-clock ``publish_time`` and the order
messages of different topics arrived in are not compared (they follow the machine's
load), nor are the recorder's own derived topics (``/tf``, ``/scene``, ``/tf_static``).
Used to show that a restructuring keeps every byte a run puts on the bus.
"""
from __future__ import annotations

import hashlib
import sys
from collections import defaultdict

from bridges.mcapfile import iter_recording, Recorded

#: topics the recorder derives itself, not bus traffic
DERIVED = {"/tf", "/tf_static", "/scene"}


def topics_of(path: str) -> dict[str, list[tuple[int, bytes]]]:
    """topic -> [(log_time ns, payload)] in file order, bus topics only."""
    rec = Recorded(path)
    out: dict[str, list[tuple[int, bytes]]] = defaultdict(list)
    for m in iter_recording(path, rec):
        topic = rec.channels[m.channel_id].topic
        if topic not in DERIVED:
            out[topic].append((m.log_time, bytes(m.data)))
    return dict(out)


def compare(a: str, b: str) -> list[str]:
    """One line per topic of either recording; the ones that differ start with 'DIFF'."""
    ta, tb = topics_of(a), topics_of(b)
    lines = []
    for topic in sorted(set(ta) | set(tb)):
        ma, mb = ta.get(topic, []), tb.get(topic, [])
        # within a topic the order is the publisher's; sort by stamp so that two
        # publishers of one topic (none today) could not make it flaky
        ma, mb = sorted(ma), sorted(mb)
        digest = hashlib.sha256(b"".join(p for _, p in ma)).hexdigest()[:12]
        if ma == mb:
            lines.append(f"same  {topic}: {len(ma)} messages, sha256 {digest}")
            continue
        first = next((i for i, (x, y) in enumerate(zip(ma, mb)) if x != y), min(len(ma), len(mb)))
        what = ("stamp" if first < min(len(ma), len(mb)) and ma[first][0] != mb[first][0]
                else "payload" if first < min(len(ma), len(mb)) else "count")
        lines.append(f"DIFF  {topic}: {len(ma)} vs {len(mb)} messages; first difference "
                     f"at #{first} ({what})")
    return lines


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 2:
        print(__doc__.splitlines()[0], file=sys.stderr)
        return 2
    lines = compare(*argv)
    print("\n".join(lines))
    return 1 if any(line.startswith("DIFF") for line in lines) else 0


if __name__ == "__main__":
    sys.exit(main())
