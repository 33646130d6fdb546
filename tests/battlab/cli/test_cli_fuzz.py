"""Property-based fuzzing of every CLI command family with malformed and adversarial files.

For every generated file the command must exit 0 (the input happened to be valid), 1 (a valid input whose
simulation failed) or 2 (the user's mistake), never print a traceback, report an error as ONE line on stderr
that names the file or argument it concerns, finish within a generous time limit, and leave no output file
behind when it fails. ``BATTLAB_FUZZ_EXAMPLES`` sets the number of examples per family (default 25, as CI runs
it); the full count, 500 per family, is a documented command (benchmarks/README.md), with
``--hypothesis-show-statistics`` for the share of each exit code.
"""

from __future__ import annotations

import io
import json
import os
import signal
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import h5py
import numpy as np
import pytest
import scipy.io
from click.testing import CliRunner, Result
from hypothesis import HealthCheck, event, example, given, settings
from hypothesis import strategies as st

from battlab.cli import main

pytestmark = pytest.mark.slow

EXAMPLES = int(os.environ.get("BATTLAB_FUZZ_EXAMPLES", "25"))
# A hang is the defect this limit catches; it is far above any case's normal run time on a busy machine, which
# includes compiling the model of a mutated BPX cell (10-30 s on a quiet machine; a case passed 60 s with the
# whole suite running on an empty model cache).
CASE_LIMIT_S = 180
FUZZ = settings(
    max_examples=EXAMPLES,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.large_base_example],
    database=None,
)

PROFILE_COLUMNS = ["Test Time / s", "Current / A"]
DATA_COLUMNS = [
    "Test Time / s",
    "Voltage / V",
    "Current / A",
    "Ambient Temperature / degC",
    "Surface Temperature T1 / degC",
]


class CaseTimeout(Exception):
    """A single CLI invocation ran past :data:`CASE_LIMIT_S`."""


@contextmanager
def time_limit(seconds: int) -> Iterator[None]:
    """Raise :class:`CaseTimeout` in the main thread if the block runs longer than ``seconds`` [s]."""

    def handler(signum: int, frame: object) -> None:
        raise CaseTimeout(f"case ran longer than {seconds} s")

    old = signal.signal(signal.SIGALRM, handler)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def run_cli(args: list[str], out_dir: Path, names: list[str]) -> Result:
    """Invoke the CLI and check the contract: exit code, no traceback, one-line error naming a file or argument,
    no output left behind on an error."""
    with time_limit(CASE_LIMIT_S):
        result = CliRunner().invoke(main, args)
    context = f"args={args}\nexit={result.exit_code}\nstdout={result.stdout!r}\nstderr={result.stderr!r}"
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise AssertionError(f"uncaught {type(result.exception).__name__}: {result.exception}\n{context}") from (
            result.exception
        )
    assert result.exit_code in (0, 1, 2), context
    event(f"exit {result.exit_code}")  # --hypothesis-show-statistics: how many inputs were refused (exit 2)
    assert "Traceback" not in result.output, context
    if result.exit_code != 0:
        lines = [line for line in result.stderr.splitlines() if line.strip()]
        errors = [line for line in lines if line.startswith("error:")]
        assert len(errors) == 1, f"expected one error line\n{context}"
        assert lines[-1] == errors[0], f"the error is not the last line on stderr\n{context}"
        assert any(n in errors[0] for n in names), f"the error names none of {names}\n{context}"
        left = sorted(p.name for p in out_dir.iterdir())
        assert not left, f"output left behind on an error: {left}\n{context}"
    return result


@contextmanager
def dirs() -> Iterator[tuple[Path, Path]]:
    """A fresh input directory and an empty output directory."""
    with tempfile.TemporaryDirectory() as tmp:
        inp, out = Path(tmp, "in"), Path(tmp, "out")
        inp.mkdir()
        out.mkdir()
        yield inp, out


# ---------------------------------------------------------------------------------------------------------------
# file contents


def _num_text(x: object) -> str:
    return repr(x) if isinstance(x, float) else str(x)


NUMBER = st.one_of(
    st.floats(min_value=-30.0, max_value=30.0),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(10**30), max_value=10**30),
    st.sampled_from(["", "abc", "1e999", "-1e999", "nan", "inf", "-inf", "1,5", "0x10", " ", "None", "1e-400"]),
)


def monotonic_times(n: int, step: float = 1.0) -> list[float]:
    return [float(i) * step for i in range(n)]


