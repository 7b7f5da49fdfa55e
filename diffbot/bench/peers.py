"""Suite ``peers``: MuJoCo on the same living room, in the same window as this machine's
``physics`` and ``lidar`` suites (the targets are the fastest peer's figures of one
window; a figure from another machine or another hour says little on a shared VM).

The room is rebuilt from the world file (``plant/worlds/living_room.toml``): the floor, the
walls, every static object as a MuJoCo geom; the robot as this project builds it for DART
(``plant/robot.py``): a chassis box, two sphere wheels on hinges driven by velocity
actuators, a frictionless sphere caster, the world file's masses; 2 ms steps. Cases: one
physics step and a 10-step control tick with the robot spinning in place (wheels -/+1
rad/s, as ``physics``), and a 180-ray lidar sweep with ``mj_multiRay`` (one C call for all
rays, as ``lidar``'s kernel) from the lidar's mount on the robot; the robot's camera frame
at 160x120 and 320x240 (``mujoco.Renderer``, EGL: no peer case without it).

MuJoCo is no dependency of this project: ``pip install mujoco`` into the venv to run it
(the suite skips without it)."""
from __future__ import annotations

import math

import numpy as np

from .harness import Case, Context, Skip, suite

CHASSIS = (0.40, 0.26, 0.10)          # m, as plant/footprint.py's box
CASTER_R = 0.04
#: the camera's vertical field of view: plant.camera.CameraConfig's default, hfov 1 rad at 4:3
CAM_FOVY_DEG = math.degrees(2 * math.atan(math.tan(0.5) * 3 / 4))


def room_mjcf(spec) -> str:
    """The world's static scene and its first robot as an MJCF document."""
    fx, fy = (v / 2 for v in spec.floor_size_m)
    g = [f'<geom type="plane" size="{fx} {fy} 0.1" friction="1 0.005 0.0001"/>']
    h, t = spec.wall_height_m, spec.wall_thickness_m
    if h > 0:
        for x, y, sx, sy in ((0, fy + t / 2, fx + t, t / 2), (0, -fy - t / 2, fx + t, t / 2),
                             (fx + t / 2, 0, t / 2, fy), (-fx - t / 2, 0, t / 2, fy)):
            g.append(f'<geom type="box" pos="{x} {y} {h / 2}" size="{sx} {sy} {h / 2}"/>')
    for o in spec.objects:
        if not o.static:
            continue
        x, y, z, yaw = o.pose
        if o.shape == "box":
            size = " ".join(str(v / 2) for v in o.size)
        elif o.shape == "cylinder":
            size = f"{o.size[0]} {o.size[1] / 2}"
        else:
            size = f"{o.size[0]}"
        g.append(f'<geom type="{o.shape}" pos="{x} {y} {z}" euler="0 0 {yaw}" size="{size}"/>')
    r = spec.robots[0]
    d = r.drive
    x, y, yaw = r.pose
    rw, sep = d.wheel_radius_m, d.wheel_separation_m
    cz = rw                                   # chassis centre at the axle's height
    robot = f"""
    <body name="robot" pos="{x} {y} {cz}" euler="0 0 {yaw}">
      <freejoint/>
      <geom type="box" size="{CHASSIS[0] / 2} {CHASSIS[1] / 2} {CHASSIS[2] / 2}"
            mass="{r.chassis_mass_kg}" contype="0" conaffinity="0"/>
      <camera name="cam" pos="0.18 0 0.15" xyaxes="0 -1 0 0 0 1" fovy="{CAM_FOVY_DEG}"/>
      <geom name="caster" type="sphere" size="{CASTER_R}" pos="-0.15 0 {CASTER_R - cz}"
            friction="0 0 0" mass="0.1"/>
      <body name="wl" pos="0 {sep / 2} 0"><joint name="jl" axis="0 1 0"/>
        <geom type="sphere" size="{rw}" mass="{r.wheel_mass_kg}" friction="1 0.005 0.0001"/></body>
      <body name="wr" pos="0 {-sep / 2} 0"><joint name="jr" axis="0 1 0"/>
        <geom type="sphere" size="{rw}" mass="{r.wheel_mass_kg}" friction="1 0.005 0.0001"/></body>
    </body>"""
    tau = d.max_wheel_torque_nm
    return f"""<mujoco model="{spec.name}">
  <compiler angle="radian"/>
  <option timestep="{spec.physics_step_s}"/>
  <worldbody>
    {chr(10).join('    ' + x for x in g)}
    {robot}
  </worldbody>
  <actuator>
    <velocity joint="jl" kv="20" forcerange="{-tau} {tau}"/>
    <velocity joint="jr" kv="20" forcerange="{-tau} {tau}"/>
  </actuator>
</mujoco>"""


