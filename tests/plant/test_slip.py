"""Wheel slip (the study's ContactProperties, friction 0.4): encoders overstate the distance.

A hard torque step (no acceleration ramp, 8 rad/s for 1.5 s, as docs/sensors.md quotes) makes
the wheels spin faster than the robot moves: the encoder distance r x (wheel angle)
exceeds the distance really travelled, and the gap shrinks as friction rises.
"""
from __future__ import annotations

import numpy as np
import pytest

from plant.sim import Simulation
from plant.world import load_world

FRICTIONS = (0.4, 0.7, 1.0)


def slip_gap(mu: float, wheel_radps: float = 8.0, seconds: float = 1.5):
    """(encoder distance, true distance) in m after a hard step at wheel/floor friction mu."""
    spec = load_world("empty", [f"materials.rubber.friction={mu}",
                                "materials.floor.friction=1.0",
                                "robots.robot1.drive.max_wheel_accel_radps2=1e6"])
    assert spec.materials["rubber"].friction == mu
    sim = Simulation(spec)
    st0 = sim.state("robot1")
    xy0, enc0 = st0.xyz[:2].copy(), st0.enc_pos.copy()
    r = spec.robot("robot1").drive.wheel_radius_m
    for _ in range(int(round(seconds / spec.control_tick_s))):
        sim.command_wheels("robot1", wheel_radps, wheel_radps)
        sim.step_tick()
    st = sim.state("robot1")
    enc = r * float(np.mean(st.enc_pos - enc0))
    true = float(np.linalg.norm(st.xyz[:2] - xy0))
    return enc, true


@pytest.fixture(scope="module")
def gaps():
    out = {mu: slip_gap(mu) for mu in FRICTIONS}
    for mu, (enc, true) in out.items():
        print(f"friction {mu}: encoder {enc:.4f} m, true {true:.4f} m, gap {enc - true:.4f} m")
    return out


def test_encoders_overstate_distance_under_slip(gaps):
    enc, true = gaps[0.4]
    assert enc == pytest.approx(8.0 * 0.12 * 1.5, rel=0.01)     # the wheels did turn
    assert enc - true > 0.05                                    # ... the robot did not follow
    assert true < enc


def test_gap_shrinks_as_friction_rises(gaps):
    g = [gaps[mu][0] - gaps[mu][1] for mu in FRICTIONS]
    assert g[0] > g[1] > g[2] > 0.0, g
    assert g[0] - g[2] > 0.03, g


def test_gentle_drive_does_not_slip_at_high_friction():
    """With the default acceleration ramp and friction 1.0, encoders match the ground."""
    spec = load_world("empty")
    sim = Simulation(spec)
    for _ in range(100):
        sim.command_wheels("robot1", 2.0, 2.0)
        sim.step_tick()
    st = sim.state("robot1")
    enc = 0.12 * float(np.mean(st.enc_pos))
    assert abs(enc - float(np.linalg.norm(st.xyz[:2]))) < 0.005
