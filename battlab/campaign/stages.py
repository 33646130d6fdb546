"""The campaign's stage runner: ordered stages, each skipped when its inputs have not changed, resumable.

A campaign directory holds every stage's artefacts (HDF5, TOML, BPX, JSON) and ``campaign.json``, the state:
the campaign's identity (what it is about: the cells, the tester, battlab's version) and, per finished stage,
its key, its files with their SHA-256 and its summary. A stage's key is the SHA-256 of its name, the settings it
reads and the content hashes of the files of the stages it needs, so:

- a stage whose key and files are unchanged is skipped, its summary reused;
- a changed setting or input file reruns that stage and everything downstream of it (their keys change too);
- an interrupted campaign resumes at the first stage without a finished record (the state is written
  atomically after every stage);
- a directory that holds another campaign (different identity) is refused before anything runs, so nothing of
  it is overwritten.

Progress goes to subscribers as :class:`battlab.progress.ProgressEvent` values (task: the stage's name; kinds
``start``, ``advance``, ``stop``, ``skipped``, ``failed``; payload :class:`StageInfo`), never printed here.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from battlab.progress import ProgressEvent, emit
from protocols.errors import InputError

STATE_FILE = "campaign.json"
STATE_FORMAT = "battlab-campaign"
STATE_VERSION = 1


@dataclass(frozen=True)
class StageOutput:
    """What a stage produced: files by role (paths relative to the campaign directory), a JSON-able summary and
    the simulated or real lab time it used [h]."""

    files: Mapping[str, str] = field(default_factory=dict)
    summary: Mapping[str, Any] = field(default_factory=dict)
    lab_hours: float = 0.0


@dataclass(frozen=True)
class StageContext:
    """What a running stage sees: the campaign directory, the outputs of the stages it needs, and a progress
    callback ``progress(done, total, text)`` for long stages."""

    directory: Path
    inputs: Mapping[str, StageOutput]
    progress: Callable[[float, float, str], None]

    def path(self, stage: str, role: str) -> Path:
        """The absolute path of another stage's file."""
        try:
            return self.directory / self.inputs[stage].files[role]
        except KeyError:
            raise InputError(f"campaign: no file {role!r} from stage {stage!r}") from None


@dataclass(frozen=True)
class Stage:
    """One step of the campaign: ``run(ctx) -> StageOutput``, reading ``settings`` (JSON-able) and the outputs of
    the stages named in ``needs``."""

    name: str
    run: Callable[[StageContext], StageOutput]
    needs: tuple[str, ...] = ()
    settings: Mapping[str, Any] = field(default_factory=dict)
    title: str = ""


@dataclass(frozen=True)
class StageInfo:
    """The payload of a campaign stage's progress events: its position (0-based ``index`` of ``total``), its title
    and, when it finished, its wall time [s]."""

    index: int
    total: int
    title: str = ""
    wall_s: float = 0.0


Subscriber = Callable[[ProgressEvent], None]


@dataclass(frozen=True)
class StageRecord:
    """A finished stage as the state file keeps it."""

    name: str
    key: str
    status: str  # "ran" or "skipped" (this time)
    output: StageOutput
    wall_s: float
    hashes: Mapping[str, str]

    def to_json(self) -> dict[str, Any]:
        return {
            "key": self.key,
            "files": dict(self.output.files),
            "sha256": dict(self.hashes),
            "summary": self.output.summary,
            "lab_hours": self.output.lab_hours,
            "wall_s": self.wall_s,
        }


def file_hash(path: Path) -> str:
    """SHA-256 of a file's bytes (of every file below it, by relative name, for a directory)."""
    h = hashlib.sha256()
    if path.is_dir():
        for p in sorted(q for q in path.rglob("*") if q.is_file()):
            h.update(str(p.relative_to(path)).encode())
            h.update(file_hash(p).encode())
        return h.hexdigest()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def stage_key(stage: Stage, inputs: Mapping[str, StageRecord]) -> str:
    """The key that decides whether a stage must run again: its name, settings and its inputs' file hashes."""
    blob = {
        "stage": stage.name,
        "settings": stage.settings,
        "inputs": {n: dict(sorted(inputs[n].hashes.items())) for n in stage.needs},
    }
    return hashlib.sha256(json.dumps(blob, sort_keys=True, default=str).encode()).hexdigest()


def _check_order(stages: Sequence[Stage]) -> None:
    seen: set[str] = set()
    for s in stages:
        if s.name in seen:
            raise InputError(f"campaign: stage {s.name!r} is listed twice")
        missing = [n for n in s.needs if n not in seen]
        if missing:
            raise InputError(f"campaign: stage {s.name!r} needs {', '.join(missing)}, which must come before it")
        seen.add(s.name)


