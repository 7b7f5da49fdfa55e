"""Any controller class as a node: ``diffbot controller python:MODULE:CLASS`` (an importable
module) or ``diffbot controller PATH.py:CLASS`` (a file; ``PATH.py`` alone if it defines
exactly one class with a ``step`` method).

The class is a controller as :mod:`bus.controller` defines it (``inputs``, ``step(obs)``,
the optional hooks). It is built once per robot with the keyword arguments given as
``--arg KEY=VALUE`` (repeatable; VALUE a Python literal, ``1.5``, ``(1, 2)``, ``'text'``,
``True``, or else taken as text), plus ``robot=`` the robot's name if its constructor has a
``robot`` parameter; the standard node options (``--robot``, ``--robots``, ``--name``,
``--endpoint`` ...) apply as to any controller. So a trained policy deploys with no code
of ours: a class that loads its model in ``__init__`` and maps the observation to a
:class:`bus.node.Twist` in ``step``. Composable into the plant's process like the shipped
controllers (``diffbot plant --compose "controller python:my.mod:Agent"``).
"""
from __future__ import annotations

import ast
import importlib
import importlib.util
import inspect
import os
import sys

from bus.node import node_arg_parser, run_node_args

PREFIX = "python:"


def is_target(word: str) -> bool:
    """Whether a controller name is a class to host (``python:...`` or a ``.py`` path)."""
    return word.startswith(PREFIX) or word.endswith(".py") or ".py:" in word


def load(target: str) -> type:
    """The controller class ``target`` names; ValueError saying why not."""
    if target.startswith(PREFIX):
        module_name, _, cls_name = target[len(PREFIX):].partition(":")
        if not module_name or not cls_name:
            raise ValueError(f"{target!r}: expected python:MODULE:CLASS")
        if os.getcwd() not in sys.path and "" not in sys.path:
            sys.path.insert(0, os.getcwd())    # as `python -m` would: the current directory
        try:
            module = importlib.import_module(module_name)
        except ImportError as exc:
            raise ValueError(f"{target!r}: cannot import {module_name} ({exc})") from None
    else:
        path, _, cls_name = target.partition(".py")
        path += ".py"
        cls_name = cls_name.lstrip(":")
        if not os.path.isfile(path):
            raise ValueError(f"{target!r}: no file {path}")
        name = "diffbot_hosted_" + os.path.splitext(os.path.basename(path))[0]
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
        if not cls_name:
            found = [c for c in vars(module).values() if isinstance(c, type)
                     and c.__module__ == name and callable(getattr(c, "step", None))]
            if len(found) != 1:
                raise ValueError(f"{path} defines {len(found)} classes with a step method "
                                 f"({', '.join(c.__name__ for c in found) or 'none'}): name "
                                 "one as PATH.py:CLASS")
            return found[0]
    cls = getattr(module, cls_name, None)
    if not isinstance(cls, type) or not callable(getattr(cls, "step", None)):
        raise ValueError(f"{target!r}: {cls_name} is not a class with a step method in "
                         f"{module.__name__}")
    return cls


def parse_kwargs(items: list[str]) -> dict:
    """``--arg KEY=VALUE`` items as keyword arguments (module docstring)."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.isidentifier():
            raise ValueError(f"--arg takes KEY=VALUE with KEY a Python name, got {item!r}")
        try:
            out[key] = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            out[key] = value
    return out


def factory(cls: type, kwargs: dict):
    """robot -> a controller object: ``cls(**kwargs)``, with ``robot=`` if it takes one."""
    try:
        takes_robot = "robot" in inspect.signature(cls).parameters
    except (TypeError, ValueError):
        takes_robot = False

    def make(robot: str):
        return cls(**kwargs, robot=robot) if takes_robot else cls(**kwargs)
    make.name = getattr(cls, "name", None) or cls.__name__.lower()
    return make


def main(target: str, argv: list[str] | None = None) -> int:
    p = node_arg_parser(f"Host the controller class {target} as a bus node.")
    p.add_argument("--arg", action="append", default=[], metavar="KEY=VALUE",
                   help="a keyword argument of the class's constructor; VALUE a Python "
                        "literal or else text (repeatable)")
    args = p.parse_args(argv)
    try:
        cls = load(target)
        kwargs = parse_kwargs(args.arg)
        make = factory(cls, kwargs)
        robots = args.robots or [args.robot]
        built = {r: make(r) for r in robots}     # constructor errors before joining the bus
    except Exception as exc:
        p.exit(2, f"diffbot controller {target}: {type(exc).__name__}: {exc}\n")

    def per_robot(robot: str):
        return built[robot]
    return run_node_args(per_robot, args, args.name or f"{make.name}_{robots[0]}")
