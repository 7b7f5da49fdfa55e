"""Suite ``gym``: the Gymnasium environment diffbot/Avoid-v0 with random actions, on both
transports, one env and ``make_vec`` (async, spawned workers) with 2 and 4 envs: environment
steps per second and simulated seconds per wall second (each step is ``dt`` = 0.1 s, five
20 ms control ticks); in-process, one env also with DART's Dantzig contact solver. The
plant's physics alone is measured beside them, as the bound. Then the batched env
(``vectorization_mode="vector_entry_point"``: N worlds in one process) with N = 1, 16, 64
in the kinematic and the dynamic world, N = 64 on 2 workers, and (kinematic) N = 256 on 2
workers, where a second process pays off on two cores; the swarm's PettingZoo env batched
(``swarm_v0.vector_env``: 1 and 8 worlds of 4 robots) against 8 ``parallel_env`` looped,
in agent steps per second; and 32 kinematic envs through the Stable-Baselines3 adapter
against the batched env alone (the sb3 extra)."""
from __future__ import annotations

import time

from .harness import Metric, Probe, Skip, suite


def _physics_rtf(sim_s: float = 2.0) -> dict:
    from plant.sim import Simulation
    from plant.world import load_world
    spec = load_world("living_room")
    sim = Simulation(spec)
    sim.command_twist("robot1", 0.3, 0.5)
    ticks = int(round(sim_s / spec.control_tick_s))
    t0 = time.perf_counter()
    for _ in range(ticks):
        sim.step_tick()
    return {"real_time_factor": sim_s / (time.perf_counter() - t0)}


def _env_rate(transport: str, num_envs: int, steps: int, mode: str | None = None,
              overrides: tuple[str, ...] = ()) -> dict:
    import gymnasium as gym
    import diffbot.envs  # noqa: F401
    if num_envs == 1:
        env = gym.make("diffbot/Avoid-v0", transport=transport,
                       overrides=((f"world.mode={mode}",) if mode else ()) + overrides)
    else:
        env = gym.make_vec("diffbot/Avoid-v0", num_envs=num_envs, vectorization_mode="async",
                           vector_kwargs={"context": "spawn"}, transport=transport)
    try:
        env.reset(seed=0)
        env.action_space.seed(0)
        dt = 0.1
        # drawn before the clock starts (Box.sample is ~15 us, a tenth of a kinematic step)
        actions = [env.action_space.sample() for _ in range(steps)]
        t0 = time.perf_counter()
        for a in actions:
            _, _, term, trunc, _ = env.step(a)
            if num_envs == 1 and (term or trunc):
                env.reset()
        wall = time.perf_counter() - t0
    finally:
        env.close()
    n = steps * num_envs
    return {"steps_per_s": n / wall, "real_time_factor": n * dt / wall}


