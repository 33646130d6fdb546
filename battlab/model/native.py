"""The compiled time stepper: CasADi generates C for the step residual and its Jacobians, ``stepper.c`` runs
Newton, a static-pivot sparse LU and the sensitivity solves, and gcc turns both into one shared library.

Build once per (cell, mesh, option set: thermal option and extensions), cached on disk under ``$BATTLAB_CACHE`` (default
``~/.cache/battlab``) by a hash of the generated source, so a fit that changes θ̄ never recompiles (θ̄ is an input).

The LU program: the pivot order comes from SuperLU (COLAMD columns, partial pivoting) on the Jacobian at a
representative state; the fill pattern of that order is computed symbolically, and the numeric factorisation
replays it (as KLU's refactorisation does). A pivot that vanishes later is reported, and the caller re-analyses.
Pivot programs are values (:class:`Pivots`): every run starts from the one of a fixed state that depends only on
θ̄ (:meth:`NativeStepper.base_pivots`), and a re-analysis belongs to the run that needed it, so a result never
depends on what ran before it in the process.
"""

from __future__ import annotations

import ctypes
import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import casadi as ca
import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from battlab.model.dfn import DFN
from battlab.model.plans import AdaptiveControl, SamplePlan, StepPlan
from battlab.model.state import guess_algebraic, initial_state
from battlab.threads import thread_map

log = logging.getLogger("battlab.model")

#: the library is built on (and cached for) this machine, so it may use its instruction set
CFLAGS = ("-O3", "-march=native")
_INT = ctypes.c_int
_PI = ctypes.POINTER(ctypes.c_int)
_PD = ctypes.POINTER(ctypes.c_double)


class NativeUnavailable(RuntimeError):
    """No C compiler, or the build failed: the caller falls back to the CasADi stepper."""


class _Problem(ctypes.Structure):
    _fields_ = [
        ("n", _INT),
        ("nx", _INT),
        ("nth", _INT),
        ("nslot", _INT),
        ("prow", _PI),
        ("pcol", _PI),
        ("jac2slot", _PI),
        ("piv", _PI),
        ("lptr", _PI),
        ("lrow", _PI),
        ("lslot", _PI),
        ("uptr", _PI),
        ("uslot", _PI),
        ("upd", _PI),
        ("ucptr", _PI),
        ("ucrow", _PI),
        ("ucslot", _PI),
        ("jth_colptr", _PI),
        ("jth_row", _PI),
        ("jac_nnz", _INT),
        ("jth_nnz", _INT),
        ("iT2", _INT),
    ]


def cache_dir() -> Path:
    d = Path(os.environ.get("BATTLAB_CACHE", Path.home() / ".cache" / "battlab"))
    d.mkdir(parents=True, exist_ok=True)
    return d


def _functions(model: DFN) -> tuple[list[ca.Function], ca.Sparsity, ca.Sparsity]:
    lay = model.layout
    nx, ny = lay.nx, lay.ny
    y = ca.SX.sym("y", ny)
    xn = ca.SX.sym("xn", nx)
    xp = ca.SX.sym("xp", nx)
    u = ca.SX.sym("u", 4)
    th = ca.SX.sym("th", model.n_theta)
    h, w = u[0], u[1]
    eq = model.equations(y, u[2], u[3], th)
    gamma = (1 + w) / (1 + 2 * w)
    psi = (1 + w) ** 2 / (1 + 2 * w) * xn - w**2 / (1 + 2 * w) * xp
    R = ca.vertcat(y[:nx] - psi - gamma * h * eq["f"], eq["g"])
    Jy = ca.jacobian(R, y)
    Jth = ca.jacobian(R, th)
    sto = eq["sto_surf"]
    o = ca.vertcat(eq["V"], eq["T1"], eq["T2"], ca.mmin(sto), ca.mmax(sto))
    fs = [
        ca.Function("bl_res", [y, xn, xp, u, th], [R]),
        ca.Function("bl_jac", [y, xn, xp, u, th], [Jy]),
        ca.Function("bl_jth", [y, xn, xp, u, th], [Jth]),
        ca.Function("bl_out", [y, u, th], [o]),
        ca.Function("bl_outj", [y, u, th], [ca.densify(ca.jacobian(eq["V"], y)), ca.densify(ca.jacobian(eq["V"], th))]),
    ]
    return fs, Jy.sparsity(), Jth.sparsity()


@dataclass
class LUProgram:
    """Index arrays of the static-pivot LU (see ``stepper.c``)."""

    arrays: dict[str, np.ndarray]
    nslot: int


