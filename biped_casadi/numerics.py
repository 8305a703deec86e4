"""Shared numerics: the one classical Runge-Kutta step, and validation of user vectors.

Every fixed-step integration of the toolkit (the reference's unactuated row, the
full-order closed loop, the zero dynamics of the Poincaré map, its variational
equation, the virtual-constraint zero dynamics) takes its steps with :func:`rk4_step`,
so the schemes are the same by construction.
"""
from __future__ import annotations

import ctypes
import errno
import functools
import hashlib
import math
import os
import subprocess
import tempfile
import threading
import warnings
from pathlib import Path

import numpy as np

from .caching import cache_dir, file_lock
from .files import name_destination

__all__ = ["rk4_step", "quintic_hermite_interval", "as_vector", "as_number", "as_count", "as_rows",
           "as_numbers",
           "jit_options",
           "compiled", "cached_library", "compiler_reason", "FastCall", "NotCompiledWarning",
           "note_not_compiled", "iteration_stop", "ipopt_solver", "ipopt_on_one_thread"]


def jit_options(optimisation: str = "-O2") -> dict:
    """CasADi options that compile a Function to machine code on first use.

    The C source and the shared object go to the system's temporary folder (and are
    removed when the Function is freed), never to the working directory.

    Parameters
    ----------
    optimisation : str
        The C compiler's optimisation flag, e.g. ``"-O1"`` (faster to compile) or
        ``"-O2"``.

    Returns
    -------
    options : dict
        Options to pass to ``casadi.Function``.
    """
    folder = tempfile.gettempdir() + os.sep
    return dict(jit=True, compiler="shell", jit_cleanup=True,
                jit_options=dict(flags=[optimisation], directory=folder, cleanup=True))


def compiled(f, flags: str = "-O2"):
    """``f`` compiled to machine code, the shared library kept in the cache folder.

    The library is named by the digest of the Function's serialisation, the flags and
    the CasADi version, so every process and every later run with an equal Function loads
    it instead of compiling again (two processes compiling the same one: the second waits
    for the first, :func:`biped_casadi.caching.file_lock`).  The C source is generated in a
    temporary folder.

    Parameters
    ----------
    f : casadi.Function or list of casadi.Function
        An SX Function (or an MX one whose calls generate code), or several: they are
        compiled into one library (one compiler run).
    flags : str
        The C compiler's optimisation flag.

    Returns
    -------
    casadi.Function or list of casadi.Function
        The compiled Function(s) (``casadi.external``), or ``f`` itself when no C compiler
        is available or the cache folder cannot be written.
    """
    import casadi as ca
    fs = list(f) if isinstance(f, (list, tuple)) else [f]
    text = "".join(g.serialize() for g in fs)
    key = hashlib.sha256((text + flags + ca.__version__).encode()).hexdigest()[:16]
    name = fs[0].name() if len(fs) == 1 else f"{fs[0].name()}_and_{len(fs) - 1}"

    def build(tmp, out):
        cg = ca.CodeGenerator(f"{name}.c", {"with_header": False})
        for g in fs:
            cg.add(g)
        c = cg.generate(tmp + os.sep)
        subprocess.run(["gcc", flags, "-fPIC", "-shared", c, "-o", out, "-lm"], check=True,
                       capture_output=True)

    try:
        so = cached_library(f"{name}_{key}.so", build)
    except (OSError, subprocess.CalledProcessError) as e:
        note_not_compiled(e)
        return f
    out = [ca.external(g.name(), str(so)) for g in fs]
    return out if isinstance(f, (list, tuple)) else out[0]


class NotCompiledWarning(UserWarning):
    """Compiled code could not be built: CasADi evaluates the Functions, more slowly.

    Raised as a warning on a full disk, a cache folder that cannot be written or a
    failing compiler (not where there is no C compiler at all)."""


_NOT_COMPILED: set = set()


