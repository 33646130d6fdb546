"""The compiled time stepper: ``stepper.c`` runs Newton, a static-pivot sparse LU and the sensitivity solves on the
functions CasADi generates, all in one shared library (:mod:`battlab.model.build` makes and caches it); what Python
needs of the functions (sparsity, a Jacobian for the pivot order) comes from the library itself.

The LU program: the pivot order comes from SuperLU (COLAMD columns, partial pivoting) on the Jacobian at a
representative state; the fill pattern of that order is computed symbolically, and the numeric factorisation
replays it (as KLU's refactorisation does). A pivot that vanishes later is reported, and the caller re-analyses.
Pivot programs are values (:class:`Pivots`): every run starts from the one of a fixed state that depends only on
θ̄ (:meth:`NativeStepper.base_pivots`), and a re-analysis belongs to the run that needed it, so a result never
depends on what ran before it in the process.
"""

from __future__ import annotations

import ctypes
import threading
from collections import OrderedDict
from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from battlab.model.build import library
from battlab.model.dfn import DFN
from battlab.model.plans import AdaptiveControl, SamplePlan, StepPlan
from battlab.model.state import guess_algebraic, initial_state

_INT = ctypes.c_int
_PI = ctypes.POINTER(ctypes.c_int)
_PD = ctypes.POINTER(ctypes.c_double)


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
        ("gx_colptr", _PI),
        ("gx_row", _PI),
        ("gx_nnz", _INT),
        ("gz_at", _PI),
        ("gx_at", _PI),
        ("gth_at", _PI),
        ("jac_kind", _PI),
    ]


@dataclass(frozen=True)
class Block:
    """A block of a sparse Jacobian as a CCS matrix of its own: column pointers, rows (within the block), and the
    position of each of its nonzeros among the whole matrix's."""

    colptr: np.ndarray
    row: np.ndarray
    at: np.ndarray

    @classmethod
    def of(cls, sp: ca.Sparsity, rows: range, cols: range) -> Block:
        colind, row = np.array(sp.colind()), np.array(sp.row())
        col = np.repeat(np.arange(sp.size2()), np.diff(colind))
        keep = (row >= rows.start) & (row < rows.stop) & (col >= cols.start) & (col < cols.stop)
        at = np.flatnonzero(keep)  # CCS order: by column, then row, as the block's own
        counts = np.bincount(col[keep] - cols.start, minlength=len(cols))
        i32 = lambda a: np.ascontiguousarray(a, dtype=np.int32)  # noqa: E731
        return cls(i32(np.concatenate([[0], np.cumsum(counts)])), i32(row[keep] - rows.start), i32(at))

    def sparsity(self, n_rows: int) -> ca.Sparsity:
        return ca.Sparsity(n_rows, self.colptr.size - 1, self.colptr.tolist(), self.row.tolist())


@dataclass(frozen=True)
class Patterns:
    """Sparsity of the Jacobians the stepper reads: the step's dR/dy and dR/dθ̄, and in them the algebraic block's
    dg/dz, dg/dx and dg/dθ̄ (zero-length solves: the algebraic rows do not depend on h)."""

    jac: ca.Sparsity
    jth: ca.Sparsity
    gz: Block
    gx: Block
    gth: Block

    #: per nonzero of dR/dy: 0 an algebraic row, 1 a differential row off the diagonal, 2 on it (``jac_scaled``)
    jac_kind: np.ndarray

    @classmethod
    def of(cls, jac: ca.Sparsity, jth: ca.Sparsity, nx: int) -> Patterns:
        ny, nth = jac.size1(), jth.size2()
        g = range(nx, ny)
        row = np.array(jac.row())
        col = np.repeat(np.arange(ny), np.diff(np.array(jac.colind())))
        kind = np.where(row >= nx, 0, np.where(row == col, 2, 1))
        return cls(
            jac,
            jth,
            Block.of(jac, g, range(nx, ny)),
            Block.of(jac, g, range(nx)),
            Block.of(jth, g, range(nth)),
            np.ascontiguousarray(kind, dtype=np.int32),
        )


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
    """The pivot programs of a run: ``step`` for steps with h > 0 (all unknowns), ``zero`` for zero-length solves
    (the consistent start and the right limits at current changes: the algebraic block dg/dz alone)."""

    step: Pivots
    zero: Pivots

    def replace(self, *, step: Pivots | None = None, zero: Pivots | None = None) -> PivotSet:
        return PivotSet(step or self.step, zero or self.zero)


#: base pivot programs kept per stepper (one per θ̄: a fit visits many)
BASE_CACHE = 8


