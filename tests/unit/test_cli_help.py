"""Every command's --help: a description, an example and the defaults; -q/-v after the command."""

from __future__ import annotations

import argparse

import pytest

from groundstation.cli import HelpFormatter, build_parser
from groundstation.commands import COMMANDS, EXAMPLES


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_help_has_description_example_and_defaults(
    name: str, capsys: pytest.CaptureFixture[str]
) -> None:
    parser = build_parser([name])
    with pytest.raises(SystemExit) as done:
        parser.parse_args([name, "--help"])
    assert done.value.code == 0
    text = capsys.readouterr().out
    assert "\nexample:\n  groundstation " + name in text
    assert EXAMPLES[name].splitlines()[0] in text
    (subs,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    sub = subs.choices[name]
    assert sub.description and len(sub.description) > 10
    for action in sub._actions:
        if not action.option_strings or action.help == "==SUPPRESS==":
            continue
        assert action.help, f"{name} {action.option_strings}: no help"
        has_default = action.default not in (None, False, [], "==SUPPRESS==")
        if has_default:  # said by the formatter or by the text itself
            shown = HelpFormatter(name)._get_help_string(action)
            assert "default" in shown, f"{name} {action.option_strings}: default not shown"


@pytest.mark.parametrize("argv", [["-q", "inspect", "x"], ["inspect", "x", "-q"],
                                  ["inspect", "-q", "x"]])
def test_quiet_before_or_after_the_command(argv: list[str]) -> None:
    args = build_parser(argv).parse_args(argv)
    assert args.quiet is True and args.verbose == 0


def test_verbose_after_the_command_counts() -> None:
    argv = ["-v", "inspect", "x", "-v"]
    assert build_parser(argv).parse_args(argv).verbose in (1, 2)
    argv = ["inspect", "x", "-vv"]
    assert build_parser(argv).parse_args(argv).verbose == 2


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_description_keeps_the_case_of_the_one_line_help(name: str) -> None:
    """``str.capitalize`` made "Mcap/.ubx -> rinex 2.11/3.04 obs" and "(to zenoh), at xn"."""
    from groundstation.commands import HELP

    parser = build_parser([name])
    (subs,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    text = HELP[name]
    assert subs.choices[name].description == text[0].upper() + text[1:] + "."


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_no_default_said_twice_and_placeholders_name_units(
        name: str, capsys: pytest.CaptureFixture[str]) -> None:
    parser = build_parser([name])
    with pytest.raises(SystemExit):
        parser.parse_args([name, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    import re

    twice = re.search(r"\(([^()\s]+)\) \(default: \1\)", text)  # "(3.04) (default: 3.04)"
    assert twice is None, twice
    assert "SHUTTER_DELAY_MS" not in text


@pytest.mark.parametrize(("argv", "said"), [
    (["solve", "f.ubx", "--base-xzy", "1,2,3"],
     ("groundstation solve: error: unrecognized arguments: --base-xzy 1,2,3; did you mean "
      "--base-xyz? (see --help)")),
    (["solve", "f.ubx", "--base-xzy=1,2,3"], "did you mean --base-xyz?"),
    (["inspect", "f.ubx", "--nonsense"],
     "groundstation inspect: error: unrecognized arguments: --nonsense (see --help)"),
])
def test_a_mistyped_option_names_the_command_and_the_option_meant(
        argv: list[str], said: str, capsys: pytest.CaptureFixture[str]) -> None:
    """A newcomer's finding: ``--base-xzy`` got "groundstation: error: unrecognized
    arguments", naming neither the command nor the option it is closest to."""
    from groundstation.cli import main

    with pytest.raises(SystemExit) as done:
        main(argv)
    assert done.value.code == 2
    err = capsys.readouterr().err
    assert said in err and len(err.strip().splitlines()) == 1, err
    assert "did you mean" not in err or "--nonsense" not in err
