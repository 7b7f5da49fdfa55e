"""The report of ``diffbot figures``: ``figures.json``, ``REPORT.md`` and ``index.html``.

:func:`build_report` gathers the figures made, their captions, parameters and measured
numbers, a study-vs-here table of headline numbers, and every run's command, exit code,
wall time and real-time factor; :func:`write_outputs` writes it as strict JSON, Markdown
and a self-contained HTML page.
"""
from __future__ import annotations

import html
import math
import os
import re
import time
from typing import Callable

from bus.jsonio import strict_json, write_json


def _mm(v) -> str:
    return "[" + ", ".join(f"{1000 * x:.2f}" for x in v) + "] mm" if v else "—"


#: the numbers worth a glance: (figure, quantity, what the study says, text from its numbers)
HEADLINES: tuple[tuple[int, str, str, Callable[[dict], str]], ...] = (
    (2, "linear velocity, both wheels 1 rad/s", "0.12 m/s",
     lambda n: f"{n['steady_linear_velocity_mps']:.4f} m/s"),
    (3, "angular velocity, wheels +1 / -1 rad/s (CCW positive)", "\"0.66 m/s\" (0.667 rad/s, CW)",
     lambda n: f"{n['steady_angular_velocity_radps']:.4f} rad/s"),
    (4, "end-point spread (std along, across the path)", "scatter plot",
     lambda n: _mm(n.get("endpoint_std_m"))),
    (7, "odometry vs GPS at the end of the square, no noise", "small discrepancies",
     lambda n: f"{1000 * n['final_odom_error_m']:.1f} mm after {n['path_length_m']:.2f} m"),
    (9, "lidar range error std, noise 0.2 (16 m)", "—",
     lambda n: f"{n['measured_residual_std_m']:.2f} m (expected with clipping "
               f"{n['expected_residual_std_with_clipping_m']:.2f} m)"),
    (10, "odometry vs GPS, encoder noise 0.2 rad (max / end)", "significant difference",
     lambda n: f"{100 * n['max_odom_error_m']:.1f} cm / {100 * n['final_odom_error_m']:.1f} cm"),
    (11, "camera pixel error std, noise 0.2 (51 levels)", "—",
     lambda n: f"{n['measured_residual_std_levels']:.1f} levels (expected with clipping "
               f"{n['expected_residual_std_with_clipping_levels']:.1f})"),
    (12, "tracking distance after settling (min-max, RMS error)", "0.6-0.7 m",
     lambda n: f"{n['distance_min_m']:.3f}-{n['distance_max_m']:.3f} m, RMS "
               f"{100 * n['distance_rms_error_m']:.1f} cm from 0.65 m"),
)


def headlines(figs: list[dict]) -> list[dict]:
    by_n = {f["number"]: f for f in figs if f["status"] == "ok"}
    out = []
    for n, what, study, text in HEADLINES:
        if n in by_n:
            try:
                measured = text(by_n[n]["numbers"])
            except (KeyError, TypeError, ValueError):
                measured = "—"
            out.append({"figure": n, "quantity": what, "study": study, "measured": measured})
    return out


def build_report(figures: dict, ctx, numbers: list[int], results: dict, args, wall: float,
                 interrupted: bool) -> dict:
    """The report as data: ``figures`` maps number -> FigureSpec (file, study_caption, jobs),
    ``results`` number -> what making it gave, ``ctx.jobs`` the runs behind them."""
    figs = []
    for n in numbers:
        f, r = figures[n], results[n]
        figs.append({"number": n, "file": f.file, "study_caption": f.study_caption,
                     "jobs": list(f.jobs), **r})
    runs = {}
    for name, j in ctx.jobs.items():
        s = j.summary
        rtf = s.get("real_time_factor", s.get("run", {}).get("real_time_factor")) if s else None
        runs[name] = {"command": ["diffbot", *j.spec.args, "--out", j.out, "--seed",
                                  str(args.seed)] if not j.spec.module
                      else ["python", "-m", j.spec.module, "--out", j.out],
                      "what": j.spec.what, "status": j.status, "exit_code": j.exit_code,
                      "wall_time_s": j.wall_s, "real_time_factor": rtf, "node": j.node,
                      "sim_time_s": s.get("sim_time_s", s.get("run", {}).get("sim_time_s"))
                      if s else None,
                      "out": os.path.relpath(j.out, ctx.out),
                      "log": os.path.relpath(j.log_path, ctx.out)}
        if j.status not in ("ok", "waiting"):
            runs[name]["log_tail"] = j.tail()
    return {"generated": time.strftime("%Y-%m-%d %H:%M:%S %z"), "seed": args.seed,
            "parallel_jobs": args.jobs, "cpus": os.cpu_count(),
            "only": args.only, "wall_time_s": wall, "interrupted": interrupted,
            "conventions": "SI units; frames x forward, y left, z up; yaw and angular velocity "
                           "counter-clockwise positive. The study's \"1 m/s\" wheel command is "
                           "1 rad/s, its \"0.66 m/s\" is an angular velocity (0.667 rad/s) and "
                           "its w = (v_left - v_right)/d counts clockwise positive.",
            "headlines": headlines(figs), "figures": figs, "runs": runs}


