"""bus.plantwatch: how long a member or recorder waits for a plant it lost: the
run's rejoin timeout from sim/info, plus a grace; never before it took part in a run."""
from __future__ import annotations

from bus.plantwatch import EXIT_PLANT_GONE, GONE_GRACE_S, PlantWatch


def test_a_lost_plant_is_waited_for_the_rejoin_timeout_and_the_grace():
    w = PlantWatch()
    w.learn({"rejoin_timeout_s": 30})
    w.here()
    w.gone(100.0)
    assert not w.expired(100.0 + 30 + GONE_GRACE_S)
    assert w.expired(100.0 + 30 + GONE_GRACE_S + 0.01)
    assert "longer than the run's rejoin timeout (30 s" in w.why(133.0)
    w.here()                                   # back in time: waiting again from scratch
    assert not w.expired(1e9)
    assert EXIT_PLANT_GONE == 3


def test_no_plant_yet_is_waited_for_as_long_as_it_takes():
    w = PlantWatch()
    w.gone(0.0)                                # never seen: not "lost"
    assert not w.expired(1e9)


def test_a_plant_that_says_no_timeout_is_waited_for_the_grace_only():
    for info in ({}, None, {"rejoin_timeout_s": None}, {"rejoin_timeout_s": "x"},
                 {"rejoin_timeout_s": -5}):
        w = PlantWatch()
        w.learn(info)
        w.here()
        w.gone(0.0)
        assert w.limit_s == GONE_GRACE_S and w.expired(GONE_GRACE_S + 0.01), info
