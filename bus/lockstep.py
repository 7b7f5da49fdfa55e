"""The plant's half of the lockstep rules of docs/PROTOCOL.md, with no Zenoh and no DART.

:class:`AckLedger`: who must answer which tick, the ACKs and member messages that came for
it, FINALs, members that left, missing outputs and second ACKs (PROTOCOL.md section 4,
"Each tick k" step 4, "Finishing", "Reset"; section 7 for what it counts as a protocol
error). The member's half is :class:`bus.member.MemberTick`. The plant (``plant/process.py``)
is an adapter: it moves messages between Zenoh and the ledger. Each method names its
section.
"""
from __future__ import annotations

from typing import Callable

from . import codec
from .protocol import PACE_TICKS

#: ACKs per member, member messages and the members owed per tick, remembered (ticks)
RECENT_TICKS = 32
#: :attr:`AckLedger.pace_ns` while no watcher says what it has taken in: no tick waits
UNPACED_NS = 1 << 63
#: the protocol error kind of a hold longer than the world's command timeout allows
#: (section 4, "Holding"; counted in the plant's stats as ``holds_past_timeout``)
HOLD_PAST = "hold past cmd_timeout"


class AckLedger:
    """The plant's record of the lockstep handshake (docs/PROTOCOL.md section 4).

    ``report(kind, text)`` counts and logs a protocol error (section 7); ``end_with`` are
    the members whose FINAL ends the run.
    """

    def __init__(self, tick_ns: int, report: Callable[[str, str], None],
                 end_with: tuple[str, ...] = (), expect: tuple[str, ...] = ()) -> None:
        self.tick_ns = tick_ns
        self.report = report
        self.end_with = tuple(end_with)
        self.expected = set(expect) | set(end_with)   # members the run cannot go on without
        self.members: set[str] = set()          # holding a sim/sync token now
        self.members_seen: set[str] = set()     # ever held one
        # member -> {tick stamp: (n_plant, final)} from its ACKs, the last few ticks: a
        # stray, late or forged ACK never hides the one the plant waits for
        self.acks: dict[str, dict[int, tuple[int, bool]]] = {}
        # member -> {tick stamp of an ACK with a hold: the last tick it holds}, the last few
        # ("Holding"): the ticks in between count as answered, with nothing
        self.holds: dict[str, dict[int, int]] = {}
        # the longest hold whose command still acts on its last held tick (the plant sets it
        # from its robots' cmd_timeout_s: bus.protocol.max_hold); a longer one is reported
        self.max_hold = codec.HOLD_MAX
        self.finished: dict[str, int] = {}      # member -> stamp of its FINAL tick
        self.final_awaited: set[str] = set()    # ending members given their grace once
        # (member, tick stamp) -> the plant-read keys of its messages stamped for that tick
        self.member_msgs: dict[tuple[str, int], set[str]] = {}
        # members gone without their FINAL that the plant holds time for ("Lost members")
        self.lost: dict[str, int] = {}          # member -> the plant's tick when it went
        self.rejoined: dict[str, int] = {}      # member -> the plant's tick when it came back
        # processes that are not members (a recorder, a view: a sim/alive token) gone with
        # the plant's link to its router: time is held for them too ("Lost members")
        self.away: set[str] = set()
        self.resent_upto = -1                   # the last tick the plant re-published
        # tick stamp -> the members present when the plant began that tick
        self.owed_by: dict[int, frozenset[str]] = {}
        # processes that are not members and say what they have taken in (sim/seen/<node>:
        # a recorder) -> the stamp they last said ("Watchers that keep up")
        self.seen: dict[str, int] = {}
        # the last tick that may be published with nobody of ``seen`` behind (:meth:`behind`),
        # kept as the reports come, so the plant's check a tick is one int compare
        self.pace_ns = UNPACED_NS

    # ------------------------------------------------------------ membership
    def join(self, node: str, now_ns: int = 0) -> bool:
        """Section 4, "Joining": a member is waited for from the next tick the plant begins;
        "Lost members": one the plant held time for is owed again every tick it has not
        ACKed yet, the one the plant is at included. True if it is such a rejoin."""
        self.members.add(node)
        self.members_seen.add(node)
        self.finished.pop(node, None)
        self.final_awaited.discard(node)
        if node not in self.lost:
            return False
        del self.lost[node]
        self.rejoined[node] = now_ns
        last = max(self.acks.get(node, {}), default=-1)
        for t, owed in self.owed_by.items():
            if t > last or not self.done(node, t):
                self.owed_by[t] = owed | {node}
        return True

    def leave(self, node: str, link_lost: bool = False) -> str:
        """Section 4, step 4 and "Lost members": a member whose ``sim/sync`` token vanished.
        "finished" if its FINAL came (kept: "Finishing"); "lost" if the plant must hold time
        for it (an ``--expect``/``--end-with`` member, the last member, or any member when
        the plant lost its own router or link: ``link_lost``); "dropped" if the others go
        on without it."""
        self.members.discard(node)
        if node in self.finished:
            return "finished"
        if node in self.expected or not self.members or link_lost:
            self.lost.setdefault(node, max(self.owed_by, default=0))
            return "lost"
        return "dropped"

    def held_for(self) -> list[str]:
        """Section 4, "Lost members": the members gone without their FINAL whose rejoin the
        plant waits for before it advances time (an ``--end-with`` member's FINAL may still
        come after its token: then it is not lost), then the other processes gone with the
        plant's link (:meth:`gone_with_link`)."""
        members = sorted(m for m in self.lost if m not in self.finished)
        if not self.away:                       # (asked every tick: the usual case first)
            return members
        return members + sorted(self.away - set(members))

    def gone_with_link(self, node: str) -> bool:
        """Section 4, "Lost members": a process that is not a member (its ``sim/alive``
        token only: a recorder, a view) went with the plant's link to its router; time is
        held until it is back (:meth:`back`) or the plant gives up on it
        (:meth:`give_up_away`). True if it is held for from now (not a member, not held
        for already)."""
        if node in self.members_seen or node in self.away:
            return False
        self.away.add(node)
        self._repace()
        return True

    def back(self, node: str) -> bool:
        """Section 4, "Lost members": a process's ``sim/alive`` token is back; True if time
        was held for it."""
        if node in self.away:
            self.away.discard(node)
            self._repace()
            return True
        return False

    def give_up_away(self) -> list[str]:
        """Section 4, "Lost members": the processes held for that are not members, given up
        on (the rejoin timeout ran out: the run goes on without them), and no longer kept up
        with ("Watchers that keep up")."""
        gone, self.away = sorted(self.away), set()
        for node in gone:
            self.seen.pop(node, None)
        self._repace()
        return gone

    def saw(self, node: str, t_ns: int) -> None:
        """Section 4, "Watchers that keep up": ``node``, a process that is not a member, has
        taken in the ticks up to ``t_ns`` (its latest ``sim/seen``; a member's is ignored)."""
        if node not in self.members_seen:
            self.seen[node] = t_ns
            self._repace()

    def unseen(self, node: str) -> None:
        """Section 4, "Watchers that keep up": ``node`` is gone (and not held for): the plant
        no longer keeps up with it."""
        if self.seen.pop(node, None) is not None:
            self._repace()

    def _repace(self) -> None:
        """:attr:`pace_ns` from ``seen`` and ``away``, whenever either changes."""
        pace = PACE_TICKS * self.tick_ns
        self.pace_ns = min((t + pace for n, t in self.seen.items() if n not in self.away),
                           default=UNPACED_NS)

    def behind(self, t_ns: int) -> list[str]:
        """Section 4, "Watchers that keep up": the processes that said what they have taken
        in and have not reached ``PACE_TICKS`` ticks before ``t_ns``: tick ``t_ns`` is not
        published until they have. One held for ("Lost members") is the hold's, with its
        timeout, until it is back. Nobody is if ``t_ns`` is at most :attr:`pace_ns`."""
        if t_ns <= self.pace_ns:                # (asked every tick: the usual case first)
            return []
        least = t_ns - PACE_TICKS * self.tick_ns
        return sorted(n for n, t in self.seen.items() if t < least and n not in self.away)

    def all_finished(self, due_ns: int) -> bool:
        """Section 4, "Finishing": every member still present sent its FINAL for a tick
        before ``due_ns`` (so its FINAL command has acted), none is lost, and at least one
        took part: the run ends, ``--end-with`` or not (a lockstep plant never runs alone)."""
        return (bool(self.members_seen) and not self.held_for()
                and all(self.finished.get(m, due_ns) < due_ns for m in self.members))

    def begin_tick(self, t_ns: int) -> None:
        """Section 4, step 4: tick ``t_ns`` is owed by the members present as it begins
        (pipelined coupling looks at its ACKs a tick later, when others may have joined)."""
        self.owed_by[t_ns] = frozenset(self.members)
        while len(self.owed_by) > RECENT_TICKS:
            del self.owed_by[next(iter(self.owed_by))]

    # ------------------------------------------------------------ messages
    def file(self, key: str, topic: str, att: codec.Attachment | None, raw: bytes | None,
             now_ns: int) -> bool:
        """File one message on a plant-read key or ``sim/ack/<node>`` (section 4, steps 3-4;
        section 7 for what is wrong with it). False if it is not to be used at all."""
        if self._plain(att, now_ns):             # (nothing to report: the usual case)
            return self._take(key, topic, att)
        if att is None or att.node is None:
            if topic == "odom":                  # a realtime-style odometry node: not ours
                return False
            why = ("no attachment" if not raw
                   else "a malformed attachment" if att is None
                   else "a plain 16-byte attachment (no member trailer)")
            self.report(f"{key}: {why}",
                        "a lockstep member's outputs carry seq, stamp and the trailer "
                        "flags|n_plant|name (docs/PROTOCOL.md); "
                        + ("applied as a command from a non-member" if topic != "ack"
                           else "ignored"))
            return topic != "ack"
        member, t = att.node, att.t_ns
        if self.tick_ns and t % self.tick_ns:
            self.report(f"{key}: stamp off the tick grid", f"t={t * 1e-9:.9f} s from {member}; "
                        "ignored")
            return False
        # A tick the member holds is told by its own earlier ACK (in order from its session),
        # so this comes before "not due", which depends on how far the plant has got.
        if (held := self.holding(member, t)) is not None:
            self.report(f"{key}: a message from {member} for a tick it holds",
                        f"t={t * 1e-9:.3f} s, held from its ACK of t={held * 1e-9:.3f} s; "
                        "ignored")
            return False
        if t > now_ns:
            self.report(f"{key}: stamped for a tick not due",
                        f"t={t * 1e-9:.3f} s from {member}, the plant is at "
                        f"t={now_ns * 1e-9:.3f} s; ignored")
            return False
        if member not in self.members and member not in self.members_seen:
            self.report(f"{key}: from {member!r}, not a lockstep member",
                        "(no sim/sync token); used, not waited for")
        return self._take(key, topic, att)

    def file_many(self, msgs: list[tuple[str, str, codec.Attachment | None, bytes | None]],
                  now_ns: int) -> list[bool]:
        """Section 4, steps 3-4: :meth:`file` of each ``(key, topic, att, raw)`` in order,
        for one member's answer to one tick (a composed member's: every message from the
        same member, for the same tick), with what they share checked once: the same
        filing, ACK and reports as :meth:`file` message by message (which it is, where
        anything is to be reported)."""
        first = msgs[0][2] if msgs else None
        if first is None or not self._plain(first, now_ns) or any(
                a is None or a.node != first.node or a.t_ns != first.t_ns
                for _, _, a, _ in msgs):
            return [self.file(key, topic, att, raw, now_ns) for key, topic, att, raw in msgs]
        if (len(msgs) > 1 and not any(m[2].flags & codec.ACK for m in msgs[:-1])
                and all(m[1] != "ack" for m in msgs)):
            # (the usual answer: outputs on distinct keys, the ACK on the last one) filed
            # with one set update, as _take of each would file them
            keys = {m[0] for m in msgs}
            got = self.member_msgs.get((first.node, first.t_ns))
            if len(keys) == len(msgs) and (got is None or got.isdisjoint(keys)):
                self._take(msgs[-1][0], msgs[-1][1], msgs[-1][2])
                self.member_msgs[(first.node, first.t_ns)].update(keys)
                return [True] * len(msgs)
        take = self._take
        return [take(key, topic, att) for key, topic, att, _ in msgs]

    def file_answer(self, keys: frozenset, last: str, topic: str,
                    att: codec.Attachment | None, now_ns: int) -> bool:
        """Section 4, steps 3-4: :meth:`file_many` of a composed member's usual answer to a
        tick: outputs on the distinct keys ``keys`` (none an ACK key), the last on ``last``
        (``topic``) with the ACK, every one with an attachment like ``att`` (the same member
        and tick): filed with one set update, True; False, with nothing filed, where
        anything is to be reported or checked message by message (then :meth:`file_many`)."""
        if att is None or not att.flags & codec.ACK or topic == "ack" \
                or not self._plain(att, now_ns):
            return False
        got = self.member_msgs.get((att.node, att.t_ns))
        if got is not None and not got.isdisjoint(keys):
            return False
        self._take(last, topic, att)
        self.member_msgs[(att.node, att.t_ns)].update(keys)
        return True

    def _plain(self, att: codec.Attachment | None, now_ns: int) -> bool:
        """Section 7: a message :meth:`file` takes with nothing to report about its
        attachment: a lockstep member's (known) for a tick on the grid, due and not held."""
        if att is None or att.node is None:
            return False
        member, t = att.node, att.t_ns
        return ((not self.tick_ns or not t % self.tick_ns) and t <= now_ns
                and (member in self.members or member in self.members_seen)
                and self.holding(member, t) is None)

    def _take(self, key: str, topic: str, att: codec.Attachment) -> bool:
        """Section 4, steps 3-4: file a member's message whose attachment passed the checks
        (first per key per tick; an ACK ends the member's answer)."""
        member, t = att.node, att.t_ns
        # A member that left is not waited for, but its ACK is still filed: its FINAL may
        # arrive just after its sim/sync token went (liveliness and data take different
        # paths), and --end-with must still end the run at that tick.
        if topic != "ack":
            got = self.member_msgs.setdefault((member, t), set())
            if key in got:
                # First per key per tick wins: what a second one would do must not depend on
                # whether it came before or after the plant applied the tick.
                if t > max(self.rejoined.get(member, -1), self.resent_upto):   # else re-sent
                    self.report(f"{key}: a second message from {member} for one tick",
                                f"t={t * 1e-9:.3f} s; the first is kept, this one ignored")
                return False
            got.add(key)
            if len(self.member_msgs) > 4 * RECENT_TICKS * max(1, len(self.members)):
                del self.member_msgs[next(iter(self.member_msgs))]
        elif t in self.acks.get(member, {}) and t <= max(self.rejoined.get(member, -1),
                                                          self.resent_upto):
            return False                                 # an empty ACK re-sent after a rejoin
        if att.flags & codec.ACK:
            self._ack(key, member, t, att.n_plant, bool(att.flags & codec.FINAL),
                      codec.hold_of(att.flags))
        return True

    def _ack(self, key: str, member: str, t: int, n_plant: int, final: bool,
             hold: int = 0) -> None:
        """Section 7: a member ACKs a tick once; a second ACK is forged or a bug, and the
        smaller ``n_plant`` is kept, so no stray ACK can hold the run forever. Section 4,
        "Holding": an ACK with a hold answers the ``hold`` ticks after ``t`` too (the first
        ACK's hold: a second one's is ignored with it)."""
        if hold and t not in self.acks.get(member, {}):
            if hold > self.max_hold:
                # Taken all the same (the member sends nothing for those ticks: waiting would
                # stall the run); the command it leaves standing expires at the bound.
                self.report(HOLD_PAST, f"{member} holds {hold} ticks from t={t * 1e-9:.3f} s; "
                            f"at most {self.max_hold} keep its commands within cmd_timeout_s: "
                            "its robots stop when their command expires")
            holds = self.holds.setdefault(member, {})
            holds[t] = t + hold * self.tick_ns
            if len(holds) > RECENT_TICKS:
                del holds[next(iter(holds))]
        acks = self.acks.setdefault(member, {})
        ack = (n_plant, final)
        if t in acks:
            self.report(f"{key}: a second ACK from {member}",
                        f"for t={t * 1e-9:.3f} s (n_plant {acks[t][0]} and {n_plant})")
            ack = (min(ack[0], acks[t][0]), ack[1] or acks[t][1])
        acks[t] = ack
        if ack[1]:
            # Kept after the member leaves: under pipelined coupling it may leave before
            # the plant has looked for its FINAL (--end-with must still see it).
            self.finished[member] = t
        if len(acks) > RECENT_TICKS:
            del acks[next(iter(acks))]

    # ------------------------------------------------------------ the barrier
    def holding(self, member: str, t_ns: int) -> int | None:
        """Section 4, "Holding": the tick of the member's ACK whose hold covers ``t_ns``
        (a later tick, up to its hold), or None."""
        holds = self.holds.get(member)
        if holds:
            for t0, t1 in reversed(holds.items()):      # (the latest first: the usual ask)
                if t0 < t_ns <= t1:
                    return t0
        return None

    def done(self, member: str, t_ns: int) -> bool:
        """Section 4, step 4: the member ACKed tick ``t_ns`` and all ``n_plant`` of its
        messages stamped ``t_ns`` are in, or an ACK of its holds ``t_ns`` ("Holding")."""
        ack = self.acks.get(member, {}).get(t_ns)
        if ack is None:
            return self.holding(member, t_ns) is not None
        return len(self.member_msgs.get((member, t_ns), ())) >= ack[0]

    def waiting_for(self, t_ns: int) -> list[str]:
        """Section 4, step 4 and "Finishing": the members owed tick ``t_ns`` (present when
        it began, still present, not finished before it) whose answer is not complete."""
        owed = self.owed_by.get(t_ns, self.members)
        return [m for m in sorted(owed) if m in self.members and not self.done(m, t_ns)
                and self.finished.get(m, t_ns) >= t_ns]

    def may_step(self, t_ns: int) -> bool:
        """Section 4, step 4 and "Lost members": whether the plant may step past the tick
        whose answers are those of ``t_ns`` (none due if negative), asked with no event
        handled since the answer: no member is lost and none owes ``t_ns``. A member that
        rejoins while the plant waits for something else (an ``--end-with`` member's FINAL,
        the hold) owes again the ticks it has not answered, and is waited for."""
        return not self.held_for() and (t_ns < 0 or not self.waiting_for(t_ns))

    def stale_command(self, t_ns: int, keys: tuple[str, ...], cmd_t: int | None,
                      refused: bool = False, owing: list[str] | None = None) -> str | None:
        """Section 4, "Couplings": None if the command about to drive a robot (stamped
        ``cmd_t``; None: it has none) is the rule's for the tick whose commands act,
        ``t_ns``: the one stamped ``t_ns``, or, where no member sent one for ``t_ns``, the
        latest before it. Otherwise what is wrong (a protocol error, section 7): a member
        still owes ``t_ns`` (the plant steps without its answer), or a member's message
        for ``t_ns`` on one of the robot's command ``keys`` was taken but is not the one
        that acts (``refused``: the plant rejected a command of ``t_ns`` for bad values,
        counted as such). Cheap when the command is the tick's: one comparison (``owing``:
        ``waiting_for(t_ns)`` if the caller has it already)."""
        if cmd_t == t_ns or t_ns < 0:
            return None
        had = "no command" if cmd_t is None else f"the command of t={cmd_t * 1e-9:.3f} s"
        if owing is None:
            owing = self.waiting_for(t_ns)
        if owing:
            return (f"t={t_ns * 1e-9:.3f} s stepped with {had} while {', '.join(owing)} "
                    "had not answered it")
        if refused:
            return None
        for m in sorted(self.owed_by.get(t_ns, ())):
            got = self.member_msgs.get((m, t_ns), ())
            if any(k in got for k in keys):
                return (f"{m}'s command for t={t_ns * 1e-9:.3f} s was taken, but {had} "
                        "acts")
        return None

    def missing_outputs(self, member: str, t_ns: int) -> tuple[int, int] | None:
        """Section 7: (n_plant the member's ACK of ``t_ns`` announced, messages that came),
        or None if it has not ACKed that tick."""
        ack = self.acks.get(member, {}).get(t_ns)
        return None if ack is None else (ack[0], len(self.member_msgs.get((member, t_ns), ())))

    def report_missing(self, t_ns: int, waiting: list[str]) -> None:
        """Section 7: a member still owed ``t_ns`` whose ACK came but not all its messages
        is a protocol error (counted and said each time the plant says whom it waits for)."""
        for m in sorted(waiting):
            missing = self.missing_outputs(m, t_ns)
            if missing is not None:
                self.report("missing outputs", f"{m} ACKed t={t_ns * 1e-9:.3f} s with "
                            f"n_plant={missing[0]} but {missing[1]} of its messages for it "
                            "arrived")

    def describe_wait(self, t_ns: int, waiting: list[str]) -> list[str]:
        """Section 7: for each member still owed ``t_ns``, whether its ACK came and how many
        of its messages."""
        parts = []
        for m in sorted(waiting):
            missing = self.missing_outputs(m, t_ns)
            got = len(self.member_msgs.get((m, t_ns), ()))
            if missing is not None:
                parts.append(f"{m} (ACKed with n_plant={missing[0]}, {got} arrived)")
            else:
                last = max(self.acks.get(m, {}), default=None)
                parts.append(f"{m} (no ACK; {got} message(s) for this tick; last ACK "
                             + (f"t={last * 1e-9:.3f} s)" if last is not None else "none)"))
        return parts

    # ------------------------------------------------------------ the end
    def ended(self, upto_ns: int) -> list[str]:
        """Section 4, "Finishing": the ``--end-with`` members whose FINAL tick is at or
        before ``upto_ns``."""
        return [m for m in self.end_with if self.finished.get(m, upto_ns + 1) <= upto_ns]

    def left_before_final(self) -> list[str]:
        """Section 4, "Finishing": ``--end-with`` members whose token went before their FINAL
        came and that were not yet given their grace (each is, once: marked here)."""
        out = [m for m in self.end_with
               if m in self.members_seen and m not in self.members and m not in self.finished
               and m not in self.final_awaited]
        self.final_awaited.update(out)
        return out

    def restart(self) -> None:
        """Section 4, "Reset": the world restarted at t = 0, so the old world's ACKs, FINALs
        and messages are forgotten (their stamps would match the new world's ticks)."""
        self.acks.clear()
        self.holds.clear()
        self.finished.clear()
        self.member_msgs.clear()
        self.owed_by.clear()
        self.rejoined.clear()
        self.seen.clear()             # (stamps of the old world; the new one's come)
        self._repace()
        self.resent_upto = -1
