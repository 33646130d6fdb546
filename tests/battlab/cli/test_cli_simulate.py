"""``battlab simulate CELL PROFILE.csv [--soc0] [--isothermal] [--sens] -o OUT``: files against the API, and
one-line errors with exit code 2."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import h5py
import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner, Result

import battlab
from battlab import Cell, parameters
from battlab.cli import main
from protocols import Profile

ONE_C = 2.7
BASE_COLUMNS = [
    "Test Time / s",
    "Voltage / V",
    "Current / A",
    "Ambient Temperature / degC",
    "Surface Temperature T1 / degC",
]


@pytest.fixture(scope="module")
def profile() -> Profile:
    """Charge and discharge pulses (both signs in the file), 1 s samples, 120 s."""
    return Profile.from_segments(
        np.array([10.0, 30.0, 20.0, 30.0, 30.0]), np.array([0.0, 2.0 * ONE_C, 0.0, -1.5 * ONE_C, 0.0])
    )


@pytest.fixture
def profile_csv(profile: Profile, tmp_path: Path) -> Path:
    return profile.to_csv(tmp_path / "pulses.csv")


def invoke(*args: str) -> Result:
    result = CliRunner().invoke(main, list(args))
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result


def read_h5(path: Path) -> tuple[dict[str, np.ndarray], dict[str, object]]:
    """Columns (by their BDF names) and metadata of a result written as HDF5."""
    with h5py.File(path, "r") as f:
        cols = {ds.attrs["column"]: ds[()] for ds in f["data"].values()}
        meta = {k: json.loads(v) for k, v in f.attrs.items()}
    return cols, meta


def check_against_api(cols: dict[str, np.ndarray], res: battlab.Result, ambient_degC: float = 25.0) -> None:
    """File columns equal the API's result (to the 10 significant digits a CSV keeps); the current keeps its
    sign (positive = charge)."""
    close = {"rtol": 1e-9, "atol": 1e-12}
    np.testing.assert_allclose(cols["Test Time / s"], res.t, **close)
    np.testing.assert_allclose(cols["Voltage / V"], res.voltage, **close)
    np.testing.assert_allclose(cols["Current / A"], res.current, **close)
    assert np.any(cols["Current / A"] > 0) and np.any(cols["Current / A"] < 0)
    np.testing.assert_allclose(cols["Surface Temperature T1 / degC"], res.T_surface - 273.15, rtol=1e-9, atol=1e-8)
    np.testing.assert_allclose(cols["Ambient Temperature / degC"], ambient_degC, atol=1e-9)
    for j, name in enumerate(res.parameters):
        np.testing.assert_allclose(cols[f"dV/d{name} / V"], res.sensitivities[:, j], rtol=1e-9, atol=1e-13)
        np.testing.assert_allclose(cols[f"dT_surface/d{name} / K"], res.sensitivities_T[:, j], rtol=1e-9, atol=1e-13)


# --- outputs ------------------------------------------------------------------------------------------------------
def test_bdf_csv_matches_the_api(nca18650: Cell, profile: Profile, profile_csv: Path, tmp_path: Path) -> None:
    out = tmp_path / "out.bdf.csv"
    result = invoke("simulate", "nca18650", str(profile_csv), "--soc0", "0.5", "--sens", "R_s_n", "-o", str(out))
    assert result.exit_code == 0, result.output
    table = pd.read_csv(out)
    assert set(BASE_COLUMNS + ["dV/dR_s_n / V", "dT_surface/dR_s_n / K"]) <= set(table.columns)
    assert not any(c.startswith("dV/d") and c != "dV/dR_s_n / V" for c in table.columns)
    res = battlab.simulate(nca18650, profile, soc0=0.5, ambient=298.15, sensitivities=["R_s_n"])
    check_against_api({c: table[c].to_numpy() for c in table.columns}, res)
    meta = json.loads((tmp_path / "out.summary.json").read_text())
    assert not (tmp_path / "out.meta.json").exists()
    assert meta["cell"] == "nca18650" and meta["soc0"] == 0.5 and meta["ended_by"] is None
    assert meta["sensitivity_parameters"] == ["R_s_n"] and meta["cell_hash"] == nca18650.hash()
    assert "out.bdf.csv" in result.stderr  # the summary line


def test_extension_option_matches_the_api(nca18650: Cell, profile: Profile, profile_csv: Path, tmp_path: Path) -> None:
    out = tmp_path / "out.bdf.csv"
    ext = ["--extension", "contact_resistance:R_c=0.004", "--extension", "current_sensor:offset=0.01,gain=-0.002"]
    names = "contact_resistance.R_c,current_sensor.gain,R_s_n"
    result = invoke("simulate", "nca18650", str(profile_csv), "--soc0", "0.5", *ext, "--sens", names, "-o", str(out))
    assert result.exit_code == 0, result.output
    table = pd.read_csv(out)
    cell = nca18650.with_extension("contact_resistance", R_c=0.004).with_extension(
        "current_sensor", offset=0.01, gain=-0.002
    )
    res = battlab.simulate(cell, profile, soc0=0.5, ambient=298.15, sensitivities=names.split(","))
    check_against_api({c: table[c].to_numpy() for c in table.columns}, res)
    meta = json.loads((tmp_path / "out.summary.json").read_text())
    assert meta["extensions"]["contact_resistance"] == {"R_c": 0.004, "dRc_dT": 0.0}
    assert meta["cell_hash"] == cell.hash()


def test_hdf5_matches_the_api(nca18650: Cell, profile: Profile, profile_csv: Path, tmp_path: Path) -> None:
    out = tmp_path / "out.h5"
    result = invoke(
        "simulate", "nca18650", str(profile_csv), "--soc0", "0.5", "--sens", "R_s_n,k_p", "--isothermal", "-o", str(out)
    )
    assert result.exit_code == 0, result.output
    cols, meta = read_h5(out)
    assert set(BASE_COLUMNS) <= set(cols)
    res = battlab.simulate(nca18650, profile, soc0=0.5, isothermal=True, sensitivities=["R_s_n", "k_p"])
    check_against_api(cols, res)
    np.testing.assert_allclose(cols["Surface Temperature T1 / degC"], 25.0, atol=1e-9)
    assert meta["isothermal"] is True and meta["sensitivity_parameters"] == ["R_s_n", "k_p"]


def test_all_sensitivities_and_ambient(nca18650: Cell, profile: Profile, profile_csv: Path, tmp_path: Path) -> None:
    out = tmp_path / "all.h5"
    result = invoke(
        "simulate", "nca18650", str(profile_csv), "--soc0", "0.4", "--sens", "all", "--ambient", "10", "-o", str(out)
    )
    assert result.exit_code == 0, result.output
    cols, _ = read_h5(out)
    assert [c for c in cols if c.startswith("dV/d")] and all(f"dV/d{n} / V" in cols for n in parameters.NAMES)
    res = battlab.simulate(nca18650, profile, soc0=0.4, ambient=283.15, sensitivities=list(parameters.NAMES))
    check_against_api(cols, res, ambient_degC=10.0)


def test_early_end_is_reported_and_written(nca18650: Cell, tmp_path: Path) -> None:
    prof = Profile.constant(-2.0 * ONE_C, 900.0, 1.0).to_csv(tmp_path / "dis.csv")
    out = tmp_path / "dis.bdf.csv"
    result = invoke("simulate", "nca18650", str(prof), "--soc0", "0.3", "-o", str(out))
    assert result.exit_code == 0, result.output
    assert "V < 2.5" in result.stderr
    table = pd.read_csv(out)
    assert 10 < len(table) < 901 and table["Voltage / V"].min() >= 2.5
    assert json.loads((tmp_path / "dis.summary.json").read_text())["ended_by"] == "V < 2.5"


def test_the_installed_command_runs(nca18650: Cell, profile: Profile, profile_csv: Path, tmp_path: Path) -> None:
    """One real run of the ``battlab`` console script in a subprocess."""
    exe = shutil.which("battlab")
    assert exe is not None, "the battlab command is not installed (pip install -e .)"
    out = tmp_path / "sub.bdf.csv"
    proc = subprocess.run(
        [exe, "simulate", "nca18650", str(profile_csv), "--soc0", "0.5", "--sens", "R_s_n", "-o", str(out)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    table = pd.read_csv(out)
    res = battlab.simulate(nca18650, profile, soc0=0.5, sensitivities=["R_s_n"])
    check_against_api({c: table[c].to_numpy() for c in table.columns}, res)


# --- bad input ----------------------------------------------------------------------------------------------------
def bad_bpx(path: Path, nmc: Path) -> Path:
    data = json.loads(nmc.read_text())
    data["Parameterisation"]["Positive electrode"]["Porosity"] = "lots"
    path.write_text(json.dumps(data))
    return path


BAD = {
    # label: (arguments with {csv} / {nan} / {nocol} / {bpx} placeholders, fragment expected on stderr)
    "unknown cell": (["nca99999", "{csv}"], "nca99999"),
    "missing profile": (["nca18650", "{missing}"], "no such profile file"),
    "NaN in profile": (["nca18650", "{nan}"], "NaN"),
    "missing column": (["nca18650", "{nocol}"], "Current / A"),
    "soc0 above 1": (["nca18650", "{csv}", "--soc0", "1.5"], "soc0"),
    "unknown sensitivity": (["nca18650", "{csv}", "--sens", "R_s_n,R_s_x"], "R_s_x"),
    "output suffix": (["nca18650", "{csv}", "-o", "{out_txt}"], ".bdf.csv"),
    "ambient out of range": (["nca18650", "{csv}", "--ambient", "200"], "ambient"),
    "invalid BPX": (["{bpx}", "{csv}"], "Porosity"),
    "unknown extension": (["nca18650", "{csv}", "--extension", "warp_drive"], "unknown model extension 'warp_drive'"),
    "extension value": (["nca18650", "{csv}", "--extension", "contact_resistance:R_c=big"], "--extension"),
    "extension name": (["nca18650", "{csv}", "--extension", "contact_resistance:R=1"], "has no parameter 'R'"),
    "thermal extension when isothermal": (
        ["nca18650", "{csv}", "--extension", "thermal:dE_k_n=1000", "--isothermal"],
        "'thermal' acts through the temperature",
    ),
    "sensitivity of an extension that is off": (
        ["nca18650", "{csv}", "--sens", "contact_resistance.R_c"],
        "extension 'contact_resistance' is not on",
    ),
}


@pytest.fixture
def bad_files(profile_csv: Path, tmp_path: Path, nmc_bpx: Path) -> dict[str, str]:
    nan = tmp_path / "nan.csv"
    nan.write_text("Test Time / s,Current / A\n0,1\n1,nan\n2,0\n")
    nocol = tmp_path / "nocol.csv"
    nocol.write_text("Test Time / s,Amps\n0,1\n1,1\n")
    return {
        "csv": str(profile_csv),
        "missing": str(tmp_path / "nope.csv"),
        "nan": str(nan),
        "nocol": str(nocol),
        "bpx": str(bad_bpx(tmp_path / "bad_cell.json", nmc_bpx)),
        "out_txt": str(tmp_path / "out.txt"),
    }


def assert_one_line_error(code: int, stdout: str, stderr: str, fragment: str) -> None:
    assert code == 2, (code, stdout, stderr)
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, f"expected one line on stderr, got {stderr!r}"
    assert "Traceback" not in stderr + stdout
    assert fragment in lines[0], lines[0]


@pytest.mark.parametrize("label", list(BAD))
def test_bad_input_is_one_line_and_exit_2(label: str, bad_files: dict[str, str], tmp_path: Path) -> None:
    args, fragment = BAD[label]
    args = [a.format(**bad_files) for a in args]
    if "-o" not in args:
        args += ["-o", str(tmp_path / "out.bdf.csv")]
    result = CliRunner().invoke(main, ["simulate", *args])
    assert not isinstance(result.exception, Exception) or isinstance(result.exception, SystemExit), result.exception
    assert_one_line_error(result.exit_code, result.stdout, result.stderr, fragment)
    assert not (tmp_path / "out.bdf.csv").exists()


@pytest.mark.parametrize(
    "args", [["nca18650", "{csv}", "--soc0", "half"], ["nca18650"]], ids=["soc0 text", "no profile"]
)
def test_usage_errors_are_one_line(args: list[str], bad_files: dict[str, str], tmp_path: Path) -> None:
    args = [a.format(**bad_files) for a in args] + ["-o", str(tmp_path / "out.bdf.csv")]
    result = CliRunner().invoke(main, ["simulate", *args])
    assert_one_line_error(result.exit_code, result.stdout, result.stderr, "simulate: ")


def test_bad_input_through_the_installed_command(bad_files: dict[str, str], tmp_path: Path) -> None:
    exe = shutil.which("battlab")
    assert exe is not None
    proc = subprocess.run(
        [exe, "simulate", "nca18650", bad_files["nan"], "-o", str(tmp_path / "x.h5")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert_one_line_error(proc.returncode, proc.stdout, proc.stderr, "nan.csv")


# --- what a new user meets ----------------------------------------------------------------------------------------


def test_a_rest_from_full_charge_is_not_beyond_the_upper_limit(tmp_path: Path) -> None:
    """The OCV at 100 % SOC equals V_max to round-off: a rest from there runs to its end."""
    Profile(np.arange(0.0, 61.0), np.zeros(61)).to_csv(tmp_path / "rest.csv")
    r = invoke("simulate", "nca18650", str(tmp_path / "rest.csv"), "--soc0", "1", "-o", str(tmp_path / "r.csv"))
    assert r.exit_code == 0, r.output
    assert pd.read_csv(tmp_path / "r.csv").shape[0] == 61 and "61 of 61 samples" in r.output


def test_its_own_output_as_the_profile_without_soc0(profile_csv: Path, tmp_path: Path) -> None:
    """A result CSV (more columns than a profile) fed back without --soc0 starts from the default SOC (1): its
    2C charge at the first change of current is beyond V_max at once, said in one line, nothing written."""
    first = tmp_path / "first.bdf.csv"
    assert invoke("simulate", "nca18650", str(profile_csv), "--soc0", "0.5", "-o", str(first)).exit_code == 0
    before = sorted(p.name for p in tmp_path.iterdir())
    r = invoke("simulate", "nca18650", str(first), "-o", str(tmp_path / "again.csv"))
    assert r.exit_code == 2 and "Traceback" not in r.output and len(r.output.strip().splitlines()) == 1
    assert "the run ends at its first sample (V > 4.2)" in r.output and "check --soc0 (1)" in r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    r = invoke("simulate", "nca18650", str(first), "--soc0", "0.5", "-o", str(tmp_path / "again.csv"))
    assert r.exit_code == 0 and (tmp_path / "again.csv").is_file()


def test_a_current_in_the_wrong_units_is_one_line_and_no_file(tmp_path: Path) -> None:
    Profile.from_segments(np.array([10.0, 30.0]), np.array([0.0, -1000.0])).to_csv(tmp_path / "mA.csv")
    r = invoke("simulate", "nca18650", str(tmp_path / "mA.csv"), "--soc0", "0.5", "-o", str(tmp_path / "o.csv"))
    assert r.exit_code == 2 and len(r.output.strip().splitlines()) == 1
    assert "mA.csv: the current reaches 1000 A = 370C" in r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mA.csv"]


def test_an_output_in_a_missing_directory_is_one_line(profile_csv: Path, tmp_path: Path) -> None:
    r = invoke("simulate", "nca18650", str(profile_csv), "-o", str(tmp_path / "nodir" / "o.csv"))
    assert r.exit_code == 2 and "does not exist" in r.output and len(r.output.strip().splitlines()) == 1


def test_a_failed_simulation_exits_non_zero(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A solver failure is not a result: exit 1, saying where; the samples before it are kept, and said so."""
    import battlab.simulation as simulation

    real = simulation.solver.run_native

    def failing(*args, **kwargs):  # the real run, reported as failing after its 40th sample
        traj = real(*args, **kwargs)
        cut = {f: getattr(traj, f)[:40] for f in ("voltage", "T1", "T2", "sto_min", "sto_max")}
        return type(traj)(**{**traj.__dict__, **cut, "n_samples": 40, "ended_by": "solver: test failure"})

    monkeypatch.setattr(simulation.solver, "run_native", failing)
    Profile(np.arange(0.0, 61.0), np.full(61, -1.0)).to_csv(tmp_path / "p.csv")
    r = invoke("simulate", "nca18650", str(tmp_path / "p.csv"), "--soc0", "0.5", "-o", str(tmp_path / "o.csv"))
    assert r.exit_code == 1 and "the simulation failed at t = 39.0 s (solver: test failure)" in r.output
    assert "the 40 of 61 samples before it are in" in r.output and pd.read_csv(tmp_path / "o.csv").shape[0] == 40


