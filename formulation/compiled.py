"""Batched evaluation of a CasADi stencil function over many stencils, as compiled C.

CasADi generates C for the stencil function; a small driver loops over the stencils; the C compiler
(``$CC``, default ``cc``) builds a shared library, cached under ``$SAGFREE_CACHE`` (default
``~/.cache/sagfree``) by a hash of the source, and ctypes calls it on numpy arrays without copies.
On the reference machine this is about 40x faster than CasADi's virtual machine (0.8 us against 35 us
per bend/twist stencil with its parameter Jacobian).

The library is built for this machine's instruction set (``MACHINE_FLAGS``: ``-march=native`` with
``-ffp-contract=off``): the generated code is long chains of scalar operations, and the VEX
encodings alone made a 100-vertex strand's stressed bend/twist Hessian 1.35x faster. Without
contraction into fused multiply-adds every operation rounds as in a portable build, so results are
the same bits on every machine. The cache key holds the CPU's identity, so a cache shared between
different machines (a home directory on a cluster) never loads a library built for another
instruction set; a compiler that refuses the flags gets the portable build.

When no compiler works, or ``SAGFREE_NO_COMPILE=1``, the same function is evaluated by CasADi's
``map`` (identical results, slower) after a one-time warning.

Inputs are arrays of shape (N, size_k); outputs are (N,) for scalars, (N, rows) for vectors and
(N, rows, cols) for matrices.
"""
from __future__ import annotations

import contextlib
import ctypes
import functools
import hashlib
import os
import platform
import signal
import subprocess
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

_DRIVER = """
#include <stddef.h>
int {name}(const double** arg, double** res, long long int* iw, double* w, int mem);
static const long long int {name}_batch_in_nnz[{n_in}] = {{{in_sizes}}};
static const long long int {name}_batch_out_nnz[{n_out}] = {{{out_sizes}}};
void {name}_batch(long long int count, const double** inputs, double** outputs) {{
  double w[{sz_w} + 1];
  long long int iw[{sz_iw} + 1];
  const double* arg[{sz_arg}];
  double* res[{sz_res}];
  for (long long int a = 0; a < {sz_arg}; ++a) arg[a] = NULL;
  for (long long int r = 0; r < {sz_res}; ++r) res[r] = NULL;
  for (long long int k = 0; k < count; ++k) {{
    for (long long int a = 0; a < {n_in}; ++a) arg[a] = inputs[a] + k * {name}_batch_in_nnz[a];
    for (long long int r = 0; r < {n_out}; ++r) res[r] = outputs[r] + k * {name}_batch_out_nnz[r];
    {name}(arg, res, iw, w, 0);
  }}
}}
"""


def cache_dir() -> Path:
    return Path(os.environ.get("SAGFREE_CACHE", Path.home() / ".cache" / "sagfree"))


def generated_c(functions: list[ca.Function]) -> str:
    """CasADi's C code of all ``functions`` in one file (each exported under its own name)."""
    with tempfile.TemporaryDirectory() as tmp:
        generator = ca.CodeGenerator("generated.c", {"with_header": False, "casadi_int": "long long int"})
        for function in functions:
            generator.add(function)
        generator.generate(tmp + os.sep)
        return Path(tmp, "generated.c").read_text()


def _source(functions: list[ca.Function]) -> str:
    """Generated C of all ``functions`` plus one batch driver per function."""
    source = generated_c(functions)
    sizes = lambda fn, n: ", ".join(str(fn(k)) for k in range(n))  # noqa: E731
    for f in functions:
        source += _DRIVER.format(
            name=f.name(), n_in=f.n_in(), n_out=f.n_out(), in_sizes=sizes(f.nnz_in, f.n_in()),
            out_sizes=sizes(f.nnz_out, f.n_out()), sz_w=f.sz_w(), sz_iw=f.sz_iw(), sz_arg=f.sz_arg(),
            sz_res=f.sz_res())
    return source


