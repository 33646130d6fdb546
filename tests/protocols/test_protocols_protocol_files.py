"""Protocol model: TOML/JSON round trips, typo reporting, limits."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import tomli_w
from hypothesis import given, settings
from hypothesis import strategies as st

from protocols import (
    CCCV,
    ConstantCurrent,
    ConstantVoltage,
    Direction,
    EndCondition,
    InputError,
    Library,
    Profile,
    ProfileStep,
    Protocol,
    Rest,
    SafetyLimits,
)
from protocols.export.program import canonical, difference


def _protocol(lib: Library) -> Protocol:
    return Protocol(
        "round trip",
        (
            CCCV(1.35, 4.2, ("current <= 0.054", "time >= 14400"), "full"),
            Rest(("time >= 600",)),
            ProfileStep(lib[339], "profile 339"),
            ConstantCurrent(-0.54, ("voltage <= 2.5", "capacity >= 0.27")),
            ConstantVoltage(3.7, ("current <= 0.05",), Direction.DISCHARGE),
        ),
        SafetyLimits(2.4, 4.3, 10.0, 318.15),
        capacity_ah=2.7,
        description="all step kinds",
    )


def _same(a: Protocol, b: Protocol) -> None:
    assert (a.name, a.limits, a.capacity_ah, a.description) == (
        b.name,
        b.limits,
        b.capacity_ah,
        b.description,
    )
    assert difference(canonical(a), canonical(b), time_tol=0, current_tol=0, value_tol=0) is None
    assert [s.label for s in a.steps] == [s.label for s in b.steps]
    for s, t in zip(a.steps, b.steps, strict=True):
        if isinstance(s, ProfileStep):
            assert isinstance(t, ProfileStep)
            assert (t.profile.id, t.profile.kind, t.profile.soc0) == (
                s.profile.id,
                s.profile.kind,
                s.profile.soc0,
            )


@pytest.mark.parametrize("suffix", [".toml", ".json"])
@pytest.mark.parametrize("inline", [True, False])
def test_round_trip(lib: Library, tmp_path: Path, suffix: str, inline: bool) -> None:
    p = _protocol(lib)
    path = p.save(tmp_path / f"p{suffix}", inline_profiles=inline)
    back = Protocol.load(path)
    _same(p, back)
    if not inline:
        assert (tmp_path / "p.profiles" / "step003.csv").is_file()
        assert "339" in path.read_text()


def test_library_id_steps_resolve_from_the_library(lib: Library, tmp_path: Path) -> None:
    lib_path = Library(list(lib)[330:345], counts=lib.counts).save(tmp_path / "lib.h5")
    text = 'name = "lib ref"\nlibrary = "lib.h5"\n[[steps]]\nkind = "profile"\nlibrary_id = 339\n'
    (tmp_path / "p.toml").write_text(text)
    p = Protocol.load(tmp_path / "p.toml")
    np.testing.assert_array_equal(p.steps[0].profile.current, lib[339].current)  # type: ignore[union-attr]
    q = Protocol.from_dict(tomli_w_loads(text.replace('library = "lib.h5"\n', "")), library=lib)
    assert q.steps[0].profile.id == 339  # type: ignore[union-attr]
    assert lib_path.is_file()


def tomli_w_loads(text: str) -> dict:
    import tomllib

    return tomllib.loads(text)


def test_c_rate_is_converted_with_the_capacity() -> None:
    data = {"capacity_ah": 3.0, "steps": [{"kind": "cc", "c_rate": -0.5, "until": ["time >= 60"]}]}
    p = Protocol.from_dict(data)
    assert p.steps[0].current == pytest.approx(-1.5)  # type: ignore[union-attr]


@pytest.mark.parametrize(
    "step,message",
    [
        (
            {"kind": "cc", "curent": 1.0, "until": ["time >= 1"]},
            "step 2 (cc): unknown field 'curent' (did you mean 'current'?)",
        ),
        (
            {"kind": "cv", "voltage": "high", "until": ["time >= 1"]},
            "step 2 (cv): field 'voltage' must be a number",
        ),
        (
            {"kind": "ccv", "current": 1.0},
            "step 2: field 'kind': unknown step kind 'ccv' (did you mean 'cccv'?)",
        ),
        ({"current": 1.0}, "step 2: missing field 'kind'"),
        (
            {"kind": "cc", "current": 1.0, "until": ["volts <= 2"]},
            "unknown quantity 'volts' (did you mean 'voltage'?)",
        ),
        (
            {"kind": "cc", "current": 1.0, "until": ["time <= 2"]},
            "step 2 (cc): end condition on time must use '>='",
        ),
        ({"kind": "cc", "current": 1.0}, "step 2 (cc): a cc step needs an end condition"),
        ({"kind": "rest", "until": ["current <= 1"]}, "step 2 (rest): a rest step cannot end on current"),
        (
            {"kind": "cccv", "current": 1.0, "until": ["time >= 1"]},
            "step 2 (cccv): missing field 'voltage' [V]",
        ),
        (
            {"kind": "cv", "voltage": 4.0, "direction": "up", "until": ["time >= 1"]},
            "direction must be 'charge'",
        ),
        ({"kind": "profile", "library_id": 1, "file": "x.csv"}, "give exactly one of 'file', 'library_id'"),
        ({"kind": "cc", "current": 1.0, "c_rate": 1.0, "until": ["time >= 1"]}, "give 'current' or 'c_rate'"),
    ],
)
def test_typos_name_the_file_step_and_field(tmp_path: Path, step: dict, message: str) -> None:
    data = {"name": "x", "steps": [{"kind": "rest", "until": ["time >= 60"]}, step]}
    path = tmp_path / "bad.toml"
    path.write_text(tomli_w.dumps(data))
    with pytest.raises(InputError) as err:
        Protocol.load(path)
    text = str(err.value)
    assert text.startswith(str(path))
    assert message in text
    assert "\n" not in text


@pytest.mark.parametrize(
    "data,message",
    [
        ({"name": "x", "setps": []}, "unknown field 'setps' (did you mean 'steps'?)"),
        ({"name": "x", "steps": []}, "non-empty list 'steps'"),
        (
            {"name": "x", "limits": {"voltage_mx": 4.2}, "steps": [{"kind": "rest", "until": "time >= 1"}]},
            "voltage_mx",
        ),
        (
            {"name": "x", "limits": {"voltage_min": 4.3}, "steps": [{"kind": "rest", "until": "time >= 1"}]},
            "below",
        ),
    ],
)
def test_top_level_errors(data: dict, message: str) -> None:
    with pytest.raises(InputError, match="protocol.json") as err:
        Protocol.from_dict(data, source="protocol.json")
    assert message in str(err.value)


def test_invalid_files(tmp_path: Path) -> None:
    (tmp_path / "a.toml").write_text("steps = [")
    with pytest.raises(InputError, match="not valid TOML"):
        Protocol.load(tmp_path / "a.toml")
    (tmp_path / "a.json").write_text("{")
    with pytest.raises(InputError, match="not valid JSON"):
        Protocol.load(tmp_path / "a.json")
    with pytest.raises(InputError, match="no such protocol file"):
        Protocol.load(tmp_path / "missing.toml")
    with pytest.raises(InputError, match=".toml or .json"):
        Protocol.load((tmp_path / "a.yaml").resolve()) if (tmp_path / "a.yaml").write_text("x") else None


def test_check_refuses_steps_beyond_the_limits(lib: Library) -> None:
    limits = SafetyLimits(current_max=5.0)
    with pytest.raises(InputError, match=r"step 1 \(cc\): current -6 A exceeds the limit 5 A"):
        Protocol("x", (ConstantCurrent(-6.0, ("time >= 1",)),), limits).check()
    with pytest.raises(InputError, match=r"step 1 \(profile\): profile 1 reaches 12 A"):
        Protocol("x", (ProfileStep(lib[1]),), limits).check()
    with pytest.raises(InputError, match="voltage 4.5 V is outside the limits"):
        Protocol("x", (CCCV(1.0, 4.5, ("time >= 1",)),)).check()


@settings(max_examples=60, deadline=None)
@given(
    quantity=st.sampled_from(["time", "voltage", "current", "capacity"]),
    op=st.sampled_from([">=", "<="]),
    value=st.floats(1e-6, 1e6, allow_nan=False),
)
def test_end_condition_text_round_trip(quantity: str, op: str, value: float) -> None:
    text = f"{quantity} {op} {value!r}"
    if quantity in ("time", "capacity") and op == "<=":
        with pytest.raises(InputError):
            EndCondition.parse(text)
        return
    e = EndCondition.parse(text)
    assert EndCondition.parse(str(e)) == e
    assert e.value == pytest.approx(value, rel=1e-11)


_step = st.one_of(
    st.builds(lambda d: Rest((f"time >= {d}",)), st.integers(1, 10_000)),
    st.builds(
        lambda i, v: ConstantCurrent(i, (f"voltage {'>=' if i > 0 else '<='} {v}", "time >= 3600")),
        st.floats(-13.5, 13.5).filter(lambda x: abs(x) > 1e-3),
        st.floats(2.5, 4.2),
    ),
    st.builds(
        lambda i, v, c: CCCV(i, v, (f"current <= {c}",)),
        st.floats(0.01, 13.5),
        st.floats(2.5, 4.2),
        st.floats(0.01, 1),
    ),
    st.builds(
        lambda v, q: ConstantVoltage(v, (f"capacity >= {q}",), Direction.DISCHARGE),
        st.floats(2.5, 4.2),
        st.floats(0.01, 3),
    ),
    st.builds(
        lambda c: ProfileStep(Profile.from_segments(np.ones(len(c)), np.array(c), id="h")),
        st.lists(st.floats(-13.5, 13.5), min_size=1, max_size=20),
    ),
)


@settings(max_examples=40, deadline=None)
@given(steps=st.lists(_step, min_size=1, max_size=6), suffix=st.sampled_from([".toml", ".json"]))
def test_any_protocol_round_trips(tmp_path_factory: pytest.TempPathFactory, steps: list, suffix: str) -> None:
    p = Protocol("generated", tuple(steps))
    path = p.save(tmp_path_factory.mktemp("rt") / f"p{suffix}")
    back = Protocol.load(path)
    _same(p, back)
    assert json.dumps(p.to_dict()) == json.dumps(back.to_dict())
