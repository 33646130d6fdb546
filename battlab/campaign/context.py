"""What every campaign stage shares: the :class:`Campaign` (settings, where plans run, the virtual bench, the
campaign directory, the runs so far) and the small file helpers the stages write their artefacts with."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from battlab.campaign import data as D
from battlab.campaign import plans as P
from battlab.campaign.config import CampaignConfig
from battlab.campaign.stages import StageContext
from battlab.campaign.tester import RunOutcome, Tester, VirtualBench, run_plan
from battlab.cell import Cell


class RunFailed(Exception):
    """A run on the tester did not complete."""


def write_json(path: Path, data: Any) -> None:
    from battlab.jsonable import json_default

    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1, default=json_default))


def read_json(path: Path) -> Any:
    return json.loads(path.read_text())


@dataclass
class Campaign:
    """What every stage shares: settings, where plans run, the virtual bench, the campaign directory."""

    config: CampaignConfig
    tester: Tester
    directory: Path
    bench: VirtualBench | None = None
    runs: list[dict[str, Any]] = field(default_factory=list)

    def __post_init__(self) -> None:
        if self.tester.virtual and self.bench is None:
            self.bench = VirtualBench(self.tester, self.config.campaign.ambient_degC)

    @property
    def ambient(self) -> float:
        return self.config.campaign.ambient_degC

    @property
    def start(self) -> Cell:
        return Cell.load(self.config.campaign.start)

    @property
    def rest_after_s(self) -> float:
        """The rest logged after each measured profile [s]: 600 s, 300 s in the quick campaign."""
        return 300.0 if self.config.quick else P.REST_AFTER_S

    def measurement(self, prof: Any) -> Any:
        return P.measurement(prof, self.q_rated, self.ambient, rest_after_s=self.rest_after_s)

    @property
    def q_rated(self) -> float:
        return float(self.start["Q_nom"])

    def run(self, plan: Any, rel: str, *, must_complete: bool = True) -> RunOutcome:
        """Run ``plan`` to ``runs/<rel>.h5`` (a log left by an interrupted attempt is moved aside first); a run that
        does not complete raises :class:`RunFailed` unless ``must_complete`` is False."""
        path = self.directory / "runs" / f"{rel}.h5"
        path.parent.mkdir(parents=True, exist_ok=True)
        if path.exists():
            k = 1
            while path.with_name(f"{path.stem}.interrupted-{k}.h5").exists():
                k += 1
            path.rename(path.with_name(f"{path.stem}.interrupted-{k}.h5"))
        w0 = time.perf_counter()
        out = run_plan(plan, self.tester, path, cell=self.config.campaign.start, bench=self.bench)
        self.runs.append({**out.health(), "wall_s": time.perf_counter() - w0})
        if out.status != "completed" and must_complete:
            raise RunFailed(f"run {rel} {out.status}: {out.reason}")
        return out

    def run_to_limit(self, plan: Any, rel: str, notes: dict[str, str], step: int = 2) -> RunOutcome:
        """A constant-current test to a voltage limit: one that aborted in or after its test step (at the cut-off
        the virtual cell's model may fail to converge, also in the current step to the rest after it) keeps its data
        up to there, noted in ``notes``; any other failure raises :class:`RunFailed`."""
        out = self.run(plan, rel, must_complete=False)
        if out.status == "completed":
            return out
        if out.status == "aborted" and _ended_in_step(out, step):
            notes[rel] = f"ended early in or after the test step: {out.reason}"
            return out
        raise RunFailed(f"run {rel} {out.status}: {out.reason}")


def _ended_in_step(out: RunOutcome, step: int) -> bool:
    d = D.load(out.log_path)
    return len(d) >= 10 and int(d.columns[D.STEP_INDEX][-1]) >= step


def health_file(camp: Campaign, ctx: StageContext, name: str, first: int) -> str:
    rel = f"health/{name}.json"
    write_json(ctx.directory / rel, camp.runs[first:])
    return rel


def rel_path(ctx: StageContext, p: str | Path) -> str:
    return str(Path(p).resolve().relative_to(ctx.directory.resolve()))


def plain(rep: dict[str, Any]) -> dict[str, Any]:
    return json.loads(json.dumps(rep, default=lambda o: o.item() if hasattr(o, "item") else str(o)))