def note_not_compiled(error: BaseException):
    """Warn once per process and reason that compiled code was not built.

    No warning when there is no C compiler at all (a property of the machine, see
    :func:`compiled`), only when one failed to build or the cache could not keep it.

    Parameters
    ----------
    error : OSError or subprocess.CalledProcessError
        Why the library was not built (``filename`` and ``strerror`` of
        :func:`cached_library`'s error name the library and the reason).
    """
    if isinstance(error, FileNotFoundError) and error.filename == "gcc":
        return
    reason = (f"{error.filename}: {error.strerror}" if isinstance(error, OSError)
              and error.filename and error.strerror else str(error).strip() or
              type(error).__name__)
    if reason in _NOT_COMPILED:
        return
    _NOT_COMPILED.add(reason)
    warnings.warn(f"compiled code not built ({reason}); CasADi evaluates the Functions "
                  "instead, more slowly", NotCompiledWarning, stacklevel=3)


#: threads of one process building the same library wait for each other (the cache's
#: claim tells processes apart, not threads)
_LIBRARY_LOCKS: dict = {}


def cached_library(filename: str, build):
    """A shared library in the cache folder's ``compiled/``, built once per name.

    Two processes asking for the same one: the second waits for the first
    (:func:`biped_casadi.caching.file_lock`).  The build runs in a temporary folder
    inside ``compiled/`` (its sources and its output), and the output is fsynced and
    moved into place only when complete: a failed or interrupted build (a full disk, a
    failing compiler, Ctrl-C) leaves nothing behind, never half a library a later run
    would load.

    Parameters
    ----------
    filename : str
        Its file name (a digest of what it is built from names the content).
    build : callable
        ``build(tmp, out)``: write the library to the path ``out``, a temporary folder
        ``tmp`` for the sources.

    Returns
    -------
    pathlib.Path
        The library.

    Raises
    ------
    OSError
        When the folder cannot be written or the build fails: its ``filename`` names the
        library (or the folder that cannot be made), its ``strerror`` the reason (the
        system's, or the compiler's first error line).
    """
    root = cache_dir() / "compiled"
    so = root / filename
    prefix = f".{filename}.build-"
    try:
        root.mkdir(parents=True, exist_ok=True)
        with _LIBRARY_LOCKS.setdefault(filename, threading.Lock()), file_lock(so):
            if not so.is_file():
                with tempfile.TemporaryDirectory(prefix=prefix, dir=root) as tmp:
                    out = os.path.join(tmp, filename)
                    build(tmp, out)
                    with open(out, "rb+") as fh:      # on disk before it is in place
                        os.fsync(fh.fileno())
                    os.replace(out, so)
    except subprocess.CalledProcessError as e:
        raise _BuildFailed(None, f"the C compiler failed (exit {e.returncode}): "
                                 f"{compiler_reason(e.stderr)}", str(so)) from None
    except OSError as e:
        name = Path(str(e.filename)) if e.filename is not None else None
        staged = next((p for p in ([name] + list(name.parents) if name else [])
                       if p.parent == root and p.name.startswith(prefix)), None)
        name_destination(e, so, staged)          # the library, not its staging folder
        if isinstance(e, FileExistsError) and name is not None and name.is_symlink() \
                and not name.exists():           # mkdir of a link to nowhere: not 'exists'
            e.strerror = f"a broken link (to {os.readlink(name)})"
        raise
    return so


class _BuildFailed(OSError):
    """A library of the cache that the compiler could not build (no errno of its own)."""

    def __str__(self):
        return f"{self.filename}: {self.strerror}"


def compiler_reason(stderr) -> str:
    """The line of a C compiler's error output that says why it failed.

    The system's reason when a line gives one (``/usr/bin/ld: final link failed: No
    space left on device``), else the first error line that is not the driver's
    summary (``collect2: error: ld returned 1 exit status``), else the first line.

    Parameters
    ----------
    stderr : str or bytes or None
        What the compiler wrote on its standard error.

    Returns
    -------
    str
        One line ('' for no output).
    """
    if isinstance(stderr, bytes):
        stderr = stderr.decode(errors="replace")
    lines = [ln.strip() for ln in (stderr or "").splitlines() if ln.strip()]
    for ln in lines:
        if any(r in ln for r in _SYSTEM_REASONS):
            return ln
    for ln in lines:
        if ("error" in ln.lower() or "failed" in ln) and not ln.startswith("collect2:"):
            return ln
    return next((ln for ln in lines if "error" in ln), lines[0] if lines else "")


