"""``battlab library`` and ``battlab export`` (the click objects of battlab.cli.library / .export)."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from battlab.cli.export import export
from battlab.cli.library import library
from protocols import InputError, Library, Protocol, ocv_test
from protocols.export import Format, difference, expected, read_back


@pytest.fixture(scope="module")
def lib_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("lib") / "library.h5"
    result = CliRunner().invoke(library, ["build", "-o", str(path)])
    assert result.exit_code == 0, result.output
    assert [line.split() for line in result.output.splitlines()][5] == [
        "soc_window",
        "540",
        "180",
        "18",
        "738",
    ]
    assert "738 profiles" in result.output and " h in total" in result.output
    return path


def test_build_writes_a_loadable_library(lib_file: Path) -> None:
    lib = Library.load(lib_file)
    assert lib.kind_counts() == {"pulse": 540, "sine": 180, "drive": 18}


def test_list_show_and_plot(lib_file: Path, tmp_path: Path) -> None:
    r = CliRunner()
    out = r.invoke(library, ["list", "-l", str(lib_file), "--kind", "drive", "--soc0", "0.4"]).output
    lines = out.strip().splitlines()
    assert len(lines) == 7 and lines[1].split()[:3] == ["733", "drive", "0.4"]
    out = r.invoke(library, ["show", "339", "-l", str(lib_file)]).output
    assert "pulse w=3s n=3 T=1800s charge" in out and "throughput    1.000000 Ah" in out
    png = tmp_path / "p.png"
    res = r.invoke(library, ["plot", "721", "-l", str(lib_file), "-o", str(png)])
    assert res.exit_code == 0 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_library_errors_are_input_errors(lib_file: Path, tmp_path: Path) -> None:
    r = CliRunner()
    res = r.invoke(library, ["show", "9999", "-l", str(lib_file)])
    assert isinstance(res.exception, InputError) and "no profile with id 9999" in str(res.exception)
    res = r.invoke(library, ["plot", "1", "-l", str(lib_file), "-o", str(tmp_path / "p.jpg")])
    assert isinstance(res.exception, InputError) and "PNG" in str(res.exception)
    res = r.invoke(library, ["list", "-l", str(tmp_path / "missing.h5")])
    assert isinstance(res.exception, InputError) and "no such library file" in str(res.exception)


@pytest.mark.parametrize("fmt", [f.value for f in Format])
def test_export_a_library_profile(lib_file: Path, tmp_path: Path, fmt: str) -> None:
    res = CliRunner().invoke(export, ["339", "--format", fmt, "-o", str(tmp_path), "-l", str(lib_file)])
    assert res.exit_code == 0, res.output
    first = Path(res.output.splitlines()[0].removeprefix("wrote "))
    assert first.is_file()
    if fmt != "pybamm":
        assert read_back(fmt, first).profile().charge_throughput == pytest.approx(1.0, abs=1e-4)


def test_export_a_protocol_file_and_a_csv(tmp_path: Path) -> None:
    plan = ocv_test().save(tmp_path / "ocv.toml")
    res = CliRunner().invoke(export, [str(plan), "-f", "arbin", "-o", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    back = read_back("arbin", tmp_path / "out" / "OCV_test_C_20_x1.sdu")
    assert difference(expected(Protocol.load(plan), "arbin"), back.items, time_tol=5e-4, current_tol=5e-7) is None
    csv = tmp_path / "in.csv"
    csv.write_text("Test Time / s,Current / A\n0,1\n10,-1\n20,-1\n")
    res = CliRunner().invoke(export, [str(csv), "-f", "maccor", "-o", str(tmp_path / "m")])
    assert res.exit_code == 0 and "note: Maccor" in res.output


def test_export_errors_are_one_line_input_errors(tmp_path: Path) -> None:
    r = CliRunner()
    for args, message in [
        (["1", "-f", "excel", "-o", str(tmp_path)], "unknown export format 'excel'"),
        (["nofile.toml", "-f", "csv", "-o", str(tmp_path)], "nofile.toml: no such file"),
        (["721", "-f", "neware", "-o", str(tmp_path)], "more than its 1000"),
    ]:
        res = r.invoke(export, args)
        assert isinstance(res.exception, InputError), args
        assert message in str(res.exception) and "\n" not in str(res.exception)
    res = r.invoke(export, ["721", "-f", "neware", "-o", str(tmp_path / "ok"), "--max-steps", "3000"])
    assert res.exit_code == 0
