"""``battlab run --quiet`` hides the progress, never the final result lines."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from battlab.cli import main

PLAN = "[[steps]]\nkind = 'rest'\nuntil = 'time >= 10'\n"


@pytest.fixture
def plan(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("BATTLAB_HOME", str(tmp_path / "home"))
    path = tmp_path / "plan.toml"
    path.write_text(PLAN)
    return path


def _run(plan: Path, out: Path, *extra: str) -> tuple[int, list[str], list[str]]:
    args = ["run", str(plan), "--cycler", "virtual", "--chamber", "virtual", "--physics", "standin", "-o", str(out)]
    r = CliRunner().invoke(main, [*args, *extra])
    assert r.exception is None or isinstance(r.exception, SystemExit), r.exception
    return r.exit_code, r.stdout.splitlines(), r.stderr.splitlines()


def test_quiet_hides_the_progress_and_keeps_the_result(plan: Path, tmp_path: Path) -> None:
    code, out, err = _run(plan, tmp_path / "loud.h5")
    assert code == 0 and any("step 1/1" in line for line in err), err  # progress, when not quiet
    code, out, err = _run(plan, tmp_path / "quiet.h5", "--quiet")
    assert code == 0
    assert not any("step" in line for line in out + err), (out, err)
    assert len(out) == 2, out
    assert out[0].startswith("run ") and " completed: " in out[0] and str(tmp_path / "quiet.h5") in out[0], out
    assert "samples" in out[1] and "gaps marked" in out[1], out


def test_quiet_keeps_the_reason_of_a_run_that_did_not_complete(plan: Path, tmp_path: Path) -> None:
    """5 A discharge of the stand-in cell for 10 h: a voltage limit stops it; the result lines say so."""
    plan.write_text("[[steps]]\nkind = 'cc'\ncurrent = -5.0\nuntil = 'time >= 36000'\n")
    code, out, err = _run(plan, tmp_path / "q.h5", "--quiet")
    assert code == 1 and out == [], (out, err)
    assert any(line.startswith("run ") and " aborted: " in line and str(tmp_path / "q.h5") in line for line in err)
    assert any(line.strip().startswith("reason: ") and len(line.strip()) > len("reason: ") for line in err), err
    assert any("battlab runs resume" in line for line in err) and not any("step" in line for line in err), err
