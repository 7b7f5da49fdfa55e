"""The manual's checker: links resolve and shown ``diffbot`` command lines parse.

Used by ``tests/house/test_docs.py`` on README.md, every ``docs/*.md`` and the other Markdown files
of the repository (``fmus/README.md``, ...); runnable alone:

    .venv/bin/python -m tests.support.docscheck              # prints every problem, exit 1 if any

**Links.** Every relative link (``[text](path#anchor)``, images, reference definitions,
HTML ``href``/``src``) outside code must name a file or folder of the repository (tracked
or about to be: ``git ls-files --cached --others --exclude-standard``, so a link to a
build product that exists here but not on GitHub fails), and its ``#anchor`` must be a
heading of the target page under GitHub's slug rules (lower case; everything but letters,
digits, ``_``, ``-`` and spaces dropped; each space a ``-``; repeats get ``-1``, ``-2``)
or an explicit ``id``/``name``. External links (``https:``, ``mailto:``) are not fetched.

**Commands.** In fenced blocks of shell (```` ```sh ````, ``bash``, ``shell``, ``console``
or no language), every command whose program is ``diffbot`` (also ``.venv/bin/diffbot``,
after ``VAR=value`` prefixes, ``$ `` prompts, ``&&``, ``;``, ``|``, ``&``) is parsed by the
real CLI: ``diffbot.cli`` dispatches to the sub-command's own ``argparse`` parser, whose
``parse_args`` is intercepted once it has parsed, so nothing runs. Backslash continuations
are joined, and so are indented lines that go on a synopsis (starting with ``[`` or ``-``).
In ```` ```toml ```` blocks, a scenario file's ``command = [...]`` is checked the same way.

A usage line may be a synopsis: ``[--opt VALUE]`` (brackets dropped, the option checked),
``a|b|c`` or ``[--rate R | --fast]`` (each alternative parsed in turn), ``--[no-]flag``,
a trailing ``...``. A **placeholder** is a word in capitals (``N``, ``DIR``,
``KEY=VALUE``, ``A-B``, ``MODEL.fmu``, ``<robot>``): the parser must expect a value
there, but its type and choices are not applied to it. Anything else is taken literally,
so ``--duration soon`` or ``--no-such-option`` fails. Options must be spelled out
(argparse would take ``--dur`` for ``--duration`` until another option starts the same).
"""
from __future__ import annotations

import argparse
import contextlib
import io
import itertools
import os
import re
import shlex
import subprocess
import sys
import tomllib
from dataclasses import dataclass
from urllib.parse import unquote

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

#: fenced-block languages whose lines are shell commands
SHELL_LANGS = {"", "sh", "bash", "shell", "console", "zsh"}


#: folders never searched for Markdown (environments, build products, vendored packages)
_SKIP_DIRS = {".git", ".venv", "node_modules", "out", "build", ".pytest_cache", "__pycache__"}


def doc_files(root: str = ROOT) -> list[str]:
    """README.md, every page of docs/, then the other Markdown files of the repository
    (``fmus/README.md``, ``examples/*/README.md``), as paths relative to ``root``."""
    docs = sorted(f for f in os.listdir(os.path.join(root, "docs")) if f.endswith(".md"))
    others = []
    for d, dirs, files in os.walk(root):
        dirs[:] = sorted(x for x in dirs if x not in _SKIP_DIRS and not x.endswith(".egg-info"))
        rel = os.path.relpath(d, root)
        if rel in (".", "docs"):
            continue
        others += [f"{rel}/{f}" for f in sorted(files) if f.endswith(".md")]
    return ["README.md"] + [f"docs/{f}" for f in docs] + others


def manual_pages(root: str = ROOT) -> list[str]:
    """The pages of the manual: docs/*.md."""
    return [p for p in doc_files(root) if p.startswith("docs/")]


# --------------------------------------------------------------------------- Markdown

@dataclass
class Block:
    lang: str
    line: int            # 1-based line number of the first line inside the fence
    lines: list[str]


_FENCE = re.compile(r"^ {0,3}(`{3,}|~{3,})\s*([^`\s]*)")


