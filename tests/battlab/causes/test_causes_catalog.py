"""The catalog of causes is the one declaration every consumer derives its table from: each of the 18 identified
parameters belongs to exactly one cause, each cause declares what the consumers need, every consumer covers every
cause, and two extensions that change one model slot cannot both be on."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

from battlab import Cell, causes, parameters
from battlab.causes.cause import Cause, Evidence
from battlab.causes.hysteresis import Hysteresis
from protocols.errors import InputError
from protocols.library import KINDS

BENCH = Path(__file__).resolve().parents[3] / "benchmarks"


def test_every_identified_parameter_belongs_to_exactly_one_cause() -> None:
    for name in parameters.NAMES:
        owners = [c.key for c in causes.CAUSES if name in c.base]
        assert len(owners) == 1, f"{name}: owned by {owners}"
        assert causes.owner(name).key == owners[0]
    for q in parameters.EXTENSION_SPECS:
        assert causes.owner(q).key == q.partition(".")[0]


@pytest.mark.parametrize("cause", causes.CAUSES, ids=lambda c: c.key)
def test_each_cause_declares_what_its_consumers_need(cause: Cause) -> None:
    assert cause.title and cause.mechanism and cause.validated_by
    assert cause.informed_by.kind in KINDS and cause.informed_by.experiment
    if cause.extension is None:
        assert cause.base, f"{cause.key}: a cause without an extension must own base parameters"
        return
    assert cause.extension.key == cause.key and cause.slots
    for p in cause.parameters:
        assert p.citation and p.unit and p.lower < p.upper, p.name
        assert not (p.shapes and p.typical is not None), f"{p.qualified}: a shape has no typical size"
        assert p.lower <= p.off <= p.upper, p.name
    assert cause.typical, f"{cause.key}: no typical size: the diagnosis cannot say when it is too small to see"
    assert cause.example, f"{cause.key}: example values switch it on for the tests and benchmarks"
    assert any(v != p.off for p in cause.parameters if (v := cause.example.get(p.name)) is not None)


def _load_benchmark(name: str):  # noqa: ANN202
    sys.path.insert(0, str(BENCH))
    try:
        spec = importlib.util.spec_from_file_location(f"_bench_{name}", BENCH / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module
    finally:
        sys.path.remove(str(BENCH))


def test_every_consumer_covers_the_whole_catalog() -> None:
    """Fails loudly (naming the consumer and the cause) when a table that should list every cause misses one."""
    from battlab.cli.options import extension_option
    from battlab.diagnose.directions import DEFAULT_CAUSES, TYPICAL
    from battlab.identify.informing import INFORMED_BY
    from battlab.model.extensions import CATALOG

    extended = [c.key for c in causes.extended()]
    consumers = {
        "battlab.parameters.EXTENSIONS": set(parameters.EXTENSIONS),
        "battlab.model.extensions.CATALOG": set(CATALOG),
        "battlab.diagnose.directions.TYPICAL": set(TYPICAL),
        "battlab.diagnose.directions.DEFAULT_CAUSES": set(DEFAULT_CAUSES)
        | {c.key for c in causes.extended() if not c.differentiable_at_off},
        "benchmarks/bench_diagnose.py SIZES": set(_load_benchmark("bench_diagnose").SIZES),
    }
    for consumer, keys in consumers.items():
        missing = [k for k in extended if k not in keys]
        assert not missing, f"{consumer} misses the cause(s) {missing}"
    missing = [k for k in causes.KEYS if k not in INFORMED_BY]
    assert not missing, f"battlab.identify.informing.INFORMED_BY misses {missing}"
    help_text = next(p for p in extension_option()(lambda **_: None).__click_params__).help
    missing = [k for k in extended if k not in help_text]
    assert not missing, f"the --extension help misses {missing}"


def test_equilibrium_replaces_the_curves_before_any_other_cause_changes_them() -> None:
    """Equilibrium's open-circuit hook replaces the cell's curve; every other cause that changes an OCP adds to it,
    so equilibrium must come first in the catalog among them."""
    from battlab.causes.extension import Extension

    touching = [c.key for c in causes.extended() if c.extension.open_circuit is not Extension.open_circuit]
    assert touching[0] == "equilibrium", touching


def test_two_extensions_owning_one_slot_cannot_both_be_on(monkeypatch: pytest.MonkeyPatch) -> None:
    """A second hysteresis model (a two-state one, say) owns the slots of the first: switching both on is refused
    in one line naming both and the slot, unless the declaration says they compose."""

    class TwoState(Hysteresis):
        key = "two_state_hysteresis"

    rival = Cause(
        key="two_state_hysteresis",
        title="two-state hysteresis",
        mechanism="test double",
        informed_by=Evidence("pulse", "rests after both directions"),
        extension=TwoState,
        parameters=tuple(
            parameters.ExtensionParameter(**{**p.__dict__, "extension": "two_state_hysteresis"})
            for p in causes.cause("hysteresis").parameters
        ),
        slots=frozenset({"ocp_hysteresis_n"}),
    )
    monkeypatch.setitem(causes.BY_KEY, rival.key, rival)
    assert causes.slot_conflicts(["hysteresis", "two_state_hysteresis"]) == [
        ("hysteresis", "two_state_hysteresis", "ocp_hysteresis_n")
    ]
    assert causes.slot_conflicts(["equilibrium", "hysteresis"]) == []  # a shift and a hysteresis add up
    composing = Cause(**{**rival.__dict__, "composes_with": frozenset({"hysteresis"})})
    monkeypatch.setitem(causes.BY_KEY, rival.key, composing)
    assert causes.slot_conflicts(["hysteresis", "two_state_hysteresis"]) == []


def test_a_cell_with_clashing_extensions_is_one_error(monkeypatch: pytest.MonkeyPatch) -> None:
    class Shift(Hysteresis):
        key = "other_shift"

    rival = Cause(
        key="other_shift",
        title="another OCP shift",
        mechanism="test double",
        informed_by=Evidence("pulse", "an OCV test"),
        extension=Shift,
        parameters=(
            parameters.ExtensionParameter(
                **{**causes.cause("equilibrium").parameters[0].__dict__, "extension": "other_shift"}
            ),
        ),
        slots=frozenset({"ocp_curve_n"}),
    )
    monkeypatch.setitem(causes.BY_KEY, rival.key, rival)
    monkeypatch.setitem(parameters.EXTENSIONS, rival.key, rival.parameters)
    cell = Cell.load("nca18650").with_extension("equilibrium")
    with pytest.raises(InputError, match=r"'equilibrium' and 'other_shift' both change the model's ocp_curve_n"):
        cell.with_extension("other_shift")


def test_an_unknown_cause_is_one_error_with_a_suggestion() -> None:
    with pytest.raises(InputError, match=r"unknown cause 'hysteresys' \(did you mean 'hysteresis'\?\)"):
        causes.cause("hysteresys")
    with pytest.raises(InputError, match=r"did you mean 'contact_resistance'"):
        Cell.load("nca18650").with_extension("contact_resistence")


def test_a_cause_refits_with_the_equilibrium_only_parameters_of_its_own() -> None:
    """``slow_cycle`` names parameters the campaign's equilibrium refit fits beside the moles: they must be the
    cause's; the current sensor's offset is one (it moves the charge count)."""
    assert causes.cause("current_sensor").slow_cycle == ("offset",)
    sensor = causes.cause("current_sensor")
    with pytest.raises(ValueError, match=r"slow_cycle names \['R_c'\], not its"):
        Cause(
            key=sensor.key,
            title="x",
            mechanism="x",
            informed_by=Evidence("pulse", "x"),
            extension=sensor.extension,
            parameters=sensor.parameters,
            slots=sensor.slots,
            slow_cycle=("R_c",),
        )
