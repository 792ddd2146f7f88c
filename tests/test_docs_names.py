"""Prose that names code is checked (issue 38): every path, module, command and option that a
page of ``docs/`` or the README names exists. A layout table that still listed a package
merged away a release ago (``src/pkmcal/measurements``) is what this guards against."""

from __future__ import annotations

import importlib
import re
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]
#: folders of the project a page may name files in
FOLDERS = ("src", "tests", "benchmarks", "examples", "docs")
_SPAN = re.compile(r"`([^`\n]+)`")
_FENCE = re.compile(r"^```[a-z]*\n(.*?)^```", re.S | re.M)
_PATH = re.compile(r"(?:^|[\s(=])((?:" + "|".join(FOLDERS) + r")/[\w./-]+)")
_MODULE = re.compile(r"\bpkmcal(?:\.[A-Za-z_]\w*)+")
#: ``pkmcal WORD ...`` up to the end of the shell command (a word with a colon is prose)
_COMMAND = re.compile(r"(?:^|[\s;|&(`$])pkmcal ([a-z][a-z-]*(?![\w:-])[^\n;|&]*)")
_OPTION = re.compile(r"(?<![\w-])(--[a-z][a-z0-9-]*)")


@cache
def _commands() -> dict[str, set[str]]:
    """Each command of ``pkmcal`` and its long options (from the app, not a copy)."""
    import typer.main

    from pkmcal.cli import app

    group = typer.main.get_command(app)
    root = {o for p in group.params for o in p.opts + p.secondary_opts}
    out = {}
    for name, command in group.commands.items():
        out[name] = root | {o for p in command.params for o in p.opts + p.secondary_opts
                            if o.startswith("--")} | {"--help"}
    return out


def _spans(text: str) -> list[str]:
    """The code a page shows: fenced blocks (joined continuation lines) and inline spans."""
    blocks = [b.replace("\\\n", " ") for b in _FENCE.findall(text)]
    rest = _FENCE.sub("", text)
    return blocks + _SPAN.findall(rest)


def _module_exists(dotted: str) -> bool:
    parts = dotted.split(".")
    for k in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:k]))
        except ImportError:
            continue
        for attr in parts[k:]:
            if not hasattr(obj, attr):
                return False
            obj = getattr(obj, attr)
        return True
    return False


def _benchmark_options() -> set[str]:
    """Options the benchmark scripts take (a page may name them beside ``python benchmarks/``)."""
    found = set()
    for script in (ROOT / "benchmarks").glob("*.py"):
        found.update(re.findall(r"[\"'](--[a-z][a-z0-9-]*)[\"']", script.read_text()))
    return found


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_named_path_and_module_exists(page):
    missing = []
    for span in _spans(page.read_text()):
        for path in _PATH.findall(span):
            path = path.rstrip(".,;:")
            if not (ROOT / path).exists():
                missing.append(path)
        for dotted in _MODULE.findall(span):
            if not _module_exists(dotted.rstrip(".")):
                missing.append(dotted)
    assert not missing, f"{page.name} names what does not exist: {sorted(set(missing))}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_named_command_and_option_exists(page):
    commands, wrong = _commands(), []
    everywhere = set().union(*commands.values()) | _benchmark_options()
    for span in _spans(page.read_text()):
        for line in span.splitlines() or [span]:
            line = re.sub(r"(^|\s)#.*", "", line)        # a shell comment is prose
            for call in _COMMAND.findall(line):
                word, *_ = call.split(maxsplit=1)
                if word.startswith("-"):
                    continue
                if word not in commands:
                    wrong.append(f"pkmcal {word}")
                    continue
                wrong += [f"pkmcal {word} {o}" for o in _OPTION.findall(call)
                          if o not in commands[word]]
            if not _COMMAND.search(line):
                wrong += [o for o in _OPTION.findall(line) if o not in everywhere]
    assert not wrong, f"{page.name} names commands or options that do not exist: {wrong}"


def test_the_check_catches_a_stale_name(tmp_path, monkeypatch):
    """The two checks fail on a page naming a package, a command and an option that are gone."""
    page = tmp_path / "stale.md"
    page.write_text("| `src/pkmcal/measurements` | gone |\n\n```sh\npkmcal measure x.yaml\n"
                    "pkmcal calibrate m.yaml d.csv --no-such-option\n```\n"
                    "See `pkmcal.nothing_here`.\n")
    with pytest.raises(AssertionError, match="measurements"):
        test_every_named_path_and_module_exists(page)
    with pytest.raises(AssertionError, match="pkmcal measure.*no-such-option"):
        test_every_named_command_and_option_exists(page)


def test_the_layout_table_lists_every_package():
    """docs/index.md's layout table names every package of src/pkmcal (and nothing gone:
    the test above)."""
    table = (ROOT / "docs" / "index.md").read_text()
    packages = [p.relative_to(ROOT).as_posix() for p in sorted((ROOT / "src" / "pkmcal").iterdir())
                if (p / "__init__.py").exists()]
    assert [p for p in packages if f"`{p}`" not in table] == []
