"""The plant's core, laid out as MuJoCo's is: a :class:`~plant.core.model.Model` (what does
not change during a run: the robots' drive parameters, their sensors' layout, rates and
noise laws, the messages' layouts), its :class:`~plant.core.data.Data` (what a tick changes,
as arrays shaped (worlds, robots, ...)), and :mod:`plant.core.step` (one call a tick for every
robot: the state read into the arrays, every robot's per-tick messages drawn and written in
one kernel call (plant/kernels/sense.c, :mod:`plant.core.outgoing`), the lidars cast in one
kernel call per configuration), and the front half of a tick: every robot's command
through its drive limiter and motion noise in one kernel call (:mod:`plant.core.drive`).
A batched environment's worlds are a model and data too, ticked by plant/kernels/ticks.c
(:class:`diffbot.envs.kinbatch.ArrayTicks`)."""
from .data import Data
from .drive import WorldDrive, world_drive
from .model import Model
from .step import UNENCODED, Settled, observe, poses, reads_truth, sense, sense_read

__all__ = ["UNENCODED", "Data", "Model", "Settled", "WorldDrive", "observe", "poses", "reads_truth",
           "sense", "sense_read", "world_drive"]
