"""One PNG per metric against each swept parameter: the median over seeds as a line, the
spread (min to max, and the interquartile range) as bands, every run as a dot."""
from __future__ import annotations

import os
import re

import numpy as np


def plot_all(rows: list[dict], params: list[str], metrics: list[str], out: str,
             title: str) -> list[str]:
    from .plots import plt, save
    ok = [r for r in rows if r.get("status") == "ok"]
    written = []
    for metric in metrics:
        if not any(_num(r.get(metric)) is not None for r in ok):
            continue
        for p in params:
            others = [q for q in params if q != p]
            fig, ax = plt.subplots(figsize=(6.4, 4.2))
            xs_all = _order([r[p] for r in ok])
            numeric = all(isinstance(x, (int, float)) for x in xs_all)
            groups: dict = {}
            for r in ok:
                groups.setdefault(tuple(r[q] for q in others), []).append(r)
            for gi, (g, grp) in enumerate(sorted(groups.items(), key=lambda kv: str(kv[0]))):
                xs = _order([r[p] for r in grp])
                pos = {x: (x if numeric else xs_all.index(x)) for x in xs}
                stats = []
                for x in xs:
                    ys = [y for y in (_num(r.get(metric)) for r in grp if r[p] == x)
                          if y is not None]
                    if ys:
                        stats.append((pos[x], np.median(ys), *np.percentile(ys, [0, 25, 75, 100]),
                                      ys))
                if not stats:
                    continue
                label = ", ".join(f"{q}={v}" for q, v in zip(others, g)) or None
                X = [s[0] for s in stats]
                line, = ax.plot(X, [s[1] for s in stats], "o-", label=label, zorder=3)
                c = line.get_color()
                ax.fill_between(X, [s[2] for s in stats], [s[5] for s in stats], color=c,
                                alpha=0.12, lw=0)
                ax.fill_between(X, [s[3] for s in stats], [s[4] for s in stats], color=c,
                                alpha=0.25, lw=0)
                for s in stats:
                    ax.plot([s[0]] * len(s[6]), s[6], ".", color=c, alpha=0.5, ms=4)
            if not numeric:
                ax.set_xticks(range(len(xs_all)), [str(x) for x in xs_all])
            n_seeds = len({r["seed"] for r in ok})
            ax.set_xlabel(p)
            ax.set_ylabel(metric)
            ax.set_title(f"{title}: {metric}\nmedian over {n_seeds} seed(s); bands: "
                         "min-max and interquartile", fontsize=9)
            ax.grid(alpha=0.3)
            if len(groups) > 1:
                ax.legend(fontsize=7)
            path = os.path.join(out, f"{_safe(metric)}_vs_{_safe(p)}.png")
            save(fig, path)
            written.append(path)
    return written


def _num(v):
    if isinstance(v, bool):
        return float(v)
    if isinstance(v, (int, float)) and np.isfinite(v):
        return float(v)
    return None


def _order(values: list) -> list:
    uniq = list(dict.fromkeys(values))
    try:
        return sorted(uniq)
    except TypeError:
        return uniq


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]", "_", name)
