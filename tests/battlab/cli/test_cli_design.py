"""`battlab sensitivity`, `battlab groups`, `battlab design` end to end on a few short library profiles."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from click.testing import CliRunner

from battlab import parameters
from battlab.cli import main
from protocols import Library, ProfileStep, Protocol

IDS = "28,37,136,541,553,583"  # 600 s profiles (pulses and sines from four start SOCs)


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("cli")
    Library.build().save(d / "library.h5")
    r = CliRunner().invoke(
        main,
        [
            "sensitivity",
            str(d / "library.h5"),
            "--cell",
            "nca18650",
            "-o",
            str(d / "sens.h5"),
            "--ids",
            IDS,
            "--workers",
            "1",
            "--no-conventional",
            "--no-progress",
        ],
    )
    assert r.exit_code == 0, r.output
    return d


def test_sensitivity_writes_store_and_summary(workdir: Path) -> None:
    s = json.loads((workdir / "sens.summary.json").read_text())
    assert s["total"] == 6 and s["computed"] == 6 and s["ok"] + s["flagged"] + s["failed"] == 6
    r = CliRunner().invoke(
        main,
        [
            "sensitivity",
            str(workdir / "library.h5"),
            "--cell",
            "nca18650",
            "-o",
            str(workdir / "sens.h5"),
            "--ids",
            IDS,
            "--workers",
            "1",
            "--no-conventional",
            "--no-progress",
        ],
    )
    assert r.exit_code == 0 and json.loads((workdir / "sens.summary.json").read_text())["reused"] == 6


def test_groups_table_json_and_figure(workdir: Path) -> None:
    out = workdir / "groups"
    r = CliRunner().invoke(main, ["groups", str(workdir / "sens.h5"), "-k", "3", "--no-perturb", "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert "paper" in r.output and "collinearity" in r.output
    data = json.loads((out / "sens.groups.json").read_text())
    assert len(data["groups"]) == 3
    assert sorted(n for g in data["groups"] for n in g) == sorted(parameters.NAMES)
    assert (out / "sens.ranking.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(data["ranking"]["order_mean"]) == 18


def test_tables_are_not_cut_when_the_output_is_not_a_terminal(workdir: Path) -> None:
    """CliRunner's output is not a terminal (as ``battlab groups ... | cat``): every column of the 8-column
    ranking table keeps its full header and values, no cell is cut to '…'."""
    r = CliRunner().invoke(main, ["groups", str(workdir / "sens.h5"), "-k", "3", "--no-perturb", "-o", str(workdir)])
    assert r.exit_code == 0, r.output
    assert "…" not in r.stdout, r.stdout
    lines = r.stdout.splitlines()
    header = next(line for line in lines if "rank" in line and "parameter" in line)
    for col in ("rank", "parameter", "symbol", "mean magnitude", "stacked QR", "group", "paper (Table 9)"):
        assert col in header, header
    assert "most collinear with" in " ".join(lines[lines.index(header) - 1 : lines.index(header) + 2]), lines
    data = json.loads((workdir / "sens.groups.json").read_text())
    for name in parameters.NAMES:  # each parameter's row whole: its name, symbol and its partner with the cosine
        row = next(line for line in lines if f" {name} " in line and parameters.SPECS[name].symbol in line)
        assert re.search(r"\b\w+ \([+-]\d\.\d{3}\)", row), row
    assert len(data["groups"]) == 3


def test_design_writes_a_loadable_plan_and_the_summary_contract(workdir: Path) -> None:
    plan = workdir / "out" / "plan.toml"
    r = CliRunner().invoke(main, ["design", str(workdir / "sens.h5"), "-o", str(plan), "-M", "2", "-k", "2"])
    assert r.exit_code == 0, r.output
    summary = json.loads((plan.with_name("plan.summary.json")).read_text())
    assert summary["criterion"] == "D" and summary["solve_seconds"] > 0
    assert len(summary["groups"]) == 2
    for g in summary["groups"]:
        assert {"parameters", "selected", "logdet"} <= set(g)
        assert len(g["selected"]) == 2 and all(str(i) in IDS.split(",") for i in g["selected"])
        assert g["first_order"]["agree"]
    assert len(summary["groups"][1]["parameters"]) == 18  # cumulative
    proto = Protocol.load(plan)
    ids = [s.profile.id for s in proto.steps if isinstance(s, ProfileStep)]
    assert ids == [i for g in summary["groups"] for i in g["selected"]]
    lib = Library.load(workdir / "library.h5")
    first = next(s.profile for s in proto.steps if isinstance(s, ProfileStep))
    assert (first.current == lib[first.id].current).all()
    for k in (1, 2):
        assert Protocol.load(plan.with_name(f"plan.group{k}.toml")).profile_duration_s == 1200.0
    assert plan.with_suffix(".weights.png").is_file()
    # the summary named after the plan, and the same as summary.json (the contract's name), no other copy
    assert json.loads((plan.parent / "summary.json").read_text()) == summary
    assert not (plan.parent / "plan.design.json").exists()


def test_design_puts_noise_trials_at_the_start_of_the_plan(workdir: Path) -> None:
    """`--noise-trials 3`: the whole plan starts with three trials of one charge-only and one discharge-only pulse
    profile of the library, labelled 'noise: ...' (the fit finds them there), then the design's profiles; the
    group plans and the groups are the design's alone; the summary lists the trials. A noise model file weights
    the design."""
    from battlab.noise import NoiseModel, direction, save

    plan = workdir / "noise" / "plan.toml"
    noise = save(NoiseModel(0.0, 2e-4, 2e-4, 0.0, 1e-5), workdir / "noise.toml")
    args = ["design", str(workdir / "sens.h5"), "-o", str(plan), "-M", "1", "-k", "2", "--noise-trials", "3"]
    r = CliRunner().invoke(main, [*args, "--noise-profiles", "1", "--noise", str(noise)])
    assert r.exit_code == 0, r.output
    s = json.loads(plan.with_name("plan.summary.json").read_text())
    assert s["noise_trials"]["trials"] == 3 and len(s["noise_trials"]["profiles"]) == 2
    steps = [st for st in Protocol.load(plan).steps if isinstance(st, ProfileStep)]
    noise_ids = s["noise_trials"]["profiles"]
    assert [st.label for st in steps[:6]] == [f"noise: profile {i} trial {k}" for i in noise_ids for k in (1, 2, 3)]
    assert sorted(direction(st.profile).value for st in steps[:6:3]) == ["charge", "discharge"]
    assert [str(st.profile.id) for st in steps[6:]] == [str(i) for g in s["groups"] for i in g["selected"]]
    assert all(st.label.startswith("group") for st in steps[6:])
    group1 = Protocol.load(plan.with_name("plan.group1.toml")).steps
    assert not any(st.label.startswith("noise") for st in group1 if isinstance(st, ProfileStep))
    assert "noise trials of profiles" in r.output
    r = CliRunner().invoke(main, [*args[:-1], "1"])
    assert r.exit_code == 2 and "--noise-trials must be 0 (none) or at least 2" in r.stderr


def test_design_rests_as_long_as_asked_before_every_profile(workdir: Path) -> None:
    from protocols.protocol import Rest

    plan = workdir / "rest" / "plan.toml"
    args = ["design", str(workdir / "sens.h5"), "-o", str(plan), "-M", "1", "-k", "2"]
    r = CliRunner().invoke(main, [*args, "--rest-before", "7200"])
    assert r.exit_code == 0, r.output
    for path in (plan, plan.with_name("plan.group1.toml")):
        steps = Protocol.load(path).steps
        before = [steps[k - 1] for k, st in enumerate(steps) if isinstance(st, ProfileStep)]
        assert before and all(isinstance(st, Rest) and st.ends[0].value == 7200.0 for st in before)
    r = CliRunner().invoke(main, [*args, "--rest-before", "600"])
    assert r.exit_code == 2 and "--rest-before must be at least 1800 s" in r.stderr


def test_design_with_a_criterion_and_a_budget(workdir: Path) -> None:
    plan = workdir / "a" / "plan.toml"
    r = CliRunner().invoke(
        main,
        [
            "design",
            str(workdir / "sens.h5"),
            "-o",
            str(plan),
            "-M",
            "2",
            "-k",
            "1",
            "--criterion",
            "A",
            "--budget",
            "1300",
        ],
    )
    assert r.exit_code == 0, r.output
    s = json.loads((plan.with_name("plan.summary.json")).read_text())
    assert s["criterion"] == "A" and s["budget"] == 1300
    assert s["groups"][0]["cost_total"] <= 1300


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["design", "missing.h5", "-o", "p.toml"], "no such sensitivity store"),
        (["design", "{lib}", "-o", "p.toml"], "not a battlab sensitivity store"),
        (["design", "{sens}", "-o", "{dir}/p.txt", "-k", "1", "-M", "2"], "the plan is a .toml file"),
        (["design", "{sens}", "-o", "{dir}/p.toml", "--groups", "{groups}"], "appears more than once"),
        (["design", "{sens}", "-o", "{dir}/p.toml", "-M", "7"], "only 6 usable profiles"),
        (["sensitivity", "{lib}", "--cell", "nosuchcell", "-o", "{dir}/x.h5"], "not a built-in cell"),
        (["sensitivity", "{lib}", "--cell", "nca18650", "-o", "{dir}/x.h5", "--ids", "9999"], "no profile(s) with id"),
        (["sensitivity", "{lib}", "--cell", "nca18650-true", "-o", "{sens}", "--ids", "28"], "refusing to add"),
    ],
)
def test_user_errors_are_one_line(workdir: Path, args: list[str], message: str) -> None:
    bad_groups = workdir / "dup.json"
    bad_groups.write_text(json.dumps({"groups": [["R_s_n", "k_n"], ["k_n"]]}))
    fill = {
        "lib": str(workdir / "library.h5"),
        "sens": str(workdir / "sens.h5"),
        "dir": str(workdir),
        "groups": str(bad_groups),
    }
    r = CliRunner().invoke(main, [a.format(**fill) for a in args])
    assert r.exit_code == 2, r.output
    err = r.stderr.strip()
    assert message in err and len(err.splitlines()) == 1


def test_plan_is_self_contained_when_the_library_file_is_gone(workdir: Path, tmp_path: Path) -> None:
    import h5py

    store = tmp_path / "moved.h5"
    store.write_bytes((workdir / "sens.h5").read_bytes())
    with h5py.File(store, "a") as f:
        f.attrs["library_path"] = str(tmp_path / "gone.h5")
    plan = tmp_path / "plan.toml"
    r = CliRunner().invoke(main, ["design", str(store), "-o", str(plan), "-M", "2", "-k", "1"])
    assert r.exit_code == 0, r.output
    assert "library_id" not in plan.read_text() and "library =" not in plan.read_text()
    proto = Protocol.load(plan)
    selected = json.loads((tmp_path / "plan.summary.json").read_text())["groups"][0]["selected"]
    assert [s.profile.id for s in proto.steps if isinstance(s, ProfileStep)] == selected


def test_design_leaves_out_profiles_that_leave_the_window_and_writes_a_plan_that_passes_it(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    """Library profile 304 (1 Ah net discharge from SOC 0.4, to SOC 0.03) passes the sweep's screen on nca18650
    (2.65 V at its end) but aborts a run on the virtual truth: the design leaves it out and checks the plan."""
    import battlab
    from battlab.io.plan import Plan
    from battlab.lab.window import check_window

    d = tmp_path_factory.mktemp("window")
    Library.build().save(d / "library.h5")
    args = ["sensitivity", str(d / "library.h5"), "--cell", "nca18650", "-o", str(d / "sens.h5")]
    r = CliRunner().invoke(main, [*args, "--ids", "28,136,304", "--workers", "1", "--no-conventional", "--no-progress"])
    assert r.exit_code == 0, r.output
    assert json.loads((d / "sens.summary.json").read_text())["ok"] == 3  # 304 passes the sweep's screen
    plan = d / "plan.toml"
    r = CliRunner().invoke(main, ["design", str(d / "sens.h5"), "-o", str(plan), "-M", "1", "-k", "2"])
    assert r.exit_code == 0, r.output
    assert "1 profiles leave the plan's SOC or voltage window" in r.output, r.output
    summary = json.loads(plan.with_name("plan.summary.json").read_text())
    assert summary["excluded"]["304"].startswith("window: from SOC 0.4 it passes SOC 0.030"), summary["excluded"]
    assert all(304 not in g["selected"] for g in summary["groups"])
    assert summary["window"]["ok"] and len(summary["window"]["profiles"]) == 2
    assert check_window(Plan.load(plan).protocol, battlab.Cell.load("nca18650")).ok
