"""What the environments promise their learners, checked against references of the test's
own rather than against each other: the footprint geometry (``diffbot/envs/geometry.py``)
against a brute-force distance to points sampled on every obstacle's outline; Avoid's
reward (progress - 0.005 per step, +1 within 0.3 m of the goal, -1 on contact, table tops
excluded) and its truncation at 300 steps; Follow's band reward, its 750 steps and its
``rgb_array`` render."""
from __future__ import annotations

import math

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
import diffbot.envs  # noqa: E402,F401
from plant.footprint import (CHASSIS_CENTRE_X_M, CONTACT_MARGIN_M,  # noqa: E402
                             FOOTPRINT_RADIUS_M)
from diffbot.envs.geometry import Footprints  # noqa: E402
from plant.world import load_world  # noqa: E402

LIVING = load_world("living_room", [])
TOUCH = FOOTPRINT_RADIUS_M + CONTACT_MARGIN_M        # 0.25 m: a footprint centre this close
ROBOT_TOP_M = 0.32                                   # objects whose underside is higher pass over


def _bottom(o) -> float:
    z = o.pose[2]
    return z - {"box": o.size[2] / 2 if o.shape == "box" else 0,
                "cylinder": o.size[1] / 2 if o.shape == "cylinder" else 0,
                "sphere": o.size[0]}[o.shape]


def _outline(o, step=0.002) -> np.ndarray:
    """Points on the outline of an object's footprint on the floor (its top view)."""
    x, y = o.pose[:2]
    if o.shape == "box":
        hx, hy = o.size[0] / 2, o.size[1] / 2
        c, s = math.cos(o.pose[3]), math.sin(o.pose[3])
        edge = []
        for (ax, ay), (bx, by) in [((-hx, -hy), (hx, -hy)), ((hx, -hy), (hx, hy)),
                                   ((hx, hy), (-hx, hy)), ((-hx, hy), (-hx, -hy))]:
            n = max(2, int(math.hypot(bx - ax, by - ay) / step))
            f = np.linspace(0, 1, n)[:, None]
            edge.append(np.hstack([ax + f * (bx - ax), ay + f * (by - ay)]))
        e = np.vstack(edge)
        return np.stack([x + c * e[:, 0] - s * e[:, 1], y + s * e[:, 0] + c * e[:, 1]], 1)
    r = o.size[0]
    a = np.linspace(0, 2 * math.pi, max(16, int(2 * math.pi * r / step)))
    return np.stack([x + r * np.cos(a), y + r * np.sin(a)], 1)


def _inside(o, p) -> bool:
    d = np.asarray(p, float) - o.pose[:2]
    if o.shape == "box":
        c, s = math.cos(o.pose[3]), math.sin(o.pose[3])
        lx, ly = c * d[0] + s * d[1], -s * d[0] + c * d[1]
        return abs(lx) <= o.size[0] / 2 and abs(ly) <= o.size[1] / 2
    return math.hypot(*d) <= o.size[0]


def reference_clearance(spec, p) -> float:
    """Distance from ``p`` to the nearest wall or object reaching below the robot's top."""
    hx, hy = spec.floor_size_m[0] / 2, spec.floor_size_m[1] / 2
    best = min(hx - abs(p[0]), hy - abs(p[1]))
    for o in spec.objects:
        if not o.static or _bottom(o) >= ROBOT_TOP_M:
            continue
        if _inside(o, p):
            return 0.0
        best = min(best, float(np.min(np.hypot(*(_outline(o) - p).T))))
    return best


def test_clearance_matches_a_brute_force_reference_in_the_living_room():
    geo = Footprints(LIVING)
    rng = np.random.default_rng(1)
    half = np.asarray(LIVING.floor_size_m) / 2
    pts = rng.uniform(-half + 0.05, half - 0.05, (150, 2))
    pts = np.vstack([pts, [[1.7, 1.55], [2.0, -1.75], [-2.5, 0.3], [2.2, -0.85]]])
    for p in pts:
        assert geo.clearance(p) == pytest.approx(reference_clearance(LIVING, p), abs=3e-3), p


