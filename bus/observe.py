"""A lockstep member's observations (docs/PROTOCOL.md section 4, step 2), taken for many
robots in one pass: :func:`observations`, what :meth:`bus.member.MemberTick.take_observation`
does for one robot and what a controller for many robots (``step_many``) gets each tick.
"""
from __future__ import annotations

from .controller import Observation

#: an input older than this (simulated s, or three of its periods) is not shown to the
#: controller: its producer is gone (realtime and fast modes, where nobody waits for it)
STALE_S = 0.5
#: samples kept per input topic (by stamp) and clock ticks waiting for their inputs
BUF_PER_TOPIC = 8
_HELD = object()     # "a bad sample came for this tick": the tick goes on, the last good is held


def observations(member, slots, t_ns: int) -> dict[str, Observation]:
    """``{robot: Observation}`` at tick ``t_ns`` for ``slots`` (robots of ``member``, a
    :class:`bus.member.MemberTick`): per robot, the latest good message of each of its inputs
    stamped at or before ``t_ns`` (a tick earlier for a lagged one), unless it is stale
    (older than ``STALE_S`` or three of its periods: its producer is gone), so a controller
    never steers on a dead input. Takes: the samples older than the one shown, and held
    marks, are dropped, and the tick's stamps are marked used. Each slot's plan (its inputs'
    keys, lags and ages) is made once per configuration."""
    lag_ns, tick_ns, key_of = member.lag_ns, member.tick_ns, member.key
    bufs, used = member.buf, member.used
    mark = used.add
    out = {}
    for slot in slots:
        plan = slot.plan
        if plan is None or plan[0] is not slot.periods or plan[1] is not lag_ns \
                or plan[2] != tick_ns:
            if plan is None or plan[:3] != (slot.periods, lag_ns, tick_ns):
                plan = (slot.periods, lag_ns, tick_ns, [
                    (t, key_of(slot.robot, t), lag_ns[t],
                     max(STALE_S * 1e9, 3 * slot.periods.get(t, 1) * tick_ns))
                    for t in slot.inputs])
            slot.plan = plan
        msgs = {}
        for topic, key, lag, stale_ns in plan[3]:
            buf = bufs.get(key)
            if not buf:
                continue
            upto = t_ns - lag                      # a lagged input never shows a newer sample
            if len(buf) == 1:                      # (the usual case, shortly)
                (s, m), = buf.items()
                if s <= upto:
                    if m is _HELD:                 # a held mark alone: dropped
                        del buf[s]
                    elif upto - s <= stale_ns:
                        msgs[topic] = m
                mark((key, upto))
                continue
            if len(buf) == 2:                      # (the usual case: the last shown, a new one)
                (s0, m0), (s1, m1) = buf.items()
                if s0 < s1 <= upto and m1 is not _HELD:      # the new one shown, the last
                    if upto - s1 <= stale_ns:                # dropped (the rule below)
                        msgs[topic] = m1
                    del buf[s0]
                    mark((key, upto))
                    continue
            good = [s for s, m in buf.items() if s <= upto and m is not _HELD]
            if good:
                best = max(good)
                if upto - best <= stale_ns:
                    msgs[topic] = buf[best]
            else:
                best = None
            for s in [s for s, m in buf.items()
                      if s <= upto and (s != best) and (best is None or s < best or m is _HELD)]:
                del buf[s]
            mark((key, upto))
        out[slot.robot] = Observation(t_ns, slot.robot, msgs)
    # (pruned once for all the robots: it keeps the stamps of this tick and the last alike)
    if len(used) > 4 * BUF_PER_TOPIC * max(1, len(member.slot_of)):
        member.used = {(k, s) for k, s in used if s >= t_ns - tick_ns}
    return out
