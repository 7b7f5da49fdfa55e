"""The plant process: owns simulated time, steps DART, publishes sensors, applies commands.

Modes (see ARCHITECTURE.md, "Time and synchronisation"):

* **lockstep** — each tick the plant publishes the sensors due, then ``sim/clock``;
  it steps on once every lockstep member (liveliness ``sim/sync/<node>``) has
  acked the tick. A member that dies leaves the set at once; a frozen one when
  its lease runs out.
* **realtime** — paced to the wall clock times ``--rate``; the last command is
  held; a robot whose command is older than its ``cmd_timeout_s`` is stopped.
* **fast** — free running, nobody is waited for.

Bad commands (undecodable, NaN/inf, absurd speeds, unknown joints) are counted
and logged at a limited rate; they never reach the physics.
"""
from __future__ import annotations

import argparse
import json
import math
import signal
import threading
import time
from dataclasses import dataclass

import numpy as np
import zenoh

from bus import codec, jsonio
from bus.cliargs import ArgumentParser, nonneg_int, positive_float
from bus.inbox import Inbox
from bus.keys import Keys
from bus.log import RejectCounter, setup_logging
from bus.node import write_json
from bus.protocol import COUPLINGS, PLANT_READS, PROTOCOL_VERSION, delays
from bus.session import BusConfigError, add_bus_args, open_session

from .physics_process import PhysicsError, PhysicsProcess
from .raycast import Scene
from .sensors import RobotSensors, scan_all
from .sim import Simulation
from .world import WorldError, WorldSpec, load_world

MODES = ("lockstep", "realtime", "fast")

#: Commands beyond this multiple of a robot's limit are rejected as absurd, not clamped.
ABSURD_FACTOR = 10.0
#: Acks per member, commands per robot and message counts remembered (ticks).
_RECENT = 32
#: lockstep: waiting this long (wall s) on a tick makes the plant say who it waits for,
#: again after twice as long each time, up to every WAIT_REPORT_MAX_S
WAIT_REPORT_S = 2.0
#: A member's last messages may reach the plant just after its sim/sync token is gone
#: (liveliness and data take different paths): how long, once, the plant waits for the
#: FINAL of an --end-with member that left without one, rather than run past its end.
LEFT_FINAL_GRACE_S = 0.5
WAIT_REPORT_MAX_S = 30.0
#: realtime: falling this far behind the wall clock (s) re-anchors it instead of catching up
STALL_S = 0.25


@dataclass
class Command:
    kind: str          # "twist" or "wheels"
    a: float
    b: float
    t_ns: int          # the tick it was computed for (its stamp; sim time when received if 0)
    wall: float        # monotonic wall time when received


