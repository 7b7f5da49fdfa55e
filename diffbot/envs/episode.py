"""What reproduces an environment's episode on a plant (:class:`Episode`): its reset info
``info["plant"]``, and the command-line values a plant and a policy node take from it
(docs/learning.md, "Deploying by episode")."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: episode seeds are drawn in [0, SEED_SPAN)
SEED_SPAN = 2**31


def next_seed(rng: np.random.Generator) -> int:
    """The seed of an env's next episode when ``reset()`` is given none: drawn from the
    env's generator, which is then seeded with it, so every episode has a reset seed (its
    ``info["plant"].seed``) and ``reset(seed=that)`` plays it again; the seeds still follow
    from the first one given."""
    return int(rng.integers(0, SEED_SPAN))


@dataclass(eq=True)
class Episode:
    """What a plant needs to play an episode: ``info["plant"]`` of every reset and step.
    Values are kept as the environment used them (Python floats); every text form here
    writes them with ``repr``, which reads back to the same bits (a pose written with 16
    significant digits can be one unit in the last place off, and a path that starts one
    ulp apart drifts apart, 1e-16 m at once growing to 1e-14 m and beyond)."""
    plant_seed: int                                   # the plant's noise seed (--seed)
    poses: dict[str, tuple[float, float, float]]      # start x, y, yaw in world (m, rad)
    goals: dict[str, tuple[float, float]]             # x, y in world (m)
    world: str = "living_room"
    overrides: tuple[str, ...] = ()                   # the env's world overrides (--set)
    disabled: tuple[str, ...] = ("camera",)           # sensors the env leaves off (--disable)
    seed: int | None = None                           # the reset seed (reset(seed=...) replays)
    world_toml: str = ""                              # a generated world's file text (world: its name)

    @property
    def robot(self) -> str:
        if len(self.poses) != 1:
            raise ValueError(f"an episode of {len(self.poses)} robots: name one")
        return next(iter(self.poses))

    @property
    def start(self) -> tuple[float, float, float]:
        return self.poses[self.robot]

    @property
    def goal(self) -> tuple[float, float]:
        return self.goals[self.robot]

    def world_args(self) -> list[str]:
        """``--set`` arguments: the start poses, then the env's overrides."""
        out = []
        for name, (x, y, yaw) in self.poses.items():
            out += ["--set", f"robots.{name}.pose=[{x!r}, {y!r}, {yaw!r}]"]
        for o in self.overrides:
            out += ["--set", o]
        return out

    def write_world(self, directory: str) -> str:
        """The world's file: a generated world's text written to ``directory/<world>.toml``
        (its path returned); a world file's name or path as it is."""
        if not self.world_toml:
            return self.world
        import os
        path = os.path.join(directory, f"{self.world}.toml")
        with open(path, "w") as f:
            f.write(self.world_toml)
        return path

    def plant_args(self, world: str | None = None) -> list[str]:
        """``diffbot plant`` arguments that build this episode's world, lockstep with
        sequential coupling (the environment's coupling: a command acts at once); a
        generated world's: with ``world``, the path :meth:`write_world` gave."""
        if world is None:
            if self.world_toml:
                raise ValueError(f"the episode's world ({self.world}) is generated: "
                                 "plant_args(ep.write_world(directory))")
            world = self.world
        out = ["--world", world, "--mode", "lockstep", "--coupling", "sequential",
               "--seed", str(self.plant_seed), *self.world_args()]
        if self.disabled:
            out += ["--disable", ",".join(self.disabled)]
        return out

    def goal_arg(self, robot: str | None = None) -> str:
        gx, gy = self.goals[robot or self.robot]
        return f"--goal={gx!r},{gy!r}"
