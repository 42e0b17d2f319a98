"""docs/cli.md against the scripts' own parsers (no job runs, nothing compiles).

docs/cli.md has a section ``## python -m <module>`` for every command module of
``experiments/`` and ``benchmarks/``, with a table of its options (flag, default, meaning).
Each script builds its parser in ``build_parser()``, which its ``main`` uses; these tests
import the module, build the parser and check that

- every command module has a section, and every section names a command module;
- every flag a section mentions exists in that script's parser, and every parser flag is
  in the section's options table;
- a default written as code in the table is the parser's default;
- the ``python -m`` commands in docs/cli.md and README.md use their script's real flags.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = {name: ROOT / name for name in ("docs/cli.md", "README.md")}
PACKAGES = ("experiments", "benchmarks")
FLAG = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")
# a command in the text: ``python -m experiments.x --flag ...`` up to the end of the line or
# of the inline code span, without a trailing shell comment
COMMAND = re.compile(r"python -m ((?:experiments|benchmarks)\.\w+)([^`\n]*)")


def command_modules() -> list[str]:
    """The modules of experiments/ and benchmarks/ that run as a command."""
    found = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).glob("*.py")):
            if 'if __name__ == "__main__":' in path.read_text():
                found.append(f"{package}.{path.stem}")
    return found


MODULES = command_modules()


@functools.cache
def sections() -> dict[str, str]:
    """Module name -> the text of its ``## python -m <module>`` section of docs/cli.md."""
    found: dict[str, str] = {}
    for part in re.split(r"^## ", DOCS["docs/cli.md"].read_text(), flags=re.M)[1:]:
        head, _, body = part.partition("\n")
        match = re.fullmatch(r"python -m ([\w.]+)", head.strip())
        if match:
            assert match.group(1) not in found, f"two sections for {match.group(1)}"
            found[match.group(1)] = body
    return found


def table_rows(body: str) -> list[list[str]]:
    """The cells of the section's table rows, header and rule left out."""
    rows = []
    for line in body.splitlines():
        if not line.startswith("|"):
            continue
        cells = [c.strip() for c in re.split(r"(?<!\\)\|", line.strip())[1:-1]]
        if cells[0] == "flag" or set(cells[0]) <= {"-", ":"}:
            continue
        rows.append(cells)
    return rows


@functools.cache
def parser(module: str) -> argparse.ArgumentParser:
    return importlib.import_module(module).build_parser()


def parser_flags(module: str) -> dict[str, argparse.Action]:
    return {
        s: action
        for action in parser(module)._actions
        for s in action.option_strings
        if s.startswith("--") and s != "--help"
    }


def commands(text: str) -> list[tuple[str, set[str]]]:
    """``(module, flags)`` of every ``python -m`` command of experiments / benchmarks."""
    found = []
    for match in COMMAND.finditer(text):
        args = match.group(2).split(" #")[0]
        found.append((match.group(1), set(FLAG.findall(args))))
    return found


def test_every_command_module_has_a_section_and_builds_its_parser() -> None:
    assert "experiments.distill" in MODULES and "benchmarks.bench_sop" in MODULES
    assert sorted(sections()) == sorted(MODULES)
    for module in MODULES:
        assert isinstance(parser(module), argparse.ArgumentParser), module


@pytest.mark.parametrize("module", MODULES)
def test_every_flag_in_a_section_is_one_of_its_script(module: str) -> None:
    body = sections()[module]
    # flags of another script's command in this section are checked against that script
    own = COMMAND.sub(lambda m: m.group(0) if m.group(1) == module else "", body)
    unknown = sorted(set(FLAG.findall(own)) - set(parser_flags(module)))
    assert not unknown, f"docs/cli.md, {module}: no such flag in its parser: {unknown}"


@pytest.mark.parametrize("module", MODULES)
def test_every_parser_flag_is_in_the_options_table(module: str) -> None:
    rows = table_rows(sections()[module])
    documented = [f for row in rows for f in FLAG.findall(row[0])]
    assert len(documented) == len(set(documented)), f"{module}: a flag documented twice"
    missing = sorted(set(parser_flags(module)) - set(documented))
    assert not missing, f"docs/cli.md, {module}: options table lacks {missing}"
    positionals = [a for a in parser(module)._actions if not a.option_strings]
    assert len([r for r in rows if not FLAG.search(r[0])]) == len(positionals), module


def _same(text: str, default: object) -> bool:
    if isinstance(default, (int, float)):
        try:
            return float(text) == default
        except ValueError:
            return False
    value = str(default)
    return text == value or (Path(value).is_absolute() and Path(value) == ROOT / text)


@pytest.mark.parametrize("module", MODULES)
def test_defaults_in_the_table_are_the_parser_defaults(module: str) -> None:
    actions = parser_flags(module)
    for row in table_rows(sections()[module]):
        flags = FLAG.findall(row[0])
        if not flags or flags[0] not in actions:
            continue  # an unknown flag fails the test above
        default = actions[flags[0]].default
        if default is None or isinstance(default, (bool, list)):
            continue  # computed or off: described in words
        literal = re.match(r"`([^`]*)`", row[1])
        assert literal, f"{module} {flags[0]}: write the default {default!r} as code"
        assert _same(literal.group(1), default), (
            f"docs/cli.md, {module} {flags[0]}: default {literal.group(1)!r}, parser {default!r}"
        )


@pytest.mark.parametrize("doc", sorted(DOCS))
def test_commands_in_the_docs_use_real_flags(doc: str) -> None:
    found = commands(DOCS[doc].read_text())
    assert found, doc
    for module, flags in found:
        assert module in MODULES, f"{doc}: {module} is not a command"
        unknown = sorted(flags - set(parser_flags(module)))
        assert not unknown, f"{doc}: python -m {module} has no {unknown}"
