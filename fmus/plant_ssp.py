"""The study's square as an SSP system of FMUs: the plant FMU and the odometry FMU.

``write_ssp`` packs ``SystemStructure.ssd`` (SSP 1.0) with the two FMUs: the plant's
``<robot>.wheel_rate_left/right`` (an encoder reading's increment over the last tick /
tick, what the bus feeds the odometry FMU) connected to the odometry FMU's
``omega_left/right``. The square-path controller is the master's own logic
(:func:`run_square`, one call per 20 ms step): it reads the odometry FMU's pose and sets the
plant's ``v`` and ``w``, as ``diffbot run square`` does over the bus. Masters: libcosim
(libcosimpy, FMI 2 FMUs) and Ecos (ecospy, FMI 2 or 3).

``diffbot fmu export-ssp --out square.ssp [--fmi 2|3]`` writes the whole system, the
controller an FMU too (fmus/models/square): plant FMU -> odometry FMU -> controller FMU ->
plant FMU, which an SSP master runs from its own command line, e.g. Ecos's
``ecos simulate --path square.ssp --stopTime 60 --stepSize 0.02`` (docs/fmu.md).

Co-simulation timing: both masters step the FMUs side by side (Jacobi), so the odometry
FMU's output at t_k+1 is the pose through the encoder readings of t_k (the bus's
``odom`` stamped t_k), and the controller's command of t_k acts from t_k on: the bus's
pipelined coupling, one tick of delay, as the square scenario runs by default.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import zipfile
from pathlib import Path
from typing import Callable

_SSD = """<?xml version="1.0" encoding="UTF-8"?>
<ssd:SystemStructureDescription xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription"
    xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon" version="1.0" name="square">
  <ssd:System name="square" description="diffbot-cosim: the study's square, plant FMU + odometry FMU">
    <ssd:Elements>
      <ssd:Component name="plant" source="resources/{plant}">
        <ssd:Connectors>
{plant_connectors}
        </ssd:Connectors>
      </ssd:Component>
      <ssd:Component name="odometry" source="resources/{odometry}">
        <ssd:Connectors>
{odometry_connectors}
        </ssd:Connectors>
      </ssd:Component>{controller}
    </ssd:Elements>
    <ssd:Connections>
      <ssd:Connection startElement="plant" startConnector="{robot}.wheel_rate_left" endElement="odometry" endConnector="omega_left"/>
      <ssd:Connection startElement="plant" startConnector="{robot}.wheel_rate_right" endElement="odometry" endConnector="omega_right"/>{controller_connections}
    </ssd:Connections>
  </ssd:System>
  <ssd:DefaultExperiment startTime="0" stopTime="{stop}"/>