@st.composite
def table_csv(draw: st.DrawFn, columns: list[str], plausible: Callable[[int], list[list[object]]]) -> bytes:
    """A CSV table: right or wrong header, plausible or adversarial values, maybe truncated."""
    header_kind = draw(st.sampled_from(["right", "missing", "extra", "renamed", "none", "duplicate", "shuffled"]))
    cols = list(columns)
    if header_kind == "missing":
        cols.pop(draw(st.integers(0, len(cols) - 1)))
    elif header_kind == "extra":
        cols.append(draw(st.sampled_from(["Voltage / V", "foo", "", "Current / mA"])))
    elif header_kind == "renamed":
        i = draw(st.integers(0, len(cols) - 1))
        cols[i] = draw(st.sampled_from(["time", "Current / mA", "Test Time / min", "I", cols[i].upper()]))
    elif header_kind == "duplicate":
        cols.append(cols[0])
    elif header_kind == "shuffled":
        cols = draw(st.permutations(cols))
    n = draw(st.integers(0, 12))
    rows = plausible(n)
    # adversarial values in a few cells
    for _ in range(draw(st.integers(0, 4))):
        if not rows:
            break
        i = draw(st.integers(0, len(rows) - 1))
        j = draw(st.integers(0, len(rows[i]) - 1))
        rows[i][j] = draw(NUMBER)
    if draw(st.booleans()):
        for r in rows:
            r[:] = r[: len(cols)] + [0.0] * (len(cols) - len(r))
    lines = [] if header_kind == "none" else [",".join(cols)]
    lines += [",".join(_num_text(v) for v in r) for r in rows]
    text = "\n".join(lines) + ("\n" if draw(st.booleans()) else "")
    data = text.encode()
    if draw(st.integers(0, 4)) == 0:
        data = data[: draw(st.integers(0, len(data)))]
    return data


def plausible_profile(n: int) -> list[list[object]]:
    return [[t, -2.7 if 2 <= i < 6 else 0.0] for i, t in enumerate(monotonic_times(n, 5.0))]


def plausible_data(n: int) -> list[list[object]]:
    return [[t, 3.9, -1.0 if i >= 3 else 0.0, 25.0, 25.0] for i, t in enumerate(monotonic_times(n, 5.0))]


def hdf5_bytes(columns: dict[str, np.ndarray]) -> bytes:
    """An HDF5 file with the given datasets, as bytes (to be renamed as anything)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp, "x.h5")
        with h5py.File(path, "w") as f:
            for k, v in columns.items():
                f[k.replace("/", "_")] = v
        return path.read_bytes()


def mat_bytes(columns: dict[str, np.ndarray]) -> bytes:
    buf = io.BytesIO()
    scipy.io.savemat(buf, {k.split(" ")[0].replace("/", "_") or "x": v for k, v in columns.items()})
    return buf.getvalue()


ARRAY = st.lists(st.floats(allow_nan=True, allow_infinity=True, width=32), min_size=0, max_size=8).map(
    lambda v: np.asarray(v, dtype=float)
)


@st.composite
def other_format(draw: st.DrawFn, columns: list[str]) -> bytes:
    """Binary garbage, an empty file, an HDF5 or a .mat file (maybe truncated)."""
    kind = draw(st.sampled_from(["garbage", "empty", "hdf5", "mat", "json"]))
    if kind == "garbage":
        return draw(st.binary(max_size=300))
    if kind == "empty":
        return b""
    if kind == "json":
        return b'{"Test Time / s": [0, 1], "Current / A": [0, 1]}'
    cols = {c: draw(ARRAY) for c in draw(st.lists(st.sampled_from(columns), unique=True, max_size=len(columns)))}
    data = hdf5_bytes(cols) if kind == "hdf5" else mat_bytes(cols)
    if draw(st.booleans()):
        data = data[: draw(st.integers(0, len(data)))]
    return data


# ---------------------------------------------------------------------------------------------------------------
# fixtures: things built once


@pytest.fixture(scope="module")
def shared(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A valid BPX cell, a valid profile, a library file, and a warm model (compiled once, outside the limit)."""
    from battlab.cell import Cell
    from battlab.io.bpx.write import write_bpx
    from protocols import Library

    root = tmp_path_factory.mktemp("fuzz")
    bpx = write_bpx(Cell.load("nca18650"), root / "cell.bpx.json")
    profile = root / "profile.csv"
    profile.write_text("Test Time / s,Current / A\n0,0\n5,-2.7\n10,-2.7\n15,0\n20,0\n")
    lib = Library.build().save(root / "library.h5")
    out = root / "warm"
    out.mkdir()
    CliRunner().invoke(main, ["simulate", "nca18650", str(profile), "-o", str(out / "w.bdf.csv")])
    return {"bpx": Path(bpx), "profile": profile, "library": Path(lib)}


# ---------------------------------------------------------------------------------------------------------------
# families


PROFILE_FILE = st.one_of(table_csv(PROFILE_COLUMNS, plausible_profile), other_format(PROFILE_COLUMNS))


