"""Keyboard teleoperation in a terminal.

Keys: up / w faster, down / s slower (or backwards), left / a turn left,
right / d turn right, space stop, q quit. Each press changes the commanded speed
by a step; the current command is shown on one status line. The keys are listed once
at start (on the terminal; on stderr when stdin is not one, e.g. piped). It publishes
``cmd_vel`` on every clock tick while the command is not zero (at rest it falls
silent after a few zeros, so ``diffbot run teleop --view`` can be driven from
Foxglove too), without holding the simulation (not a lockstep member), so it suits
realtime mode. Works on any terminal or pseudo-terminal.
"""
from __future__ import annotations

import os
import select
import sys
import termios
import threading
import tty

from bus.cliargs import positive_float
from bus.controller import Twist
from bus.node import node_arg_parser, run_node_args

#: at rest the zero command is repeated this many ticks (a lost one is covered), then withheld
_REST_TICKS = 5

HELP = ("teleop keys: up/w faster, down/s slower (backwards below 0), left/a turn left, "
        "right/d turn right, space stop, q quit ({linear:.2f} m/s, {angular:.2f} rad/s a press)")

KEYS = {
    "\x1b[A": "up", "w": "up", "W": "up",
    "\x1b[B": "down", "s": "down", "S": "down",
    "\x1b[D": "left", "a": "left", "A": "left",
    "\x1b[C": "right", "d": "right", "D": "right",
    " ": "stop", "q": "quit", "Q": "quit", "\x03": "quit",
}


def parse_keys(buf: str) -> tuple[list[str], str]:
    """Split typed characters into actions; returns (actions, unfinished escape sequence)."""
    actions = []
    i = 0
    while i < len(buf):
        if buf[i] == "\x1b":
            if len(buf) - i < 3:
                return actions, buf[i:]
            seq = buf[i:i + 3]
            if seq in KEYS:
                actions.append(KEYS[seq])
            i += 3
            continue
        if buf[i] in KEYS:
            actions.append(KEYS[buf[i]])
        i += 1
    return actions, ""


class Teleop:
    name = "teleop"
    inputs: list[str] = []
    sync = False

    def __init__(self, linear_step: float = 0.05, angular_step: float = 0.2,
                 max_linear: float = 0.5, max_angular: float = 2.0, fd: int | None = None,
                 out=None, err=None) -> None:
        self.linear_step, self.angular_step = linear_step, angular_step
        self.max_linear, self.max_angular = max_linear, max_angular
        self.v = 0.0
        self.w = 0.0
        self.done = False
        self._rest_sent = 0
        self.fd = sys.stdin.fileno() if fd is None else fd
        self.out = out or sys.stdout
        # the keys before the first press: with the status line on a terminal, else (keys
        # piped in) on stderr, where a reader of the run's log finds them
        help_out = self.out if os.isatty(self.fd) else (err or sys.stderr)
        help_out.write(HELP.format(linear=linear_step, angular=angular_step) + "\n")
        help_out.flush()
        self.lock = threading.Lock()
        self._thread = threading.Thread(target=self._read_keys, daemon=True)
        self._thread.start()

    def apply(self, action: str) -> None:
        with self.lock:
            if action == "up":
                self.v = min(self.max_linear, self.v + self.linear_step)
            elif action == "down":
                self.v = max(-self.max_linear, self.v - self.linear_step)
            elif action == "left":
                self.w = min(self.max_angular, self.w + self.angular_step)
            elif action == "right":
                self.w = max(-self.max_angular, self.w - self.angular_step)
            elif action == "stop":
                self.v = self.w = 0.0
            elif action == "quit":
                self.v = self.w = 0.0
                self.done = True
        self.out.write(f"\rlinear {self.v:+.2f} m/s  angular {self.w:+.2f} rad/s   "
                       "(arrows/WASD, space stops, q quits)   ")
        self.out.flush()

    def _read_keys(self) -> None:
        old = None
        if os.isatty(self.fd):
            old = termios.tcgetattr(self.fd)
            tty.setcbreak(self.fd)
        pending = ""
        try:
            while not self.done:
                ready, _, _ = select.select([self.fd], [], [], 0.1)
                if not ready:
                    continue
                data = os.read(self.fd, 64)
                if not data:
                    break
                actions, pending = parse_keys(pending + data.decode("utf-8", "replace"))
                for a in actions:
                    self.apply(a)
        finally:
            if old is not None:
                termios.tcsetattr(self.fd, termios.TCSADRAIN, old)

    def close(self) -> None:
        """Stop reading keys and give the terminal back its settings."""
        self.done = True
        self._thread.join(1.0)

    def step(self, obs):
        """The current command every tick while moving; at rest, one zero and then silence,
        so another driver (Foxglove's Teleop panel through ``diffbot view``) can take over."""
        with self.lock:
            if self.v == 0.0 and self.w == 0.0:
                if self._rest_sent >= _REST_TICKS:
                    return None
                self._rest_sent += 1
            else:
                self._rest_sent = 0
            return Twist(self.v, self.w)


def main(argv=None) -> int:
    p = node_arg_parser("Drive a robot from the keyboard.")
    p.add_argument("--linear-step", type=positive_float, default=0.05, help="m/s per key press")
    p.add_argument("--angular-step", type=positive_float, default=0.2, help="rad/s per key press")
    args = p.parse_args(argv)
    ctrl = Teleop(args.linear_step, args.angular_step)
    try:
        return run_node_args(ctrl, args, args.name or f"teleop_{args.robot}")
    finally:
        ctrl.close()
        print()


if __name__ == "__main__":
    sys.exit(main())
