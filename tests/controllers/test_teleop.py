"""Teleop over a pseudo-terminal: keys move the robot, q quits."""
from __future__ import annotations

import os
import pty
import subprocess
import sys
import threading
import time

import pytest

from bus import codec
from bus.keys import Keys
from controllers.teleop import parse_keys

from ..conftest import ROOT, wait_for


def test_key_parsing_handles_arrows_wasd_and_split_escapes():
    acts, rest = parse_keys("w\x1b[Aa\x1b[Dd s q")
    assert acts == ["up", "up", "left", "left", "right", "stop", "down", "stop", "quit"]
    assert rest == ""
    acts, rest = parse_keys("w\x1b[")
    assert acts == ["up"] and rest == "\x1b["
    acts, _ = parse_keys(rest + "B")
    assert acts == ["down"]


@pytest.mark.slow
def test_teleop_drives_the_robot_over_a_pty(procs, endpoint, bus):
    procs.diffbot("plant", "--world", "empty", "--mode", "realtime", "--endpoint", endpoint,
                  name="plant")
    s = bus()
    xs = []
    lock = threading.Lock()

    def on_gt(sample):
        m = codec.decode(sample.payload.to_bytes(), "nav_msgs/msg/Odometry")
        with lock:
            xs.append(m.pose.pose.position.x)
    sub = s.declare_subscriber(Keys().topic("robot1", "ground_truth"), on_gt)
    master, slave = pty.openpty()
    p = procs.diffbot("controller", "teleop", "--endpoint", endpoint, name="teleop",
                      stdin=slave, stdout=slave, stderr=slave)
    os.close(slave)
    screen = bytearray()

    def reader():
        while True:
            try:
                data = os.read(master, 1024)
            except OSError:
                return
            if not data:
                return
            screen.extend(data)
    threading.Thread(target=reader, daemon=True).start()
    wait_for(lambda: b"teleop_robot1 on robot robot1" in screen, 30, what="teleop to start")
    for _ in range(4):
        os.write(master, b"w")                  # 4 x 0.05 m/s
        time.sleep(0.05)
    wait_for(lambda: b"linear +0.20 m/s" in screen, 5, what="status line")
    time.sleep(1.5)
    with lock:
        x1 = xs[-1]
    assert x1 > 0.1, f"robot moved only {x1:.3f} m"
    os.write(master, b" ")
    time.sleep(0.5)
    with lock:
        x2 = xs[-1]
    time.sleep(0.5)
    with lock:
        assert abs(xs[-1] - x2) < 0.01         # space stopped it
    os.write(master, b"q")
    assert p.wait(10) == 0
    os.close(master)
    sub.undeclare()


def test_the_keys_are_listed_at_start_on_the_terminal_or_else_on_stderr():
    import io

    from controllers.teleop import Teleop
    master, slave = pty.openpty()
    out, err = io.StringIO(), io.StringIO()
    t = Teleop(fd=slave, out=out, err=err)          # a terminal: before any key press
    t.close()
    assert "teleop keys:" in out.getvalue() and "q quit" in out.getvalue() and not err.getvalue()
    os.close(master)
    os.close(slave)
    r, w = os.pipe()                                # keys piped in: the help goes to stderr
    out, err = io.StringIO(), io.StringIO()
    t = Teleop(0.1, 0.3, fd=r, out=out, err=err)
    t.close()
    assert "teleop keys:" in err.getvalue() and "0.10 m/s, 0.30 rad/s" in err.getvalue()
    assert not out.getvalue()
    os.close(r)
    os.close(w)
