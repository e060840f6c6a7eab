"""Help for a user: every subcommand's --help and every error the harness raises speak to a
user (no issue numbers), every option says what it does, and the top-level help lists the
subcommands by the task they serve."""

from __future__ import annotations

import argparse
import ast
import re
from pathlib import Path

import pytest

from harness.cli import STUDIES, TASKS, main, parser

HARNESS = Path(__file__).parents[1] / "harness"
INTERNAL = re.compile(r"\bissues?\b|solver scripts|\(window\)", re.IGNORECASE)


def help_text(capsys, *argv: str) -> str:
    with pytest.raises(SystemExit) as done:
        main([*argv, "--help"])
    assert done.value.code == 0
    return capsys.readouterr().out


@pytest.mark.parametrize("name", STUDIES)
def test_a_subcommands_help_has_no_internal_reference_and_explains_every_option(name, capsys):
    text = help_text(capsys, name)
    assert not INTERNAL.search(text), INTERNAL.search(text)
    sub = next(a for a in parser(name)._actions if isinstance(a, argparse._SubParsersAction)).choices[name]
    assert text.startswith(f"usage: python -m harness {name} ")  # its own usage, not the top level's
    for action in sub._actions:
        # A sentence, not a label: at least a few words.
        assert action.help and len(action.help.split()) >= 4, (name, action.option_strings or action.dest)


def test_the_top_level_help_lists_the_subcommands_by_task(capsys):
    text = help_text(capsys)
    assert not INTERNAL.search(text)
    assert sorted(n for names in TASKS.values() for n in names) == sorted(STUDIES)
    own = text.index("your own part")
    assert own < text.index("  solve ") < text.index("  convergence ") < text.index("checking the scheme")
    for name in STUDIES:
        assert f"  {name} " in text, name


def strings_in(node: ast.AST) -> list[str]:
    return [n.value for n in ast.walk(node) if isinstance(n, ast.Constant) and isinstance(n.value, str)]


def user_facing_strings(tree: ast.AST) -> list[tuple[int, str]]:
    """What a user reads: the text of raised errors, of print() and of help= / description=."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Raise) and node.exc is not None:
            out += [(node.lineno, s) for s in strings_in(node.exc)]
        elif isinstance(node, ast.Call):
            if isinstance(node.func, ast.Name) and node.func.id == "print":
                out += [(node.lineno, s) for arg in node.args for s in strings_in(arg)]
            out += [(node.lineno, s) for k in node.keywords if k.arg in ("help", "description") for s in strings_in(k.value)]
    return out


def test_no_error_or_message_of_the_harness_names_an_issue():
    found = [f"{path.relative_to(HARNESS.parent)}:{line}: {text!r}"
             for path in sorted(HARNESS.rglob("*.py"))
             for line, text in user_facing_strings(ast.parse(path.read_text()))
             if INTERNAL.search(text)]
    assert not found, "\n".join(found)


@pytest.mark.parametrize("name", STUDIES)
def test_a_studys_description_names_no_issue(name):
    from harness.cli import plugin

    assert not INTERNAL.search(plugin(name).__doc__ or "")
