"""Suite ``lidar``: the 180-ray lidar sweep in the living room."""
from __future__ import annotations

from .common import sensor_scene
from .harness import Case, Context, suite

@suite("lidar", "one 180-ray lidar sweep in the living room")
def lidar_suite(ctx: Context):
    from plant import lidar
    from plant.raycast import Scene
    spec, sim, st, scene = sensor_scene("living_room", "robot1")
    cfg = spec.robot("robot1").sensors.lidar or lidar.LidarConfig()
    where = (f"{len(scene)} shapes (floor, 4 walls, {len(spec.objects)} objects, the robot), "
             f"{cfg.num_rays} rays over {cfg.fov_rad:.3g} rad, max range {cfg.max_range_m:g} m")
    yield Case("sweep 180 rays", lambda: lidar.scan(cfg, st.tf, scene, exclude_owner="robot1"),
               notes=where + "; target <= 0.3 ms")
    yield Case("sweep + noise", lambda: lidar.measure(cfg, st.tf, scene, None, "robot1"),
               notes="lidar.measure: sweep, clip, (no) noise: what the plant calls")
    yield Case("scene snapshot", lambda: Scene(sim.shapes()),
               notes="world shapes -> arrays, once per tick a lidar or camera is due")
