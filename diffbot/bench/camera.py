"""Suite ``camera``: pinhole camera frames in the follow world."""
from __future__ import annotations

from .common import sensor_scene
from .harness import Case, Context, suite

#: the peers' figures for a frame (quiet machine; neither peer is installable here)
PEERS = {(160, 120): ("6.5 ms", "2.08 ms"), (320, 240): ("20.8 ms", "3.70 ms")}


@suite("camera", "pinhole camera frames in the living room (follow world)")
def camera_suite(ctx: Context):
    from dataclasses import replace

    from plant import camera as cam
    from plant.camera_reference import render_full_reference
    from plant.noise import NoiseModel, stream_key, webots_camera
    spec, sim, st, scene = sensor_scene("living_room_follow", "follower")
    base = spec.robot("follower").sensors.camera or cam.CameraConfig()
    pose = cam.camera_pose(base, st.tf)
    where = f"{len(scene)} shapes, the leader and its green ball in view"
    noise = NoiseModel(webots_camera(10.0 / 255.0), stream_key(0, "bench", "camera"))
    # the targets (render and noise): 160x120 <= 0.7 ms, 320x240 <= 1.4 ms
    for (w, h), target in (((160, 120), 0.7e-3), ((320, 240), 1.4e-3)):
        cfg = replace(base, width=w, height=h)
        cam.render(cfg, pose, scene, exclude_owner="follower")    # rays cached per size
        yield Case(f"render {w}x{h} + noise", lambda cfg=cfg: noise.apply(
            cam.render(cfg, pose, scene, "follower"), 0), target=f"<= {target * 1e3:g} ms",
            notes=f"noise std 10 (follow's), drawn in the call (plant/kernels/noise.c); "
                  f"peers (frame alone, quiet machine): PyBullet {PEERS[(w, h)][0]}, "
                  f"MuJoCo {PEERS[(w, h)][1]}")
        yield Case(f"render {w}x{h}", lambda cfg=cfg: cam.render(cfg, pose, scene, "follower"),
                   notes=f"{where}; plant/kernels/camera.c")
    cfg = replace(base, width=160, height=120)
    yield Case("render 160x120, numpy reference",
               lambda: render_full_reference(cfg, pose, scene, "follower"),
               notes="plant.camera_reference: what the kernel replaced")
    dist = replace(base, k1=-0.25, k2=0.08, p1=0.001, p2=-0.001)
    cam.render(dist, pose, scene, exclude_owner="follower")
    yield Case("render 160x120, lens distortion", lambda: cam.render(dist, pose, scene, "follower"),
               notes="k1 -0.25, k2 0.08, p1 0.001, p2 -0.001 (per-pixel rays, tiled culling)")
    yield Case("third-person 640x480", lambda: cam.third_person((-2.5, -2.0, 2.2), (0, 0, 0), scene),
               notes="figure 1's kind of picture, from above the room")
