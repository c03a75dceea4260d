"""What a user of the installed package meets outside a checkout (issue 45.1): the examples are
package data, ``missing-link examples DIR`` writes them out, a missing file that is an example
says where the installed one is, no help text names a checkout's path, and a dry run that could
not build says so.  The wheel itself, in a fresh venv: tests/test_install.py."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from missing_link.cli.commands import COMMANDS
from missing_link.cli.examples import example_files, installed
from missing_link.cli.main import build_parser, main
from missing_link.deploy.boardfile import load_board_file

ROOT = Path(__file__).resolve().parent.parent


def test_the_examples_are_package_data_and_the_checkout_links_to_them() -> None:
    names = {str(f) for f in example_files()}
    assert {"missing-link.toml", "boards/rover.py", "boards/thesis-rig-uno.py",
            "security/make-certs.sh"} <= names  # fmt: skip
    assert installed() == ROOT / "src" / "missing_link" / "examples"
    assert (ROOT / "examples").resolve() == installed()  # (what users of a checkout type)
    data = "\n".join((ROOT / "pyproject.toml").read_text().splitlines())
    assert '"examples/boards/*.py"' in data and '"examples/*.toml"' in data


def test_examples_writes_them_all_and_keeps_what_is_there(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "ex"
    assert main(["examples", str(out)]) == 0
    for f in example_files():
        assert (out / f).read_bytes() == (installed() / f).read_bytes(), f
    assert (out / "security" / "make-certs.sh").stat().st_mode & 0o111
    for board in sorted((out / "boards").glob("*.py")):
        load_board_file(board)  # (every one checks as it is)
    told = capsys.readouterr().out
    assert f"missing-link board --file {out / 'boards' / 'thesis-rig.py'}" in told
    (out / "boards" / "rover.py").write_text("# mine\n")
    assert main(["examples", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("missing-link: error: ") and "--force" in err and "\n" not in err
    assert (out / "boards" / "rover.py").read_text() == "# mine\n"
    assert main(["examples", str(out), "--force"]) == 0
    assert (out / "boards" / "rover.py").read_bytes() == (
        installed() / "boards/rover.py"
    ).read_bytes()


@pytest.mark.parametrize(
    ("argv", "example"),
    [
        (["board", "--file", "examples/boards/rover.py", "--listen", "pty"], "boards/rover.py"),
        (["flash", "examples/boards/thesis-rig-uno.py", "--dry-run"], "boards/thesis-rig-uno.py"),
        (["gen-firmware", "thesis-rig-uno.py", "--out", "fw"], "boards/thesis-rig-uno.py"),
        (["run", "--config", "examples/missing-link.toml"], "missing-link.toml"),
        (["create-msgs", "examples/original-board.toml", "--out", "x"], "original-board.toml"),
    ],
)
def test_a_missing_example_says_where_the_installed_one_is(
    argv: list[str],
    example: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Run from a directory without examples/ (as from an installed package): before, "cannot
    read" and nothing else."""
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err, err
    assert str(installed() / example) in err and "missing-link examples DIR" in err, err


def test_a_missing_board_file_under_examples_names_the_installed_ones(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["board", "--file", "examples/boards/mybot.py", "--listen", "pty"]) == 2
    err = capsys.readouterr().err
    assert "rover.py" in err and "thesis-rig.py" in err and "missing-link examples DIR" in err


def _helps(parser: argparse.ArgumentParser) -> list[str]:
    out = [parser.format_help()]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                out += _helps(sub)
    return out


def test_no_help_text_names_a_checkouts_path() -> None:
    """`run --help` pointed at examples/, which an installed package does not have."""
    for c in COMMANDS:
        text = "\n".join(_helps(build_parser(c.name)))
        assert "examples/" not in text, (c.name, text)
    for name in ("run", "flash", "board", "update"):
        text = " ".join("\n".join(_helps(build_parser(name))).split())
        assert "`missing-link examples DIR` writes" in text, name


def test_an_avr_dry_run_that_could_not_build_fails(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Before, it exited 0 listing a make that could not run."""
    monkeypatch.setenv("PATH", str(Path(__file__).parent))  # (no make, no avr-gcc here)
    uno = installed() / "boards" / "thesis-rig-uno.py"
    assert main(["flash", str(uno), "--dry-run"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("missing-link: error: cannot build or write AVR firmware: no make, ")
    assert "avr-gcc" in err and "\n" not in err