@suite("peers", "MuJoCo on the same living room in this window: physics step, control tick, "
                "180-ray lidar (needs `pip install mujoco`)")
def peers_suite(ctx: Context):
    import os
    os.environ.setdefault("MUJOCO_GL", "egl")      # (read when mujoco is imported)
    try:
        import mujoco
    except ImportError:
        raise Skip("mujoco is not installed (no dependency: pip install mujoco)") from None
    from plant.world import load_world
    spec = load_world("living_room")
    model = mujoco.MjModel.from_xml_string(room_mjcf(spec))
    data = mujoco.MjData(model)
    data.ctrl[:] = (1.0, -1.0)                # spinning in place, as the physics suite
    for _ in range(200):
        mujoco.mj_step(model, data)
    what = (f"MuJoCo {mujoco.__version__}, {model.ngeom} geoms, dt "
            f"{spec.physics_step_s * 1e3:g} ms, robot spinning in place")
    substeps = spec.substeps

    def tick():
        for _ in range(substeps):
            mujoco.mj_step(model, data)
    yield Case("living_room: physics step (MuJoCo)", lambda: mujoco.mj_step(model, data),
               notes=what + "; compare physics: living_room: physics step")
    yield Case(f"living_room: control tick ({substeps} steps, MuJoCo)", tick,
               notes="compare physics: living_room: control tick")
    lid = spec.robots[0].sensors.lidar
    body = model.body("robot").id
    n = lid.num_rays
    ang = lid.angle_min + lid.angle_increment * np.arange(n)
    local = np.stack([np.cos(ang), np.sin(ang), np.zeros(n)], axis=1)
    geomid = np.zeros(n, np.int32)
    dist = np.zeros(n)

    def sweep():
        rot = data.xmat[body].reshape(3, 3)
        pnt = data.xpos[body] + rot @ np.array([0.0, 0.0, 0.1])
        vec = (local @ rot.T).reshape(-1)
        mujoco.mj_multiRay(model, data, pnt, vec, None, True, body, geomid, dist, None, n,
                           lid.max_range_m)
        return dist
    sweep()
    hits = int((geomid >= 0).sum())
    yield Case("180-ray lidar sweep (MuJoCo mj_multiRay)", sweep,
               notes=f"{hits} of {n} rays hit, fov {math.degrees(lid.fov_rad):.0f} deg; "
                     "compare lidar: scene snapshot + sweep")
    for w, h in ((160, 120), (320, 240)):
        try:
            renderer = mujoco.Renderer(model, h, w)
        except Exception as exc:                  # no OpenGL: no camera peer
            yield Case(f"camera {w}x{h} (MuJoCo)", lambda: None,
                       notes=f"not measured: MuJoCo cannot render here ({exc})")
            continue

        def frame(r=renderer):
            r.update_scene(data, camera="cam")
            return r.render()
        frame()
        yield Case(f"camera {w}x{h} (MuJoCo Renderer, {os.environ['MUJOCO_GL']})", frame,
                   notes="update_scene + render, no noise; compare camera: render "
                         f"{w}x{h}")