def fmt(v) -> str:
    if v is None:
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        if not math.isfinite(v):
            return "—"
        if v == 0:
            return "0"
        a = abs(v)
        return f"{v:.5g}" if 1e-3 <= a < 1e5 else f"{v:.3e}"
    if isinstance(v, (list, tuple)):
        if v and all(isinstance(e, dict) for e in v):
            return "; ".join(", ".join(f"{k} {fmt(x)}" for k, x in e.items()) for e in v)
        return "[" + ", ".join(fmt(e) for e in v) + "]"
    return str(v)


def write_outputs(out: str, report: dict) -> None:
    report = strict_json(report)
    write_json(os.path.join(out, "figures.json"), report)
    _write_atomic(os.path.join(out, "REPORT.md"), render_markdown(report))
    _write_atomic(os.path.join(out, "index.html"), render_html(report))


def _write_atomic(path: str, text: str) -> None:
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "w", encoding="utf-8") as f:
        f.write(text)
    os.replace(tmp, path)


def _runs_rows(report: dict) -> list[list[str]]:
    rows = []
    for name, r in report["runs"].items():
        cmd = r["command"]
        if "--out" in cmd:                       # the output and the seed have their columns
            cmd = cmd[:cmd.index("--out")]
        rows.append([name, r["status"], fmt(r["exit_code"]), fmt(r["wall_time_s"]),
                     fmt(r["real_time_factor"]), fmt(r["sim_time_s"]), " ".join(cmd), r["out"]])
    return rows


RUN_HEAD = ["job", "status", "exit", "wall time [s]", "real-time factor", "sim time [s]",
            "command", "output"]


def _intro(report: dict) -> str:
    made = sum(1 for f in report["figures"] if f["status"] == "ok")
    return (f"{made} of {len(report['figures'])} figure(s) written by `diffbot figures` on "
            f"{report['generated']}: seed {report['seed']}, {report['parallel_jobs']} job(s) at "
            f"a time on {report['cpus']} CPU(s), total wall time "
            f"{report['wall_time_s']:.1f} s" + (" (INTERRUPTED)" if report["interrupted"] else "")
            + "." + (" Real-time factors and job wall times were measured with the jobs "
                     "sharing the CPUs; `--jobs 1` gives each run the machine alone."
                     if report["parallel_jobs"] > 1 and len(report["runs"]) > 1 else ""))


def render_markdown(report: dict) -> str:
    L = ["# The study's figures, reproduced", "", _intro(report), "",
         f"Conventions: {report['conventions']}", "",
         "Each figure comes from the run named under it (`runs/<job>/`, its log in "
         "`runs/<job>.log`; `summary.json` there has every number).", ""]
    if report["headlines"]:
        L += ["| figure | quantity | the study | this run |", "|---|---|---|---|"]
        L += [f"| {h['figure']} | {_md(h['quantity'])} | {_md(h['study'])} | {_md(h['measured'])} |"
              for h in report["headlines"]]
        L.append("")
    for f in report["figures"]:
        L.append(f"## Figure {f['number']}: {f['study_caption']}")
        L.append("")
        if f["status"] != "ok":
            L += [f"**Not made**: {f.get('error', '')}", ""]
            tail = "\n".join(report["runs"][j].get("log_tail", "") for j in f["jobs"]).strip()
            if tail:
                L += ["```", tail, "```", ""]
            continue
        L += [f"![Figure {f['number']}]({f['file']})", ""]
        L += [f"*Figure {f['number']}: {f['study_caption']}* {f['caption']}", ""]
        for extra in f.get("extra_files", []):
            L += [f"Animation: [{extra}]({extra})", "", f"![{extra}]({extra})", ""]
        L += [f"Run: {', '.join('`' + j + '`' for j in f['jobs'])}", ""]
        if f["parameters"]:
            L += ["| parameter | value |", "|---|---|"]
            L += [f"| `{k}` | {_md(fmt(v))} |" for k, v in f["parameters"].items()]
            L.append("")
        if f["numbers"]:
            L += ["| measured | value |", "|---|---|"]
            L += [f"| `{k}` | {_md(fmt(v))} |" for k, v in f["numbers"].items()]
            L.append("")
    L += ["## Runs", "", "| " + " | ".join(RUN_HEAD) + " |", "|" + "---|" * len(RUN_HEAD)]
    L += ["| " + " | ".join(_md(c) for c in row) + " |" for row in _runs_rows(report)]
    L.append("")
    return "\n".join(L)