#: the system's reasons a compiler's output may quote (the C library's wording)
_SYSTEM_REASONS = tuple(os.strerror(e) for e in (errno.ENOSPC, errno.EDQUOT, errno.EACCES,
                                                 errno.EROFS, errno.EIO, errno.EFBIG))


class FastCall:
    """A CasADi Function called on numpy arrays through its evaluation buffer.

    An ordinary call from Python converts every argument and result between numpy and
    CasADi's matrices: about 0.1 ms per call on the project's machine, more than the
    arithmetic of a small Function.  Here the inputs are copied into arrays the Function
    reads in place and the results come back as new numpy arrays (a call costs a few
    microseconds).  Every input and output must be dense (else the ordinary call is
    used); each thread has its own buffer.

    Parameters
    ----------
    f : casadi.Function
        The Function (SX, MX or external).

    Examples
    --------
    >>> import casadi as ca
    >>> x = ca.SX.sym("x", 2)
    >>> g = FastCall(ca.Function("g", [x], [2 * x, ca.sumsqr(x)]))
    >>> g([1.0, 2.0])
    [array([[2.],
           [4.]]), array([[5.]])]
    """

    def __init__(self, f):
        self.f = f
        self._in = [(f.size1_in(i), f.size2_in(i)) for i in range(f.n_in())]
        self._out = [(f.size1_out(i), f.size2_out(i)) for i in range(f.n_out())]
        self.dense = all(f.sparsity_in(i).is_dense() for i in range(f.n_in())) and \
            all(f.sparsity_out(i).is_dense() for i in range(f.n_out()))
        self._local = threading.local()

    def _buffer(self):
        b = getattr(self._local, "b", None)
        if b is None:
            buf, ev = self.f.buffer()
            args = [np.zeros(r * c) for r, c in self._in]
            for i, a in enumerate(args):
                buf.set_arg(i, memoryview(a))
            b = self._local.b = (buf, ev, args)
        return b

    def __call__(self, *args):
        """The Function's outputs at ``args`` (numbers or arrays of the inputs' shapes,
        read column by column), as 2-D numpy arrays."""
        if not self.dense:
            return [np.array(v) for v in self.f.call([np.asarray(a, float) for a in args])]
        buf, ev, ins = self._buffer()
        for a, x, (r, c) in zip(ins, args, self._in):
            x = np.asarray(x, float)
            a[:] = (x.reshape(-1, order="F") if x.ndim == 2 else x.ravel()) if x.size > 1 \
                else x.reshape(-1)
        outs = [np.empty(r * c) for r, c in self._out]
        for i, o in enumerate(outs):
            buf.set_res(i, memoryview(o))
        ev()
        return [o.reshape((r, c), order="F") for o, (r, c) in zip(outs, self._out)]