def split_fences(text: str) -> tuple[list[Block], list[str]]:
    """The fenced code blocks, and the text's lines with those blocks blanked out."""
    blocks, prose = [], []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        m = _FENCE.match(lines[i])
        if not m:
            prose.append(lines[i])
            i += 1
            continue
        fence, lang = m.group(1), m.group(2).lower()
        body, start = [], i + 1
        prose.append("")
        i += 1
        while i < len(lines) and not re.match(rf"^ {{0,3}}{fence[0]}{{{len(fence)},}}\s*$", lines[i]):
            body.append(lines[i])
            prose.append("")
            i += 1
        if i < len(lines):
            prose.append("")              # the closing fence
            i += 1
        blocks.append(Block(lang, start + 1, body))
    return blocks, prose


def _drop_code_spans(line: str) -> str:
    return re.sub(r"(`+)(.+?)\1", lambda m: " " * len(m.group(0)), line)


def _inline_text(md: str) -> str:
    """A heading's text as GitHub renders it: links and images by their text, no tags,
    no emphasis markers, code spans kept verbatim."""
    out = []
    for k, part in enumerate(re.split(r"(`+[^`]*`+)", md)):
        if part.startswith("`"):
            out.append(part.strip("`"))
            continue
        part = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", part)
        part = re.sub(r"<[^>]+>", "", part)
        part = re.sub(r"(?<![\w])_+|_+(?![\w])", "", part)     # _emphasis_, not snake_case
        out.append(part)
    return "".join(out)


def github_slug(heading: str) -> str:
    """GitHub's anchor for a heading (github-slugger): lower case, drop what is not a
    letter, digit, ``_``, ``-`` or space, each space a ``-``."""
    text = _inline_text(heading).strip().lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(text: str) -> set[str]:
    """Every anchor a page offers: its headings' slugs (repeats numbered) and HTML ids."""
    _, prose = split_fences(text)
    seen: dict[str, int] = {}
    found: set[str] = set()
    for i, line in enumerate(prose):
        m = re.match(r"^ {0,3}#{1,6}(?:\s+(.*?))?\s*$", line)
        heading = None
        if m:
            heading = re.sub(r"\s+#+\s*$", "", m.group(1) or "")
        elif (i + 1 < len(prose) and line.strip() and not line.startswith(("|", "-", "*", ">"))
              and re.match(r"^ {0,3}(=+|-+)\s*$", prose[i + 1])
              and (i == 0 or not prose[i - 1].strip() or re.match(r"^ {0,3}#", prose[i - 1]))):
            heading = line.strip()                       # setext heading
        if heading is None:
            continue
        slug = github_slug(heading)
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        found.add(slug if n == 0 else f"{slug}-{n}")
    for line in prose:
        found.update(re.findall(r"""<[^>]*\s(?:id|name)\s*=\s*["']([^"']+)["']""", line))
    return found


