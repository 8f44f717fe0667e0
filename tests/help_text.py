"""Checks of command-line help text shared by the tests of the entry points."""

import dataclasses
import re

import pytest


def assert_every_flag_documented(help_text: str, flags: list[str]) -> None:
    """Each flag's entry in tyro's help has words besides its metavar and default: a field without a
    docstring shows only "(default: ...)".  Works with and without the box-drawing characters."""
    lines = [re.sub("[│╭╮╰╯─]", " ", line).strip() for line in help_text.splitlines()]
    for flag in flags:
        first = next(i for i, line in enumerate(lines) if re.match(rf"{re.escape(flag)}([ ,]|$)", line))
        entry = [lines[first][len(flag) :]]
        for line in lines[first + 1 :]:
            if not line or line.startswith("-"):
                break
            entry.append(line)
        text = re.sub(r"\{[^}]*\}|\[[^\]]*\]", " ", " ".join(entry)).split("(default:")[0]
        assert len(re.findall(r"\b[a-z]{2,}\b", text)) >= 2, f"{flag} has no help text: {text!r}"


def assert_help_documents_every_field(capsys, main, args_type) -> None:
    """`main(["--help"])` exits 0 and documents the flag of every field of the dataclass `args_type`."""
    with pytest.raises(SystemExit) as stop:
        main(["--help"])
    assert stop.value.code == 0
    flags = ["--" + field.name.replace("_", "-") for field in dataclasses.fields(args_type)]
    assert_every_flag_documented(capsys.readouterr().out, flags)