def analyse(jac_sparsity: ca.Sparsity, values: np.ndarray) -> LUProgram:
    """Pivot order from SuperLU on a numeric Jacobian, then the symbolic fill and the replay program."""
    n = jac_sparsity.size1()
    colind = np.array(jac_sparsity.colind())
    row = np.array(jac_sparsity.row())
    A = sp.csc_matrix((values, row, colind), shape=(n, n))
    lu = splu(A, permc_spec="COLAMD", diag_pivot_thresh=1.0, options={"SymmetricMode": False})
    # scipy: Pr A Pc = L U with (Pr A)[perm_r[i]] = A[i] and (A Pc)[:, perm_c[j]] = A[:, j]
    inv_prow = np.asarray(lu.perm_r)  # original row -> position
    inv_pcol = np.asarray(lu.perm_c)  # original column -> position
    prow = np.argsort(inv_prow)  # position -> original row
    pcol = np.argsort(inv_pcol)  # position -> original column
    # permuted pattern as row sets and column sets
    rows: list[set[int]] = [set() for _ in range(n)]
    cols: list[set[int]] = [set() for _ in range(n)]
    for j in range(n):
        for k in range(colind[j], colind[j + 1]):
            i2, j2 = int(inv_prow[row[k]]), int(inv_pcol[j])
            rows[i2].add(j2)
            cols[j2].add(i2)
    for k in range(n):
        rows[k].add(k)
        cols[k].add(k)
    # symbolic elimination (no pivoting): fill
    for k in range(n):
        below = [i for i in cols[k] if i > k]
        right = [j for j in rows[k] if j > k]
        for i in below:
            ri = rows[i]
            for j in right:
                if j not in ri:
                    ri.add(j)
                    cols[j].add(i)
    slot: dict[tuple[int, int], int] = {}
    for i in range(n):
        for j in sorted(rows[i]):
            slot[(i, j)] = len(slot)
    jac2slot = np.array(
        [slot[(int(inv_prow[row[k]]), int(inv_pcol[j]))] for j in range(n) for k in range(colind[j], colind[j + 1])],
        dtype=np.int32,
    )
    piv = np.array([slot[(k, k)] for k in range(n)], dtype=np.int32)
    lptr, lrow, lslot, uptr, uslot, upd = [0], [], [], [0], [], []
    ucptr, ucrow, ucslot = [0], [], []
    for k in range(n):
        below = sorted(i for i in cols[k] if i > k)
        right = sorted(j for j in rows[k] if j > k)
        lrow += below
        lslot += [slot[(i, k)] for i in below]
        lptr.append(len(lrow))
        uslot += [slot[(k, j)] for j in right]
        uptr.append(len(uslot))
        upd += [slot[(i, j)] for i in below for j in right]
        above = sorted(i for i in cols[k] if i < k)
        ucrow += above
        ucslot += [slot[(i, k)] for i in above]
        ucptr.append(len(ucrow))
    arr = {
        name: np.ascontiguousarray(v, dtype=np.int32)
        for name, v in {
            "prow": prow,
            "pcol": pcol,
            "jac2slot": jac2slot,
            "piv": piv,
            "lptr": lptr,
            "lrow": lrow,
            "lslot": lslot,
            "uptr": uptr,
            "uslot": uslot,
            "upd": upd,
            "ucptr": ucptr,
            "ucrow": ucrow,
            "ucslot": ucslot,
        }.items()
    }
    return LUProgram(arr, len(slot))


@dataclass(frozen=True, eq=False)
class Pivots:
    """A pivot program ready for ``bl_run``, with the arrays its pointers refer to (kept alive with it)."""

    problem: _Problem
    keep: tuple[np.ndarray, ...]


@dataclass(frozen=True, eq=False)
class PivotSet:
    """The pivot programs of a run: ``step`` for steps with h > 0, ``zero`` for zero-length solves (the consistent
    start and the right limits at current changes), whose Jacobians differ in value (no mass terms)."""

    step: Pivots
    zero: Pivots

    def replace(self, *, step: Pivots | None = None, zero: Pivots | None = None) -> PivotSet:
        return PivotSet(step or self.step, zero or self.zero)


#: base pivot programs kept per stepper (one per θ̄: a fit visits many)
BASE_CACHE = 8


