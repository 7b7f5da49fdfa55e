"""An FMU node whose values are all float64 scalars steps through fmus/floatstep.py (one
set and one get call a tick): every tick's message is the general path's, byte for byte,
through bad samples, a repeated tick, a failed step and a reset; and the message a member
composed beside it is handed, built from the output values, is its bytes decoded."""
from __future__ import annotations

import math

import pytest

from bus import codec

from ..plant.test_handover import _same
from .test_fmu_node import encoder_run, fmus, make_node, obs  # noqa: F401 (fmus: a fixture)

pytestmark = [pytest.mark.xdist_group("fmus"), pytest.mark.background]

ODOM = "nav_msgs/msg/Odometry"


def _inputs(n: int):
    """(tick, left, right) of a noisy encoder run with bad samples, a missing message, a
    tick repeated and time going back."""
    left, right = encoder_run(n, seed=5)
    bad = {40: (math.nan, 1.0), 41: (1.0, math.inf), 90: (1e308, -1e308), 91: None}
    for k in range(n):
        yield k, *(bad[k] if bad.get(k) else (left[k], right[k])), k in bad and not bad[k]
        if k == 60:
            yield k, left[k], right[k], False            # the same tick again
        if k == 150:
            yield 3, left[3], right[3], False            # a reset: time goes back


@pytest.mark.parametrize("version", (2, 3))
def test_float_path_publishes_the_general_paths_bytes(fmus, version):
    fast, general = make_node(fmus[version]), make_node(fmus[version])
    general.floats = None
    assert fast.floats is not None
    used = 0
    step = fast.floats.step

    def counted(*args):
        nonlocal used
        used += 1
        return step(*args)
    fast.floats.step = counted
    try:
        for node in (fast, general):                     # a doStep refused at one tick
            real = node.fmu.fmu.doStep
            node.fail_at = 120

            def do_step(*args, node=node, real=real):
                if node.fail_at and abs(args[0] - (1.0 + node.fail_at * 0.02 - 0.02)) < 1e-9:
                    node.fail_at = None                  # (once: the next tick covers it)
                    raise RuntimeError("refused")
                return real(*args)
            node.fmu.fmu.doStep = do_step
        for k, left, right, missing in _inputs(220):
            o = obs(k, left, right)
            if missing:
                o.msgs.clear()
            got, want = fast.step(o), general.step(o)
            assert (got is None) == (want is None), k
            if got is not None:
                assert got["odom"].data == want["odom"].data, k
                _same(got["odom"].made(), codec.decode(got["odom"].data, ODOM), str(k))
        assert used > 150
        assert fast.stats() == general.stats()
        assert fast.rejects.counts["input"] >= 3 and fast.rejects.counts["step"] == 1
    finally:
        fast.close()
        general.close()
