"""docs/learning.md's Python snippets run as written (each in a fresh interpreter): the
conventions, the batched env, rendering, deployment by seed. Blocks that start worker
processes or need an extra that is not installed (async make_vec, Stable-Baselines3) are
left to their own tests."""
from __future__ import annotations

import os
import re
import subprocess
import sys

import pytest

pytest.importorskip("gymnasium")

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DOC = os.path.join(ROOT, "docs", "learning.md")
SKIP = ("vectorization_mode=\"async\"", "stable_baselines3")


def _blocks() -> list[tuple[int, str]]:
    text = open(DOC, encoding="utf-8").read()
    out = []
    for m in re.finditer(r"^```python\n(.*?)^```", text, re.S | re.M):
        line = text[:m.start()].count("\n") + 1
        out.append((line, m.group(1)))
    return out


BLOCKS = [(line, code) for line, code in _blocks() if not any(s in code for s in SKIP)]


def test_the_page_has_the_snippets():
    joined = "\n".join(code for _, code in BLOCKS)
    for what in ("normalize_actions=True", "vector_entry_point", "render_mode=\"rgb_array\"",
                 "plant_args()"):
        assert what in joined, f"no runnable snippet shows {what}"


@pytest.mark.slow
@pytest.mark.timeout(300)
@pytest.mark.parametrize("line,code", BLOCKS, ids=[f"line{line}" for line, _ in BLOCKS])
def test_snippet_runs(line, code):
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, timeout=280)
    assert out.returncode == 0, f"docs/learning.md:{line}:\n{out.stderr[-3000:]}"
