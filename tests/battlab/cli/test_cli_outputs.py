"""Every command that writes a file checks its output path before the work. Commands that write into an
existing directory (library, simulate, run) refuse a missing one; commands that make their output's directory
(design, sensitivity, groups, fit, validate, diagnose, export) refuse a path through a file. Either is one line naming
the path, exit code 2, and nothing written."""

from __future__ import annotations

import errno
from pathlib import Path

import pytest
from click.testing import CliRunner

from battlab.cli import describe_os_error, main

REFUSING = ("library build", "library plot", "simulate", "run")
CREATING = ("export", "sensitivity", "groups", "design", "fit", "validate", "diagnose")
COMMANDS = REFUSING + CREATING


def _commands(tmp: Path, out: Path) -> dict[str, list[str]]:
    """Each writing command with its output in ``out`` (inputs made in ``tmp`` where a command reads them first)."""
    profile = tmp / "p.csv"
    profile.write_text("Test Time / s,Current / A\n0,0\n10,-1\n20,0\n")
    plan = tmp / "plan.toml"
    plan.write_text("")
    data = tmp / "d.csv"
    data.write_text("")
    store = str(tmp / "sens.h5")
    return {
        "library build": ["library", "build", "-o", str(out / "l.h5")],
        "library plot": ["library", "plot", "1", "-o", str(out / "p.png")],
        "export": ["export", str(profile), "-f", "csv", "-o", str(out / "dir")],
        "simulate": ["simulate", "nca18650", str(profile), "-o", str(out / "o.bdf.csv")],
        "sensitivity": ["sensitivity", str(tmp / "l.h5"), "--cell", "nca18650", "-o", str(out / "s.h5")],
        "groups": ["groups", store, "-o", str(out / "g")],
        "design": ["design", store, "-o", str(out / "plan.toml")],
        "fit": ["fit", str(data), "--cell", "nca18650", "-o", str(out / "c.bpx.json")],
        "validate": ["validate", str(data), "--cell", "nca18650", "-o", str(out / "v")],
        "diagnose": ["diagnose", str(data), "--cell", "nca18650", "-o", str(out / "report")],
        "run": ["run", str(plan), "--cycler", "virtual", "--chamber", "virtual", "-o", str(out / "r.h5")],
    }


@pytest.mark.parametrize("name", REFUSING)
def test_a_missing_output_directory_is_one_line_exit_2_and_nothing_written(
    name: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("BATTLAB_HOME", str(tmp_path / "home"))
    missing = tmp_path / "nodir"
    args = _commands(tmp_path, missing)[name]
    assert set(COMMANDS) == set(_commands(tmp_path, missing))
    before = sorted(p.name for p in tmp_path.rglob("*"))
    r = CliRunner().invoke(main, args)
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert r.exit_code == 2, (r.exit_code, r.stdout, r.stderr, r.exception)
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith("error: "), lines
    assert f"directory {missing} does not exist" in lines[0], lines
    assert "None" not in lines[0] and "Traceback" not in r.stderr
    assert not missing.exists()
    assert sorted(p.name for p in tmp_path.rglob("*")) == before


@pytest.mark.parametrize("name", COMMANDS)
def test_an_output_below_a_file_is_one_line_exit_2_and_nothing_written(
    name: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("BATTLAB_HOME", str(tmp_path / "home"))
    blocker = tmp_path / "afile"
    blocker.write_text("not a directory")
    args = _commands(tmp_path, blocker / "sub")[name]
    before = sorted(p.name for p in tmp_path.rglob("*"))
    r = CliRunner().invoke(main, args)
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert r.exit_code == 2, (r.exit_code, r.stdout, r.stderr, r.exception)
    assert len(lines) == 1 and lines[0].startswith(f"error: {blocker / 'sub'}"), lines
    why = f"{blocker} is a file, not a directory" if name in CREATING else f"directory {blocker / 'sub'} does not exist"
    assert why in lines[0], lines
    assert sorted(p.name for p in tmp_path.rglob("*")) == before


def test_an_os_error_without_a_file_name_is_its_own_message_not_none() -> None:
    """h5py and others raise FileNotFoundError with ``filename`` None and the path in the message."""
    text = describe_os_error(FileNotFoundError("Unable to create file (name = 'nodir/l.h5',\n errno = 2)"))
    assert "None" not in text and "nodir/l.h5" in text and "\n" not in text
    assert describe_os_error(FileNotFoundError(errno.ENOENT, "No such file or directory", "a/b.h5")) == (
        "a/b.h5: No such file or directory"
    )


def test_design_refuses_a_plan_name_before_reading_the_store(tmp_path: Path) -> None:
    r = CliRunner().invoke(main, ["design", str(tmp_path / "nostore.h5"), "-o", str(tmp_path / "plan.txt")])
    assert r.exit_code == 2 and r.stderr.strip() == f"error: {tmp_path / 'plan.txt'}: the plan is a .toml file"
    assert list(tmp_path.iterdir()) == []