class NativeStepper:
    """A compiled model: ``run`` advances a schedule of steps and writes the samples' outputs."""

    def __init__(self, model: DFN) -> None:
        t0 = time.perf_counter()
        self.model = model
        fs, self.jac_sp, self.jth_sp = _functions(model)
        self._f = {f.name(): f for f in fs}
        units = _sources(fs)
        src = "\n".join(text for _, text in units)
        debug = "debug" if os.environ.get("BATTLAB_DEBUG_STEPPER") else ""
        digest = hashlib.sha256((src + debug + " ".join(CFLAGS) + _machine_tag()).encode()).hexdigest()[:20]
        lib_path = cache_dir() / f"bl_{digest}.so"
        self.generate_seconds = time.perf_counter() - t0
        t1 = time.perf_counter()
        if not lib_path.is_file():
            log.info(
                "compiling the model for cell %r (first use of this cell and mesh here; about 10-30 s, cached in %s)",
                model.cell.name,
                lib_path.parent,
            )
            _compile(units, lib_path)
        self.compile_seconds = time.perf_counter() - t1
        self.lib = ctypes.CDLL(str(lib_path))
        self.lib.bl_run.restype = _INT
        P, I_, D = ctypes.c_void_p, _INT, ctypes.c_double
        # pointers as addresses: the arrays are contiguous (float64, int32 where the C code reads int)
        self.lib.bl_run.argtypes = [P, P, I_, P, P, P, P, P, P, I_, P, P, P, I_, P, P, P, P, I_, D, I_]
        self.lib.bl_run.argtypes += [P] * 11
        self.lib.bl_adapt.restype = _INT
        self.lib.bl_adapt.argtypes = [P, P, I_, P, P, P, P, D, I_, P, P, P, P, P, P, P, P, P, I_, D, I_, P]
        self.lib.bl_adapt.argtypes += [P] * 12 + [I_, P, P, P]
        self._jth_colptr = np.ascontiguousarray(self.jth_sp.colind(), dtype=np.int32)
        self._jth_row = np.ascontiguousarray(self.jth_sp.row(), dtype=np.int32)
        self._base: OrderedDict[bytes, PivotSet] = OrderedDict()
        self._lock = threading.Lock()

    # --- LU analysis ---
    def outputs(self, y: np.ndarray, current: float, T_amb: float, th: np.ndarray) -> np.ndarray:
        """[V, T1, T2, sto_min, sto_max] at state ``y`` with ``current`` [A, + = discharge] and ``T_amb`` [K]."""
        return np.asarray(self._f["bl_out"](y, np.array([0.0, 0.0, current, T_amb]), th)).ravel()

    def analyse_at(self, y: np.ndarray, xn: np.ndarray, xp: np.ndarray, u: np.ndarray, th: np.ndarray) -> Pivots:
        """A pivot program for the Jacobian at a state (when the one in use meets a vanishing pivot)."""
        vals = np.array(self._f["bl_jac"](y, xn, xp, u, th).nonzeros())
        return self._pivots(analyse(self.jac_sp, vals))

    def base_pivots(self, th: np.ndarray) -> PivotSet:
        """The pivot programs every run at ``th`` starts from: analysed at rest at 50 % SOC and T_ref under a 1C
        discharge, for a 1 s step and a zero-length solve (a state that depends on θ̄ alone, not on earlier
        runs); cached per θ̄. Thread-safe."""
        th = np.ascontiguousarray(th, dtype=np.float64)
        key = th.tobytes()
        with self._lock:
            found = self._base.get(key)
            if found is not None:
                self._base.move_to_end(key)
                return found
        model = self.model
        x0 = initial_state(model, 0.5, th, model.T_ref)
        y = np.concatenate([x0, guess_algebraic(model, x0, 0.0)])
        q = float(model.cell["Q_nom"])
        pivots = PivotSet(
            self.analyse_at(y, x0, x0, np.array([1.0, 0.0, q, model.T_ref]), th),
            self.analyse_at(y, x0, x0, np.array([0.0, 0.0, q, model.T_ref]), th),
        )
        with self._lock:
            self._base[key] = pivots
            while len(self._base) > BASE_CACHE:
                self._base.popitem(last=False)
        return pivots

    def _pivots(self, program: LUProgram) -> Pivots:
        lay = self.model.layout
        a = program.arrays

        def p(x: np.ndarray) -> ctypes._Pointer:
            return x.ctypes.data_as(_PI)

        problem = _Problem(
            lay.ny,
            lay.nx,
            self.model.n_theta,
            program.nslot,
            p(a["prow"]),
            p(a["pcol"]),
            p(a["jac2slot"]),
            p(a["piv"]),
            p(a["lptr"]),
            p(a["lrow"]),
            p(a["lslot"]),
            p(a["uptr"]),
            p(a["uslot"]),
            p(a["upd"]),
            p(a["ucptr"]),
            p(a["ucrow"]),
            p(a["ucslot"]),
            p(self._jth_colptr),
            p(self._jth_row),
            self.jac_sp.nnz(),
            self.jth_sp.nnz(),
            lay.slices()["T2"].start,
        )
        return Pivots(problem, (*a.values(), self._jth_colptr, self._jth_row))

    def run(
        self,
        pivots: PivotSet,
        steps: StepPlan,
        samples: SamplePlan,
        th: np.ndarray,
        sel: np.ndarray,
        y: np.ndarray,
        xp: np.ndarray,
        S: np.ndarray,
        Sp: np.ndarray,
        out: np.ndarray,
        outdV: np.ndarray,
        outdT2: np.ndarray,
        limits: np.ndarray,
        tol: float = 1e-9,
        maxit: int = 20,
    ) -> tuple[int, int, int]:
        """Advance in place with the pivot programs ``pivots`` over ``steps``, writing ``samples`` from
        ``samples.next`` on (advanced in place); returns (steps done, code, Newton iterations); code 0 done, 1 sample
        ``samples.next`` broke a limit, -1 Newton failed, -2 a pivot of ``pivots.step`` vanished, -5 one of
        ``pivots.zero`` (the state is then that before the failed step), -4 no right-limit solution."""
        ns = len(sel)
        d = lambda x: np.ascontiguousarray(x, dtype=np.float64).ctypes.data  # noqa: E731
        ints = np.array([samples.next, 0, 0], dtype=np.int32)  # next sample (in/out), code, Newton iterations
        Sy = np.zeros(self.model.layout.ny * max(ns, 1))
        dense = samples.yhist is not None
        a = ints.ctypes.data
        done = self.lib.bl_run(
            ctypes.addressof(pivots.step.problem),
            ctypes.addressof(pivots.zero.problem),
            steps.h.size,
            steps.h.ctypes.data,
            steps.w.ctypes.data,
            steps.current.ctypes.data,
            steps.T_amb.ctypes.data,
            steps.t_end.ctypes.data,
            steps.emit.ctypes.data,
            samples.t.size,
            samples.t.ctypes.data,
            samples.current.ctypes.data,
            a,
            int(dense),
            samples.yhist.ctypes.data if dense else None,
            samples.Shist.ctypes.data if dense and ns else None,
            d(th),
            np.ascontiguousarray(sel, dtype=np.int32).ctypes.data,
            ns,
            tol,
            maxit,
            d(limits),
            y.ctypes.data,
            xp.ctypes.data,
            S.ctypes.data,
            Sp.ctypes.data,
            Sy.ctypes.data,
            out.ctypes.data,
            outdV.ctypes.data,
            outdT2.ctypes.data,
            a + 4,
            a + 8,
        )
        samples.next = int(ints[0])
        return int(done), int(ints[1]), int(ints[2])

    def adapt(
        self,
        pivots: PivotSet,
        segments: StepPlan,
        samples: SamplePlan,
        control: AdaptiveControl,
        th: np.ndarray,
        sel: np.ndarray,
        y: np.ndarray,
        xp: np.ndarray,
        S: np.ndarray,
        Sp: np.ndarray,
        out: np.ndarray,
        outdV: np.ndarray,
        outdT2: np.ndarray,
        limits: np.ndarray,
        tol: float = 1e-9,
        maxit: int = 20,
    ) -> tuple[int, int, int]:
        """Error-controlled steps over ``segments`` (one per stretch of constant current: h the duration, ω = 0 to
        restart, t_end its end), recording the accepted steps in ``control``; returns (segments done, code,
        Newton iterations) with the codes of :meth:`run` and -6 (``control``'s plan is full: grow it, call again)."""
        ns = len(sel)
        d = lambda x: np.ascontiguousarray(x, dtype=np.float64).ctypes.data  # noqa: E731
        ints = np.array([samples.next, 0, 0, control.n], dtype=np.int32)  # next sample, code, iterations, steps
        Sy = np.zeros(self.model.layout.ny * max(ns, 1))
        a = ints.ctypes.data
        assert samples.yhist is not None and samples.yhist.size == 3 * self.model.layout.ny
        done = self.lib.bl_adapt(
            ctypes.addressof(pivots.step.problem),
            ctypes.addressof(pivots.zero.problem),
            segments.h.size,
            segments.h.ctypes.data,
            segments.w.ctypes.data,
            segments.current.ctypes.data,
            segments.t_end.ctypes.data,
            float(segments.T_amb[0]) if segments.h.size else 298.15,
            samples.t.size,
            samples.t.ctypes.data,
            samples.current.ctypes.data,
            a,
            samples.yhist.ctypes.data,
            samples.Shist.ctypes.data if ns else None,
            control.state.ctypes.data,
            control.settings.ctypes.data,
            d(th),
            np.ascontiguousarray(sel, dtype=np.int32).ctypes.data,
            ns,
            tol,
            maxit,
            d(limits),
            y.ctypes.data,
            xp.ctypes.data,
            S.ctypes.data,
            Sp.ctypes.data,
            Sy.ctypes.data,
            out.ctypes.data,
            outdV.ctypes.data,
            outdT2.ctypes.data,
            control.h.ctypes.data,
            control.w.ctypes.data,
            control.current.ctypes.data,
            control.t_end.ctypes.data,
            control.h.size,
            a + 12,
            a + 4,
            a + 8,
        )
        samples.next = int(ints[0])
        control.n = int(ints[3])
        return int(done), int(ints[1]), int(ints[2])