class NativeStepper:
    """A compiled model: ``run`` advances a schedule of steps and writes the samples' outputs."""

    def __init__(self, model: DFN) -> None:
        self.model = model
        built = library(model)
        self.generate_seconds, self.compile_seconds = built.generate_seconds, built.compile_seconds
        self.lib = ctypes.CDLL(str(built.path))
        self.patterns = Patterns.of(_sparsity(self.lib, "bl_jac", 0), _sparsity(self.lib, "bl_jac", 1), model.layout.nx)
        self.lib.bl_run.restype = _INT
        P, I_, D = ctypes.c_void_p, _INT, ctypes.c_double
        # pointers as addresses: the arrays are contiguous (float64, int32 where the C code reads int)
        self.lib.bl_run.argtypes = [P, P, I_, P, P, P, P, P, P, I_, P, P, P, I_, P, P, P, P, I_, D, I_]
        self.lib.bl_run.argtypes += [P] * 11
        self.lib.bl_adapt.restype = _INT
        self.lib.bl_adapt.argtypes = [P, P, I_, P, P, P, P, D, I_, P, P, P, P, P, P, P, P, P, I_, D, I_, P]
        self.lib.bl_adapt.argtypes += [P] * 12 + [I_, P, P, P]
        pat = self.patterns
        self._jth = tuple(np.ascontiguousarray(a, dtype=np.int32) for a in (pat.jth.colind(), pat.jth.row()))
        self._base: OrderedDict[bytes, PivotSet] = OrderedDict()
        self._lock = threading.Lock()
        self._inputs = model.input_values()

    def _with_inputs(self, th: np.ndarray) -> np.ndarray:
        """θ̄ followed by this cell's values of the model's inputs: what the C functions take as ``th``."""
        return np.ascontiguousarray(np.concatenate([np.asarray(th, np.float64), self._inputs]))

    def profile(self) -> dict[str, tuple[int, float]] | None:
        """Calls and CPU cycles per kind of work since the last call (a ``BATTLAB_PROFILE_STEPPER`` build), else
        None."""
        fn = getattr(self.lib, "bl_profile", None)
        if fn is None:
            return None
        kinds = (
            "residual",
            "jacobian",
            "jacobian_with_theta",
            "algebraic_residual",
            "output",
            "output_jacobian",
            "factor",
            "solve",
            "solve_multi",
        )
        buf = np.zeros(2 * len(kinds))
        fn(buf.ctypes.data_as(_PD))
        return {k: (int(buf[2 * i]), float(buf[2 * i + 1])) for i, k in enumerate(kinds)}

    # --- LU analysis ---
    def outputs(self, y: np.ndarray, current: float, T_amb: float, th: np.ndarray) -> np.ndarray:
        """[V, T1, T2, sto_min, sto_max] at state ``y`` with ``current`` [A, + = discharge] and ``T_amb`` [K]."""
        return _call(self.lib, "bl_out", [y, np.array([0.0, 0.0, current, T_amb]), self._with_inputs(th)])[0]

    def jacobian(self, y: np.ndarray, xn: np.ndarray, xp: np.ndarray, u: np.ndarray, th: np.ndarray) -> np.ndarray:
        """The nonzeros of the step Jacobian dR/dy (CCS, ``patterns.jac``) at a state, u = [h, ω, I_dis, T_amb]."""
        return _call(self.lib, "bl_jac", [y, xn, xp, u, self._with_inputs(th)])[0]

    def analyse_at(self, y: np.ndarray, xn: np.ndarray, xp: np.ndarray, u: np.ndarray, th: np.ndarray) -> Pivots:
        """A pivot program for the step Jacobian at a state (when the one in use meets a vanishing pivot)."""
        return self._pivots(analyse(self.patterns.jac, self.jacobian(y, xn, xp, u, th)), zero=False)

    def analyse_zero_at(self, y: np.ndarray, u: np.ndarray, th: np.ndarray) -> Pivots:
        """A pivot program for the algebraic block dg/dz at a state (zero-length solves; ``u[0]`` = h = 0)."""
        x = y[: self.model.layout.nx]
        vals = self.jacobian(y, x, x, u, th)[self.patterns.gz.at]
        return self._pivots(analyse(self.patterns.gz.sparsity(self.model.layout.nz), vals), zero=True)

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
            self.analyse_zero_at(y, np.array([0.0, 0.0, q, model.T_ref]), th),
        )
        with self._lock:
            self._base[key] = pivots
            while len(self._base) > BASE_CACHE:
                self._base.popitem(last=False)
        return pivots

    def _pivots(self, program: LUProgram, zero: bool) -> Pivots:
        """The C problem of a pivot program: of the step (all ny unknowns) or of zero-length solves (the nz algebraic
        ones)."""
        lay = self.model.layout
        a = program.arrays
        pat = self.patterns
        th_colptr, th_row = (pat.gth.colptr, pat.gth.row) if zero else self._jth

        def p(x: np.ndarray) -> ctypes._Pointer:
            return x.ctypes.data_as(_PI)

        problem = _Problem(
            lay.nz if zero else lay.ny,
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
            p(th_colptr),
            p(th_row),
            pat.gz.at.size if zero else pat.jac.nnz(),
            int(th_row.size),
            lay.slices()["T2"].start,
            p(pat.gx.colptr),
            p(pat.gx.row),
            int(pat.gx.row.size),
            p(pat.gz.at),
            p(pat.gx.at),
            p(pat.gth.at),
            p(pat.jac_kind),
        )
        return Pivots(problem, (*a.values(), th_colptr, th_row))

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
        th, sel, limits = self._with_inputs(th), np.ascontiguousarray(sel, dtype=np.int32), _f64(limits)
        ints = np.array([samples.next, 0, 0], dtype=np.int32)  # next sample (in/out), code, Newton iterations
        Sy = np.zeros(self.model.layout.ny * max(ns, 1))
        dense = samples.yhist is not None
        a = _addr(ints)
        done = self.lib.bl_run(
            ctypes.addressof(pivots.step.problem),
            ctypes.addressof(pivots.zero.problem),
            steps.h.size,
            _addr(steps.h),
            _addr(steps.w),
            _addr(steps.current),
            _addr(steps.T_amb),
            _addr(steps.t_end),
            _addr(steps.emit),
            samples.t.size,
            _addr(samples.t),
            _addr(samples.current),
            a,
            int(dense),
            _addr(samples.yhist) if dense else None,
            _addr(samples.Shist) if dense and ns else None,
            _addr(th),
            _addr(sel),
            ns,
            tol,
            maxit,
            _addr(limits),
            *(_addr(a) for a in (y, xp, S, Sp, Sy, out, outdV, outdT2)),
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
        th, sel, limits = self._with_inputs(th), np.ascontiguousarray(sel, dtype=np.int32), _f64(limits)
        ints = np.array([samples.next, 0, 0, control.n], dtype=np.int32)  # next sample, code, iterations, steps
        Sy = np.zeros(self.model.layout.ny * max(ns, 1))
        a = _addr(ints)
        assert samples.yhist is not None and samples.yhist.size == 3 * self.model.layout.ny
        done = self.lib.bl_adapt(
            ctypes.addressof(pivots.step.problem),
            ctypes.addressof(pivots.zero.problem),
            segments.h.size,
            _addr(segments.h),
            _addr(segments.w),
            _addr(segments.current),
            _addr(segments.t_end),
            float(segments.T_amb[0]) if segments.h.size else 298.15,
            samples.t.size,
            _addr(samples.t),
            _addr(samples.current),
            a,
            _addr(samples.yhist),
            _addr(samples.Shist) if ns else None,
            _addr(control.state),
            _addr(control.settings),
            _addr(th),
            _addr(sel),
            ns,
            tol,
            maxit,
            _addr(limits),
            *(_addr(a) for a in (y, xp, S, Sp, Sy, out, outdV, outdT2)),
            _addr(control.h),
            _addr(control.w),
            _addr(control.current),
            _addr(control.t_end),
            control.h.size,
            a + 12,
            a + 4,
            a + 8,
        )
        samples.next = int(ints[0])
        control.n = int(ints[3])
        return int(done), int(ints[1]), int(ints[2])


_LL = ctypes.c_longlong  # casadi_int in the generated code


def _sparsity(lib: ctypes.CDLL, name: str, i: int) -> ca.Sparsity:
    """Output ``i``'s sparsity of a generated function, from the library (CasADi's compressed form: rows, columns,
    then 1 for dense or the column pointers and rows)."""
    fn = getattr(lib, f"{name}_sparsity_out")
    fn.restype, fn.argtypes = ctypes.POINTER(_LL), [_LL]
    p = fn(i)
    n_row, n_col = int(p[0]), int(p[1])
    if p[2] == 1:  # dense (a sparse pattern's column pointers start at 0)
        return ca.Sparsity.dense(n_row, n_col)
    colind = [int(p[2 + k]) for k in range(n_col + 1)]
    row = [int(p[3 + n_col + k]) for k in range(colind[-1])]
    return ca.Sparsity(n_row, n_col, colind, row)


def _call(lib: ctypes.CDLL, name: str, inputs: list[np.ndarray]) -> list[np.ndarray]:
    """Evaluate a generated function of the library (its C interface): the nonzeros of each output."""
    fn, work = getattr(lib, name), getattr(lib, f"{name}_work")
    n_out = getattr(lib, f"{name}_n_out")
    n_out.restype = _LL
    sizes = [_LL() for _ in range(4)]
    work(*(ctypes.byref(s) for s in sizes))
    n_arg, n_res, n_iw, n_w = (max(int(s.value), 1) for s in sizes)
    args = [_f64(np.ravel(a)) for a in inputs]
    outs = [np.zeros(_sparsity(lib, name, i).nnz()) for i in range(int(n_out()))]
    arg = (ctypes.c_void_p * n_arg)(*(_addr(a) for a in args))
    res = (ctypes.c_void_p * n_res)(*(_addr(o) for o in outs))
    iw, w = np.zeros(n_iw, dtype=np.int64), np.zeros(n_w)
    if fn(arg, res, ctypes.c_void_p(_addr(iw)), ctypes.c_void_p(_addr(w)), 0):
        raise RuntimeError(f"compiled model: {name} failed")
    return outs


def _addr(a: np.ndarray) -> int:
    """The address of a contiguous array's data (``ndarray.ctypes.data`` costs about 10 µs a call)."""
    return a.__array_interface__["data"][0]


def _f64(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)