@dataclass
class _Build:
    """A compiler run started by this process: ``start_compiling`` in the background, or
    ``compile_library`` in the foreground (which waits for it at once)."""

    process: subprocess.Popen
    directory: tempfile.TemporaryDirectory
    built: Path
    library: Path
    portable: list[str]  # the command without MACHINE_FLAGS, run if the compiler refuses them

    def finish(self) -> Path:
        """Wait for the compiler and move the library into the cache (atomic: concurrent processes
        never load a half-written file); OSError with the compiler's messages if it failed."""
        try:
            try:
                _, errors = self.process.communicate(timeout=600)
            except subprocess.TimeoutExpired:
                self.process.kill()
                raise OSError(f"{os.environ.get('CC', 'cc')} took over 600 s") from None
            if self.process.returncode != 0:  # the compiler may not know MACHINE_FLAGS: the portable build
                portable = subprocess.run(self.portable, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                          text=True, timeout=600)
                if portable.returncode != 0:
                    raise OSError(f"{os.environ.get('CC', 'cc')} failed: {portable.stderr.strip()[-2000:]}")
            os.replace(self.built, self.library)
        finally:
            self.directory.cleanup()
        return self.library


#: (library path, process id) -> its build; keyed by process so that a forked child never waits for,
#: nor cleans up after, a compiler its parent started
_BUILDS: dict[tuple[Path, int], _Build] = {}


#: Flags that build for this machine's instruction set with portable rounding (module docstring).
MACHINE_FLAGS = ("-march=native", "-ffp-contract=off")


@functools.cache
def cpu_identity() -> str:
    """What the native build depends on: the CPU's model and feature flags (Linux), else the
    platform's processor and architecture names."""
    try:
        with open("/proc/cpuinfo") as f:
            lines = [line for line in f if line.startswith(("model name", "flags", "Features", "CPU part"))]
        if lines:
            return "".join(sorted(set(lines)))
    except OSError:
        pass
    return f"{platform.machine()} {platform.processor()}"


def _library(source: str, stem: str, optimization: str = "-O2") -> Path:
    key = "\0".join([source, optimization, *MACHINE_FLAGS, cpu_identity()])
    return cache_dir() / f"{stem}_{hashlib.sha256(key.encode()).hexdigest()[:24]}.so"


def start_compiling(source: str, stem: str = "stencils", optimization: str = "-O2", background: bool = True) -> None:
    """Start building the library of ``source`` (a compiler process, no thread); in the
    ``background`` at lower priority, so that it overlaps other work (``builds_paused`` stops it
    during timed batches). ``compile_library`` of the same source then waits for it. A no-op if the
    library is cached or this process is already building it."""
    library = _library(source, stem, optimization)
    if library.exists() or (library, os.getpid()) in _BUILDS:
        return
    library.parent.mkdir(parents=True, exist_ok=True)
    directory = tempfile.TemporaryDirectory(dir=library.parent)
    c_file, built = Path(directory.name, "generated.c"), Path(directory.name, "generated.so")
    c_file.write_text(source)
    portable = [os.environ.get("CC", "cc"), optimization, "-fPIC", "-shared", "-o", str(built), str(c_file), "-lm"]
    process = subprocess.Popen(portable[:2] + list(MACHINE_FLAGS) + portable[2:], stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE, text=True,
                               preexec_fn=(lambda: os.nice(10)) if background else None)
    _BUILDS[library, os.getpid()] = _Build(process, directory, built, library, portable)


@contextlib.contextmanager
def builds_paused():
    """Background builds of this process stopped (SIGSTOP) inside, continued after: a timed batch
    must not share the cores with a compiler, or its times depend on whether this was a first run."""
    running = [b.process for (_, pid), b in _BUILDS.items() if pid == os.getpid() and b.process.poll() is None]
    for process in running:
        process.send_signal(signal.SIGSTOP)
    try:
        yield
    finally:
        for process in running:
            if process.poll() is None:
                process.send_signal(signal.SIGCONT)


def compile_library(source: str, stem: str = "stencils", optimization: str = "-O2") -> Path:
    """Build (or reuse) the shared library for the C ``source``, cached as ``{stem}_{hash}.so``
    (waiting for a build ``start_compiling`` began in this process); raises OSError."""
    start_compiling(source, stem, optimization, background=False)
    build = _BUILDS.pop((_library(source, stem, optimization), os.getpid()), None)
    return build.finish() if build is not None else _library(source, stem, optimization)


