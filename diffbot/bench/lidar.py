"""Suite ``lidar``: the 180-ray lidar sweep in the living room (the C kernel, the scene it
reads, the numpy reference), and 64 robots' sweeps in one call (a batched environment)."""
from __future__ import annotations

from .common import sensor_scene
from .harness import Case, Context, suite

#: the target for one tick's sweep, scene snapshot included: the fastest peer's cost
#: (MuJoCo's mj_multiRay: 59 us)
TARGET_US = 60


@suite("lidar", "one 180-ray lidar sweep in the living room")
def lidar_suite(ctx: Context):
    from plant import lidar
    from plant.raycast import Scene
    spec, sim, st, scene = sensor_scene("living_room", "robot1")
    cfg = spec.robot("robot1").sensors.lidar or lidar.LidarConfig()
    where = (f"{len(scene)} shapes (floor, 4 walls, {len(spec.objects)} objects, the robot), "
             f"{cfg.num_rays} rays over {cfg.fov_rad:.3g} rad, max range {cfg.max_range_m:g} m")
    yield Case("scene snapshot + sweep (a tick's lidar)",
               lambda: lidar.scan(cfg, st.tf, sim.scene(), exclude_owner="robot1"),
               target=f"<= {TARGET_US} µs",
               notes="sim.scene() then lidar.scan (C kernel); peers (quiet machine): "
                     "PyBullet 1.58 ms, MuJoCo 0.059 ms")
    yield Case("sweep 180 rays", lambda: lidar.scan(cfg, st.tf, scene, exclude_owner="robot1"),
               notes=where + "; plant/kernels/lidar.c")
    yield Case("sweep + noise", lambda: lidar.measure(cfg, st.tf, scene, None, "robot1"),
               notes="lidar.measure: sweep, clip, (no) noise: what the plant calls")
    yield Case("scene snapshot", sim.scene,
               notes="Simulation.scene: the robot's parts' poses from DART written into a copy "
                     "of the world's scene built once")
    yield Case("scene snapshot of the solids as objects", lambda: Scene(sim.shapes()),
               notes="Scene(sim.shapes()): a Shape a part first (figures list them so)")
    yield Case("sweep 180 rays, numpy reference",
               lambda: lidar.scan_many_reference(cfg, [st.tf], scene, ["robot1"]),
               notes="lidar.scan_many_reference: what the kernel replaced, the same bits")
    poses = [st.tf] * 64
    names = ["robot1"] * 64
    yield Case("64 sweeps in one call", lambda: lidar.scan_many(cfg, poses, scene, names),
               notes="lidar.scan_many: 64 robots in one world")
    scenes, worlds = [scene] * 64, list(range(64))
    yield Case("64 worlds' sweeps in one call",
               lambda: lidar.scan_worlds(cfg, scenes, poses, names, worlds),
               notes="lidar.scan_worlds: a robot in each of 64 worlds (a batched environment's tick)")
