"""What the launcher's observer subscribes to: a run without figures leaves out the keys
its analysis reads only to draw them (the follow's camera images: 57 kB a frame the plant
would otherwise put on the bus and the launcher keep)."""
from __future__ import annotations

from types import SimpleNamespace

from bus.keys import Keys
from diffbot.analysis.follow import FollowAnalysis
from diffbot.analysis.runs import SquareAnalysis
from diffbot.launch.launcher import analysis_keys
from plant.world import load_world


def test_the_follows_camera_images_are_observed_only_when_figures_are_drawn():
    keys, world = Keys(), load_world("living_room_follow")
    image = keys.topic("follower", "camera/image_raw")
    drawn = analysis_keys(FollowAnalysis, keys, None, world, draw=True)
    bare = analysis_keys(FollowAnalysis, keys, None, world, draw=False)
    assert image in drawn and image not in bare
    assert set(drawn) - set(bare) == {image}          # the data the analysis writes stays
    spec, square = SimpleNamespace(robot="robot1"), load_world("living_room")
    assert analysis_keys(SquareAnalysis, keys, spec, square, draw=False) == \
        analysis_keys(SquareAnalysis, keys, spec, square, draw=True)   # (it names none)
