"""What the plant says about itself: its ``sim/info`` (docs/PROTOCOL.md section 5), its
run's counters (``--stats``, the launcher's summary) and the line it logs when it starts.
Read from a :class:`plant.process.Plant` on its main thread."""
from __future__ import annotations

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
            "per_tick_ms": {k[:-2]: 1e3 * v / max(p.ticks, 1) for k, v in p.timing.items()}}


def say_running(p) -> None:
    p.log.info("running %s (%s mode, tick %.0f ms, %d physics steps per tick%s)",
               p.spec.name, p.mode, p.tick_ns / 1e6, p.spec.substeps,
               "" if p.tick.physics is None else ", physics in its own process"
               + (", stepping while publishing" if p.tick.stepper.overlap else ""))
