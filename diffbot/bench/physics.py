"""Suite ``physics``: one DART physics step, a control tick, a world build, a tick's sensor
messages."""
from __future__ import annotations

from .harness import Case, Context, suite

@suite("physics", "one DART physics step and one control tick of the robot, and a tick's sensor "
       "messages from the plant's core and message by message")
def physics_suite(ctx: Context):
    from plant.sim import Simulation
    from plant.world import load_world
    from time import perf_counter
    for world in ("empty", "living_room"):
        spec = load_world(world)
        sim = Simulation(spec)
        robot = next(iter(sim.robots))
        for _ in range(10):  # let the drive limiter ramp the targets up to the command
            sim.command_wheels(robot, 1.0, -1.0)
        robots, w = list(sim.robots.values()), sim.world
        targets = sim.command_targets().tolist()
        detector = type(w.getConstraintSolver().getCollisionDetector()).__name__
        n = len(sim.objects)
        what = (f"{n} static object{'' if n == 1 else 's'}, {detector}, dt {spec.physics_step_s * 1e3:g} ms,"
                f" robot spinning in place (wheels -/+1 rad/s)")

        def step(number, robots=robots, w=w, targets=targets):
            it = range(number)
            t0 = perf_counter()
            for _ in it:
                for r, (wl, wr) in zip(robots, targets):
                    r.apply(wl, wr)
                w.step()
            return perf_counter() - t0
        room = world == "living_room"
        yield Case(f"{world}: physics step", step, timer=True, notes=what + (
            "; peers (quiet machine, 2 ms step): PyBullet 125 us, MuJoCo 9 us" if room else ""))
        yield Case(f"{world}: control tick ({spec.substeps} steps)", sim.step_tick,
                   target="<= 150 µs" if room else "", notes="Simulation.step_tick()")
        yield Case(f"{world}: build world", lambda spec=spec: Simulation(spec),
                   notes="Simulation(spec): what a reset costs")
    yield from tick_messages(ctx)


def tick_messages(ctx: Context):
    """One tick's sensor messages (encoded, every topic read, no lidar due) of the swarm
    world with encoder and GPS noise, from the plant's core (what every host uses) and
    message by message (the reference the tests compare it with)."""
    import os
    import tempfile
    from plant.noise import NoiseConfig
    from plant.swarm_world import write_swarm_world
    from plant.tick import Tick, tick_messages as one_by_one
    from plant.world import load_world
    sizes = ((1, "kinematic"), (1, "dynamic"), (96, "kinematic")) if ctx.quick else (
        (1, "kinematic"), (8, "kinematic"), (96, "kinematic"), (1, "dynamic"), (8, "dynamic"))
    for n, mode in sizes:
        fd, path = tempfile.mkstemp(suffix=".toml", dir=ctx.tmpdir)
        os.close(fd)
        try:
            spec = load_world(write_swarm_world(path, n, seed=3, mode=mode))
        finally:
            os.unlink(path)
        for r in spec.robots:
            r.sensors.encoder_noise = NoiseConfig(std=0.01)
            r.sensors.gps_noise = NoiseConfig(std=0.02)
            r.sensors.command_noise_std_radps = 0.05      # (tick_commands')
        t = Tick(spec)
        t.step()                                          # (tick 1: no lidar due)
        what = f"a tick's sensor messages, {n} {mode} robot{'s' if n > 1 else ''}"
        yield Case(f"{what}: the core", lambda t=t: list(t.messages(None, encoded=True)),
                   notes="Tick.messages: one kernel call for every robot's per-tick messages")
        yield Case(f"{what}: message by message", lambda t=t: list(one_by_one(
            t.t_ns, t.tick_ns, t.sensors, t.stepper.state, t.stepper.shapes, None, True)),
                   notes="plant.tick.tick_messages, the reference the core is tested against")
        if mode == "kinematic":
            yield from tick_commands(t, n)


def tick_commands(t, n: int):
    """One tick's commands of ``t``'s ``n`` robots (a twist each, motion noise on: std 0.05
    rad/s, set with the world's sensors' noise in :func:`tick_messages`): filed and run in one
    kernel call by the core (what every host does), and robot by robot in Python (the
    reference the tests compare it with)."""
    import numpy as np
    from bus.controller import Twist
    from plant.core import drive as cd
    from plant.drive import DriveLimiter
    spec, d = t.spec, t.sim.drive
    std = d.std
    cmds = [(name, Twist(0.3, 0.1 * i)) for i, name in enumerate(d.names)]

    def core(t=t, cmds=cmds):
        for name, c in cmds:
            t.drive(name, c)
        t.sim.command_targets()
    lims = [DriveLimiter(r.drive) for r in spec.robots]
    kind, out = np.full(n, cd.TWIST), np.zeros((n, 2))
    vw = np.array([(c.linear, c.angular) for _, c in cmds], float).reshape(n, 2)

    def by_robot(lims=lims, kind=kind, keys=d.keys.copy(), out=out):
        kind[:] = cd.TWIST
        cd.reference_commands(lims, kind, vw, std, keys, 0, spec.control_tick_s, out)
    what = f"a tick's commands, {n} robot{'s' if n > 1 else ''}, motion noise"
    yield Case(f"{what}: the core", core,
               notes="Tick.drive of every robot, then one kernel call (plant_drive_commands)")
    yield Case(f"{what}: robot by robot", by_robot,
               notes="DriveLimiter and the motion noise in Python, the reference")
