"""Suite ``bus``: Zenoh round trip to an echo process (``diffbot.bench.echo``, started by
the suite)."""
from __future__ import annotations

import contextlib
import os
import shutil
import threading
import time

from .common import private_endpoint, spawn, stop, tail
from .harness import Case, Context, suite

PING, PONG = "diffbot_bench/ping", "diffbot_bench/pong"


def echo_main(endpoint: str) -> int:
    """The bus suite's child: echo every sample on PING back on PONG until b"stop"."""
    from bus.session import open_session
    parent = os.getppid()

    def orphan_watch():  # never outlive the benchmark, even if it was SIGKILLed
        while True:
            time.sleep(0.5)
            if os.getppid() != parent:
                os._exit(0)
    threading.Thread(target=orphan_watch, daemon=True).start()
    s = open_session("node", endpoint)
    try:
        pub = s.declare_publisher(PONG)
        sub = s.declare_subscriber(PING)
        while True:
            data = sub.recv().payload.to_bytes()
            if data == b"stop":
                return 0
            pub.put(data)
    finally:
        s.close()


@suite("bus", "Zenoh round trip to an echo process (router here, client there, unix socket)")
def bus_suite(ctx: Context):
    from time import perf_counter

    from bus.session import open_session
    d, endpoint = private_endpoint(ctx, "bus")
    session = open_session("plant", endpoint)
    child = None
    dead = threading.Event()
    done = threading.Event()
    try:
        pub = session.declare_publisher(PING)
        sub = session.declare_subscriber(PONG)
        child = spawn(["--echo", endpoint], os.path.join(d, "echo.log"),
                      module="diffbot.bench.echo")

        def watch():  # a dead echo process must not leave recv() blocked forever
            while not done.wait(0.1):
                if child.poll() is not None:
                    dead.set()
                    with contextlib.suppress(Exception):
                        session.put(PONG, b"")  # our own subscriber sees our own puts
        threading.Thread(target=watch, daemon=True).start()
        deadline = time.monotonic() + 30
        while True:  # say hello until the echo answers (its subscriber is then routed)
            if dead.is_set() or time.monotonic() > deadline:
                raise RuntimeError(f"echo process did not answer: {tail(os.path.join(d, 'echo.log'))}")
            pub.put(b"hello")
            got = None
            t_end = time.monotonic() + 0.1
            while got is None and time.monotonic() < t_end:
                got = sub.try_recv()
                if got is None:
                    time.sleep(0.002)
            if got is not None:
                break
        time.sleep(0.2)
        while sub.try_recv() is not None:  # drop stray hellos
            pass

        for size, label in ((64, "64 B"), (160 * 120 * 3, "57.6 KB (160x120 rgb8)")):
            if dead.is_set():
                raise RuntimeError("echo process died")
            payload = os.urandom(size)
            pub.put(payload)
            echoed = sub.recv().payload.to_bytes()
            if echoed != payload:
                raise RuntimeError(f"echo returned {len(echoed)} B for {size} B")

            def rtt(number, payload=payload):
                it = range(number)
                t0 = perf_counter()
                for _ in it:
                    pub.put(payload)
                    sub.recv()
                    if dead.is_set():
                        raise RuntimeError("echo process died")
                return perf_counter() - t0
            notes = "put + blocking FIFO recv, echo in another process"
            if size > 3000:
                notes += "; Zenoh shared memory on by default above ~3 KB"
            yield Case(f"round trip {label}", rtt, timer=True, notes=notes)
    finally:
        done.set()
        if child is not None:
            if child.poll() is None:
                with contextlib.suppress(Exception):
                    session.put(PING, b"stop")
                child.wait(2)
            stop([child], grace_s=1.0)
        session.close()
        shutil.rmtree(d, ignore_errors=True)
