"""Every ``gbo`` sub-command explains itself: a one-line description and an example in ``--help``."""

from __future__ import annotations

import argparse

import pytest

from evaluation.cli import build_parser, main


def _commands(parser: argparse.ArgumentParser, prefix=()):
    """``(argv prefix, parser)`` of every sub-command, nested ones included (``twin compare``)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield (*prefix, name), sub
                yield from _commands(sub, (*prefix, name))


COMMANDS = [argv for argv, _ in _commands(build_parser())]


def test_every_subcommand_is_listed():
    assert {"demo", "bench", "tune", "sessions", "export", "twin", ("twin", "diagnose")} <= \
        {argv[0] if len(argv) == 1 else argv for argv in COMMANDS}


@pytest.mark.parametrize("argv", COMMANDS, ids=" ".join)
def test_help_has_a_description_and_an_example(argv, capsys):
    with pytest.raises(SystemExit) as exit_:
        main([*argv, "--help"])
    assert exit_.value.code == 0
    text = capsys.readouterr().out
    usage, _, rest = text.partition("\n\n")
    description = rest.split("\n\n")[0].strip()
    assert description and not description.startswith(("positional arguments", "options")), text
    example = text[text.index("Example"):] if "Example" in text else ""
    assert example.splitlines()[1].strip().startswith("gbo "), text  # an example command under "Example(s):"


def test_import_is_documented_in_the_help_of_tune(capsys):
    with pytest.raises(SystemExit):
        main(["tune", "--help"])
    text = capsys.readouterr().out
    assert "--import MODULE" in text and "registers" in text