</ssd:SystemStructureDescription>
"""


def _connectors(names: list[tuple[str, str]]) -> str:
    return "\n".join(f'          <ssd:Connector name="{n}" kind="{k}"><ssc:Real/></ssd:Connector>'
                     for n, k in names)


_CONTROLLER = """
      <ssd:Component name="controller" source="resources/{controller}">
        <ssd:Connectors>
{connectors}
        </ssd:Connectors>
      </ssd:Component>"""

_CONTROLLER_CONNECTIONS = "".join(
    f'\n      <ssd:Connection startElement="{a}" startConnector="{b}" endElement="{c}" '
    f'endConnector="{d}"/>' for a, b, c, d in (
        ("odometry", "x", "controller", "x"), ("odometry", "y", "controller", "y"),
        ("odometry", "theta", "controller", "theta"),
        ("controller", "v", "plant", "{robot}.v"), ("controller", "w", "plant", "{robot}.w")))


def write_ssp(out: str | os.PathLike, plant_fmu: str | os.PathLike,
              odometry_fmu: str | os.PathLike, robot: str = "robot1", stop_s: float = 120.0,
              controller_fmu: str | os.PathLike | None = None) -> Path:
    """An .ssp archive (a zip: SystemStructure.ssd, resources/*.fmu) of the square.
    ``controller_fmu``: the square-path controller FMU (fmus/models/square), connected from
    the odometry FMU's pose to the plant's v, w: a system any SSP master runs on its own;
    without it the master's own logic drives the plant (:func:`run_square`)."""
    plant, odometry = Path(plant_fmu), Path(odometry_fmu)
    controller = Path(controller_fmu) if controller_fmu else None
    ssd = _SSD.format(
        plant=plant.name, odometry=odometry.name, robot=robot, stop=stop_s,
        controller=_CONTROLLER.format(controller=controller.name, connectors=_connectors(
            [("x", "input"), ("y", "input"), ("theta", "input"), ("v", "output"),
             ("w", "output"), ("done", "output")])) if controller else "",
        controller_connections=_CONTROLLER_CONNECTIONS.replace("{robot}", robot)
        if controller else "",
        plant_connectors=_connectors([(f"{robot}.v", "input"), (f"{robot}.w", "input"),
                                      (f"{robot}.wheel_rate_left", "output"),
                                      (f"{robot}.wheel_rate_right", "output"),
                                      (f"{robot}.x", "output"), (f"{robot}.y", "output"),
                                      (f"{robot}.yaw", "output")]),
        odometry_connectors=_connectors([("omega_left", "input"), ("omega_right", "input"),
                                         ("x", "output"), ("y", "output"),
                                         ("theta", "output")]))
    target = Path(out)
    target.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(target, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("SystemStructure.ssd", ssd)
        zf.write(plant, f"resources/{plant.name}")
        zf.write(odometry, f"resources/{odometry.name}")
        if controller:
            zf.write(controller, f"resources/{controller.name}")
    return target


def to_world(start: tuple[float, float, float], x: float, y: float, th: float):
    """A pose of the odometry frame (which starts at the robot's start pose) in the world."""
    x0, y0, th0 = start
    c, s = math.cos(th0), math.sin(th0)
    return x0 + c * x - s * y, y0 + s * x + c * y, th0 + th


class _Libcosim:
    def __init__(self, ssp: str, step_s: float, robot: str) -> None:
        from libcosimpy.CosimExecution import CosimExecution
        from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
        from libcosimpy.CosimManipulator import CosimManipulator
        from libcosimpy.CosimObserver import CosimObserver
        log_output_level(CosimLogLevel.WARNING)
        self.ex = CosimExecution.from_ssp_file(str(ssp), step_size=int(round(step_s * 1e9)))
        self.plant = self.ex.slave_index_from_instance_name("plant")
        self.odo = self.ex.slave_index_from_instance_name("odometry")
        self.vr = {(s.index, v.name.decode()): v.reference for s in self.ex.slave_infos()
                   for v in self.ex.slave_variables(s.index)}
        self.manipulator = CosimManipulator.create_override()
        self.ex.add_manipulator(self.manipulator)
        self.observer = CosimObserver.create_last_value()
        self.ex.add_observer(self.observer)
        self.robot = robot

    def start(self) -> int:
        """Initialise; the ticks gone (libcosim initialises in its first step: the robot
        stands still through it)."""
        self.step()
        return 1

    def get(self, slave: str, names: list[str]) -> list[float]:
        index = self.plant if slave == "plant" else self.odo
        return list(self.observer.last_real_values(index, [self.vr[(index, n)] for n in names]))

    def command(self, v: float, w: float) -> None:
        self.manipulator.slave_real_values(
            self.plant, [self.vr[(self.plant, f"{self.robot}.{k}")] for k in "vw"], [v, w])

    def step(self) -> None:
        if not self.ex.step(1):
            raise RuntimeError("libcosim: a step failed")

    def close(self) -> None:
        pass


class _Ecos:
    def __init__(self, ssp: str, step_s: float, robot: str) -> None:
        from ecospy import EcosSimulation
        self.sim = EcosSimulation(ssp_path=str(ssp), step_size=step_s)
        self.robot = robot

    def start(self) -> int:
        self.sim.init()
        return 0

    def get(self, slave: str, names: list[str]) -> list[float]:
        return [self.sim.get_real(f"{slave}::{n}") for n in names]

    def command(self, v: float, w: float) -> None:
        self.sim.set_real(f"plant::{self.robot}.v", v)
        self.sim.set_real(f"plant::{self.robot}.w", w)

    def step(self) -> None:
        self.sim.step(1)

    def close(self) -> None:
        self.sim.terminate()
        self.sim.free()


MASTERS = {"libcosim": _Libcosim, "ecos": _Ecos}


def run_square(ssp: str | os.PathLike, controller_step: Callable[[float, tuple], tuple],
               start: tuple[float, float, float], master: str = "libcosim",
               robot: str = "robot1", step_s: float = 0.02, max_s: float = 300.0,
               done: Callable[[], bool] = lambda: False) -> dict:
    """Run the SSP's system under ``master``, the controller as the master's logic:
    ``controller_step(t, (x, y, yaw))`` of the odometry pose in the odometry frame returns
    ``(v, w)``; the run ends when ``done()`` (the last command then is zero). Returns the
    odometry error (world frame, odometry through the readings of t_k against the true pose
    at t_k) at the end and at its worst, the path length and the run's duration."""
    m = MASTERS[master](ssp, step_s, robot)
    truth, errors, length = [], [], 0.0
    try:
        k0 = k = m.start()
        t = k * step_s
        while t < max_s:
            odom = m.get("odometry", ["x", "y", "theta"])
            true = m.get("plant", [f"{robot}.x", f"{robot}.y"])
            if truth:
                length += math.hypot(true[0] - truth[-1][0], true[1] - truth[-1][1])
            if k > k0:
                # the odometry output at t_k integrates the readings through t_k-1
                ox, oy, _ = to_world(start, *odom)
                errors.append(math.hypot(ox - truth[-1][0], oy - truth[-1][1]))
            truth.append(true)
            if done():
                break
            v, w = controller_step(t, tuple(odom))
            m.command(v, w)
            m.step()
            k += 1
            t = k * step_s
    finally:
        m.close()
    return {"master": master, "final_odom_error_m": errors[-1] if errors else math.nan,
            "max_odom_error_m": max(errors, default=math.nan), "path_length_m": length,
            "duration_s": t}


def export_ssp(out: str | os.PathLike, fmi: int = 2, world: str = "living_room",
               robot: str = "robot1", stop_s: float = 60.0, overrides=()) -> Path:
    """The square as a self-contained SSP (plant, odometry and controller FMUs of FMI
    ``fmi``): the plant exported here, the odometry and controller FMUs built from their
    sources (fmus/build.py) into a temporary folder."""
    from .build import build_fmu
    from .plant_export import export_plant
    with tempfile.TemporaryDirectory(prefix="square_ssp_") as tmp:
        # (FMI 3: the scan as scalars, which a master's CSV of every output can hold)
        plant = export_plant(Path(tmp, f"plant_fmi{fmi}.fmu"), world, [robot], fmi, overrides,
                             scan_scalars=True)
        return write_ssp(out, plant, build_fmu(fmi, tmp), robot, stop_s,
                         build_fmu(fmi, tmp, "square"))


def main(argv: list[str] | None = None, prog: str = "diffbot fmu export-ssp") -> int:
    p = argparse.ArgumentParser(prog=prog, description="Write the study's square as an SSP "
                                "system: the plant FMU, the odometry FMU and the square-path "
                                "controller FMU, connected (any SSP master runs it alone).")
    p.add_argument("--fmi", type=int, choices=(2, 3), default=2, help="FMI version of the "
                   "three FMUs (default 2: libcosim takes FMI 2 only)")
    p.add_argument("--world", default="living_room", help="world file or shipped name")
    p.add_argument("--robot", default="robot1", help="the robot that drives the square")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="world file override (repeatable)")
    p.add_argument("--stop", type=float, default=60.0, help="the SSP's default stop time, s")
    p.add_argument("--out", required=True, help="the .ssp file to write")
    args = p.parse_args(argv)
    from plant.world import WorldError
    from .build import FmuBuildError
    try:
        path = export_ssp(args.out, args.fmi, args.world, args.robot, args.stop, args.overrides)
    except (FmuBuildError, WorldError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2 if isinstance(e, WorldError) else 1
    print(path)
    return 0