def test_table_tops_are_passed_under_their_legs_are_not():
    geo = Footprints(LIVING)
    # under the coffee table's top (0.40 m up): only its legs are obstacles, 0.49 m away
    legs = [o for o in LIVING.objects if o.name.startswith("coffee_table_leg")]
    nearest_leg = min(math.hypot(1.7 - o.pose[0], 1.55 - o.pose[1]) - o.size[0] for o in legs)
    assert nearest_leg == pytest.approx(0.490, abs=1e-3)
    assert geo.clearance(np.array([1.7, 1.55])) == pytest.approx(nearest_leg, abs=1e-9)
    assert geo.contacts({"r": np.array([1.7, 1.55])}) == set()
    # a footprint reaching a leg is a contact (leg 1 at (1.45, 1.1), radius 0.025)
    for gap, touching in [(TOUCH - 0.002, True), (TOUCH + 0.002, False)]:
        c = np.array([1.45 - 0.025 - gap, 1.1])
        assert (geo.contacts({"r": c}) == {"r"}) is touching, gap
    # the TV (0.5 m up) hangs over the floor in front of its stand: not an obstacle
    tv = next(o for o in LIVING.objects if o.name == "tv")
    assert _bottom(tv) > ROBOT_TOP_M


def test_contact_thresholds_walls_and_robots():
    geo = Footprints(load_world("empty", []))
    half = geo.half
    for gap, touching in [(TOUCH - 0.001, True), (TOUCH + 0.001, False)]:
        assert bool(geo.contacts({"r": np.array([half[0] - gap, 0.0])})) is touching
        assert bool(geo.contacts({"r": np.array([0.0, -half[1] + gap])})) is touching
        pair = {"a": np.array([0.0, 0.0]),
                "b": np.array([2 * FOOTPRINT_RADIUS_M + CONTACT_MARGIN_M + 2 * gap - 2 * TOUCH,
                               0.0])}
        assert geo.contacts(pair) == ({"a", "b"} if touching else set())
    # the footprint's centre is the chassis box's, behind the axle
    assert np.allclose(Footprints.centre(1.0, 2.0, math.pi / 2), [1.0, 2.0 + CHASSIS_CENTRE_X_M])


def test_free_points_keep_their_margins_and_a_full_room_says_so():
    geo = Footprints(LIVING)
    rng = np.random.default_rng(5)
    start = np.array([-1.0, -1.0])
    for _ in range(50):
        p = geo.free_point(rng, 0.2, avoid=[start], away_m=0.8, within=(start, 1.0, 3.0))
        assert reference_clearance(LIVING, p) >= FOOTPRINT_RADIUS_M + 0.2 - 3e-3
        assert 1.0 <= math.hypot(*(p - start)) <= 3.0
    with pytest.raises(RuntimeError, match="too crowded"):
        geo.free_point(rng, 2.2, tries=200)        # 2.44 m from everything: nowhere


def test_a_free_point_is_the_first_good_draw_and_the_generator_stops_after_it():
    """free_point tests its draws several at a time, yet picks what drawing them one by one
    picks (here: that loop, the distances as 2-vectors) and leaves the generator just after
    that draw, whatever the margins, the points to keep away from and the ring."""
    geo = Footprints(LIVING)

    def one_by_one(rng, margin, avoid=(), away=0.0, within=None):
        need = FOOTPRINT_RADIUS_M + margin
        while True:
            p = rng.uniform(-geo.half + need, geo.half - need)
            if geo.clearance(p) < need or any(np.hypot(*(p - q)) < away for q in avoid):
                continue
            if within is None or within[1] <= np.hypot(*(p - within[0])) <= within[2]:
                return p

    for seed in range(40):
        a, b = np.random.default_rng(seed), np.random.default_rng(seed)
        starts: list = []
        for f, rng in ((one_by_one, a), (geo.free_point, b)):
            got = [f(rng, 0.3), f(rng, 0.3, [np.array([0.5, 0.5])], 1.5)]
            got.append(f(rng, 0.2, got[:1], 0.8, (got[1], 1.0, 3.0)))
            got.append(f(rng, 0.6))     # (few points keep 0.84 m from everything)
            starts.append((np.array(got).tobytes(), rng.uniform(0, 1, 4).tobytes()))
        assert starts[0] == starts[1], f"seed {seed}"


