"""The sweep's table: one row per run (``sweep.csv``, and ``sweep.parquet`` when pyarrow
is importable), each run's row also kept beside its output (``row.json``) for resuming."""
from __future__ import annotations

import csv
import json
import math
import os

#: columns every row has, before the parameters' and after them the metrics'
HEAD = ("run",)
TAIL = ("seed", "status", "exit_code", "attempts", "wall_time_s", "real_time_factor",
        "sim_time_s", "node", "host")
LAST = ("out", "log_tail")
ROW_FILE = "row.json"


def flatten(d, prefix: str = "") -> dict:
    """Every scalar number (and bool) of a nested dict, keys joined with dots; None kept
    (a metric the run could not measure is an empty cell, not a missing column)."""
    out: dict = {}
    for k, v in (d or {}).items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(flatten(v, key + "."))
        elif isinstance(v, bool):
            out[key] = int(v)
        elif isinstance(v, (int, float)) or v is None:
            out[key] = v
    return out


def make_row(run, point, axes, sweep_out: str) -> dict:
    s = run.summary or {}
    row = {"run": run.name}
    row.update({a.key: v if isinstance(v, (int, float, str)) else t   # a table value: as typed
                for a, v, t in zip(axes, point.values, point.texts)})
    row.update({"seed": point.seed, "status": run.status, "exit_code": run.exit_code,
                "attempts": run.attempts, "wall_time_s": run.wall_s,
                "real_time_factor": s.get("real_time_factor"),
                "sim_time_s": s.get("sim_time_s"), "node": run.node, "host": run.host})
    row.update(flatten(s.get("metrics")))
    row["out"] = os.path.relpath(run.out, sweep_out)
    row["log_tail"] = "" if run.status == "ok" else run.tail()
    return row


def save_row(row: dict, run_out: str, argv: list[str]) -> None:
    if not os.path.isdir(run_out):
        return                                  # never started (skipped): nothing to keep
    with open(os.path.join(run_out, ROW_FILE), "w") as f:
        json.dump({"argv": argv, "row": row}, f, indent=1, default=str)


def finished_row(run_out: str, argv: list[str]) -> dict | None:
    """The row of a run that finished ``ok`` with this very command, else None."""
    try:
        with open(os.path.join(run_out, ROW_FILE)) as f:
            kept = json.load(f)
    except (OSError, ValueError):
        return None
    if kept.get("argv") != argv or kept.get("row", {}).get("status") != "ok":
        return None
    return kept["row"]


def columns(rows: list[dict], params: list[str]) -> list[str]:
    metrics = sorted({k for r in rows for k in r}
                     - set(HEAD) - set(TAIL) - set(LAST) - set(params))
    return [*HEAD, *params, *TAIL, *metrics, *LAST]


def write_table(rows: list[dict], params: list[str], out: str) -> list[str]:
    """Write ``sweep.csv`` (and ``sweep.parquet`` if pyarrow imports); the files written."""
    cols = columns(rows, params)
    path = os.path.join(out, "sweep.csv")
    tmp = path + ".tmp"
    with open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: _cell(r.get(k)) for k in cols})
    os.replace(tmp, path)                       # a reader never sees half a table
    written = [path]
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return written
    table = pa.table({k: [_plain(r.get(k)) for r in rows] for k in cols})
    pq.write_table(table, os.path.join(out, "sweep.parquet"))
    return written + [os.path.join(out, "sweep.parquet")]


def _cell(v):
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return ""
    if isinstance(v, float):
        return repr(v)                          # every bit: the table is the result
    if isinstance(v, (dict, list)):
        return json.dumps(v)
    return v


def _plain(v):
    return json.dumps(v) if isinstance(v, (dict, list)) else v