def rk4_step(f, x, h):
    """One classical fourth-order Runge-Kutta step of ``dx/dt = f(x, c)``.

    ``f(x, c)`` is the right-hand side at the stage of fraction ``c`` of the step
    (0, 1/2, 1/2 and 1), so the caller decides what a stage means: a time
    ``t + c h``, or a row of a table of coefficients tabulated at the stage times.
    Works on numbers, numpy arrays and CasADi symbols alike.

    Parameters
    ----------
    f : callable
        ``f(x, c)`` -> dx/dt, with ``c`` in {0, 0.5, 1}.
    x : array or casadi.SX / casadi.MX
        State at the start of the step.
    h : float or casadi symbol
        Step length.

    Returns
    -------
    x_next : same type as ``x``
        State after the step.
    """
    k1 = f(x, 0.0)
    k2 = f(x + h / 2 * k1, 0.5)
    k3 = f(x + h / 2 * k2, 0.5)
    k4 = f(x + h * k3, 1.0)
    return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def quintic_hermite_interval(th, h, y0, dy0, ddy0, y1, dy1, ddy1):
    """The quintic Hermite interpolant on one interval, and its two time derivatives.

    On [t_i, t_i + h] with th = (t - t_i) / h, y = sum_k c_k th^k is the quintic with the
    values and first two derivatives (y0, dy0, ddy0) at t_i and (y1, dy1, ddy1) at
    t_i + h: c0 = y0, c1 = h dy0, c2 = h^2 ddy0 / 2, and c3, c4, c5 from the conditions
    at th = 1 written on the residuals R0 = y1 - c0 - c1 - c2, R1 = h dy1 - c1 - 2 c2,
    R2 = h^2 ddy1 - 2 c2 (the difference y1 - y0 is taken first, so the derivatives keep
    every digit: a numerically inverted 6 x 6 system loses ~1e-11 on dy).  Pure
    arithmetic: numbers, numpy arrays (element-wise) and CasADi symbols alike.

    Parameters
    ----------
    th : float, array or casadi
        Position in the interval, (t - t_i) / h.
    h : float or casadi
        The interval's length.
    y0, dy0, ddy0, y1, dy1, ddy1 : float, array or casadi
        Values and derivatives at both ends.

    Returns
    -------
    tuple
        (y, dy/dt, d2y/dt2) at th.
    """
    c0, c1, c2 = y0, h * dy0, h**2 * ddy0 / 2
    R0 = y1 - c0 - c1 - c2
    R1 = h * dy1 - c1 - 2 * c2
    R2 = h**2 * ddy1 - 2 * c2
    c3 = 10 * R0 - 4 * R1 + R2 / 2
    c4 = -15 * R0 + 7 * R1 - R2
    c5 = 6 * R0 - 3 * R1 + R2 / 2
    y = c0 + th * (c1 + th * (c2 + th * (c3 + th * (c4 + th * c5))))
    dy = (c1 + th * (2 * c2 + th * (3 * c3 + th * (4 * c4 + th * 5 * c5)))) / h
    ddy = (2 * c2 + th * (6 * c3 + th * (12 * c4 + th * 20 * c5))) / h**2
    return y, dy, ddy


def as_vector(x, n: int, name: str) -> np.ndarray:
    """``x`` as a finite float vector of ``n`` components.

    Parameters
    ----------
    x : array_like
        The value given by the user.
    n : int
        Required number of components.
    name : str
        The argument's name, used in the error message.

    Returns
    -------
    numpy.ndarray
        Shape ``(n,)``, dtype float.

    Raises
    ------
    ValueError
        Naming ``name`` when the shape is wrong or a value is not finite.
    """
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be {n} numbers, got {x!r}") from None
    if a.shape != (n,):
        raise ValueError(f"{name} must have {n} components, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite, got {a.tolist()}")
    return a