_INLINE_LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]*)>?(?:\s+[\"'(][^)]*)?\)")
_REF_DEF = re.compile(r"^ {0,3}\[[^\]]+\]:[ \t]*<?(\S+?)>?(?:\s|$)", re.M)
_HTML_LINK = re.compile(r"""\s(?:href|src)\s*=\s*["']([^"']+)["']""")


def links(text: str) -> list[tuple[int, str]]:
    """(line, target) of every link outside code, in order."""
    _, prose = split_fences(text)
    body = "\n".join(_drop_code_spans(line) for line in prose)
    body = re.sub(r"<!--.*?-->", lambda m: re.sub(r"[^\n]", " ", m.group(0)), body, flags=re.S)
    found = sorted((m.start(1), m.group(1)) for rx in (_INLINE_LINK, _REF_DEF, _HTML_LINK)
                   for m in rx.finditer(body))           # a link's text may wrap lines
    return [(body.count("\n", 0, at) + 1, target) for at, target in found]


def _is_external(target: str) -> bool:
    return bool(re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*:", target)) or target.startswith("//")


def _repo_files(root: str) -> set[str] | None:
    """Files GitHub will show: tracked or about to be (not ignored); None outside git."""
    try:
        out = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"],
                             cwd=root, capture_output=True, check=True, timeout=60).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    files = {f for f in out.decode().split("\0") if f}
    return files | {os.path.dirname(f) for f in files} | {
        d for f in files for d in itertools.accumulate(f.split("/")[:-1], lambda a, b: f"{a}/{b}")}


def check_links(path: str, root: str = ROOT, repo_files: set[str] | None = None) -> list[str]:
    """Problems with the relative links of ``path`` (relative to ``root``), one line each."""
    text = open(os.path.join(root, path), encoding="utf-8").read()
    problems = []
    cache: dict[str, set[str]] = {}
    for line, target in links(text):
        if not target or _is_external(target):
            if not target:
                problems.append(f"{path}:{line}: empty link target")
            continue
        file_part, _, anchor = target.partition("#")
        file_part = unquote(file_part)
        if file_part:
            rel = os.path.normpath(os.path.join(os.path.dirname(path), file_part))
        else:
            rel = path
        where = f"{path}:{line}: {target}"
        if rel.startswith("..") or os.path.isabs(file_part):
            problems.append(f"{where}: points outside the repository")
            continue
        if not os.path.exists(os.path.join(root, rel)):
            problems.append(f"{where}: no such file {rel}")
            continue
        if repo_files is not None and rel not in repo_files and rel != ".":
            problems.append(f"{where}: {rel} exists here but is not in the repository "
                            "(ignored or generated: it will not be there on GitHub)")
            continue
        if not anchor:
            continue
        if rel.endswith(".md"):
            if rel not in cache:
                cache[rel] = anchors(open(os.path.join(root, rel), encoding="utf-8").read())
            if unquote(anchor) not in cache[rel]:
                near = [a for a in cache[rel] if anchor.split("-")[0] in a][:3]
                problems.append(f"{where}: no heading #{anchor} in {rel}"
                                + (f" (there are: {', '.join(sorted(near))})" if near else ""))
        elif not re.fullmatch(r"L\d+(-L\d+)?", anchor):
            problems.append(f"{where}: #{anchor} on a file that is not Markdown")
    return problems


# --------------------------------------------------------------------------- commands

def _strip_comment(line: str) -> str:
    """The line without its shell comment: ``#`` at a word's start, outside quotes."""
    quote = None
    for i, c in enumerate(line):
        if quote:
            if c == quote:
                quote = None
            elif c == "\\" and quote == '"':
                continue
        elif c in "'\"":
            quote = c
        elif c == "#" and (i == 0 or line[i - 1].isspace()):
            return line[:i]
    return line


def _logical_lines(block: Block) -> list[tuple[int, str]]:
    """The block's lines with continuations joined, comments and ``$ `` prompts removed."""
    out: list[tuple[int, str]] = []
    pending: tuple[int, str] | None = None
    for n, raw in enumerate(block.lines, block.line):
        line = _strip_comment(raw).rstrip()
        if block.lang == "console" or line.startswith("$ "):
            if not line.startswith("$ ") and pending is None:
                continue                                   # output, not a command
            line = line[2:] if line.startswith("$ ") else line
        cont = line.endswith("\\")
        if cont:
            line = line[:-1]
        if pending is not None:
            pending = (pending[0], pending[1] + " " + line.strip())
        elif (out and raw[:1].isspace() and line.strip().startswith(("[", "-"))
              and _is_diffbot(out[-1][1])):
            out[-1] = (out[-1][0], out[-1][1] + " " + line.strip())   # a wrapped synopsis
            continue
        else:
            pending = (n, line)
        if not cont:
            out.append(pending)
            pending = None
    if pending is not None:
        out.append(pending)
    return [(n, s) for n, s in out if s.strip()]


def _program(word: str) -> bool:
    return os.path.basename(word) == "diffbot"


def _is_diffbot(line: str) -> bool:
    return bool(re.search(r"(^|[\s;&|(/])diffbot(\s|$)", line))


def _starts_with_diffbot(line: str) -> bool:
    words = line.split()
    while words and re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*=.*", words[0]):
        words = words[1:]
    return bool(words) and _program(words[0])


def _shell_words(line: str) -> list[str]:
    lex = shlex.shlex(line, posix=True, punctuation_chars="&;()")
    lex.whitespace_split = True
    lex.commenters = ""
    return list(lex)


def commands(text: str) -> list[tuple[int, list[str]]]:
    """(line, argv after ``diffbot``) of every diffbot command in a shell block."""
    blocks, _ = split_fences(text)
    found = []
    for block in blocks:
        if block.lang == "toml":
            found.extend(_toml_commands(block))
            continue
        if block.lang not in SHELL_LANGS:
            continue
        for n, line in _logical_lines(block):
            if not _is_diffbot(line):
                continue
            if not block.lang and not _starts_with_diffbot(line):
                continue                   # a block of no language: only plain command lines
            try:
                words = _shell_words(line)
            except ValueError as exc:                     # unbalanced quotes
                found.append((n, ["<unparsable shell line>", str(exc), line]))
                continue
            for cmd in _split_commands(words):
                cmd = _drop_redirections(cmd)
                while cmd and re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*=.*", cmd[0]):
                    cmd = cmd[1:]                          # VAR=value prefixes
                if cmd and cmd[0] in ("exec", "nohup", "time"):
                    cmd = cmd[1:]
                if cmd and _program(cmd[0]):
                    found.append((n, cmd[1:]))
    return found


_REDIRECT = re.compile(r"(\d*|&)(>>?|<)(&\d+|&-)?(.*)")


def _drop_redirections(cmd: list[str]) -> list[str]:
    """A command's words without its shell redirections (``2> FILE``, ``>log``, ``2>&1``):
    they are the shell's, not the command's arguments."""
    out, skip = [], False
    for word in cmd:
        if skip:
            skip = False
            continue
        m = _REDIRECT.fullmatch(word)
        if m:
            skip = not m.group(3) and not m.group(4)    # the target is the next word
            continue
        out.append(word)
    return out


def _toml_commands(block: Block) -> list[tuple[int, list[str]]]:
    """A scenario file's ``command = ["controller", ...]``: the arguments of ``diffbot``."""
    found = []
    for n, line in enumerate(block.lines, block.line):
        m = re.match(r"^\s*command\s*=\s*(\[.*?\])\s*(#.*)?$", line)
        if m:
            try:
                found.append((n, [str(a) for a in tomllib.loads(f"c = {m.group(1)}")["c"]]))
            except tomllib.TOMLDecodeError as exc:
                found.append((n, ["<unparsable TOML>", str(exc), line]))
    return found


def _split_commands(words: list[str]) -> list[list[str]]:
    """Words split at ``&&``, ``||``, ``;``, ``&``, ``|`` (outside synopsis brackets)."""
    cmds, cur, depth = [], [], 0
    for w in words:
        depth += w.count("[") - w.count("]")
        if w in ("&&", "||", ";", "&", ";;", "(", ")") or (w == "|" and depth <= 0):
            cmds.append(cur)
            cur = []
        else:
            cur.append(w)
    cmds.append(cur)
    return [c for c in cmds if c]


# --------------------------------------------------------------------------- synopsis

_PLACEHOLDER = re.compile(r"^(?:[A-Z][A-Z0-9_]*(?:[=,:/\-.+][A-Z0-9_]*|\.\.\.)*(?:\.[a-z0-9]+)?"
                          r"|.*<[a-z_][a-z0-9_-]*>.*)$")


def is_placeholder(word: str) -> bool:
    """``N``, ``DIR``, ``KEY=VALUE``, ``A-B``, ``KEY=V1,V2,...``, ``MODEL.fmu``, ``<robot>``."""
    return bool(_PLACEHOLDER.match(word))


def expand_synopsis(argv: list[str]) -> list[list[str]]:
    """The concrete argument lists a usage line stands for: brackets dropped, each
    alternative of ``a|b``, ``[x | y]`` and ``--[no-]flag`` once (the others at their first)."""
    # items: a list of alternatives, each a list of words
    items: list[list[list[str]]] = []
    group: list[list[str]] | None = None
    depth = 0
    for w in argv:
        if w in ("...", "]..."):
            if w == "]...":
                depth -= 1
                if depth == 0 and group is not None:
                    items.append(group)
                    group = None
            continue
        opening = len(w) - len(w.lstrip("["))
        if opening and not w.startswith("--["):
            depth += opening
            w = w[opening:]
            if depth == opening:
                group = [[]]
        closing = 0
        if w.endswith("...") and not is_placeholder(w):
            w = w[:-3]
        while w.endswith("]") and depth > 0 and not re.search(r"\[[^\]]*\]$", w):
            w, closing = w[:-1], closing + 1
        while w.endswith("]...") and depth > 0:
            w, closing = w[:-4], closing + 1
        if group is not None:
            if w == "|" and depth == 1:
                group.append([])
            elif w:
                group[-1].append(w)
        elif w:
            items.append([[w]])
        depth -= closing
        if closing and depth == 0 and group is not None:
            items.append(group)
            group = None
    if group is not None:
        items.append(group)

    def word_alternatives(w: str) -> list[str]:
        m = re.fullmatch(r"(--)\[no-\](.+)", w)
        if m:
            return [f"--{m.group(2)}", f"--no-{m.group(2)}"]
        if "|" in w and not is_placeholder(w):
            return w.split("|")
        return [w]

    # expand words inside each alternative
    slots: list[list[list[str]]] = []
    for alts in items:
        expanded = []
        for alt in alts:
            choices = [word_alternatives(w) for w in alt]
            expanded.append([[c[0] for c in choices]])
            for i, c in enumerate(choices):
                for other in c[1:]:
                    expanded[-1].append([x[0] if j != i else other for j, x in enumerate(choices)])
        slots.append([seq for e in expanded for seq in e])
    base = [seq[0] for seq in slots]
    variants = [[w for seq in base for w in seq]]
    for i, seqs in enumerate(slots):
        for seq in seqs[1:]:
            variants.append([w for j, s in enumerate(base) for w in (seq if j == i else s)])
    return variants


# --------------------------------------------------------------------------- parsing

class _Parsed(Exception):
    pass


@contextlib.contextmanager
def _parse_only():
    """Within: an ArgumentParser's parse_args parses, checks that every option is spelled
    out, and raises _Parsed instead of returning; placeholders skip type and choices."""
    AP = argparse.ArgumentParser
    orig = AP.parse_args, AP._get_value, AP._check_value
    seen: dict = {}

    def parse_args(self, args=None, namespace=None):
        seen["parser"] = self
        ns = orig[0](self, args, namespace)
        for w in (args or []):
            if w == "--":
                break
            opt = w.split("=", 1)[0]
            if opt.startswith("--") and opt not in self._option_string_actions:
                full = [o for o in self._option_string_actions if o.startswith(opt)]
                self.error(f"{opt}: abbreviated; spell it out ({', '.join(full)})")
        raise _Parsed(ns)

    def get_value(self, action, arg_string):
        if isinstance(arg_string, str) and is_placeholder(arg_string):
            return arg_string
        return orig[1](self, action, arg_string)

    def check_value(self, action, value):
        if isinstance(value, str) and is_placeholder(value):
            return
        return orig[2](self, action, value)

    AP.parse_args, AP._get_value, AP._check_value = parse_args, get_value, check_value
    try:
        yield seen
    finally:
        AP.parse_args, AP._get_value, AP._check_value = orig


#: sub-commands that take no options at all (no parser to ask)
NO_ARGS = ("scenarios",)


def parse_error(argv: list[str]) -> str | None:
    """None if ``diffbot ARGV`` parses with the real CLI (nothing is run), else why not."""
    from diffbot import cli
    if argv and argv[0] in NO_ARGS:
        return f"diffbot {argv[0]} takes no arguments" if argv[1:] else None
    out, err = io.StringIO(), io.StringIO()
    argv0 = sys.argv[0]
    try:
        with _parse_only(), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = cli._dispatch(list(argv))
    except _Parsed:
        return None
    except SystemExit as exc:
        if exc.code in (0, None) and any(a in ("-h", "--help") for a in argv):
            return None
        return (err.getvalue() or out.getvalue()).strip() or f"exit {exc.code}"
    except Exception as exc:      # noqa: BLE001 - any failure to parse is the finding
        return f"{type(exc).__name__}: {exc}"
    finally:
        sys.argv[0] = argv0
    if code == 0 and (not argv or any(a in ("-h", "--help") for a in argv)):
        return None
    said = (err.getvalue() or out.getvalue()).strip().splitlines()
    return said[0] if said else f"returned {code} without parsing its arguments"


def check_commands(path: str, root: str = ROOT) -> tuple[int, list[str]]:
    """(how many command lines were checked, problems one line each) for ``path``."""
    text = open(os.path.join(root, path), encoding="utf-8").read()
    problems, n = [], 0
    for line, argv in commands(text):
        n += 1
        shown = " ".join(shlex.quote(a) for a in argv)
        for variant in expand_synopsis(argv):
            why = parse_error(variant)
            if why:
                problems.append(f"{path}:{line}: diffbot {shown}"
                                + (f" [as: {' '.join(variant)}]" if variant != argv else "")
                                + f": {why}")
                break
    return n, problems


def main() -> int:
    files = _repo_files(ROOT)
    bad = 0
    for path in doc_files():
        problems = check_links(path, repo_files=files)
        n, cmd_problems = check_commands(path)
        for p in problems + cmd_problems:
            print(p)
        bad += len(problems) + len(cmd_problems)
        print(f"# {path}: {n} command line(s), {len(problems) + len(cmd_problems)} problem(s)",
              file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
