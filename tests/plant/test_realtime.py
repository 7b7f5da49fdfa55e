"""Realtime pacing, where the time itself is the contract: ``diffbot plant --mode realtime
--rate R`` runs R simulated seconds per wall second, and ``diffbot replay`` keeps a
recording's spacing at ``--rate`` times real time (docs/recording.md). Both are checked
against the wall clock with the documented slack (tests/conftest.py, SLACK_S), never
as a speed test: they must neither run ahead nor fall behind by more than that."""
from __future__ import annotations

import json
import threading
import time

import pytest

from bus import codec
from bus.keys import Keys
from bridges.mcapfile import McapRecording

from ..conftest import SLACK_S, check_realtime_pace, wait_for

#: serial: pacing against the wall clock (a second xdist worker would disturb it: tests/conftest.py)
pytestmark = [pytest.mark.slow, pytest.mark.serial]
K = Keys()
TICK_NS = 20_000_000


@pytest.mark.parametrize("rate", [1.0, 4.0])
def test_realtime_plant_runs_rate_simulated_seconds_per_wall_second(procs, endpoint, tmp_path,
                                                                    rate):
    stats = tmp_path / "plant.json"
    p = procs.diffbot("plant", "--world", "empty", "--mode", "realtime", "--rate", str(rate),
                      "--duration", "3", "--disable", "camera,lidar",
                      # 2 physics steps a tick, not 20: ~1 ms of work per 5 ms tick at rate 4,
                      # so what is checked is the pacing, not whether a loaded machine keeps up
                      "--set", "world.physics_step_s=0.01", "--endpoint", endpoint,
                      "--stats", str(stats), name="plant")
    assert p.wait(60) == 0, procs.log(p)
    s = json.loads(stats.read_text())
    assert s["sim_time_s"] == pytest.approx(3.0)
    check_realtime_pace(s, rate)


class ClockTap:
    """(wall arrival, stamp) of every sim/clock, by a node called ``tap`` (a liveliness
    token, so that a replay started with ``--expect tap`` waits for it)."""

    def __init__(self, session) -> None:
        self.lock = threading.Lock()
        self.seen: list[tuple[float, int]] = []
        self.sub = session.declare_subscriber(K.clock, self._on)
        self.token = session.liveliness().declare_token(K.alive("tap"))

    def _on(self, s) -> None:
        t = codec.msg_stamp_ns(codec.decode(s.payload.to_bytes(), "rosgraph_msgs/msg/Clock"))
        with self.lock:
            self.seen.append((time.monotonic(), t))

    def count(self) -> int:
        with self.lock:
            return len(self.seen)

    def close(self) -> None:
        self.token.undeclare()
        self.sub.undeclare()


@pytest.mark.parametrize("rate", [1.0, 4.0])
def test_replay_keeps_the_recorded_spacing_at_rate_times_real_time(procs, endpoint, bus,
                                                                  tmp_path, rate):
    n = 101                                                   # 2 s of 20 ms ticks
    rec = McapRecording(str(tmp_path / "clock.mcap"))
    for i in range(n):
        t = i * TICK_NS
        rec.write(K.clock, "rosgraph_msgs/msg/Clock", codec.encode(codec.clock(t)), t,
                  1_700_000_000_000_000_000 + t, i)
    rec.close()
    replay = procs.diffbot("replay", str(tmp_path / "clock.mcap"), "--rate", str(rate),
                           "--expect", "tap", "--linger", "5", "--endpoint", endpoint,
                           name="replay")
    tap = ClockTap(bus())
    try:
        wait_for(lambda: tap.count() == n, 60, what=f"{n} replayed clocks")
    finally:
        tap.close()
    assert replay.wait(30) == 0, procs.log(replay)
    (w0, t0), *_, (w1, t1) = tap.seen
    assert t1 - t0 == (n - 1) * TICK_NS
    span = (t1 - t0) * 1e-9 / rate                      # 2 s at rate 1, 0.5 s at rate 4
    # never ahead of the recorded spacing (up to delivery jitter of the first message) ...
    early = max((t - t0) * 1e-9 / rate - (w - w0) for w, t in tap.seen)
    assert early < 0.05, f"a message came {early:.3f} s early at --rate {rate:g}"
    # ... and not behind it by more than the slack
    assert w1 - w0 < span + SLACK_S, f"{w1 - w0:.2f} s for {span:.2f} s at --rate {rate:g}"
