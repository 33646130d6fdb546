"""The compiled model's library: CasADi generates C for the step residual and its Jacobians (:func:`functions`), gcc
builds it with ``stepper.c`` into one shared library (:func:`library`), cached on disk under ``$BATTLAB_CACHE``
(default ``~/.cache/battlab``) by a hash of the generated source.

A fit that changes θ̄ never recompiles (θ̄ is an input) and cells whose differences do not reach the equations share
one library; the values the equilibrium, thermal and Arrhenius fits move (the electrode moles through ε_s±, the area,
the heat capacities and transfer coefficients, the activation energies: :data:`battlab.parameters.MODEL_INPUTS`) are
inputs too, passed after θ̄. A small index file maps what the source is
made from (the cell's values except θ̄ and those inputs, mesh, options, the model's source files, CasADi's version,
compiler flags, processor) to that library, so a process that meets a known model loads it without generating the
code again.
"""

from __future__ import annotations

import functools
import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import casadi as ca

from battlab import parameters
from battlab.model.dfn import DFN
from battlab.threads import thread_map

log = logging.getLogger("battlab.model")


@dataclass(frozen=True)
class Library:
    """A built (or found) library and what this process spent on it [s]."""

    path: Path
    generate_seconds: float = 0.0
    compile_seconds: float = 0.0


def library(model: DFN) -> Library:
    """The shared library of ``model``: the one its index names, else the code generated and, when that code is new,
    compiled (:class:`NativeUnavailable` when it cannot be)."""
    index = cache_dir() / f"key_{_fingerprint(model)}"
    found = _indexed(index)
    if found is not None:
        return Library(found)
    t0 = time.perf_counter()
    units = _sources(functions(model))
    digest = hashlib.sha256("\n".join(text for _, text in units).encode()).hexdigest()[:24]
    lib_path = cache_dir() / f"bl_{digest}.so"
    generated = time.perf_counter() - t0
    compiled = 0.0
    if not lib_path.is_file():
        log.info(
            "compiling the model for cell %r (first use of this cell and mesh; about 10-30 s, cached in %s)",
            model.cell.name,
            lib_path.parent,
        )
        _compile(units, lib_path)
        compiled = time.perf_counter() - t0 - generated
    _write_atomic(index, lib_path.name)
    return Library(lib_path, generated, compiled)


#: the library is built on (and cached for) this machine, so it may use its instruction set
CFLAGS = ("-O3", "-march=native")


class NativeUnavailable(RuntimeError):
    """No C compiler, or the build failed: the caller falls back to the CasADi stepper."""


def cache_dir() -> Path:
    d = Path(os.environ.get("BATTLAB_CACHE", Path.home() / ".cache" / "battlab"))
    d.mkdir(parents=True, exist_ok=True)
    return d


def functions(model: DFN) -> list[ca.Function]:
    """The CasADi functions the stepper calls (see ``stepper.c``), with θ̄ and then the model's inputs as ``th``."""
    lay = model.layout
    nx, ny = lay.nx, lay.ny
    y = ca.SX.sym("y", ny)
    xn = ca.SX.sym("xn", nx)
    xp = ca.SX.sym("xp", nx)
    u = ca.SX.sym("u", 4)
    th = ca.SX.sym("th", model.n_theta)
    given = ca.SX.sym("inputs", len(parameters.MODEL_INPUTS))  # the cell values the model takes as inputs
    h, w = u[0], u[1]
    eq = model.equations(y, u[2], u[3], th, given)
    gamma = (1 + w) / (1 + 2 * w)
    psi = (1 + w) ** 2 / (1 + 2 * w) * xn - w**2 / (1 + 2 * w) * xp
    R = ca.vertcat(y[:nx] - psi - gamma * h * eq["f"], eq["g"])
    Jy = ca.jacobian(R, y)
    Jth = ca.jacobian(R, th)
    sto = eq["sto_surf"]
    o = ca.vertcat(eq["V"], eq["T1"], eq["T2"], ca.mmin(sto), ca.mmax(sto))
    cse = {"cse": True}  # common subexpressions once: the Jacobians' code a third smaller, faster to build and run
    # the C functions' "th" is θ̄ followed by the inputs (the stepper passes it through; derivatives are θ̄'s only)
    th_in = ca.vertcat(th, given)
    fs = [
        ca.Function("bl_res", [y, xn, xp, u, th_in], [R], cse),
        ca.Function("bl_jac", [y, xn, xp, u, th_in], [Jy, Jth], cse),
        ca.Function("bl_g", [y, u, th_in], [eq["g"]], cse),
        ca.Function("bl_out", [y, u, th_in], [o], cse),
        ca.Function(
            "bl_outj", [y, u, th_in], [ca.densify(ca.jacobian(eq["V"], y)), ca.densify(ca.jacobian(eq["V"], th))], cse
        ),
    ]
    return fs


