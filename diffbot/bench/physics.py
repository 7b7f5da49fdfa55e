"""Suite ``physics``: one DART physics step, a control tick, a world build."""
from __future__ import annotations

from .harness import Case, Context, suite

@suite("physics", "one DART physics step and one control tick of the robot")
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
        detector = type(w.getConstraintSolver().getCollisionDetector()).__name__
        n = len(sim.objects)
        what = (f"{n} static object{'' if n == 1 else 's'}, {detector}, dt {spec.physics_step_s * 1e3:g} ms,"
                f" robot spinning in place (wheels -/+1 rad/s)")

        def step(number, robots=robots, w=w):
            it = range(number)
            t0 = perf_counter()
            for _ in it:
                for r in robots:
                    r.apply()
                w.step()
            return perf_counter() - t0
        room = world == "living_room"
        yield Case(f"{world}: physics step", step, timer=True, notes=what + (
            "; peers (quiet machine, 2 ms step): PyBullet 125 us, MuJoCo 9 us" if room else ""))
        yield Case(f"{world}: control tick ({spec.substeps} steps)", sim.step_tick,
                   target="<= 150 µs" if room else "", notes="Simulation.step_tick()")
        yield Case(f"{world}: build world", lambda spec=spec: Simulation(spec),
                   notes="Simulation(spec): what a reset costs")
