"""A userspace delay wire: forwards every Ethernet frame between pairs of interfaces after
a fixed delay, for kernels without ``sch_netem`` (stdlib only, needs root).

    python -m tests.support.netwire IFACE_A IFACE_B [IFACE_C IFACE_D ...] --delay-ms 1

Interfaces are taken in pairs (A<->B, C<->D, ...); they must be up, without addresses
(run it in a namespace of its own, between two veth pairs). Each frame leaves
``delay`` after the kernel received it (its SO_TIMESTAMPNS stamp, so time the process
spends not scheduled is counted, not added), in arrival order per direction. Frames the
wire sent itself (PACKET_OUTGOING) are skipped.

Offloads: a veth hands its peer GSO "super-frames" (up to 64 KiB of TCP) with the
checksum left to fill in (CHECKSUM_PARTIAL). The sockets use PACKET_VNET_HDR, so each
frame comes with its virtio-net header (GSO size/type, checksum start/offset) and is sent
on with that same header: the kernel keeps it a GSO frame with a partial checksum, exactly
what the veth would have passed on. Without it the TCP checksums arrive unfilled and a
TCP connection through the wire never completes (tried), and GSO frames are longer than
the MTU. No ethtool needed (there is none here), nor turning offloads off.

Prints ``wire up`` once bound, and its counters on SIGTERM/SIGINT.
"""
from __future__ import annotations

import argparse
import collections
import os
import select
import signal
import socket
import struct
import sys
import time

ETH_P_ALL = 0x0003
SOL_PACKET = 263
PACKET_ADD_MEMBERSHIP = 1
PACKET_MR_PROMISC = 1
PACKET_VNET_HDR = 15
PACKET_OUTGOING = 4
SO_TIMESTAMPNS = 35
SCM_TIMESTAMPNS = SO_TIMESTAMPNS
VNET_HDR_LEN = 10                     # struct virtio_net_hdr
VIRTIO_NET_HDR_F_DATA_VALID = 2       # receive-only flag: not ours to send
BUF_BYTES = 256 * 1024                # > any GSO frame a veth makes (64 KiB by default)
DRAIN_MAX = 64                        # frames read per socket before looking at the clock


def open_port(ifname: str) -> socket.socket:
    s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
    s.setsockopt(SOL_PACKET, PACKET_VNET_HDR, 1)
    s.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 * 1024 * 1024)
    s.bind((ifname, ETH_P_ALL))
    mreq = struct.pack("iHH8s", socket.if_nametoindex(ifname), PACKET_MR_PROMISC, 0, b"")
    s.setsockopt(SOL_PACKET, PACKET_ADD_MEMBERSHIP, mreq)
    s.setblocking(False)
    return s


class Direction:
    """Frames read on ``src``, waiting for their time to leave on ``dst``."""

    def __init__(self, src: socket.socket, dst: socket.socket, name: str) -> None:
        self.src, self.dst, self.name = src, dst, name
        self.queue: collections.deque[tuple[int, bytes]] = collections.deque()
        self.frames = self.bytes = self.max_frame = self.dropped = 0
        self.late_ns_max = self.late_ns_sum = 0

    def read(self, delay_ns: int) -> None:
        for _ in range(DRAIN_MAX):
            try:
                data, anc, flags, addr = self.src.recvmsg(BUF_BYTES, 256)
            except BlockingIOError:
                return
            if addr[2] == PACKET_OUTGOING:
                continue
            if flags & socket.MSG_TRUNC:
                self.dropped += 1
                continue
            stamp = next((int.from_bytes(d[:8], "little", signed=True) * 1_000_000_000
                          + int.from_bytes(d[8:16], "little", signed=True)
                          for lvl, typ, d in anc
                          if lvl == socket.SOL_SOCKET and typ == SCM_TIMESTAMPNS),
                         time.time_ns())
            if data[0] & VIRTIO_NET_HDR_F_DATA_VALID:
                data = bytes([data[0] & ~VIRTIO_NET_HDR_F_DATA_VALID]) + data[1:]
            self.queue.append((stamp + delay_ns, data))

    def send_due(self, now_ns: int) -> None:
        q = self.queue
        while q and q[0][0] <= now_ns:
            due, data = q.popleft()
            try:
                self.dst.send(data)
            except OSError as exc:            # full queue or a frame the device refuses
                self.dropped += 1
                if self.dropped <= 5:
                    print(f"wire {self.name}: dropped a {len(data) - VNET_HDR_LEN} B "
                          f"frame: {exc}", file=sys.stderr, flush=True)
                continue
            late = time.time_ns() - due
            self.frames += 1
            self.bytes += len(data) - VNET_HDR_LEN
            self.max_frame = max(self.max_frame, len(data) - VNET_HDR_LEN)
            self.late_ns_max = max(self.late_ns_max, late)
            self.late_ns_sum += late

    def summary(self) -> str:
        mean_us = self.late_ns_sum / self.frames / 1e3 if self.frames else 0.0
        return (f"{self.name}: {self.frames} frames, {self.bytes} B, largest "
                f"{self.max_frame} B, dropped {self.dropped}, sent late by mean "
                f"{mean_us:.0f} us / max {self.late_ns_max / 1e3:.0f} us")


def run(ifaces: list[str], delay_ns: int) -> list[Direction]:
    ports = {name: open_port(name) for name in ifaces}
    dirs: list[Direction] = []
    for a, b in zip(ifaces[::2], ifaces[1::2]):
        dirs += [Direction(ports[a], ports[b], f"{a}->{b}"),
                 Direction(ports[b], ports[a], f"{b}->{a}")]
    by_src = {d.src.fileno(): d for d in dirs}
    print("wire up", flush=True)
    try:
        while True:
            now = time.time_ns()
            for d in dirs:
                d.send_due(now)
            heads = [d.queue[0][0] for d in dirs if d.queue]
            timeout = max(0.0, (min(heads) - time.time_ns()) / 1e9) if heads else None
            readable, _, _ = select.select(list(by_src), [], [], timeout)
            for fd in readable:
                by_src[fd].read(delay_ns)
    except KeyboardInterrupt:
        return dirs


def _stop(signum, frame):
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tests.support.netwire", description=__doc__.split("\n\n")[0])
    ap.add_argument("ifaces", nargs="+", metavar="IFACE",
                    help="interfaces, in pairs: A B [C D ...] joins A<->B, C<->D")
    ap.add_argument("--delay-ms", type=float, default=1.0,
                    help="one-way delay added to every frame (default 1)")
    ap.add_argument("--realtime", action="store_true",
                    help="run as SCHED_FIFO priority 1 (root): on a busy machine frames "
                         "then leave ~75 us after their due time instead of ~200 us")
    a = ap.parse_args(argv)
    if len(a.ifaces) % 2 or a.delay_ms < 0:
        ap.error("give interfaces in pairs and a delay >= 0")
    if a.realtime:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
        except OSError as exc:
            print(f"wire: --realtime ignored: {exc}", file=sys.stderr, flush=True)
    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    try:
        dirs = run(a.ifaces, int(a.delay_ms * 1e6))
    except OSError as exc:
        print(f"wire: {exc}", file=sys.stderr)
        return 2
    for d in dirs:
        print(d.summary(), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