def _fingerprint(model: DFN) -> str:
    """What the library is built from: the cell's values except θ̄ and the model's other inputs (and which extensions
    are on), the mesh, the option set, the source of the model and its code generation, CasADi's version, compiler
    flags, processor."""
    h = hashlib.sha256()
    for part in (
        model.cell.structure_hash(),
        repr(model.mesh),
        repr(model.options),
        ca.__version__,
        " ".join((*CFLAGS, *_debug_flags())),
        _machine_tag(),
        _source_digest(),
    ):
        h.update(part.encode() + b"\0")
    return h.hexdigest()[:24]


def _indexed(index: Path) -> Path | None:
    """The library an index file names, if both are there."""
    try:
        lib = index.with_name(index.read_text().strip())
    except OSError:
        return None
    return lib if lib.name.startswith("bl_") and lib.is_file() else None


def _write_atomic(path: Path, text: str) -> None:
    part = path.with_name(f"{path.name}.{os.getpid()}.{threading.get_ident()}.part")
    part.write_text(text)
    os.replace(part, path)


@functools.cache
def _source_digest() -> str:
    """SHA-256 of every source file of the package (the generated code depends on the model, the cell, its function
    expressions, the parameter specifications and the causes' extension submodels; hashing them all cannot miss a
    new dependency, and a changed file costs one code generation, not a compile, when the code comes out the
    same)."""
    root = Path(__file__).resolve().parents[1]
    files = sorted(root.rglob("*.py")) + sorted(root.rglob("*.c"))
    h = hashlib.sha256()
    for f in files:
        h.update(str(f.relative_to(root)).encode() + b"\0" + f.read_bytes())
    return h.hexdigest()


def _debug_flags() -> list[str]:
    """Diagnostic builds: ``BATTLAB_DEBUG_STEPPER`` prints Newton's iterations, ``BATTLAB_PROFILE_STEPPER`` counts
    the calls and cycles of each kind of work (``NativeStepper.profile``)."""
    return [
        f
        for env, f in (("BATTLAB_DEBUG_STEPPER", "-DBL_DEBUG"), ("BATTLAB_PROFILE_STEPPER", "-DBL_PROFILE"))
        if os.environ.get(env)
    ]


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


#: tanh through exp: glibc's tanh goes through expm1, about three times the cost of exp, and the open-circuit
#: potentials are sums of tanh terms (about a fifth of a residual's time). Exact to 2e-16 absolute (the terms are
#: scaled and added to volts); ±1 at overflow.
FAST_TANH = """#include <math.h>
static inline double bl_tanh(double x) { return 1.0 - 2.0 / (exp(2.0 * x) + 1.0); }
#define tanh(x) bl_tanh(x)
"""


def _sources(fs: list[ca.Function]) -> list[tuple[str, str]]:
    """The library's C translation units, (name, text): one per CasADi function (each with its own prefix for
    CasADi's internal symbols, tanh as :data:`FAST_TANH`) and the stepper, which declares the functions it calls.
    Separate units compile side by side: the model Jacobian alone is about 40 % of the build."""
    units = []
    for f in fs:
        cg = ca.CodeGenerator(f"{f.name()}.c", {"with_header": False, "casadi_int": "long long int"})
        cg.add(f)
        prefix = f"#define CASADI_CODEGEN_PREFIX\n#define CODEGEN_PREFIX {f.name()}_\n"
        code = cg.dump()
        if "#include <math.h>\n" not in code:
            raise NativeUnavailable("CasADi's generated code no longer includes math.h where expected")
        units.append((f.name(), prefix + code.replace("#include <math.h>\n", FAST_TANH, 1)))
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
    flags = [*CFLAGS, "-fPIC", *_debug_flags()]
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