class Plant:
    """The plant's bus side around a :class:`Simulation`."""

    def __init__(self, spec: WorldSpec, session: zenoh.Session, keys: Keys, mode: str, log,
                 rate: float = 1.0, expect: tuple[str, ...] = (), duration_s: float | None = None,
                 join_timeout_s: float = 30.0, disabled: tuple[str, ...] = (),
                 end_with: tuple[str, ...] = (), coupling: str = "sequential",
                 physics_process: bool = False) -> None:
        self.spec = spec
        self.session = session
        self.keys = keys
        self.mode = mode
        self.log = log
        self.rate = rate
        self.expect = tuple(expect)
        self.end_with = tuple(end_with)
        self.duration_ns = None if duration_s is None else int(round(duration_s * 1e9))
        self.join_timeout_s = join_timeout_s
        self.tick_ns = int(round(spec.control_tick_s * 1e9))
        self.coupling = coupling
        # Lockstep only: the coupling's delays, in ticks (docs/PROTOCOL.md).
        self.delays = delays(coupling) if mode == "lockstep" else delays("sequential")
        self.delay_ns = self.delays["actuation_delay_ticks"] * self.tick_ns
        self.disabled = set(disabled)
        self.seed = spec.seed
        # DART in a process of its own (plant/physics_process.py); None: stepped here
        self.physics: PhysicsProcess | None = None
        self.physics_process = physics_process
        self.build()
        self.rejects = RejectCounter(log)
        self.stop_event = threading.Event()
        self.members: set[str] = set()
        self.members_seen: set[str] = set()
        # member -> {tick stamp: (n_plant, final)} from its ACKs, the last few ticks: a stray,
        # late or forged ack never hides the one the plant waits for
        self.acks: dict[str, dict[int, tuple[int, bool]]] = {}
        self.finished: dict[str, int] = {}      # member -> stamp of its FINAL tick
        self._final_awaited: set[str] = set()   # ending members given their grace once
        # (member, tick stamp) -> messages of it on the keys the plant reads, for that tick
        self.member_msgs: dict[tuple[str, int], int] = {}
        # robot -> {tick stamp: Command} (lockstep: the command computed for each tick)
        self.cmd_by_tick: dict[str, dict[int, Command]] = {}
        # lockstep protocol problems (no or bad attachment, a tick not due, missing outputs),
        # counted per kind and said at most every 2 s
        self.protocol = RejectCounter(log, verb="lockstep protocol:")
        self.stalls = 0                          # realtime: times the wall clock was re-anchored
        self._pace0 = 0.0                        # realtime: wall time of sim time 0
        self.reset_in_tick = False               # a sim/reset came during the current tick
        self._stall_logged = -1e9
        self.commands: dict[str, Command] = {}
        self.published: dict[str, int] = {}
        self.ticks = 0
        self.timing = {"publish_s": 0.0, "wait_s": 0.0, "physics_s": 0.0}
        self.wall_start = 0.0
        self.end_reason = "stopped"
        self.wall_end = 0.0
        self._seq = 0
        self._pubs: dict[str, zenoh.Publisher] = {}
        # In lockstep nothing may be lost: block rather than drop when a queue is full.
        self.congestion = (zenoh.CongestionControl.BLOCK if mode == "lockstep"
                           else zenoh.CongestionControl.DROP)
        self.inbox = Inbox(session)
        self._robot_of_key: dict[str, tuple[str, str]] = {}
        for name in self.sim.robots:
            for topic in PLANT_READS:
                if topic == "odom" and mode != "lockstep":
                    continue                     # read only for lockstep members' ACKs
                key = keys.topic(name, topic)
                self._robot_of_key[key] = (name, topic)
                self.inbox.subscribe(key, "out")
        self.inbox.subscribe(keys.ack(), "out")
        self.inbox.watch_liveliness(keys.sync(), "member")
        self.inbox.watch_liveliness(keys.alive(), "alive")
        self.alive: set[str] = set()
        self._queryables = [
            session.declare_queryable(keys.info, self._on_info),
            session.declare_queryable(keys.reset, lambda q: self.inbox.queue.put(_QueryEvent(q))),
        ]
        self._token = session.liveliness().declare_token(keys.alive("plant"))

    def build(self) -> None:
        """(Re)build the world and the sensors with the current seed."""
        for r in self.spec.robots:
            if "lidar" in self.disabled:
                r.sensors.lidar = None
            if "camera" in self.disabled:
                r.sensors.camera = None
        self.sim = Simulation(self.spec)
        self.sensors = {r.name: RobotSensors(r, self.spec.control_tick_s, self.seed)
                        for r in self.spec.robots}
        self._robot_index = {name: i for i, name in enumerate(self.sim.robots)}
        if self.physics_process:
            if self.physics is None:
                self.physics = PhysicsProcess(self.spec)
            else:
                self.physics.build(self.spec)

    # ------------------------------------------------------------------ the world's state
    def _state(self, robot: str):
        if self.physics is None:
            return self.sim.state(robot)
        return self.physics.state(self._robot_index[robot])

    def _shapes(self):
        if self.physics is None:
            return self.sim.shapes()
        assert self.physics.parts is not None, "a scene is due but the snapshot has no parts"
        return self.sim.shapes(self.physics.parts)

    def _finite(self) -> bool:
        return self.sim.is_finite() if self.physics is None else self.physics.finite

    def _start_step(self) -> None:
        """Step one tick with the targets apply_commands set; with a physics process, only
        start it (:meth:`_finish_step` waits for it)."""
        if self.physics is None:
            self.sim.step_tick()
            return
        tick = self.sim.time_ns // self.tick_ns + 1
        self.physics.start_step([r.targets for r in self.sim.robots.values()],
                                any(s.needs_scene(tick) for s in self.sensors.values()))

    def _finish_step(self) -> None:
        if self.physics is not None:
            self.physics.finish_step()
            self.sim.steps += self.spec.substeps      # the clock of the plant's own copy

    # ------------------------------------------------------------------ queryables
    def info(self) -> dict:
        d = self.sim.describe()
        for name, sensors in self.sensors.items():
            d["robots"][name]["topics"] = dict(sensors.periods)
        d.update(protocol=PROTOCOL_VERSION, mode=self.mode, coupling=self.coupling,
                 **self.delays, seed=self.seed, time_ns=self.sim.time_ns,
                 namespace=self.keys.namespace, rate=self.rate)
        return d

    def _on_info(self, query: zenoh.Query) -> None:
        query.reply(self.keys.info, jsonio.dumps(self.info()))

    def _reset(self, query: zenoh.Query) -> None:
        """Rebuild the world (``world.reset()`` only resets DART's clock), optionally with a
        new seed or new start poses: ``{"seed": 3, "poses": {"robot1": [x, y, yaw]}}``."""
        try:
            raw = query.payload.to_bytes() if query.payload is not None else b""
            req = json.loads(raw) if raw.strip() else {}
            seed, poses = self._check_reset(req)
        except (ValueError, RecursionError) as exc:   # JSONDecodeError is a ValueError
            self.rejects.reject("reset", str(exc))
            query.reply_err(jsonio.dumps({"error": str(exc)}))
            return
        # Checked in full before anything changes: a bad request leaves the world as it was.
        if seed is not None:
            self.seed = self.spec.seed = seed
        for name, pose in poses.items():
            self.spec.robot(name).pose = pose
        self.build()
        self.commands.clear()
        self.reset_in_tick = True
        self._pace0 = time.monotonic() - self.sim.time_ns * 1e-9 / self.rate
        self.log.info("world rebuilt (seed %d)", self.seed)
        query.reply(self.keys.reset, jsonio.dumps({"ok": True, "seed": self.seed, "time_ns": 0}))

    def _check_reset(self, req) -> tuple[int | None, dict[str, tuple[float, float, float]]]:
        """(seed or None, new poses) of a reset request; ValueError if any part is bad."""
        if not isinstance(req, dict):
            raise ValueError("request must be a JSON object")
        unknown = set(req) - {"seed", "poses"}
        if unknown:
            raise ValueError(f"unknown request keys: {', '.join(sorted(map(str, unknown)))}")
        seed = req.get("seed")
        if seed is not None and (not isinstance(seed, int) or isinstance(seed, bool)
                                 or not 0 <= seed < 2**63):
            raise ValueError("seed must be an integer in [0, 2**63)")
        poses = req.get("poses") or {}
        if not isinstance(poses, dict):
            raise ValueError('poses must be an object {"robot": [x, y, yaw]}')
        half = [s / 2 for s in self.spec.floor_size_m]
        out = {}
        for name, pose in poses.items():
            if name not in self.sim.robots:
                raise ValueError(f"unknown robot {name!r}")
            if (not isinstance(pose, list) or len(pose) != 3 or
                    not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                            and math.isfinite(v) for v in pose)):
                raise ValueError(f"pose of {name} must be [x, y, yaw] (finite numbers)")
            x, y, yaw = (float(v) for v in pose)
            if abs(x) > half[0] or abs(y) > half[1] or abs(yaw) > 1e3:
                raise ValueError(f"pose of {name} {pose} is off the {2 * half[0]:g} x "
                                 f"{2 * half[1]:g} m floor (or yaw beyond 1000 rad)")
            out[name] = (x, y, yaw)
        return seed, out

    # ------------------------------------------------------------------ publishing
    def _publisher(self, key: str) -> zenoh.Publisher:
        pub = self._pubs.get(key)
        if pub is None:
            pub = self._pubs[key] = self.session.declare_publisher(
                key, encoding=zenoh.Encoding.APPLICATION_CDR,
                congestion_control=self.congestion)
        return pub

    def _put(self, key: str, msg, t_ns: int) -> None:
        self._seq += 1
        self._publisher(key).put(codec.encode(msg), attachment=codec.attachment(self._seq, t_ns))
        self.published[key] = self.published.get(key, 0) + 1

    def _publish(self) -> None:
        self.publish_tick()
        for sensors in self.sensors.values():
            sensors.prefetch()

    def publish_tick(self) -> None:
        """The sensors due at this tick, robot by robot, then ``sim/clock``."""
        t = self.sim.time_ns
        tick = t // self.tick_ns
        scene = None
        if any(s.needs_scene(tick) for s in self.sensors.values()):
            scene = Scene(self._shapes())
        states = {name: self._state(name) for name in self.sensors}
        scans = scan_all(self.sensors, states, tick, scene) if scene is not None else {}
        for name, sensors in self.sensors.items():
            for topic, msg in sensors.messages(tick, t, states[name], scene, scans.get(name)):
                self._put(self.keys.topic(name, topic), msg, t)
        self._put(self.keys.clock, codec.clock(t), t)

    # ------------------------------------------------------------------ input
    def handle(self, ev) -> None:
        if isinstance(ev, _QueryEvent):
            # Answered at once, even while the plant waits for a tick's acks (a node may ask
            # from inside its step); the acks of that tick are kept, and run() does not step
            # the new world with them: it starts over at t = 0.
            self._reset(ev.query)
        elif ev.tag == "out":
            self._on_output(ev)
        elif ev.tag == "alive":
            (self.alive.add if ev.alive else self.alive.discard)(self.keys.node_of(ev.key))
        elif ev.tag == "member":
            node = self.keys.node_of(ev.key)
            if ev.alive:
                self.members.add(node)
                self.members_seen.add(node)
                self.finished.pop(node, None)
                self._final_awaited.discard(node)
                self.log.info("lockstep member joined: %s", node)
            else:
                self.members.discard(node)
                self.acks.pop(node, None)
                for k in [k for k in self.member_msgs if k[0] == node]:
                    del self.member_msgs[k]
                self.log.warning("lockstep member left: %s", node)

    def _on_output(self, ev) -> None:
        """A message on a key the plant reads: a command to apply, and in lockstep a
        member's output, counted for its tick, whose ACK tells the member is done."""
        robot, topic = self._robot_of_key.get(ev.key, (None, "ack"))
        att = codec.parse_attachment(ev.attachment)
        if self.mode == "lockstep" and not self._member_output(ev.key, topic, att,
                                                               ev.attachment):
            return
        if topic in ("cmd_vel", "wheel_cmd"):
            self._on_command(ev, robot, topic, att)

    def _member_output(self, key: str, topic: str, att, raw: bytes | None) -> bool:
        """Lockstep bookkeeping of one message; False if it is not to be used at all."""
        if att is None or att.node is None:
            if topic == "odom":                  # a realtime-style odometry node: not ours
                return False
            why = ("no attachment" if not raw
                   else "a malformed attachment" if att is None
                   else "a plain 16-byte attachment (no member trailer)")
            self.protocol.reject(f"{key}: {why}",
                                 "a lockstep member's outputs carry seq, stamp and the trailer "
                                 "flags|n_plant|name (docs/PROTOCOL.md); "
                                 + ("applied as a command from a non-member" if topic != "ack"
                                    else "ignored"))
            return topic != "ack"
        member, t = att.node, att.t_ns
        if self.tick_ns and t % self.tick_ns:
            self.protocol.reject(f"{key}: stamp off the tick grid",
                                 f"t={t * 1e-9:.9f} s from {member}; ignored")
            return False
        if t > self.sim.time_ns:
            self.protocol.reject(f"{key}: stamped for a tick not due",
                                 f"t={t * 1e-9:.3f} s from {member}, the plant is at "
                                 f"t={self.sim.time_ns * 1e-9:.3f} s; ignored")
            return False
        if member not in self.members and member not in self.members_seen:
            self.protocol.reject(f"{key}: from {member!r}, not a lockstep member",
                                 "(no sim/sync token); used, not waited for")
        # A member that left is not waited for, but its ACK is still filed: its FINAL may
        # arrive just after its sim/sync token went (liveliness and data take different
        # paths), and --end-with must still end the run at that tick.
        if topic != "ack":
            k = (member, t)
            self.member_msgs[k] = self.member_msgs.get(k, 0) + 1
            if len(self.member_msgs) > 4 * _RECENT * max(1, len(self.members)):
                del self.member_msgs[next(iter(self.member_msgs))]
        if att.flags & codec.ACK:
            acks = self.acks.setdefault(member, {})
            ack = (att.n_plant, bool(att.flags & codec.FINAL))
            if t in acks:
                # A member ACKs a tick once: a second ACK is forged or a bug. The smaller count
                # is kept, so no stray ACK can hold the run forever.
                self.protocol.reject(f"{key}: a second ACK from {member}",
                                     f"for t={t * 1e-9:.3f} s (n_plant {acks[t][0]} and "
                                     f"{att.n_plant})")
                ack = (min(ack[0], acks[t][0]), ack[1] or acks[t][1])
            acks[t] = ack
            if ack[1]:
                # Kept after the member leaves: under pipelined coupling it may leave before
                # the plant has looked for its FINAL (--end-with must still see it).
                self.finished[member] = t
            if len(acks) > _RECENT:
                del acks[next(iter(acks))]
        return True

    def _on_command(self, ev, robot: str, topic: str, att) -> None:
        drive = self.sim.robots[robot].spec.drive
        try:
            if topic == "cmd_vel":
                msg = codec.decode(ev.payload, "geometry_msgs/msg/TwistStamped")
                tw = msg.twist
                if not all(math.isfinite(v) for v in (tw.linear.x, tw.linear.y, tw.linear.z,
                                                      tw.angular.x, tw.angular.y, tw.angular.z)):
                    raise ValueError("non-finite twist")
                if msg.header.frame_id not in ("", "base_link"):
                    raise ValueError(f"twist in frame {msg.header.frame_id!r}; "
                                     "expected base_link")
                a, b = float(tw.linear.x), float(tw.angular.z)
                lim_a, lim_b = drive.max_linear_mps, drive.max_angular_radps
                kind = "twist"
            else:
                msg = codec.decode(ev.payload, "sensor_msgs/msg/JointState")
                a, b = _wheel_speeds(msg)
                lim_a = lim_b = drive.max_wheel_speed_radps
                kind = "wheels"
            self._check_stamp(msg.header.stamp, drive.cmd_timeout_s)
        except (codec.CodecError, ValueError) as exc:
            self.rejects.reject(f"{robot}/{topic}", str(exc))
            return
        if not (math.isfinite(a) and math.isfinite(b)):
            self.rejects.reject(f"{robot}/{topic}", f"non-finite command ({a}, {b})")
            return
        if abs(a) > ABSURD_FACTOR * lim_a or abs(b) > ABSURD_FACTOR * lim_b:
            self.rejects.reject(f"{robot}/{topic}", f"absurd command ({a:g}, {b:g}); "
                                f"limits are {lim_a:g}, {lim_b:g}")
            return
        t = codec.stamp_ns(msg.header.stamp) or self.sim.time_ns
        cmd = self.commands[robot] = Command(kind, a, b, t, time.monotonic())
        if self.mode == "lockstep":
            by_tick = self.cmd_by_tick.setdefault(robot, {})
            by_tick[t] = cmd
            if len(by_tick) > _RECENT:
                del by_tick[min(by_tick)]

    def _check_stamp(self, stamp, timeout_s: float) -> None:
        """Raise ValueError for a command stamped in the future, or (lockstep, realtime) older
        than the robot's ``cmd_timeout_s``. A zero stamp means "now" (unstamped)."""
        if stamp.sec < 0 or not 0 <= stamp.nanosec < 1_000_000_000:
            raise ValueError(f"invalid stamp ({stamp.sec} s, {stamp.nanosec} ns)")
        t = codec.stamp_ns(stamp)
        if t == 0:
            return
        now = self.sim.time_ns
        if t > now + self.tick_ns:
            raise ValueError(f"stamped t={t * 1e-9:.3f} s, in the future (now "
                             f"{now * 1e-9:.3f} s)")
        if self.mode != "fast" and now - t > timeout_s * 1e9:
            raise ValueError(f"stamped t={t * 1e-9:.3f} s, older than cmd_timeout "
                             f"{timeout_s:g} s (now {now * 1e-9:.3f} s)")

    def apply_commands(self) -> None:
        """Hand each robot its latest command, or zero if it has none or it timed out."""
        now_wall = time.monotonic()
        now_ns = self.sim.time_ns
        for name, robot in self.sim.robots.items():
            cmd = (self._lockstep_command(name, now_ns - self.delay_ns)
                   if self.mode == "lockstep" else self.commands.get(name))
            if cmd is not None:
                timeout = robot.spec.drive.cmd_timeout_s
                age = (now_ns - cmd.t_ns) * 1e-9 if self.mode == "lockstep" else now_wall - cmd.wall
                if age > timeout:
                    self.log.warning("%s: no command for %.2f s (cmd_timeout %.2f s): stopping it",
                                     name, age, timeout)
                    self.commands.pop(name, None)
                    self.cmd_by_tick.pop(name, None)
                    cmd = None
            if cmd is None:
                self.sim.command_twist(name, 0.0, 0.0)
            elif cmd.kind == "twist":
                self.sim.command_twist(name, cmd.a, cmd.b)
            else:
                self.sim.command_wheels(name, cmd.a, cmd.b)

    def _lockstep_command(self, robot: str, upto_ns: int) -> Command | None:
        """The command computed for the latest tick at or before ``upto_ns`` (the current
        tick in sequential coupling, the one before in pipelined): what arrives early for a
        later tick waits for its turn, so runs are the same whatever the timing."""
        by_tick = self.cmd_by_tick.get(robot)
        if not by_tick:
            return None
        ticks = [t for t in by_tick if t <= upto_ns]
        if not ticks:
            return None
        best = max(ticks)
        for t in [t for t in ticks if t < best]:          # older ones are done with
            del by_tick[t]
        return by_tick[best]

    def drain(self, timeout: float | None = 0.0) -> bool:
        """Handle queued events; wait up to ``timeout`` for the first. True if any came."""
        ev = self.inbox.get(timeout=timeout) if timeout else _nowait(self.inbox)
        if ev is None:
            return False
        self.handle(ev)
        while (ev := _nowait(self.inbox)) is not None:
            self.handle(ev)
        return True

    # ------------------------------------------------------------------ loop
    def wait_for_members(self) -> bool:
        """Before the first tick: wait for the expected nodes (in lockstep, for any member
        if none were named)."""
        want = set(self.expect)
        deadline = time.monotonic() + self.join_timeout_s
        if want:
            self.log.info("waiting for nodes: %s", ", ".join(sorted(want)))
        else:
            self.log.info("lockstep: waiting for a controller to join (or use --mode fast)")
        while not self.stop_event.is_set():
            self.drain(0.1)
            present = self.members if self.mode == "lockstep" else self.alive
            if (want and want <= present) or (not want and present):
                return True
            if want and time.monotonic() > deadline:
                self.log.error("nodes did not join within %.0f s: %s",
                               self.join_timeout_s, ", ".join(sorted(want - present)))
                return False
        return False

    def _acked(self, member: str, t_ns: int) -> bool:
        """The member ACKed tick ``t_ns`` and every message it counted for it is in."""
        ack = self.acks.get(member, {}).get(t_ns)
        return ack is not None and self.member_msgs.get((member, t_ns), 0) >= ack[0]

    def wait_for_acks(self, t_ns: int, required: set[str]) -> None:
        """Until every member still present has ACKed tick ``t_ns`` with all its messages;
        after WAIT_REPORT_S of wall time, say whom it waits for (then less and less often)."""
        since = time.monotonic()
        every = WAIT_REPORT_S
        report_at = since + every
        # What came meanwhile, even when nobody is to be waited for (every member gone): a
        # member joining, a late FINAL, a sim/reset query would otherwise stay queued.
        self.drain(0.0)
        while not self.stop_event.is_set() and not self.reset_in_tick:
            # (a sim/reset answered meanwhile rebuilt the world: this tick is gone)
            waiting = [m for m in required if m in self.members and not self._acked(m, t_ns)
                       and self.finished.get(m, t_ns) >= t_ns]   # (none after its FINAL)
            if not waiting:
                return
            now = time.monotonic()
            if now >= report_at:
                self._report_wait(t_ns, waiting, now - since)
                every = min(2 * every, WAIT_REPORT_MAX_S)
                report_at = now + every
            self.drain(0.5)

    def _await_final_of_leavers(self) -> None:
        """An --end-with member that left without its FINAL having come: its last messages
        may still be on their way, so give them LEFT_FINAL_GRACE_S once (a crashed member
        costs the run that much), and the run ends at the member's last tick."""
        for m in self.end_with:
            if (m in self.members_seen and m not in self.members and m not in self.finished
                    and m not in self._final_awaited):
                self._final_awaited.add(m)
                deadline = time.monotonic() + LEFT_FINAL_GRACE_S
                while (m not in self.finished and not self.stop_event.is_set()
                       and (left := deadline - time.monotonic()) > 0):
                    self.drain(min(left, 0.05))

    def _report_wait(self, t_ns: int, waiting: list[str], waited_s: float) -> None:
        parts = []
        for m in sorted(waiting):
            ack = self.acks.get(m, {}).get(t_ns)
            got = self.member_msgs.get((m, t_ns), 0)
            if ack is not None:
                self.protocol.reject("missing outputs",
                                     f"{m} ACKed t={t_ns * 1e-9:.3f} s with n_plant={ack[0]} "
                                     f"but {got} of its messages for it arrived")
                parts.append(f"{m} (ACKed with n_plant={ack[0]}, {got} arrived)")
            else:
                last = max(self.acks.get(m, {}), default=None)
                parts.append(f"{m} (no ACK; {got} message(s) for this tick; last ACK "
                             + (f"t={last * 1e-9:.3f} s)" if last is not None else "none)"))
        self.log.warning("lockstep: waited %.1f s for tick t=%.3f s: %s", waited_s,
                         t_ns * 1e-9, "; ".join(parts))

    def run(self) -> int:
        self.drain(0.05)
        if (self.mode == "lockstep" or self.expect) and not self.wait_for_members():
            return 1 if not self.stop_event.is_set() else 0
        self.wall_start = self._pace0 = time.monotonic()
        tick_ns = self.tick_ns
        # With a physics process, tick k is published while the physics steps to k + 1:
        # when the commands for that step do not wait for tick k's sensors (pipelined
        # lockstep; fast mode, which takes what has come).
        overlap = self.physics is not None and (
            self.mode == "fast" or (self.mode == "lockstep" and self.delay_ns > 0))
        self.log.info("running %s (%s mode, tick %.0f ms, %d physics steps per tick%s)",
                      self.spec.name, self.mode, tick_ns / 1e6, self.spec.substeps,
                      "" if self.physics is None else ", physics in its own process"
                      + (", stepping while publishing" if overlap else ""))
        try:
            while not self.stop_event.is_set():
                t = self.sim.time_ns
                required = set(self.members)
                c0 = time.perf_counter()
                if not overlap:
                    self._publish()
                c1 = time.perf_counter()
                if self.duration_ns is not None and t >= self.duration_ns:
                    if overlap:
                        self._publish()
                    if self.mode == "lockstep":
                        self.wait_for_acks(t, required)
                    self.end_reason = "duration reached"
                    break
                if self.mode == "lockstep":
                    # Sequential: tick t's commands; pipelined: tick t-1's, while the nodes
                    # compute tick t's (none before the first tick).
                    due = t - self.delay_ns
                    if due >= 0:
                        self.wait_for_acks(due, required)
                    self._await_final_of_leavers()
                    ended = [m for m in self.end_with if self.finished.get(m, due + 1) <= due]
                    if ended:
                        if overlap:
                            self._publish()
                        if self.delay_ns:   # pipelined: the others' outputs of tick t too,
                            self.wait_for_acks(t, required)    # so the end is exact
                        self.end_reason = f"{ended[0]} finished"
                        self.log.info("%s finished at t=%.3f s: stopping", ended[0],
                                      due * 1e-9)
                        break
                else:
                    self.drain(0.0)
                if self.mode == "realtime":
                    due = self._pace0 + (t + tick_ns) * 1e-9 / self.rate
                    behind = time.monotonic() - due
                    if behind > max(STALL_S, 5 * tick_ns * 1e-9 / self.rate):
                        # Stopped (SIGSTOP, debugger) or starved: do not race to catch up,
                        # which would replay the missed wall time at full speed.
                        self.stalls += 1
                        self._pace0 += behind
                        due -= behind
                        if time.monotonic() - self._stall_logged > 5.0:
                            self._stall_logged = time.monotonic()
                            self.log.warning("realtime: %.2f s behind the wall clock at "
                                             "t=%.3f s (stopped or overloaded); carrying on "
                                             "from now", behind, t * 1e-9)
                    while (left := due - time.monotonic()) > 0 and not self.stop_event.is_set():
                        self.drain(min(left, 0.05))
                if self.reset_in_tick:          # the world was rebuilt: publish its t = 0
                    self.reset_in_tick = False
                    self.acks.clear()           # the old world's stamps would match the new
                    self.finished.clear()
                    self.member_msgs.clear()
                    self.cmd_by_tick.clear()
                    continue
                c2 = time.perf_counter()
                self.apply_commands()
                self._start_step()
                publish_s = c1 - c0
                if overlap:                     # while the physics process steps
                    self._publish()
                    publish_s = time.perf_counter() - c2
                self._finish_step()
                c3 = time.perf_counter()
                self.ticks += 1
                self.timing["publish_s"] += publish_s
                self.timing["wait_s"] += c2 - c1
                # (overlapped: the part of the step that publishing did not hide)
                self.timing["physics_s"] += c3 - c2 - (publish_s if overlap else 0.0)
                if not self._finite():
                    self.log.error("physics diverged at t=%.3f s; rebuilding the world", t * 1e-9)
                    self.build()
        finally:
            self.wall_end = time.monotonic()
        return 0

    def stats(self) -> dict:
        wall = max(self.wall_end - self.wall_start, 1e-9) if self.wall_start else 0.0
        sim_s = self.sim.time_ns * 1e-9
        return {"node": "plant", "world": self.spec.name, "mode": self.mode, "seed": self.seed,
                "end_reason": self.end_reason,
                "sim_time_s": sim_s, "wall_time_s": wall, "ticks": self.ticks,
                "real_time_factor": sim_s / wall if wall else None,
                "published": self.published, "rejected": dict(self.rejects.counts),
                "members_seen": sorted(self.members_seen), "stalls": self.stalls,
                "protocol": PROTOCOL_VERSION, "coupling": self.coupling, **self.delays,
                "physics_process": self.physics is not None,
                "protocol_errors": dict(self.protocol.counts),
                "per_tick_ms": {k[:-2]: 1e3 * v / max(self.ticks, 1)
                                for k, v in self.timing.items()}}

    def close(self, reason: str = "stopped") -> None:
        """Tell the nodes the simulation ended (so they exit 0, not "plant gone"), then leave."""
        end_token = None
        try:
            self.session.put(self.keys.end, reason.encode())
            # Also as a liveliness token: declarations are ordered with the undeclaration
            # of sim/alive/plant below, so a node always sees the end before the absence.
            end_token = self.session.liveliness().declare_token(self.keys.end)
            time.sleep(0.05)
        except Exception:
            pass
        self._token.undeclare()
        if end_token is not None:
            end_token.undeclare()
        for q in self._queryables:
            q.undeclare()
        self.inbox.close()
        if self.physics is not None:
            self.physics.close()