@FUZZ
@given(content=PROFILE_FILE, suffix=st.sampled_from([".csv", ".csv", ".bdf.csv"]))
@example(content=b"\x80", suffix=".csv")  # binary, not UTF-8
@example(content=b"Test Time / s,Current / A\n0\x00,0\n", suffix=".csv")  # NUL byte
@example(content=b"Test Time / s,Current / A\n-1e30,0.0\n-1e-211,0.0\n", suffix=".csv")  # 1e30 s: ran for ever
def test_simulate_profile_files(shared: dict[str, Path], content: bytes, suffix: str) -> None:
    """``simulate nca18650 PROFILE -o OUT`` with truncated, mistyped, non-finite, huge or non-monotonic profiles."""
    with dirs() as (inp, out):
        path = inp / f"profile{suffix}"
        path.write_bytes(content)
        run_cli(["simulate", "nca18650", str(path), "-o", str(out / "out.bdf.csv")], out, [path.name])


def _json_value() -> st.SearchStrategy[object]:
    return st.recursive(
        st.one_of(
            st.none(),
            st.booleans(),
            st.floats(allow_nan=False, allow_infinity=False),
            st.integers(-(10**20), 10**20),
            st.text(max_size=10),
            st.sampled_from(
                [
                    "exec('import os')",
                    "__import__('os').system('true')",
                    "x.__class__.__mro__",
                    "().__class__.__bases__[0].__subclasses__()",
                    "lambda x: x",
                    "1/0",
                    "x**x**x**x**x",
                    "9**9**9**9",
                    "open('/etc/passwd').read()",
                    "x[0]",
                    "sto" * 2000,
                    "(" * 500 + "x" + ")" * 500,
                    "x +",
                    "",
                ]
            ),
        ),
        lambda children: st.one_of(st.lists(children, max_size=3), st.dictionaries(st.text(max_size=5), children)),
        max_leaves=6,
    )


@st.composite
def bpx_file(draw: st.DrawFn, valid: dict[str, object]) -> bytes:
    """A BPX file with mutated fields, deleted fields, or broken JSON."""
    kind = draw(st.sampled_from(["mutate", "mutate", "delete", "broken", "type"]))
    doc = json.loads(json.dumps(valid))
    if kind == "type":
        return json.dumps(draw(st.one_of(st.lists(st.integers(), max_size=3), st.integers(), st.text()))).encode()
    if kind == "broken":
        text = json.dumps(doc)
        return text[: draw(st.integers(0, len(text) - 1))].encode()
    for _ in range(draw(st.integers(1, 3))):
        paths = list(_leaf_paths(doc))  # again: an earlier change may have removed a subtree
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent = doc
        for key in path[:-1]:
            parent = parent[key]
        if kind == "delete":
            del parent[path[-1]]
        else:
            parent[path[-1]] = draw(_json_value())
    return json.dumps(doc).encode()


def _leaf_paths(doc: object, prefix: tuple[str, ...] = ()) -> Iterator[tuple[str, ...]]:
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield prefix + (k,)
            yield from _leaf_paths(v, prefix + (k,))


@pytest.fixture(scope="module")
def valid_bpx(shared: dict[str, Path]) -> dict[str, object]:
    return json.loads(shared["bpx"].read_text())


@FUZZ
@given(data=st.data())
def test_simulate_bpx_files(shared: dict[str, Path], valid_bpx: dict[str, object], data: st.DataObject) -> None:
    """``simulate CELL.json PROFILE -o OUT`` with invalid JSON, missing fields, code in function strings, wrong
    types."""
    content = data.draw(bpx_file(valid_bpx))
    with dirs() as (inp, out):
        path = inp / "cell.bpx.json"
        path.write_bytes(content)
        args = ["simulate", str(path), str(shared["profile"]), "-o", str(out / "out.h5")]
        run_cli(args, out, [path.name, shared["profile"].name])


DATA_FILE = st.one_of(table_csv(DATA_COLUMNS, plausible_data), other_format(DATA_COLUMNS))


@FUZZ
@given(content=DATA_FILE, suffix=st.sampled_from([".csv", ".bdf.csv", ".mat", ".h5"]))
@example(content=b"\x80", suffix=".csv")  # binary, not UTF-8
@example(content=b"Test Time / s,Voltag", suffix=".mat")  # scipy's reader raised IndexError
@example(content=b"Test Time / s,Voltage / V,Current / A\n0,3.9,0\n1,5,3.9,0\n", suffix=".csv")  # row too long
def test_validate_data_files(shared: dict[str, Path], content: bytes, suffix: str) -> None:
    """``validate DATA --cell nca18650 --ambient 25`` with garbage, truncated or adversarial data files."""
    with dirs() as (inp, out):
        path = inp / f"data{suffix}"
        path.write_bytes(content)
        # -o inside the case's output directory: a valid file must not leave validation/ in the working directory
        args = ["validate", str(path), "--cell", "nca18650", "--ambient", "25", "-o", str(out / "validation")]
        run_cli(args, out, [path.name])


