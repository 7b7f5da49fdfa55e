"""What the plant says about itself: its ``sim/info`` (docs/PROTOCOL.md section 5), its
run's counters (``--stats``, the launcher's summary) and the line it logs when it starts.
Read from a :class:`plant.process.Plant` on its main thread."""
from __future__ import annotations

import time

from bus.lockstep import HOLD_PAST
from bus.protocol import PROTOCOL_MINOR, PROTOCOL_VERSION

from .commands import STALE


def info(p) -> dict:
    """What ``sim/info`` answers: the world, each robot's topics and their periods, the
    protocol, mode, coupling and its delays, seed, time and the world's epoch."""
    d = p.sim.describe()
    for name, sensors in p.tick.sensors.items():
        d["robots"][name]["topics"] = dict(sensors.periods)
    d.update(protocol=PROTOCOL_VERSION, protocol_minor=PROTOCOL_MINOR, mode=p.mode,
             coupling=p.coupling,
             **p.delays, seed=p.seed, time_ns=p.sim.time_ns,
             namespace=p.keys.namespace, rate=p.rate,
             rejoin_timeout_s=p.rejoin_timeout_s,
             epoch=p.epoch)
    return d


def stats(p) -> dict:
    """The run's counters: times, ticks, messages, members, protocol errors, per-tick cost."""
    wall = max(p.wall_end - p.wall_start, 1e-9) if p.wall_start else 0.0
    sim_s = p.sim.time_ns * 1e-9
    errors = p.protocol_errors.counts
    return {"node": "plant", "world": p.spec.name, "mode": p.mode, "seed": p.seed,
            "end_reason": p.end_reason,
            "sim_time_s": sim_s, "wall_time_s": wall, "ticks": p.ticks,
            "real_time_factor": sim_s / wall if wall else None,
            "published": p.published, "rejected": dict(p.rejects.counts),
            "members_seen": sorted(p.ledger.members_seen),
            "members_lost": sorted(p.ledger.lost), "exit_code": p.exit_code,
            "stalls": p.strategy.stalls,
            "paced_s": round(p.strategy.paced_s, 3),
            "protocol": PROTOCOL_VERSION, "coupling": p.coupling, **p.delays,
            "physics_process": p.tick.physics is not None,
            "composed": p.composed.names if p.composed is not None else [],
            "protocol_errors": dict(errors),
            "stale_commands": errors.get(STALE, 0),
            "holds_past_timeout": errors.get(HOLD_PAST, 0),
            "per_tick_ms": {k[:-2]: 1e3 * v / max(p.ticks, 1) for k, v in p.timing.items()},
            "cpu_per_tick_ms": cpu_per_tick_ms(p)}


def cpu_now(p) -> tuple[float, float | None]:
    """(this process's CPU seconds, its physics process's or None)."""
    physics = p.tick.physics
    return time.process_time(), None if physics is None else physics.cpu_s()


def cpu_per_tick_ms(p) -> dict:
    """CPU ms a tick over the loop: the plant's process (all its threads) and, with one,
    its physics process. Unlike the wall clock, not stretched by other work on the cores."""
    ticks = max(p.ticks, 1)
    (c0, w0), (c1, w1) = p.cpu_start, p.cpu_end
    out = {"plant": 1e3 * (c1 - c0) / ticks}
    if w0 is not None and w1 is not None and w1 >= w0:    # (not across a new worker)
        out["physics"] = 1e3 * (w1 - w0) / ticks
    return out


def say_running(p) -> None:
    p.log.info("running %s (%s mode, tick %.0f ms, %d physics steps per tick%s)",
               p.spec.name, p.mode, p.tick_ns / 1e6, p.spec.substeps,
               "" if p.tick.physics is None else ", physics in its own process"
               + (", stepping while publishing" if p.tick.stepper.overlap else ""))
