"""The command table (diffbot/cli.py's COMMANDS) is the one list of commands: the usage,
the dispatch and the README's commands table are made from it."""
from __future__ import annotations

import importlib
import os

from diffbot import cli

from ..conftest import ROOT


def test_the_readmes_commands_table_is_the_command_table():
    text = open(os.path.join(ROOT, "README.md"), encoding="utf-8").read()
    table = cli.commands_table()
    assert table in text, ("README.md's commands table differs from diffbot/cli.py's "
                           "COMMANDS; paste this in its place:\n" + table)


def test_every_command_runs_a_function_that_exists():
    """Each row's ``module:function`` imports (the dispatch does it lazily, so a typo would
    only show when a user types that command)."""
    for c in cli.COMMANDS:
        module, _, function = c.target.partition(":")
        assert callable(getattr(importlib.import_module(module), function, None)), c


def test_the_usage_and_the_dispatch_come_from_the_table(capsys, monkeypatch):
    usage = cli.usage()
    for c in cli.COMMANDS:
        assert f"    diffbot {c.name} " in usage, c.name
    calls = []
    monkeypatch.setattr(cli, "COMMANDS", cli.COMMANDS + (
        cli.Command("probe", "", "tests.runs.test_cli_table:_probe", "a probe"),))
    _probe.calls = calls
    assert cli._dispatch(["probe", "--x"]) == 7 and calls == [["--x"]]
    assert "    diffbot probe" in cli.usage()
    assert cli._dispatch(["prob"]) == 2
    assert "did you mean 'probe'?" in capsys.readouterr().err


def _probe(argv):
    _probe.calls.append(argv)
    return 7


def test_a_group_without_its_sub_command_lists_them(capsys):
    """``diffbot fmu`` alone: exit 2, each sub-command with its help line on stderr;
    ``diffbot fmu --help``: the same on stdout, exit 0."""
    subs = [c for c in cli.COMMANDS if c.name.startswith("fmu ")]
    assert len(subs) == 3
    assert cli._dispatch(["fmu"]) == 2
    err = capsys.readouterr().err
    assert all(f"diffbot {c.name} " in err and c.help in err for c in subs), err
    assert cli._dispatch(["fmu", "--help"]) == 0
    assert "diffbot fmu export-ssp" in capsys.readouterr().out