class _QueryEvent:
    """A ``sim/reset`` query handed to the main loop (the world is rebuilt between ticks)."""
    tag = "reset"

    def __init__(self, query: zenoh.Query) -> None:
        self.query = query


def _nowait(inbox: Inbox):
    try:
        return inbox.queue.get_nowait()
    except Exception:
        return None


def _wheel_speeds(msg) -> tuple[float, float]:
    vel = np.asarray(msg.velocity, dtype=float)
    if len(vel) != 2:
        raise ValueError(f"wheel_cmd needs 2 velocities, got {len(vel)}")
    names = list(msg.name)
    if not names:
        return float(vel[0]), float(vel[1])
    if sorted(names) != ["left_wheel_joint", "right_wheel_joint"]:
        raise ValueError(f"unknown joint names {names}")
    d = dict(zip(names, vel))
    return float(d["left_wheel_joint"]), float(d["right_wheel_joint"])


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(prog="diffbot plant", description="Run the DART plant on the bus.")
    p.add_argument("--world", default="living_room",
                   help="world file, or the name of a shipped world (living_room, empty)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a world-file value, e.g. world.mode=kinematic or "
                        "'robots.robot1.encoders.noise={webots_noise = 0.2}' (repeatable)")
    p.add_argument("--mode", choices=MODES, default="lockstep")
    p.add_argument("--coupling", choices=COUPLINGS, default="sequential",
                   help="lockstep: sequential (commands of tick k from tick k's sensors act at "
                        "once; exact) or pipelined (the plant steps while the nodes compute: "
                        "commands act one tick later, node-to-node inputs are a tick old)")
    p.add_argument("--rate", type=positive_float, default=1.0,
                   help="realtime mode: simulated seconds per wall second (default 1)")
    p.add_argument("--duration", type=positive_float, default=None, metavar="S",
                   help="stop after S simulated seconds (default: run until stopped)")
    p.add_argument("--seed", type=nonneg_int, default=None, help="noise seed (default: the world's)")
    p.add_argument("--expect", default="", metavar="NODES",
                   help="lockstep: comma-separated members to wait for before the first tick")
    p.add_argument("--join-timeout", type=positive_float, default=30.0, metavar="S")
    p.add_argument("--end-with", default="", metavar="NODES",
                   help="lockstep: stop, without stepping further, at the tick where one of "
                        "these members finishes (so a run's length is reproducible)")
    p.add_argument("--disable", default="", metavar="SENSORS",
                   help="comma-separated sensors of the world file to leave off: lidar, camera")
    p.add_argument("--physics-process", action="store_true",
                   help="step DART in a process of its own; with pipelined lockstep or fast "
                        "mode the plant then publishes tick k while the physics steps to k+1 "
                        "(two cores; same bytes)")
    p.add_argument("--stats", metavar="FILE", help="write counters and timing as JSON at exit")
    p.add_argument("--log-level", default="INFO")
    add_bus_args(p)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    log = setup_logging("plant", args.log_level)
    try:
        spec = load_world(args.world, args.set)
        if args.seed is not None:
            spec.seed = args.seed
        keys = Keys(args.namespace)
        if args.rate <= 0 or not math.isfinite(args.rate):
            raise WorldError(f"--rate must be > 0, got {args.rate}")
        disabled = tuple(x for x in args.disable.split(",") if x)
        if set(disabled) - {"lidar", "camera"}:
            raise WorldError(f"--disable takes lidar and/or camera, got {args.disable!r}")
    except (WorldError, ValueError) as exc:
        log.error("%s", exc)
        return 2
    try:
        session = open_session("plant", args.endpoint, args.zenoh_config)
    except BusConfigError as exc:
        log.error("%s", exc)
        return 2
    plant = None
    try:
        plant = Plant(spec, session, keys, args.mode, log, rate=args.rate,
                      expect=tuple(n for n in args.expect.split(",") if n),
                      duration_s=args.duration, join_timeout_s=args.join_timeout,
                      disabled=disabled,
                      end_with=tuple(n for n in args.end_with.split(",") if n),
                      coupling=args.coupling, physics_process=args.physics_process)

        def on_signal(signum, frame):
            plant.stop_event.set()
        signal.signal(signal.SIGINT, on_signal)
        signal.signal(signal.SIGTERM, on_signal)
        code = plant.run()
        st = plant.stats()
        log.info("stopped at t=%.2f s after %d ticks (%.1fx real time)", st["sim_time_s"],
                 st["ticks"], st["real_time_factor"] or 0.0)
        return code
    except PhysicsError as exc:
        log.error("%s", exc)
        if plant is not None:
            plant.end_reason = "physics process failed"
        return 1
    finally:
        if plant is not None:
            if args.stats:
                write_json(args.stats, plant.stats())
            plant.close(plant.end_reason)
        session.close()