def _vec_rate(mode: str, num_envs: int, env_steps: int, workers: int = 1) -> dict:
    import gymnasium as gym
    import numpy as np
    import diffbot.envs  # noqa: F401
    env = gym.make_vec("diffbot/Avoid-v0", num_envs=num_envs,
                       vectorization_mode="vector_entry_point",
                       overrides=(f"world.mode={mode}",), workers=workers)
    try:
        env.reset(seed=0)
        env.action_space.seed(0)
        steps = max(2, env_steps // num_envs)
        actions = [env.action_space.sample() for _ in range(steps)]
        t0, c0 = time.perf_counter(), time.process_time()
        for a in actions:
            env.step(np.asarray(a))
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    finally:
        env.close()
    n = steps * num_envs
    return {"steps_per_s": n / wall, "cpu_steps_per_s": n / cpu, "real_time_factor": n * 0.1 / wall}


def _sb3_rate(num_envs: int, env_steps: int, rounds: int = 3) -> dict:
    """The batched env alone (its default next-step autoreset) and through the SB3 adapter
    (:class:`diffbot.envs.sb3.AvoidVecEnv`: same-step autoreset, one info dict per env,
    episode statistics), kinematic world, the same random actions, in alternate rounds."""
    try:
        from diffbot.envs.sb3 import AvoidVecEnv
    except ImportError:
        raise Skip("stable-baselines3 is not installed (the sb3 extra: make setup)") from None
    import numpy as np
    from diffbot.envs.vector import AvoidVectorEnv
    kw = dict(overrides=("world.mode=kinematic",))
    alone, adapter = AvoidVectorEnv(num_envs, **kw), AvoidVecEnv(num_envs, **kw)
    try:
        alone.reset(seed=0)
        adapter.seed(0)
        adapter.reset()
        steps = max(2, env_steps // num_envs)
        rng = np.random.default_rng(0)
        high = alone.single_action_space.high
        actions = [(rng.uniform(-1, 1, (num_envs, 2)) * high).astype(np.float32)
                   for _ in range(steps)]
        wall, cpu = np.zeros(2), np.zeros(2)     # [alone, adapter]
        for _ in range(rounds):
            t0, c0 = time.perf_counter(), time.process_time()
            for a in actions:
                alone.step(a)
            t1, c1 = time.perf_counter(), time.process_time()
            for a in actions:
                adapter.step_async(a)
                adapter.step_wait()
            wall += (t1 - t0, time.perf_counter() - t1)
            cpu += (c1 - c0, time.process_time() - c1)
    finally:
        alone.close()
        adapter.close()
    n = steps * num_envs * rounds
    return {"alone": n / wall[0], "adapter": n / wall[1], "ratio": cpu[0] / cpu[1]}


#: robots in each world of the swarm's cases
SWARM_ROBOTS = 4


def _swarm_rate(mode: str, num_worlds: int, env_steps: int, looped: bool = False) -> dict:
    """``swarm_v0.vector_env`` with ``num_worlds`` worlds of :data:`SWARM_ROBOTS` Avoid
    robots (``looped``: as many ``parallel_env`` stepped one after the other, the same
    actions), random actions drawn beforehand: agent steps (a live robot's step) per
    second."""
    import numpy as np
    from diffbot.envs import swarm_v0
    kw = dict(n_robots=SWARM_ROBOTS, mode=mode, robot="avoid")
    if looped:
        envs = [swarm_v0.parallel_env(**kw) for _ in range(num_worlds)]
        for i, e in enumerate(envs):
            e.reset(seed=i)
        agents = envs[0].possible_agents
    else:
        venv = swarm_v0.vector_env(num_worlds=num_worlds, **kw)
        venv.reset(seed=0)
        envs, agents = venv.envs, venv.possible_agents
    try:
        steps = max(2, env_steps // num_worlds)
        high = envs[0].action_space(agents[0]).high
        rng = np.random.default_rng(0)
        actions = (rng.uniform(-1, 1, (steps, num_worlds, len(agents), 2))
                   * high).astype(np.float32)
        n = 0
        t0, c0 = time.perf_counter(), time.process_time()
        for act in actions:
            n += sum(len(e.agents) for e in envs)
            if not looped:
                venv.step(act)
                continue
            for e, a in zip(envs, act):
                if not e.agents:
                    e.reset()
                    continue
                e.step({name: a[j] for j, name in enumerate(agents) if name in e.agents})
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    finally:
        for e in envs:
            e.close()
    return {"agent_steps_per_s": n / wall, "cpu_agent_steps_per_s": n / cpu}


#: the batched env's targets at N = 64 on one process (2 cores), env steps/s: training
#: wants many steps per second, and the kinematic world has no physics to pay for (its
#: target keeps the rate its array path reached)
VEC_TARGETS = {"kinematic": ">= 50,000/s", "dynamic": ">= 1,000/s"}
#: and for one env (simulated s per wall s): (transport, world mode) -> target
ONE_ENV_TARGETS = {("inproc", "dynamic"): "target >= 80x", ("inproc", "kinematic"): "target >= 1,000x",
                   ("bus", "dynamic"): "target >= 20x", ("bus", "kinematic"): "target >= 20x"}
#: the one knob of the dynamic world a training user may turn for speed: DART's default
#: Dantzig contact solver instead of the living room's PGS (exact Coulomb limit, which the
#: study's slip results need; Dantzig over-grips ~20 % under hard acceleration: docs/sensors.md,
#: "Friction and contacts")
DANTZIG = ("world.contact_solver=dantzig",)


@suite("gym", "diffbot/Avoid-v0 steps per second, in-process and over the bus, one env "
              "and make_vec with 2 and 4, batched (vector_entry_point) with 1, 16, 64, "
              "64 on 2 workers and (kinematic) 256 on 2 workers, the swarm's vector env with "
              "1 and 8 worlds against its parallel_env looped, and through the SB3 adapter")
def gym_suite(ctx):
    try:
        import gymnasium  # noqa: F401
    except ImportError:
        raise Skip("gymnasium is not installed (the learn extra: make setup)") from None
    steps = 100 if ctx.quick else 400
    repeats = 1 if ctx.quick else 3
    yield Probe("living room physics alone", _physics_rtf, [
        Metric("real_time_factor", "living room physics alone: real-time factor", "x",
               notes="Simulation.step_tick, one robot: the bound for inproc")],
        repeats=repeats, warmup=0)
    for mode in ("kinematic", "dynamic"):
        # env steps a repeat: ~0.2 s of kinematic steps at N = 64 (more for its fast
        # steps, so a repeat is not a handful of steps), a few s of dynamic ones
        env_steps = (256 if ctx.quick else 2560) if mode == "kinematic" else \
            (128 if ctx.quick else 640)
        sizes = ((1, 1), (16, 1), (64, 1), (64, 2)) + (((256, 2),) if mode == "kinematic" else ())
        for n, k in sizes:
            what = f"Avoid-v0 batched {mode}, {n} env" + ("s" if n > 1 else "") + \
                (f", {k} workers" if k > 1 else "")
            yield Probe(what, lambda m=mode, n=n, k=k, e=env_steps: _vec_rate(m, n, e, k), [
                Metric("steps_per_s", f"{what}: env steps per second", "1/s",
                       target=VEC_TARGETS[mode] if (n, k) == (64, 1) else "",
                       notes=("vector_entry_point, one process (lidars on a thread a CPU)"
                              if k == 1 else f"vector_entry_point, workers={k}: {k} processes")
                             + "; random actions"),
                Metric("cpu_steps_per_s", f"{what}: env steps per CPU second", "1/s",
                       notes="this process's CPU time (workers=1: all of it)"),
                Metric("real_time_factor", f"{what}: simulated s per wall s", "x",
                       notes="all envs together, dt = 0.1 s per step")],
                repeats=repeats, warmup=0)
    for mode in ("kinematic", "dynamic"):
        # agent steps a repeat: ~0.5 s of kinematic ones, a few s of dynamic ones
        agent_steps = (256 if ctx.quick else 2560) if mode == "kinematic" else \
            (128 if ctx.quick else 640)
        for w, looped in ((1, False), (8, False), (8, True)):
            what = (f"swarm_v0 {mode}, {SWARM_ROBOTS} robots x {w} world"
                    + ("s" if w > 1 else "") + (", parallel_env looped" if looped
                                                 else ", vector_env"))
            yield Probe(what, lambda m=mode, w=w, x=looped, e=agent_steps // SWARM_ROBOTS:
                        _swarm_rate(m, w, e, x), [
                Metric("agent_steps_per_s", f"{what}: agent steps per second", "1/s",
                       notes=("one parallel_env per world, stepped one after the other"
                              if looped else "swarm_v0.vector_env: the worlds' ticks together")
                             + "; robot='avoid', random actions"),
                Metric("cpu_agent_steps_per_s", f"{what}: agent steps per CPU second", "1/s",
                       notes="this process's CPU time")],
                repeats=repeats, warmup=0)
    what = "Avoid-v0 SB3 adapter, kinematic, 32 envs"
    yield Probe(what, lambda: _sb3_rate(32, 640 if ctx.quick else 3200), [
        Metric("adapter", f"{what}: env steps per second", "1/s",
               notes="diffbot.envs.sb3.AvoidVecEnv step_async/step_wait, random actions"),
        Metric("alone", f"{what}: the batched env alone, env steps per second", "1/s",
               notes="AvoidVectorEnv.step, the same actions, rounds alternating"),
        Metric("ratio", f"{what}: adapter / batched env alone", "x",
               notes="steps per CPU second of this process (one process: all of it), "
                     "which a busy machine disturbs less than wall time; target >= 0.8")], repeats=repeats, warmup=0)
    for transport in ("inproc", "bus"):
        rows = ((1, None, ()), (1, "kinematic", ()), (2, None, ()), (4, None, ()))
        if transport == "inproc":
            rows = rows[:1] + ((1, None, DANTZIG),) + rows[1:]
        for n, mode, extra in rows:
            what = f"Avoid-v0 {transport}, " + ("1 env" if n == 1 else f"make_vec {n} async") \
                + (f", {mode} world" if mode else "") + (", Dantzig solver" if extra else "")
            target = ONE_ENV_TARGETS.get((transport, mode or "dynamic")) \
                if n == 1 and not extra else None
            yield Probe(what, lambda t=transport, n=n, m=mode, x=extra:
                        _env_rate(t, n, steps, m, x), [
                Metric("steps_per_s", f"{what}: env steps per second", "1/s",
                       notes="all envs together; random actions, drawn beforehand"),
                Metric("real_time_factor", f"{what}: simulated s per wall s", "x",
                       notes="dt = 0.1 s per step"
                             + ("" if mode else "; the living room's dynamic world")
                             + (f" with overrides={extra!r} (the study's worlds keep PGS)"
                                if extra else "")
                             + (f"; {target}" if target else ""))],
                repeats=repeats, warmup=0)
