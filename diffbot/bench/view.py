"""Suite ``view``: what watching costs -- ``follow`` in lockstep with and without the live view.

Each repeat runs ``diffbot run follow`` twice, side by side in time: plain, then with
``--view`` and a Foxglove client connected that subscribes to every channel and decodes
every message (tests/js/view_client.mjs under Node: the worst case, everything watched).
The issue's target: the view slows a lockstep run by at most 10 %.
"""
from __future__ import annotations

import json
import os
import shutil
import socket
import tempfile

from diffbot import procs

from .common import spawn, stop, tail
from .harness import ROOT, Context, Metric, Probe, Skip, suite

#: simulated seconds per run (follow's own 60 s would take ~40 s of wall time per run)
DURATION_S = 20.0
CLIENT = os.path.join(ROOT, "tests", "js", "view_client.mjs")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _run(ctx: Context, view: bool) -> tuple[dict, dict]:
    """(summary.json, the client's counts) of one follow run."""
    out = tempfile.mkdtemp(prefix="view-", dir=ctx.tmpdir)
    children = []
    try:
        args = ["run", "follow", "--out", out, "--duration", f"{DURATION_S:g}"]
        client_out = os.path.join(out, "client.json")
        if view:
            port = _free_port()
            args += ["--view", "--view-port", str(port)]
        run = spawn(args, os.path.join(out, "run.log"))
        children.append(run)
        if view:
            argv = [shutil.which("node"), CLIENT, f"ws://127.0.0.1:{port}", "follower",
                    client_out, "watch"]
            children.append(procs.Child("client", argv, os.path.join(out, "client.log"),
                                        cwd=os.path.dirname(CLIENT),
                                        die_with_parent=True).start())
        rc = run.wait(600)
        if rc != 0:
            raise RuntimeError(f"diffbot run follow exited {rc}: {tail(os.path.join(out, 'run.log'))}")
        with open(os.path.join(out, "summary.json")) as f:
            summary = json.load(f)
        counts = {}
        if view:
            stop(children[1:], grace_s=5.0)
            try:
                with open(client_out) as f:
                    counts = json.load(f).get("counts", {})
            except (OSError, ValueError):
                counts = {}
        return summary, counts
    finally:
        stop(children, grace_s=5.0)
        shutil.rmtree(out, ignore_errors=True)


def compare(ctx: Context) -> dict:
    plain, _ = _run(ctx, view=False)
    watched, counts = _run(ctx, view=True)
    a, b = plain["real_time_factor"], watched["real_time_factor"]
    return {"rtf_plain": a, "rtf_view": b, "slowdown": 1.0 - b / a,
            "client_messages": float(sum(counts.values())),
            "client_images": float(counts.get("/follower/camera/image", 0))}


@suite("view", "follow in lockstep with and without `diffbot view` + a client watching all")
def view_suite(ctx: Context):
    if shutil.which("node") is None or not os.path.isdir(
            os.path.join(ROOT, "tests", "js", "node_modules", "@foxglove")):
        raise Skip("needs node and tests/js/node_modules (make setup) for the watching client")
    try:
        import foxglove  # noqa: F401
    except ImportError:
        raise Skip("needs foxglove-sdk (pip install 'diffbot-cosim[view]')") from None
    yield Probe("follow +view", lambda: compare(ctx), [
        Metric("rtf_plain", "follow: real-time factor, no view", "x"),
        Metric("rtf_view", "follow: real-time factor, view + client", "x"),
        Metric("slowdown", "follow: slowdown with the view", "(fraction)",
               notes="1 - rtf_view / rtf_plain; target <= 0.10"),
        Metric("client_messages", "client: messages received", "msgs"),
        Metric("client_images", "client: camera frames received", "frames",
               notes=f"of {DURATION_S * 25:g} rendered; --image-rate 15 per wall s"),
    ], repeats=1 if ctx.quick else 3, warmup=0, notes=f"{DURATION_S:g} s simulated per run")