_warned = False


def batch_functions(functions: list[ca.Function]) -> list["BatchFunction"]:
    """Compile ``functions`` into one shared library (one compiler run) and wrap each for batches."""
    global _warned
    for f in functions:
        for k in range(f.n_out()):
            if f.nnz_out(k) != f.numel_out(k):
                raise ValueError(f"output {k} of {f.name()} must be dense")
    drivers = [None] * len(functions)
    if os.environ.get("SAGFREE_NO_COMPILE") != "1":
        try:
            library = ctypes.CDLL(str(compile_library(_source(functions))))
            drivers = [getattr(library, f"{f.name()}_batch") for f in functions]
        except (OSError, subprocess.SubprocessError) as exc:
            if not _warned:
                _warned = True
                warnings.warn(f"sagfree: compiling stencil functions failed ({exc}); using CasADi's "
                              "virtual machine, which is correct but about 40x slower. Install a C "
                              "compiler (or set CC) for full speed.", RuntimeWarning, stacklevel=2)
    return [BatchFunction(f, d) for f, d in zip(functions, drivers)]


class BatchFunction:
    """Evaluate ``function`` over N stencils through its compiled ``driver``, or CasADi's map."""

    def __init__(self, function: ca.Function, driver=None):
        self.function = function
        self._in_sizes = [function.nnz_in(k) for k in range(function.n_in())]
        self._out_shapes = [function.size_out(k) for k in range(function.n_out())]
        #: each output's entries per stencil (its nonzeros: the stencil functions' outputs are dense)
        self.out_sizes = tuple(function.nnz_out(k) for k in range(function.n_out()))
        self._driver = driver
        if driver is not None:
            driver.restype = None
        self._pointer_types = (ctypes.c_void_p * len(self._in_sizes), ctypes.c_void_p * len(self._out_shapes))

    @property
    def compiled(self) -> bool:
        return self._driver is not None

    @functools.cached_property
    def address(self) -> int:
        """The compiled batch driver's address, for numba code to call (at_rest.call_driver):
        driver(long long count, const double** inputs, double** outputs). An integer, where a ctypes
        function object cost numba ~3 us to unbox at every call."""
        if self._driver is None:
            raise RuntimeError(f"{self.function.name()} is not compiled")
        return int(ctypes.cast(self._driver, ctypes.c_void_p).value)

    def __call__(self, *inputs: np.ndarray) -> list[np.ndarray]:
        count = len(inputs[0])
        arrays = [np.ascontiguousarray(a, dtype=np.float64).reshape(count, size)
                  for a, size in zip(inputs, self._in_sizes)]
        if not count:
            outputs = [np.empty((0, r * c)) for r, c in self._out_shapes]
        elif self._driver is not None:
            outputs = [np.empty((count, r * c)) for r, c in self._out_shapes]
            in_type, out_type = self._pointer_types
            self._driver(ctypes.c_longlong(count), in_type(*[_address(a) for a in arrays]),
                         out_type(*[_address(a) for a in outputs]))
        else:
            mapped = self.function.map(count, "serial")
            results = mapped.call([a.T for a in arrays])
            outputs = [np.asarray(o).T.reshape(count, -1) for o in results]
        return [_shaped(o, r, c) for o, (r, c) in zip(outputs, self._out_shapes)]


def _address(array: np.ndarray) -> int:
    """The data address of a C-contiguous array: through the buffer protocol (3x cheaper than
    ``array.ctypes.data``, which dominated a stencil call's overhead), or ctypes for read-only ones."""
    try:
        return ctypes.addressof(ctypes.c_char.from_buffer(array))
    except (TypeError, ValueError):
        return array.ctypes.data


def _shaped(flat: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """(N, rows*cols) column-major blocks as (N,), (N, rows) or (N, rows, cols)."""
    if rows == 1 and cols == 1:
        return flat[:, 0]
    if cols == 1:
        return flat
    return flat.reshape(len(flat), cols, rows).transpose(0, 2, 1)