# ---------------------------------------------------------------------- Avoid-v0

def _towards_goal(info) -> list[float]:
    x, y, yaw = info["pose"]
    gx, gy = info["goal"]
    b = math.atan2(gy - y, gx - x) - yaw
    b = math.atan2(math.sin(b), math.cos(b))
    return [0.3 if abs(b) < 0.3 else 0.0, 2.0 * b]


def test_avoid_reward_is_progress_minus_step_cost_plus_one_at_the_goal():
    env = gym.make("diffbot/Avoid-v0")
    try:
        _, info = env.reset(seed=0)
        for n in range(300):
            before = info["distance"]
            _, r, term, trunc, info = env.step(_towards_goal(info))
            progress = before - info["distance"]
            assert not trunc and not info["contact"]
            x, y, _ = info["pose"]
            assert info["distance"] == pytest.approx(
                math.hypot(info["goal"][0] - x, info["goal"][1] - y), abs=1e-12)
            if term:
                break
            assert info["distance"] >= 0.3 and r == pytest.approx(progress - 0.005, abs=1e-12)
        assert term and info["is_success"], (n, info)
        assert info["distance"] < 0.3
        assert r == pytest.approx(progress - 0.005 + 1.0, abs=1e-12)
        with pytest.raises(RuntimeError, match="the episode is over"):
            env.step([0.0, 0.0])
    finally:
        env.close()


def test_avoid_contact_costs_one_and_ends_the_episode():
    env = gym.make("diffbot/Avoid-v0")
    try:
        _, info = env.reset(seed=0)
        geo = Footprints(LIVING)
        for _ in range(300):
            before = info["distance"]
            _, r, term, trunc, info = env.step([0.3, 0.0])          # straight ahead, blind
            if term:
                break
            assert r == pytest.approx(before - info["distance"] - 0.005, abs=1e-12)
        assert term and info["contact"] and not info["is_success"]
        assert r == pytest.approx(before - info["distance"] - 0.005 - 1.0, abs=1e-12)
        centre = Footprints.centre(*info["pose"])
        assert reference_clearance(LIVING, centre) < TOUCH + 3e-3
        assert geo.clearance(centre) > TOUCH - 0.06       # found within one step (<= 3 cm)
    finally:
        env.close()


def test_avoid_is_truncated_at_300_steps_not_before():
    env = gym.make("diffbot/Avoid-v0")
    try:
        env.reset(seed=3)
        for n in range(1, 301):
            _, r, term, trunc, info = env.step([0.0, 0.0])
            assert not term
            assert trunc is (n == 300), n
            assert r == pytest.approx(-0.005, abs=1e-3)              # standing still
        assert info["t"] == pytest.approx(30.0)
    finally:
        env.close()


# ---------------------------------------------------------------------- Follow-v0

def test_follow_band_reward_its_episode_length_and_rgb_array_render():
    assert gym.spec("diffbot/Follow-v0").max_episode_steps == 750
    env = gym.make("diffbot/Follow-v0", render_mode="rgb_array")
    try:
        obs, info = env.reset(seed=0)
        seen = set()
        for action in [[0.0, 0.0]] * 10 + [[0.5, 0.0]] * 25 + [[-0.5, 0.0]] * 30:
            obs, r, term, trunc, info = env.step(action)
            d = info["distance"]
            want = 1.0 if 0.60 <= d <= 0.70 else -min(0.60 - d if d < 0.60 else d - 0.70, 1.0)
            assert r == pytest.approx(want, abs=1e-12), d
            seen.add("in" if r == 1.0 else "out")
            frame = env.render()          # the room from above, the camera beside it
            k = frame.shape[0] // 120
            assert frame.dtype == np.uint8 and k >= 1 and frame.shape[1] > 160 * k
            camera = frame[:120 * k, -160 * k:]
            assert np.array_equal(camera[::k, ::k], obs["image"]) and camera.std() > 5
            if term:
                break
        assert seen == {"in", "out"}, "drive through the band and out of it"
    finally:
        env.close()
