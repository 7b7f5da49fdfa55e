"""The manual cannot drift from the code: in README.md and every docs/*.md page, each
relative link resolves (file and anchor) and each ``diffbot ...`` command line shown in a
shell block parses with the real CLI (nothing is run). The rules: tests/support/docscheck.py."""
from __future__ import annotations

import os
import re
import subprocess

import pytest

from ..support import docscheck as dc

FILES = dc.doc_files()


@pytest.fixture(scope="module")
def repo_files():
    return dc._repo_files(dc.ROOT)


@pytest.mark.parametrize("path", FILES)
def test_relative_links_resolve(path, repo_files):
    problems = dc.check_links(path, repo_files=repo_files)
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("path", FILES)
def test_shown_commands_parse(path):
    _, problems = dc.check_commands(path)
    assert not problems, "\n".join(problems)


def test_the_readme_is_a_front_door_into_every_page():
    text = open(os.path.join(dc.ROOT, "README.md"), encoding="utf-8").read()
    assert len(text.splitlines()) <= 220
    linked = {os.path.normpath(t.partition("#")[0]) for _, t in dc.links(text)}
    missing = [p for p in dc.manual_pages() if p not in linked]
    assert not missing, f"README.md does not link these pages of the manual: {missing}"
    # the command check is not vacuous: the README shows commands and they are checked
    n, _ = dc.check_commands("README.md")
    assert n >= 3


# ------------------------------------------------------------------ the checker itself

@pytest.mark.parametrize("heading, slug", [
    ("What happens when ...", "what-happens-when-"),
    ("Any FMU on the bus: `diffbot fmu-node`", "any-fmu-on-the-bus-diffbot-fmu-node"),
    ("5. `sim/info`", "5-siminfo"),
    ("C++ & Python", "c--python"),
    ("The `__init__` of *a* [link](x.md)", "the-__init__-of-a-link"),
    ("Sensors and noise", "sensors-and-noise"),
    ("Ünïcode: größe", "ünïcode-größe"),
])
def test_anchors_follow_githubs_slugs(heading, slug):
    assert dc.github_slug(heading) == slug


def test_anchors_number_repeats_and_skip_code_blocks():
    text = "# Errors\n\n## Errors\n\n```sh\n# not a heading\n```\n\nSetext\n------\n"
    assert dc.anchors(text) == {"errors", "errors-1", "setext"}


def _repo(tmp_path, files: dict[str, str]):
    for name, body in files.items():
        p = tmp_path / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(body)
    subprocess.run(["git", "init", "-q"], cwd=tmp_path, check=True)
    return dc._repo_files(str(tmp_path))


def test_broken_links_are_found(tmp_path):
    files = _repo(tmp_path, {
        ".gitignore": "build/\n",
        "build/x.fmu": "",
        "docs/b.md": "# B page\n\n## Part two\n",
        "README.md": "[ok](docs/b.md#part-two) [top](#readme) ![img](docs/b.md)\n"
                     "[gone](docs/c.md) [anchor](docs/b.md#part-three) [built](build/x.fmu)\n"
                     "`[in code](nowhere.md)` [web](https://example.com/x#y) [wrapped\n"
                     "text](docs/b.md#part-four)\n\n# Readme\n\n"
                     "```sh\n[also code](nowhere.md)\n```\n[ref]: docs/missing.md\n",
    })
    problems = dc.check_links("README.md", root=str(tmp_path), repo_files=files)
    assert [p.split(": ", 2)[1] for p in problems] == [
        "docs/c.md", "docs/b.md#part-three", "build/x.fmu", "docs/b.md#part-four",
        "docs/missing.md"]
    assert problems[3].startswith("README.md:4: ")        # the line the link's target is on
    assert "no heading #part-three in docs/b.md" in problems[1]
    assert "not in the repository" in problems[2]


def _cmds(block: str, lang: str = "sh") -> list[list[str]]:
    return [argv for _, argv in dc.commands(f"```{lang}\n{block}\n```\n")]


def test_command_lines_are_found_as_a_shell_would_split_them():
    assert _cmds("ROS_DOMAIN_ID=3 .venv/bin/diffbot plant --world empty &  # a # comment\n"
                 "cd x && diffbot topics --json | head\n"
                 "diffbot run square \\\n    --seed 1\n"
                 "diffbot run swarm [--robots N]\n                  [--seed S]\n"
                 "echo diffbot is not the program here; pip install diffbot\n") == [
        ["plant", "--world", "empty"], ["topics", "--json"], ["run", "square", "--seed", "1"],
        ["run", "swarm", "[--robots", "N]", "[--seed", "S]"]]
    assert _cmds("$ diffbot scenarios\nsquare  robot1 drives a square", "console") == [["scenarios"]]
    assert _cmds("diffbot run square", "python") == []
    assert _cmds('[[process]]\ncommand = ["controller", "avoid", "--robot", "r0"]   # c',
                 "toml") == [["controller", "avoid", "--robot", "r0"]]
    assert _cmds("plant/  the plant (diffbot plant)", "") == []


def test_a_synopsis_stands_for_each_of_its_alternatives():
    assert dc.expand_synopsis(["run", "x", "[--mode", "lockstep|realtime]", "[--[no-]view]",
                               "[--rate", "R", "|", "--fast]", "[KEY=V1,V2,...]..."]) == [
        ["run", "x", "--mode", "lockstep", "--view", "--rate", "R", "KEY=V1,V2,..."],
        ["run", "x", "--mode", "realtime", "--view", "--rate", "R", "KEY=V1,V2,..."],
        ["run", "x", "--mode", "lockstep", "--no-view", "--rate", "R", "KEY=V1,V2,..."],
        ["run", "x", "--mode", "lockstep", "--view", "--fast", "KEY=V1,V2,..."]]


@pytest.mark.parametrize("argv", [
    ["run", "square", "--duration", "S", "--mode", "realtime", "--out", "DIR"],
    ["controller", "square_path", "--robot", "<robot>", "--side", "1.5"],
    ["plant", "--help"],
    ["scenarios"],
])
def test_commands_that_parse(argv):
    assert dc.parse_error(argv) is None


@pytest.mark.parametrize("argv, why", [
    (["run", "square", "--no-such-option"], "unrecognized arguments"),
    (["run", "square", "--duration", "soon"], "expected a number"),
    (["run", "square", "--mode", "slow"], "invalid choice"),
    (["run", "square", "--dur", "5"], "abbreviated"),
    (["controller", "square_pth"], "did you mean 'square_path'"),
    (["plant", "--world"], "expected one argument"),
    (["runn", "square"], "unknown command"),
    (["scenarios", "--all"], "takes no arguments"),
])
def test_commands_that_do_not_parse_say_why(argv, why):
    assert why in (dc.parse_error(argv) or "")


def test_a_bad_command_in_a_page_is_reported_with_its_line(tmp_path):
    (tmp_path / "p.md").write_text("# P\n\n```sh\ndiffbot run square --seed 1\n"
                                   "diffbot run square [--mode lockstep|sometimes]\n```\n")
    n, problems = dc.check_commands("p.md", root=str(tmp_path))
    assert n == 2 and len(problems) == 1
    assert re.match(r"p\.md:5: diffbot run square .*--mode sometimes.*invalid choice", problems[0])