def as_number(x, name: str, *, positive: bool = False, nonnegative: bool = False) -> float:
    """``x`` as a finite float (optionally > 0 or >= 0).

    Parameters
    ----------
    x : object
        The value given by the user.
    name : str
        The argument's name, used in the error message.
    positive, nonnegative : bool
        Require ``x > 0`` or ``x >= 0``.

    Returns
    -------
    float

    Raises
    ------
    ValueError
        Naming ``name`` when ``x`` is not a finite number in the required range.
    """
    if isinstance(x, bool) or not isinstance(x, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a number, got {x!r}")
    v = float(x)
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {x!r}")
    if positive and not v > 0:
        raise ValueError(f"{name} must be positive, got {x!r}")
    if nonnegative and not v >= 0:
        raise ValueError(f"{name} must be non-negative, got {x!r}")
    return v


def as_count(x, name: str, low: int = 1) -> int:
    """``x`` as an integer of at least ``low`` (numpy integers too; not bools or floats).

    Parameters
    ----------
    x : object
        The value given by the user.
    name : str
        The argument's name, used in the error message.
    low : int
        The least value allowed.

    Returns
    -------
    int

    Raises
    ------
    ValueError
        Naming ``name`` when ``x`` is not an integer >= ``low``.
    """
    if isinstance(x, bool) or not isinstance(x, (int, np.integer)) or x < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {x!r}")
    return int(x)


def as_rows(x, width: int, name: str) -> np.ndarray:
    """``x`` as finite rows of ``width`` numbers: one row ``(width,)`` or ``(n, width)``.

    Parameters
    ----------
    x : array_like
        The value given by the user.
    width : int
        Numbers per row.
    name : str
        The argument's name, used in the error message.

    Returns
    -------
    numpy.ndarray
        Shape (n, width), dtype float.

    Raises
    ------
    ValueError
        Naming ``name`` when it is not numbers, has another shape (a column) or is not
        finite.
    """
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be numbers, ({width},) or (n, {width})") from None
    if a.ndim not in (1, 2) or a.shape[-1] != width or a.size == 0:
        raise ValueError(f"{name} must be ({width},) or (n, {width}), got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite")
    return np.atleast_2d(a)


def as_numbers(x, name: str) -> np.ndarray:
    """``x`` (a number or an array of numbers, any shape) as floats; words are refused.

    ``numpy.asarray("0.1", dtype=float)`` parses the text: a user's string would pass.

    Parameters
    ----------
    x : object
        The value given by the user.
    name : str
        The argument's name, used in the error message.

    Returns
    -------
    numpy.ndarray
        dtype float, the shape of ``x``.

    Raises
    ------
    ValueError
        Naming ``name`` when ``x`` holds text, None or other objects.
    """
    a = np.asarray(x)
    if a.dtype.kind not in "biuf" and not (a.dtype == object and a.size and all(
            isinstance(v, (int, float, np.number)) and not isinstance(v, bool) for v in a.flat)):
        raise ValueError(f"{name} must be a number or an array of numbers, got {x!r:.60}")
    return np.asarray(a, dtype=float)


def iteration_stop(name: str, nx: int, ng: int, stop):
    """An IPOPT iteration callback that ends the search when ``stop`` says so.

    For CasADi's ``iteration_callback`` option.  CasADi keeps only a weak reference to it: the caller keeps the object alive for the
    solve.

    Parameters
    ----------
    name : str
        The callback Function's name.
    nx, ng : int
        The NLP's variables and constraints.
    stop : callable
        ``stop(g)`` with the constraint values of an iterate (a NumPy vector): True to
        end the search (IPOPT's 'User_Requested_Stop').

    Returns
    -------
    casadi.Callback
    """
    import casadi as ca

    class _Stop(ca.Callback):
        def __init__(self):
            ca.Callback.__init__(self)
            self.construct(name, {})

        def get_n_in(self):
            return ca.nlpsol_n_out()

        def get_n_out(self):
            return 1

        def get_name_in(self, i):
            return ca.nlpsol_out(i)

        def get_name_out(self, i):
            return "stop"

        def get_sparsity_in(self, i):
            n = {"f": 1, "x": nx, "lam_x": nx, "g": ng, "lam_g": ng}.get(ca.nlpsol_out(i))
            return ca.Sparsity(0, 0) if n is None else ca.Sparsity.dense(n)

        def eval(self, arg):
            return [1 if stop(np.array(arg[2]).ravel()) else 0]

    return _Stop()


def ipopt_solver(name: str, problem: dict, options: dict):
    """CasADi's IPOPT on ``problem``, its linear algebra on one thread.

    MUMPS factorises with the OpenBLAS that CasADi ships, whose threads default to the
    cores (or ``OMP_NUM_THREADS``): the same solve ended 1e-4 apart on two threads and
    on one (a Dask worker's nanny sets one).  One thread makes a solve's numbers the same
    in this process, on any machine and on any worker.

    Parameters
    ----------
    name : str
        The solver Function's name.
    problem, options : dict
        ``casadi.nlpsol``'s problem and options.

    Returns
    -------
    casadi.Function
    """
    import casadi as ca
    ipopt_on_one_thread()
    return ca.nlpsol(name, "ipopt", problem, options)


@functools.cache
def ipopt_on_one_thread() -> None:
    """Load CasADi's IPOPT and put its OpenBLAS on one thread, for this process.

    :func:`ipopt_solver` calls it; a ``casadi.Opti`` solved with IPOPT calls it first.
    """
    import casadi as ca
    ca.load_nlpsol("ipopt")        # loads IPOPT and the OpenBLAS it links
    try:                           # found by its name, not loaded again
        ctypes.CDLL("libcasadi-tp-openblas.so.0").openblas_set_num_threads(1)
    except (OSError, AttributeError):     # another platform's build: no such library
        pass