class StateFile:
    """``campaign.json`` in a campaign directory: identity plus finished stages, replaced atomically."""

    def __init__(self, directory: Path, identity: Mapping[str, Any]) -> None:
        self.directory = directory
        self.path = directory / STATE_FILE
        self.identity = dict(identity)
        self.stages: dict[str, dict[str, Any]] = {}
        if self.path.exists():
            try:
                data = json.loads(self.path.read_text())
            except (OSError, json.JSONDecodeError) as exc:
                raise InputError(f"{self.path}: not a readable campaign state ({exc})") from None
            if not isinstance(data, dict) or data.get("format") != STATE_FORMAT:
                raise InputError(f"{self.path}: not a battlab campaign state file")
            if data.get("identity") != self.identity:
                old, new = data.get("identity", {}), self.identity
                diff = sorted(k for k in set(old) | set(new) if old.get(k) != new.get(k))
                raise InputError(
                    f"{directory}: holds another campaign (differs in {', '.join(diff)}); "
                    "choose a new directory with -o (nothing was changed)"
                )
            self.stages = dict(data.get("stages", {}))
        elif directory.exists() and any(directory.iterdir()):
            raise InputError(f"{directory}: exists and is not a campaign directory; choose a new one with -o")

    def finished(self, stage: str) -> dict[str, Any] | None:
        return self.stages.get(stage)

    def record(self, rec: StageRecord) -> None:
        self.stages[rec.name] = rec.to_json()
        self.save()

    def forget_after(self, names: Sequence[str]) -> None:
        """Drop records of stages that no longer exist in the pipeline."""
        self.stages = {k: v for k, v in self.stages.items() if k in names}

    def save(self) -> None:
        self.directory.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_suffix(".json.tmp")
        body = {"format": STATE_FORMAT, "version": STATE_VERSION, "identity": self.identity, "stages": self.stages}
        tmp.write_text(json.dumps(body, indent=2, default=str))
        os.replace(tmp, self.path)


def _reusable(entry: Mapping[str, Any] | None, key: str, directory: Path) -> bool:
    if not entry or entry.get("key") != key:
        return False
    for role, rel in entry.get("files", {}).items():
        p = directory / rel
        if not p.exists() or file_hash(p) != entry.get("sha256", {}).get(role):
            return False
    return True


def run_stages(
    directory: str | Path,
    stages: Sequence[Stage],
    identity: Mapping[str, Any],
    subscribers: Sequence[Subscriber] = (),
) -> list[StageRecord]:
    """Run ``stages`` in order in ``directory``, skipping those whose inputs are unchanged; returns one record per
    stage. A stage that raises leaves the earlier stages' records in place (so a rerun resumes there) and the
    exception propagates."""
    directory = Path(directory)
    _check_order(stages)
    state = StateFile(directory, identity)
    state.forget_after([s.name for s in stages])
    directory.mkdir(parents=True, exist_ok=True)
    if not state.path.exists():
        state.save()
    records: dict[str, StageRecord] = {}
    total = len(stages)

    def send(
        kind: str, k: int, stage: Stage, done: float = 0, of: float = 0, text: str = "", wall: float = 0.0
    ) -> None:
        emit(subscribers, ProgressEvent(stage.name, kind, done, of, text, StageInfo(k, total, stage.title, wall)))

    for k, stage in enumerate(stages):
        key = stage_key(stage, records)
        entry = state.finished(stage.name)
        if _reusable(entry, key, directory):
            assert entry is not None
            out = StageOutput(entry["files"], entry["summary"], float(entry.get("lab_hours", 0.0)))
            records[stage.name] = StageRecord(stage.name, key, "skipped", out, float(entry["wall_s"]), entry["sha256"])
            send("skipped", k, stage)
            continue
        send("start", k, stage)

        def progress(done: float, of: float, text: str = "", _k: int = k, _s: Stage = stage) -> None:
            send("advance", _k, _s, done, of, text)

        ctx = StageContext(directory, {n: records[n].output for n in stage.needs}, progress)
        t0 = time.perf_counter()
        try:
            out = stage.run(ctx)
        except BaseException as exc:
            send("failed", k, stage, text=str(exc))
            raise
        wall = time.perf_counter() - t0
        hashes = {}
        for role, rel in out.files.items():
            p = directory / rel
            if not p.exists():
                raise InputError(f"campaign stage {stage.name!r}: its file {role!r} ({rel}) was not written")
            hashes[role] = file_hash(p)
        rec = StageRecord(stage.name, key, "ran", out, wall, hashes)
        state.record(rec)
        records[stage.name] = rec
        send("stop", k, stage, wall=wall)
    return [records[s.name] for s in stages]