@FUZZ
@given(content=DATA_FILE, suffix=st.sampled_from([".csv", ".bdf.csv", ".mat", ".h5"]))
def test_fit_data_files(shared: dict[str, Path], content: bytes, suffix: str) -> None:
    """``fit DATA --cell nca18650 --params R_s_n --ambient 25 --max-iter 2 -o OUT`` with bad data files."""
    with dirs() as (inp, out):
        path = inp / f"data{suffix}"
        path.write_bytes(content)
        args = ["fit", str(path), "--cell", "nca18650", "--params", "R_s_n", "--ambient", "25", "--max-iter", "2"]
        run_cli([*args, "-o", str(out / "cell.bpx.json")], out, [path.name])


VALID_PROTOCOL = """name = "p"
capacity_ah = 2.7

[limits]
voltage_min = 2.45
voltage_max = 4.25
current_max = 13.5
temperature_max = 323.15

[[steps]]
kind = "cc"
current = -1.35
until = ["time >= 60"]

[[steps]]
kind = "rest"
until = ["time >= 30"]
"""


@st.composite
def protocol_file(draw: st.DrawFn) -> tuple[bytes, str]:
    """A protocol TOML or JSON: a valid one with a line mutated, deleted or truncated, or garbage."""
    kind = draw(st.sampled_from(["mutate", "delete", "truncate", "garbage", "json"]))
    lines = VALID_PROTOCOL.splitlines()
    if kind == "garbage":
        return draw(st.binary(max_size=200)), draw(st.sampled_from([".toml", ".json"]))
    if kind == "json":
        value = draw(_json_value())
        return json.dumps(value).encode(), ".json"
    if kind == "truncate":
        return VALID_PROTOCOL[: draw(st.integers(0, len(VALID_PROTOCOL)))].encode(), ".toml"
    i = draw(st.integers(0, len(lines) - 1))
    if kind == "delete":
        del lines[i]
    elif "=" in lines[i]:
        key = lines[i].split("=")[0].strip()
        value = draw(
            st.one_of(
                st.sampled_from(['"abc"', "nan", "inf", "-inf", "1e308", "-1e308", "[]", "{}", "true", "0", '""']),
                st.integers(-(10**18), 10**18).map(str),
                st.sampled_from(['["current >= abc"]', '["time >= -5"]', '["volt <= 4"]', '["time >= 1e300"]']),
            )
        )
        lines[i] = f"{key} = {value}"
    else:
        lines[i] = draw(st.sampled_from(["[[steps]]", "[limits]", "[x]", "[[limits]]", "="]))
    return ("\n".join(lines) + "\n").encode(), ".toml"


@FUZZ
@given(spec=protocol_file())
@example(spec=(b"\x80", ".toml"))  # binary, not UTF-8
@example(spec=(VALID_PROTOCOL.replace("current = -1.35", "current = 14").encode(), ".toml"))  # beyond the limits
@example(spec=(VALID_PROTOCOL.replace("time >= 60", "time >= 1e-4").encode(), ".toml"))  # finer than Maccor's
def test_export_protocol_files(shared: dict[str, Path], spec: tuple[bytes, str]) -> None:
    """``export FILE --format maccor -o DIR`` with broken protocol TOML/JSON."""
    content, suffix = spec
    with dirs() as (inp, out):
        path = inp / f"protocol{suffix}"
        path.write_bytes(content)
        target = out / "schedule"
        result = run_cli(["export", str(path), "--format", "maccor", "-o", str(target)], out, [path.name])
        if result.exit_code != 0:
            assert not target.exists()


@FUZZ
@given(
    profile_id=st.one_of(
        st.integers(-(10**6), 10**6).map(str),
        st.integers(-(10**30), 10**30).map(str),
        st.sampled_from(["", " ", "abc", "1.5", "1e3", "0x10", "-0", "737", "738", "nan", "--", "١٢"]),
        st.text(max_size=8),
    )
)
def test_library_show_ids(shared: dict[str, Path], profile_id: str) -> None:
    """``library show ID`` with out-of-range, negative, huge and non-numeric ids."""
    with dirs() as (_inp, out):
        names = [profile_id.strip() or "PROFILE_ID", "PROFILE_ID", "profile_id", "profile id", "with id"]
        run_cli(["library", "show", "--library", str(shared["library"]), "--", profile_id], out, names)