def _machine_tag() -> str:
    """The CPU's identity (``-march=native`` code must not be reused on another processor)."""
    import platform

    tag = platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith(("flags", "model name")):
                tag += line
    except OSError:
        pass
    return tag


def _sources(fs: list[ca.Function]) -> list[tuple[str, str]]:
    """The library's C translation units, (name, text): one per CasADi function (each with its own prefix for
    CasADi's internal symbols) and the stepper, which declares the functions it calls. Separate units compile
    side by side: the model Jacobian alone is about 40 % of the build."""
    units = []
    for f in fs:
        cg = ca.CodeGenerator(f"{f.name()}.c", {"with_header": False, "casadi_int": "long long int"})
        cg.add(f)
        prefix = f"#define CASADI_CODEGEN_PREFIX\n#define CODEGEN_PREFIX {f.name()}_\n"
        units.append((f.name(), prefix + cg.dump()))
    declared = "".join(
        f"int {n}(const casadi_real **arg, casadi_real **res, casadi_int *iw, casadi_real *w, int mem);\n"
        f"int {n}_work(casadi_int *sz_arg, casadi_int *sz_res, casadi_int *sz_iw, casadi_int *sz_w);\n"
        for n in (f.name() for f in fs)
    )
    stepper = resources.files("battlab.model").joinpath("stepper.c").read_text()
    units.append(("bl_stepper", "#define casadi_real double\n#define casadi_int long long int\n" + declared + stepper))
    return units


