"""The bus protocol's version and lockstep constants (the contract: docs/PROTOCOL.md).

Keys are spelled in :mod:`bus.keys`, payloads and attachments encoded in :mod:`bus.codec`;
this module holds what both sides of lockstep must agree on, and a test checks it
against docs/PROTOCOL.md.
"""
from __future__ import annotations

from .codec import HOLD_MAX

#: announced by the plant in ``sim/info`` as ``"protocol"``; a node of another version exits 2
PROTOCOL_VERSION = 5
#: additions within the version (``sim/info`` ``protocol_minor``; absent: 0): 1 ``sim/seen``,
#: 2 the hold's bound enforced and counted, the reset reply's ``epoch``; 3 ``sim/poses``
#: (docs/PROTOCOL.md 8)
PROTOCOL_MINOR = 3

#: how the plant and the lockstep members are coupled (co-simulation master algorithm)
COUPLINGS = ("sequential", "pipelined")

#: robot topics the plant subscribes to in lockstep: the commands it applies, and ``odom``
#: only to take a member's ACK from it (a member whose last output of a tick is on one of
#: these needs no ``sim/ack/<node>`` message)
PLANT_READS = ("cmd_vel", "wheel_cmd", "odom")

#: lockstep: the plant keeps its last this many ticks' messages and re-publishes them when a
#: lost member or a watcher comes back (section 4, "Lost members"): what a blip swallowed,
#: for the members (at most the last three ticks) and for a recorder, whose share of the
#: router's queue may lag further behind (up to PACE_TICKS and the members' last outputs)
REPUBLISH_TICKS = 25

#: lockstep: the plant never publishes a tick more than this many ticks after the latest
#: ``sim/seen/<node>`` of a process that reports one (section 4, "Watchers that keep up"),
#: so what a blip swallows of that process's share is within the re-published ticks (the
#: rest of REPUBLISH_TICKS: members' outputs of a tick may reach it after the next clocks)
PACE_TICKS = 20
#: how often a watcher that keeps up says what it has taken in (every this many ticks)
SEEN_EVERY_TICKS = 5
#: at a run's end, how long (wall s) the plant waits for every process that answers a get on
#: ``sim/seen/*`` to have taken in its last tick before it says sim/end and leaves (what is
#: still on its way when the plant's session closes is lost)
END_SEEN_S = 2.0


def encode_seen(t_ns: int) -> bytes:
    """``sim/seen/<node>``'s payload: the stamp as a little-endian u64."""
    return int(t_ns).to_bytes(8, "little")


def decode_seen(payload: bytes) -> int:
    """The stamp of a ``sim/seen/<node>`` payload; ValueError unless it is 8 bytes."""
    if len(payload) != 8:
        raise ValueError(f"sim/seen: {len(payload)} bytes, not 8 (a u64 stamp)")
    return int.from_bytes(payload, "little")


class ProtocolError(Exception):
    """The other side speaks another protocol version: a node must not join (this project's
    nodes exit 2, at the start and when a plant comes back, docs/PROTOCOL.md)."""


def delays(coupling: str) -> dict[str, int]:
    """The delays a coupling adds, in control ticks: commands stamped t_k act from
    t_{k + actuation_delay_ticks}; a node sees other nodes' outputs of tick
    k - node_input_delay_ticks at tick k."""
    if coupling not in COUPLINGS:
        raise ValueError(f"unknown coupling {coupling!r} (choose from {', '.join(COUPLINGS)})")
    d = 1 if coupling == "pipelined" else 0
    return {"actuation_delay_ticks": d, "node_input_delay_ticks": d}


def command_expired(age_ns: int, cmd_timeout_s: float) -> bool:
    """Section 4, "Couplings": whether a command ``age_ns`` old (the simulated time of the
    tick it acts from, minus its stamp) is past a robot's ``cmd_timeout_s``, which stops the
    robot. An age equal to the timeout is not past it; compared in whole nanoseconds."""
    return age_ns > round(cmd_timeout_s * 1e9)


def max_hold(tick_ns: int, cmd_timeout_s: float, actuation_delay_ticks: int) -> int:
    """Section 4, "Holding": the longest hold whose command still acts on its last held
    tick: the command of t_k acts at t_{k+h+delay} at the latest, aged (h + delay) ticks,
    which must not be past ``cmd_timeout_s`` (:func:`command_expired`). So (h + delay) x
    tick <= cmd_timeout_s, at most the HOLD_MAX (63) the trailer holds; 0 if even one tick is
    past it."""
    h = round(cmd_timeout_s * 1e9) // max(1, tick_ns) - actuation_delay_ticks
    return max(0, min(HOLD_MAX, h))


def world_max_hold(tick_ns: int, cmd_timeouts_s, actuation_delay_ticks: int) -> int:
    """:func:`max_hold` of a world: for the smallest of its robots' ``cmd_timeouts_s`` (a
    hold is the member's, whichever robots it drives); HOLD_MAX for a world without robots."""
    timeouts = [t for t in cmd_timeouts_s if t is not None]
    if not timeouts:
        return HOLD_MAX
    return max_hold(tick_ns, min(timeouts), actuation_delay_ticks)


def info_max_hold(info: dict) -> int:
    """:func:`world_max_hold` of a plant's ``sim/info`` (section 5): its control tick, its
    coupling's actuation delay and its robots' ``drive.cmd_timeout_s``."""
    return world_max_hold(round(info["control_tick_s"] * 1e9),
                          (r.get("drive", {}).get("cmd_timeout_s")
                           for r in info.get("robots", {}).values()),
                          int(info.get("actuation_delay_ticks", 0)))


def check_version(info: dict) -> None:
    """Raise :class:`ProtocolError` unless the plant's ``sim/info`` speaks this version."""
    theirs = info.get("protocol")
    if theirs != PROTOCOL_VERSION:
        said = f"bus protocol {theirs}" if theirs is not None else "no bus protocol version " \
               "(a plant older than protocol 2)"
        raise ProtocolError(f"the plant speaks {said}; this node speaks bus protocol "
                            f"{PROTOCOL_VERSION} (docs/PROTOCOL.md): use matching versions")
