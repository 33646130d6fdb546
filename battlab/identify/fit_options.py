"""What ``battlab fit`` is asked to do: one immutable :class:`FitOptions` value, whose fields carry their own
command-line help (``battlab fit``'s options are made from them, :mod:`battlab.cli.fit`)."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from battlab.cell import Cell
from battlab.identify.cumulative import FitSettings
from battlab.identify.data_files import Ambient
from protocols.errors import InputError

#: what SOC 1 of a fitted cell is: where its OCV reaches V_max, or the state at the start of the OCV test
FULL_CHARGE = ("v-max", "ocv-start")
#: the OCV test's branches that make the pseudo-OCV
OCV_BRANCHES = ("both", "discharge", "charge")
#: the start-SOC span of measurements with a logged preparation: their rest voltage after a 30 min rest is still
#: relaxing (on nca18650-true a few tenths of a percent of SOC from the end state)
PREPARED_SOC_SPAN = 0.01


def _opt(help: str, **cli: Any) -> Any:
    """A field's command-line metadata: its help text and how the option is spelled (``flag``, ``metavar``,
    ``choices``, ``is_flag``, ``multiple``, ``type``)."""
    return {"help": help, **cli}


@dataclass(frozen=True)
class FitOptions:
    """One fit (see :func:`battlab.identify.workflow.fit`). ``data``: paths of logged data; ``cell``: the start
    cell (a built-in name, a BPX file or a :class:`Cell`). The other fields are the fit's settings, each with the
    help text of its ``battlab fit`` option."""

    data: tuple[str | Path, ...]
    cell: Cell | str | Path
    plan: str | Path | None = field(
        default=None,
        metadata=_opt("Design plan (protocols TOML); its <plan>.summary.json gives the parameter groups.", type="path"),
    )
    params: str | None = field(
        default="table9",
        metadata=_opt(
            "Without a plan: 'table9' (paper's groups, cumulative), 'all', 'none' (no stage) or comma-separated names "
            "[default: the groups of a run log's plan, else table9].",
            flag=("--params", "--groups"),
            cli_default=None,
        ),
    )
    #: the design's groups (parameters, selected library ids), as a plan's summary gives them (the campaign)
    groups: tuple[tuple[tuple[str, ...], frozenset[str]], ...] | None = None
    ocp_terms: int = field(
        default=0,
        metadata=_opt("Terms of the positive-OCP correction in the equilibrium fit (0 = the paper's method)."),
    )
    rated_capacity: float | None = field(default=None, metadata=_opt("Set the cell's 1C capacity [Ah]."))
    full_charge: str = field(
        default="v-max",
        metadata=_opt(
            "SOC 1 of the fitted cell: where its OCV reaches V_max, or the state at the start of the OCV test (a test "
            "that starts from the lab's full charge: then soc0=1 is the cell as charged).",
            choices=FULL_CHARGE,
        ),
    )
    ocv_branch: str = field(
        default="both",
        metadata=_opt(
            "Pseudo-OCV from the mean of the OCV test's discharge and charge, or from one branch (shifted by its "
            "rest-step overpotential): with hysteresis, 'discharge' is the equilibrium that discharge tests see.",
            choices=OCV_BRANCHES,
        ),
    )
    soc0: float | None = field(default=None, metadata=_opt("Start SOC of data that do not start at rest."))
    ambient: Ambient = None
    dt: float = field(default=1.0, metadata=_opt("Resample dynamic data to this step [s]."))
    max_iter: int = field(default=40, metadata=_opt("Function evaluations per stage."))
    #: (data file, the log of its preparation): the measurement starts with the preparation as unscored lead-in
    #: (:func:`battlab.identify.runlog.after_preparation`); the CLI's ``--preparation DATA=PREP``
    preparations: tuple[tuple[str | Path, str | Path], ...] = ()
    soc_span: float | None = field(
        default=None,
        metadata=_opt(
            "Fit each experiment's start SOC within +- this of its rest-voltage SOC (a measurement started after a "
            "short rest, whose rest voltage is still relaxing) [default: 0.01 with --preparation, else 0].",
        ),
    )
    polish: int = field(
        default=8,
        metadata=_opt(
            "Of the evaluations per stage, those kept for Gauss-Newton steps after the optimiser stops at its limit."
        ),
    )
    widen: float = field(
        default=0.0,
        metadata=_opt(
            "Let the 18 parameters' search reach beyond their built-in ranges (the paper cell's) by this fraction of "
            "each range's width on either side (of a log-scaled range, of its decades): a cell of another make need "
            "not lie inside them; porosities stay below 1 - eps_s.",
        ),
    )
    fix_sign: bool = field(default=False, metadata=_opt("Flip a current logged with positive = discharge."))
    #: (target, names) fits of cell values outside the 18 after the stages (:mod:`battlab.identify.values`)
    value_stages: tuple[tuple[str, str], ...] = ()
    arrhenius: bool = field(
        default=False,
        metadata=_opt(
            "Fit the stages on the data within 5 K of T_ref, then refit their parameters with an activation energy "
            "(D_s, k, D_e_scale, kappa_scale) per other ambient and set the activation energies from them.",
        ),
    )
    output: str | Path | None = None
    hold_radii: bool = True
    #: leave out (and report) the parameters the data cannot inform instead of refusing the fit (the campaign's
    #: extend step: a cause's temperature coefficients at one ambient)
    drop_uninformed: bool = False
    #: a :class:`battlab.noise.NoiseModel` or a noise file; None: eq. 38 from the run logs' trials, else the paper's
    noise: Any = None
    per_file_ageing: tuple[str, ...] | str = field(
        default=(),
        metadata=_opt(
            "Give each data file its own ageing state, fitted with the shared parameters: 'n_Li' (cyclable lithium "
            "[mol], within +-15 % of the start cell's; every file starts at the OCV the start cell has at soc0) and/or "
            "'capacity' (active electrode area, 0.7-1.05 of the start cell's), e.g. n_Li,capacity; for tests of one "
            "cell on different dates. Each file's values and 95 % intervals go to the summary and the BPX metadata; "
            "the written cell holds their mean (one cell for every date).",
            metavar="NAMES",
            cli_default=None,
        ),
    )

    def __post_init__(self) -> None:
        object.__setattr__(self, "data", tuple(self.data))
        if self.full_charge not in FULL_CHARGE:
            raise InputError(f"full charge {self.full_charge!r}: expected one of {', '.join(FULL_CHARGE)}")
        if self.ocv_branch not in OCV_BRANCHES:
            raise InputError(f"OCV branch {self.ocv_branch!r}: expected one of {', '.join(OCV_BRANCHES)}")
        if self.max_iter < 1:
            raise InputError(f"max_iter {self.max_iter}: at least 1 evaluation per stage")
        if self.dt <= 0:
            raise InputError(f"dt {self.dt:g} s: the resampling step must be positive")
        object.__setattr__(self, "preparations", tuple((str(a), str(b)) for a, b in self.preparations))
        given = {Path(p).resolve() for p in self.data}
        for d, _ in self.preparations:
            if Path(d).resolve() not in given:
                raise InputError(f"--preparation {d}=…: {d} is not one of the data files")
        if self.soc_span is None:
            object.__setattr__(self, "soc_span", PREPARED_SOC_SPAN if self.preparations else 0.0)
        if not 0.0 <= self.soc_span <= 0.5:
            raise InputError(f"soc span {self.soc_span:g}: expected between 0 and 0.5")

    @property
    def settings(self) -> FitSettings:
        """The cumulative fit's settings (the same defaults as the campaign's)."""
        return FitSettings(
            max_evaluations=self.max_iter,
            polish=self.polish,
            hold_radii=self.hold_radii,
            soc_span=self.soc_span or 0.0,
            widen=self.widen,
        )

    def start_cell(self) -> Cell:
        return self.cell if isinstance(self.cell, Cell) else Cell.load(self.cell)


def cli_fields() -> list[Any]:
    """The fields with a command-line option (their metadata holds its help)."""
    return [f for f in fields(FitOptions) if f.metadata.get("help")]
