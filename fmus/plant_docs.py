"""The plant FMU's ``documentation/`` page (FMI 3 ``documentation/index.html``, FMI 2
``documentation/_main.html``): what the FMU needs to run, the whole-tick rule, its variables."""
from __future__ import annotations

from html import escape

from .plant_fmu import Var


def _range(v: Var) -> str:
    if v.min is None and v.max is None:
        return ""
    return f"[{v.min:g}, {v.max:g}]"


def page(variables: list[Var], fmi: int, world: str, tick_s: float, version: str) -> str:
    """The HTML page (one file, no external resources)."""
    rows = []
    scans = [v for v in variables if v.field == "scan" and v.index > 0]
    for v in variables:
        if v.field == "scan" and v.index > 0:
            continue                       # scan[2] ... scan[n]: one row for them all
        name, what = v.name, v.description
        if v.field == "scan" and v.index == 0:
            n = len([s for s in scans if s.robot == v.robot]) + 1
            name, what = f"{v.name[:-3]}[1] ... [{n}]", "last lidar scan's ray k's range"
        kind = v.type + (f"[{v.size}]" if v.size else "")
        rows.append(f"<tr><td><code>{escape(name)}</code></td><td>{v.causality}</td>"
                    f"<td>{kind}</td><td>{escape(v.unit)}</td><td>{_range(v)}</td>"
                    f"<td>{escape(what)}</td></tr>")
    ms = f"{tick_s * 1e3:g}"
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>diffbot-cosim plant FMU</title>
<style>body{{font-family:sans-serif;max-width:60em;margin:2em auto}}
table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:2px 6px;text-align:left}}
</style></head><body>
<h1>diffbot-cosim plant FMU (FMI {fmi}.0, world {escape(world)})</h1>
<p>The DART plant of <a href="https://pypi.org/project/diffbot-cosim/">diffbot-cosim</a>
{escape(version)}: differential-drive robots with their drive limits, noise and lidar, as a
co-simulation FMU. Its instances step the same tick as the project's plant node and
Gymnasium environments: the same numbers at the same seed and commands.</p>
<h2>What it needs to run</h2>
<p>A <b>tool-coupling FMU</b> (<code>needsExecutionTool="true"</code>): it carries no Python.
The machine it runs on needs Python 3.10 or later with diffbot-cosim {escape(
'.'.join(version.split('.')[:2]))}.x installed (<code>pip install diffbot-cosim</code> or its
wheel). In a master that runs Python (fmpy, libcosimpy, ecospy) the master's Python is used.
Elsewhere the FMU takes the Python named by the environment variable
<code>DIFFBOT_FMU_PYTHON</code>, else the active virtual environment's
(<code>$VIRTUAL_ENV/bin/python</code>), else <code>python3</code> on <code>PATH</code>, and
loads its shared <code>libpython</code>. What it found and what is missing goes to the FMI
logger.</p>
<h2>Communication steps: whole {ms} ms ticks</h2>
<p>The plant advances in control ticks of {ms} ms. <code>doStep</code> takes a communication
step that is a whole number of ticks ({ms} ms, {2 * tick_s * 1e3:g} ms, ...), from the
FMU's current time; any other step is refused with an error that says so. Inputs hold over
the step and act from its first tick; outputs are the values the plant publishes at the
step's end. The lidar scans every few ticks (<code>scan</code> is held between scans;
<code>scan_count</code> changes when a new one arrives). FMU states can be taken, set and
serialized (a rollback steps again to the same outputs, to the bit).</p>
<h2>Variables</h2>
<table><tr><th>name</th><th>causality</th><th>type</th><th>unit</th><th>range</th>
<th>what</th></tr>
{chr(10).join(rows)}
</table>
<p>Commands outside the range are limited by the drive (the FMU warns).</p>
</body></html>
"""


def file_name(fmi: int) -> str:
    """The documentation entry point of the FMI version."""
    return "index.html" if fmi == 3 else "_main.html"