def _last_line(proc: subprocess.CompletedProcess[str], cc: str) -> str:
    """The compiler's last line of complaint (or its exit code when it said nothing)."""
    lines = proc.stderr.strip().splitlines()
    return lines[-1] if lines else f"{cc} exited with code {proc.returncode}"


def _compile(units: list[tuple[str, str]], lib_path: Path) -> None:
    """Build the shared library ``lib_path`` from ``units``: each unit compiled on its own, as many at once as
    this process has cores (largest first), then linked; the library appears whole or not at all."""
    cc = shutil.which(os.environ.get("CC", "gcc")) or shutil.which("cc")
    if cc is None:
        raise NativeUnavailable("no C compiler found (set CC)")
    flags = [*CFLAGS, "-fPIC"] + (["-DBL_DEBUG"] if os.environ.get("BATTLAB_DEBUG_STEPPER") else [])
    with tempfile.TemporaryDirectory() as tmp:

        def build(unit: tuple[str, str]) -> subprocess.CompletedProcess[str]:
            name, text = unit
            c_file = Path(tmp) / f"{name}.c"
            c_file.write_text(text)
            return subprocess.run(
                [cc, *flags, "-c", "-o", str(c_file.with_suffix(".o")), str(c_file)], capture_output=True, text=True
            )

        ordered = sorted(units, key=lambda u: -len(u[1]))
        for proc in thread_map(build, ordered):
            if proc.returncode != 0:
                raise NativeUnavailable(f"C build failed: {_last_line(proc, cc)}")
        so = Path(tmp) / lib_path.name
        objects = [str(Path(tmp) / f"{name}.o") for name, _ in units]
        proc = subprocess.run([cc, *flags, "-shared", "-o", str(so), *objects, "-lm"], capture_output=True, text=True)
        if proc.returncode != 0:
            raise NativeUnavailable(f"C link failed: {_last_line(proc, cc)}")
        part = lib_path.with_name(f"{lib_path.name}.{os.getpid()}.{threading.get_ident()}.part")
        shutil.move(str(so), part)
        os.replace(part, lib_path)
