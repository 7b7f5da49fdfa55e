"""Suite ``view``: what watching costs -- ``follow`` in lockstep with and without the live view.

Each repeat runs ``diffbot run follow`` four times, one after the other: plain; with
``--view`` and no client; with a Foxglove client (tests/js/view_client.mjs under Node,
decoding every message it gets) watching what the shipped layout shows; and with one
watching every channel (the worst case). The target: the view slows a lockstep
run by at most 10 %.
"""
from __future__ import annotations

import json
import os
import shutil
import socket
import tempfile

from diffbot.runner import procs

from .common import spawn, stop, tail
from .harness import ROOT, Context, Metric, Probe, Skip, suite

#: simulated seconds per run (follow's own 60 s would take ~40 s of wall time per run)
DURATION_S = 20.0
CLIENT = os.path.join(ROOT, "tests", "js", "view_client.mjs")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _run(ctx: Context, view: bool, client: str | None = None) -> tuple[dict, dict]:
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
        if client:
            argv = [shutil.which("node"), CLIENT, f"ws://127.0.0.1:{port}", "follower",
                    client_out, client]
            children.append(procs.Child("client", argv, os.path.join(out, "client.log"),
                                        cwd=os.path.dirname(CLIENT),
                                        die_with_parent=True).start())
        rc = run.wait(600)
        if rc != 0:
            raise RuntimeError(f"diffbot run follow exited {rc}: {tail(os.path.join(out, 'run.log'))}")
        with open(os.path.join(out, "summary.json")) as f:
            summary = json.load(f)
        if view:
            try:
                with open(os.path.join(out, "logs", "view.json")) as f:
                    summary["view_cpu_s"] = json.load(f)["cpu_s"]
            except (OSError, ValueError, KeyError):
                summary["view_cpu_s"] = float("nan")
        counts = {}
        if client:
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
    a = _run(ctx, view=False)[0]["real_time_factor"]
    s_idle = _run(ctx, view=True)[0]
    idle = s_idle["real_time_factor"]
    s_lay, layout_counts = _run(ctx, view=True, client="layout")
    lay = s_lay["real_time_factor"]
    s_all, counts = _run(ctx, view=True, client="watch")
    every = s_all["real_time_factor"]
    return {"cpu_idle": s_idle["view_cpu_s"] / DURATION_S,
            "cpu_layout": s_lay["view_cpu_s"] / DURATION_S,
            "cpu_all": s_all["view_cpu_s"] / DURATION_S,"rtf_plain": a, "rtf_idle": idle, "rtf_layout": lay, "rtf_all": every,
            "slowdown_idle": 1.0 - idle / a, "slowdown_layout": 1.0 - lay / a,
            "slowdown_all": 1.0 - every / a,
            "layout_messages": float(sum(layout_counts.values())),
            "all_messages": float(sum(counts.values())),
            "all_images": float(counts.get("/follower/camera/image_raw", 0))}


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
        Metric("rtf_idle", "follow: real-time factor, view, no client", "x"),
        Metric("rtf_layout", "follow: real-time factor, view + layout client", "x"),
        Metric("rtf_all", "follow: real-time factor, view + client on all", "x"),
        Metric("slowdown_idle", "slowdown: view, no client", "(fraction)",
               notes="1 - rtf / rtf_plain; target <= 0.10"),
        Metric("slowdown_layout", "slowdown: view + layout client", "(fraction)",
               notes="the shipped layout's channels"),
        Metric("slowdown_all", "slowdown: view + client on all", "(fraction)",
               notes="every channel, every message decoded"),
        Metric("cpu_idle", "view CPU per simulated s, no client", "s",
               notes="whole process incl. ~0.35 s of imports"),
        Metric("cpu_layout", "view CPU per simulated s, layout client", "s"),
        Metric("cpu_all", "view CPU per simulated s, client on all", "s"),
        Metric("layout_messages", "layout client: messages received", "msgs"),
        Metric("all_messages", "all-channel client: messages received", "msgs"),
        Metric("all_images", "all-channel client: camera frames", "frames",
               notes=f"of {DURATION_S * 25:g} rendered; --image-rate 15 per wall s"),
    ], repeats=1 if ctx.quick else 3, warmup=0, notes=f"{DURATION_S:g} s simulated per run")