def test_v_limits_follow_logged_excursions_and_T0_sets_the_start(tmp_path: Path) -> None:
    """Regen at full charge goes above 4.2 V: with --v-limits the prediction follows it; --T0 starts warm."""
    t = np.arange(0.0, 301.0)
    Profile(t, np.where((t // 20) % 2 == 0, -2.0 * ONE_C, 2.0 * ONE_C)).to_csv(tmp_path / "regen.csv")
    base = ["simulate", "nca18650", str(tmp_path / "regen.csv"), "--soc0", "0.99"]
    stopped = invoke(*base, "-o", str(tmp_path / "a.csv"))
    assert stopped.exit_code == 0 and "ended early: V > 4.2" in stopped.output
    r = invoke(*base, "--v-limits", "2.5,4.5", "--T0", "35", "-o", str(tmp_path / "b.csv"))
    assert r.exit_code == 0 and "301 of 301 samples" in r.output, r.output
    df = pd.read_csv(tmp_path / "b.csv")
    assert df["Voltage / V"].max() > 4.2
    assert df["Surface Temperature T1 / degC"].iloc[0] == pytest.approx(35.0)
    assert df["Surface Temperature T1 / degC"].iloc[-1] < 33.0  # cooling towards the 25 degC ambient
    bad = invoke(*base, "--v-limits", "4.5", "-o", str(tmp_path / "c.csv"))
    assert bad.exit_code == 2 and "expected MIN,MAX" in bad.output


def test_ocp_option_matches_the_api(nca18650: Cell, profile: Profile, profile_csv: Path, tmp_path: Path) -> None:
    """``--ocp p=FILE`` puts a half-cell curve into the cell as ``Cell.with_ocp`` does; a bad spec is one line."""
    from battlab.io.ocp import with_half_cell_ocp

    x = np.linspace(0.2, 0.99, 60)
    curve = tmp_path / "p.csv"
    curve.write_text("sto,ocp\n" + "\n".join(f"{a},{b + 0.01}" for a, b in zip(x, nca18650.fn("U_p", x), strict=True)))
    out = tmp_path / "out.bdf.csv"
    result = invoke("simulate", "nca18650", str(profile_csv), "--soc0", "0.5", "--ocp", f"p={curve}", "-o", str(out))
    assert result.exit_code == 0, result.output
    res = battlab.simulate(with_half_cell_ocp(nca18650, "p", curve), profile, soc0=0.5, ambient=298.15)
    base = battlab.simulate(nca18650, profile, soc0=0.5, ambient=298.15)
    table = pd.read_csv(out)
    np.testing.assert_allclose(table["Voltage / V"], res.voltage, rtol=1e-9, atol=1e-12)
    assert np.mean(table["Voltage / V"] - base.voltage) > 0.005  # the 10 mV higher curve is in
    bad = invoke("simulate", "nca18650", str(profile_csv), "--ocp", f"q={curve}", "-o", str(tmp_path / "x.csv"))
    assert bad.exit_code != 0 and "--ocp" in bad.output and len(bad.output.strip().splitlines()) == 1
