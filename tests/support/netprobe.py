"""Small network probes for the namespace tests (stdlib only; ``ping`` needs root):

    python -m tests.support.netprobe ping HOST [-c 200] [-i 0.01]     # ICMP echo; prints JSON
    python -m tests.support.netprobe sink IP PORT                     # take one TCP stream, print its
                                                              # size and sha256 as JSON
    python -m tests.support.netprobe send IP PORT BYTES               # send BYTES of seeded data

``ping`` prints {"sent", "received", "min_ms", "avg_ms", "max_ms"}; the machine has no
iputils ``ping``, and a test can read JSON.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import random
import select
import socket
import struct
import sys
import time


def _checksum(b: bytes) -> int:
    if len(b) % 2:
        b += b"\0"
    s = sum(struct.unpack(f"!{len(b) // 2}H", b))
    s = (s >> 16) + (s & 0xFFFF)
    s += s >> 16
    return ~s & 0xFFFF


def ping(host: str, count: int, interval_s: float, timeout_s: float = 1.0) -> dict:
    s = socket.socket(socket.AF_INET, socket.SOCK_RAW, socket.IPPROTO_ICMP)
    ident = os.getpid() & 0xFFFF
    rtts: list[float] = []
    try:
        for seq in range(count):
            body = struct.pack("!d", time.monotonic()) + bytes(48)
            hdr = struct.pack("!BBHHH", 8, 0, 0, ident, seq)
            pkt = struct.pack("!BBHHH", 8, 0, _checksum(hdr + body), ident, seq) + body
            t0 = time.monotonic()
            s.sendto(pkt, (host, 0))
            deadline = t0 + timeout_s
            while (left := deadline - time.monotonic()) > 0:
                if not select.select([s], [], [], left)[0]:
                    break
                data = s.recv(2048)
                ihl = (data[0] & 0x0F) * 4
                typ, _, _, rid, rseq = struct.unpack("!BBHHH", data[ihl:ihl + 8])
                if typ == 0 and rid == ident and rseq == seq:
                    rtts.append((time.monotonic() - t0) * 1e3)
                    break
            time.sleep(max(0.0, t0 + interval_s - time.monotonic()))
    finally:
        s.close()
    out = {"sent": count, "received": len(rtts)}
    if rtts:
        out.update(min_ms=min(rtts), avg_ms=sum(rtts) / len(rtts), max_ms=max(rtts))
    return out


def _data(n: int) -> bytes:
    return random.Random(14).randbytes(n)


def sink(ip: str, port: int) -> dict:
    with socket.create_server((ip, port)) as srv:
        print("listening", flush=True)
        conn, _ = srv.accept()
        h, n = hashlib.sha256(), 0
        with conn:
            while chunk := conn.recv(1 << 16):
                h.update(chunk)
                n += len(chunk)
    return {"bytes": n, "sha256": h.hexdigest()}


def send(ip: str, port: int, n: int) -> dict:
    data = _data(n)
    t0 = time.monotonic()
    with socket.create_connection((ip, port), timeout=20) as c:
        c.sendall(data)
        c.shutdown(socket.SHUT_WR)
        c.recv(1)
    return {"bytes": n, "sha256": hashlib.sha256(data).hexdigest(),
            "seconds": time.monotonic() - t0}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tests.support.netprobe")
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("ping")
    p.add_argument("host")
    p.add_argument("-c", type=int, default=200)
    p.add_argument("-i", type=float, default=0.01)
    p = sub.add_parser("sink")
    p.add_argument("ip")
    p.add_argument("port", type=int)
    p = sub.add_parser("send")
    p.add_argument("ip")
    p.add_argument("port", type=int)
    p.add_argument("bytes", type=int)
    a = ap.parse_args(argv)
    if a.cmd == "ping":
        out = ping(a.host, a.c, a.i)
    elif a.cmd == "sink":
        out = sink(a.ip, a.port)
    else:
        out = send(a.ip, a.port, a.bytes)
    print(json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
