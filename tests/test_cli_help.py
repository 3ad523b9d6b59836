"""Every subcommand's help: a description, and each option's default."""

import argparse
import re

import pytest

from contact_edit_addon.commands.cli import build_parser, main


def subcommands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    [commands] = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(commands.choices)


def help_of(name: str, capsys) -> str:
    with pytest.raises(SystemExit) as exit_:
        main([name, "--help"])
    assert exit_.value.code == 0
    return " ".join(capsys.readouterr().out.split())  # argparse wraps lines anywhere


def test_every_subcommand_describes_itself_and_shows_every_default(capsys):
    commands = subcommands()
    assert {
        "bench",
        "ablation",
        "build-extension",
        "demo",
        "pose",
        "synthesize",
        "import-grab",
        "retarget",
    } <= set(commands)
    for name, sub in commands.items():
        text = help_of(name, capsys)
        assert sub.description and " ".join(sub.description.split()) in text, name
        for action in sub._actions:
            if isinstance(action, argparse._HelpAction) or action.default is argparse.SUPPRESS:
                continue
            where = f"{name} {'/'.join(action.option_strings) or action.dest}"
            assert action.help, where
            if not action.option_strings or action.required or action.default is False:
                continue  # positionals and required options have no default; flags are off unless given
            if action.default is None:  # the help says what happens without the option
                assert "(default: " in action.help, where
                continue
            shown = f"{' '.join(action.help.split())} (default: {action.default})"
            assert shown in text, where
            # Said once: no hand-written "(default …)" beside the one argparse adds.
            assert not re.search(r"\(default\b", action.help), where


def test_help_examples(capsys):
    text = help_of("synthesize", capsys)
    assert "--frames FRAMES frame count (default: 600)" in text
    assert "the object the hand manipulates (default: mug)" in text
    assert "frame rate (GRAB's) (default: 120.0)" in help_of("import-grab", capsys)
    text = help_of("retarget", capsys)
    assert "--workers WORKERS worker processes (default: one per CPU)" in text
    assert "interrupted run resumes" in text
    assert "--debug" in text
    with pytest.raises(SystemExit):
        main(["--help"])
    assert "--debug" in capsys.readouterr().out
