"""Suite ``camera``: pinhole camera frames in the follow world."""
from __future__ import annotations

from .common import sensor_scene
from .harness import Case, Context, suite

@suite("camera", "pinhole camera frames in the living room (follow world)")
def camera_suite(ctx: Context):
    from dataclasses import replace

    from plant import camera as cam
    spec, sim, st, scene = sensor_scene("living_room_follow", "follower")
    base = spec.robot("follower").sensors.camera or cam.CameraConfig()
    pose = cam.camera_pose(base, st.tf)
    where = f"{len(scene)} shapes, the leader and its green ball in view"
    for (w, h), target in (((160, 120), 3e-3), ((320, 240), 10e-3)):
        cfg = replace(base, width=w, height=h)
        cam.render(cfg, pose, scene, exclude_owner="follower")    # rays cached per size
        yield Case(f"render {w}x{h}", lambda cfg=cfg: cam.render(cfg, pose, scene, "follower"),
                   notes=f"{where}; target <= {target * 1e3:g} ms")
    dist = replace(base, k1=-0.25, k2=0.08, p1=0.001, p2=-0.001)
    cam.render(dist, pose, scene, exclude_owner="follower")
    yield Case("render 160x120, lens distortion", lambda: cam.render(dist, pose, scene, "follower"),
               notes="k1 -0.25, k2 0.08, p1 0.001, p2 -0.001 (per-pixel rays, tiled culling)")
    yield Case("third-person 640x480", lambda: cam.third_person((-2.5, -2.0, 2.2), (0, 0, 0), scene),
               notes="figure 1's kind of picture, from above the room")
