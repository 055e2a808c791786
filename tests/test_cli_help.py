"""The short help of every command: under 80 lines at any terminal width, first sentences
only, no RST markup, and exactly the flags tyro parses (its own help, ``--help-full``)."""

from __future__ import annotations

import contextlib
import io
import re
import subprocess
import sys

import pytest

from safe_bc.cli.commands import COMMANDS, main, parse
from safe_bc.cli.help import first_sentence, plain


def _out(argv: list[str]) -> str:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit) as info:
        parse(argv)
    assert info.value.code == 0
    return out.getvalue()


@pytest.mark.parametrize("columns", ["80", "200"])
@pytest.mark.parametrize("command", list(COMMANDS))
def test_short_help_is_under_80_lines_without_rst(
    command: str, columns: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("COLUMNS", columns)
    text = _out([command, "--help"])
    lines = text.splitlines()
    assert len(lines) < 80, (command, len(lines))
    assert "``" not in text and ":class:" not in text and ":attr:" not in text
    width = min(int(columns), 120)
    assert max(len(line) for line in lines) <= width, command


@pytest.mark.parametrize("command", list(COMMANDS))
def test_short_help_lists_the_flags_tyro_parses(command: str) -> None:
    def flags(text: str) -> set[str]:
        return set(re.findall(r"(?<![\w-])--[a-z][\w.-]*", text)) - {"--help", "--help-full"}

    short = _out([command, "--help"])
    full = _out([command, "--help-full"])
    # the flags the short help names in its entries (not in its prose)
    entries = "\n".join(line.split("[", 1)[0] for line in short.splitlines() if line[:4] == "  --")
    cells = [line.strip("│| ").split("  ")[0] for line in full.splitlines()]
    rows = "\n".join(cell for cell in cells if cell.startswith("-"))
    assert flags(entries) == flags(rows)
    assert len(flags(entries)) >= 3


def test_short_help_shows_first_sentences_and_defaults() -> None:
    text = _out(["train", "--help"])
    entry = next(line for line in text.splitlines() if "--selection.eps" in line)
    assert "[None]" in entry and "Width of the critical edge" in entry
    assert "None (default): the task's" in " ".join(text.split())  # an unset width: the task's
    assert "A row is critical" not in text  # the docstring's second sentence
    assert "--out PATH [required]" in text
    assert "Alias --seed for --bc.train.seed." in text


def test_first_sentence_and_plain() -> None:
    assert first_sentence("Adam learning rate.") == "Adam learning rate."
    assert first_sentence("A ``x`` e.g. 2.5 px. Then more.") == "A x e.g. 2.5 px."
    assert first_sentence("One line\nwrapped. Two.\n\nThree.") == "One line wrapped."
    assert first_sentence("Cut at the paragraph\n\nNext.") == "Cut at the paragraph"
    assert plain(":class:`~safe_bc.X` and :attr:`y`, `z`") == "safe_bc.X and y, z"


def test_help_imports_neither_torch_nor_ray() -> None:
    code = (
        "import sys; from safe_bc.cli.commands import main\n"
        "try:\n    main(['train', '--help'])\nexcept SystemExit:\n    pass\n"
        "print(sorted(m for m in ('torch', 'ray', 'pandas', 'pyarrow') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip().splitlines()[-1] == "[]"


def test_help_full_is_tyros(capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit) as info:
        main(["tune", "--help-full"])
    assert info.value.code == 0
    assert "StudySpec.trials" in capsys.readouterr().out