def _md(s: str) -> str:
    return s.replace("|", "\\|").replace("\n", " ")


CSS = """
body { font-family: system-ui, sans-serif; max-width: 1100px; margin: 2em auto; padding: 0 1em;
       color: #222; line-height: 1.45; }
figure { margin: 2.5em 0; padding-bottom: 1.5em; border-bottom: 1px solid #ddd; }
figure img { max-width: 100%; border: 1px solid #ccc; }
figcaption { margin: .6em 0; }
table { border-collapse: collapse; margin: .5em 1.5em .5em 0; font-size: 90%;
        display: inline-table; vertical-align: top; }
td, th { border: 1px solid #ccc; padding: 2px 8px; text-align: left; }
th { background: #f3f3f3; }
code { font-size: 92%; }
.failed { color: #b00; font-weight: bold; }
pre { background: #f6f6f6; padding: .6em; overflow-x: auto; font-size: 85%; }
"""


def render_html(report: dict) -> str:
    e = html.escape
    intro = re.sub(r"`([^`]+)`", r"<code>\1</code>", e(_intro(report)))
    H = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
         "<title>diffbot-cosim: the study's figures</title>", f"<style>{CSS}</style></head><body>",
         "<h1>The study's figures, reproduced</h1>", f"<p>{intro}</p>",
         f"<p>Conventions: {e(report['conventions'])}</p>",
         "<p>Each figure comes from the run named under it (<code>runs/&lt;job&gt;/</code>, "
         "its log in <code>runs/&lt;job&gt;.log</code>; <code>summary.json</code> there has "
         "every number).</p>"]
    if report["headlines"]:
        H.append("<table><tr><th>figure</th><th>quantity</th><th>the study</th><th>this run</th>"
                 "</tr>" + "".join(f'<tr><td><a href="#fig{h["figure"]}">{h["figure"]}</a></td>'
                                   f"<td>{e(h['quantity'])}</td><td>{e(h['study'])}</td>"
                                   f"<td>{e(h['measured'])}</td></tr>"
                                   for h in report["headlines"]) + "</table>")
    H.append("<ul>" + "".join(f'<li><a href="#fig{f["number"]}">Figure {f["number"]}: '
                               f'{e(f["study_caption"])}</a>'
                               + ("" if f["status"] == "ok" else ' <span class="failed">(not made)'
                                  '</span>') + "</li>" for f in report["figures"]) + "</ul>")
    for f in report["figures"]:
        n = f["number"]
        H.append(f'<figure id="fig{n}">')
        if f["status"] != "ok":
            H.append(f"<h2>Figure {n}: {e(f['study_caption'])}</h2>")
            H.append(f'<p class="failed">Not made: {e(f.get("error", ""))}</p>')
            tail = "\n".join(report["runs"][j].get("log_tail", "") for j in f["jobs"]).strip()
            if tail:
                H.append(f"<pre>{e(tail)}</pre>")
            H.append("</figure>")
            continue
        H.append(f'<a href="{e(f["file"])}"><img src="{e(f["file"])}" '
                 f'alt="Figure {n}: {e(f["study_caption"])}"></a>')
        H.append(f"<figcaption><b>Figure {n}: {e(f['study_caption'])}</b> "
                 f"{e(f['caption'])}</figcaption>")
        for extra in f.get("extra_files", []):
            H.append(f'<p>Animation (<a href="{e(extra)}">{e(extra)}</a>):<br>'
                     f'<img src="{e(extra)}" alt="{e(extra)}"></p>')
        H.append(f"<p>Run: {', '.join('<code>' + e(j) + '</code>' for j in f['jobs'])}</p>")
        for title, d in (("parameter", f["parameters"]), ("measured", f["numbers"])):
            if d:
                H.append(f"<table><tr><th>{title}</th><th>value</th></tr>"
                         + "".join(f"<tr><td><code>{e(k)}</code></td><td>{e(fmt(v))}</td></tr>"
                                   for k, v in d.items()) + "</table>")
        H.append("</figure>")
    H.append("<h2>Runs</h2><table><tr>" + "".join(f"<th>{e(h)}</th>" for h in RUN_HEAD) + "</tr>")
    for row in _runs_rows(report):
        H.append("<tr>" + "".join(f"<td>{e(c)}</td>" for c in row[:-1])
                 + f'<td><a href="{e(row[-1])}/">{e(row[-1])}</a></td></tr>')
    H.append("</table></body></html>")
    return "\n".join(H) + "\n"


