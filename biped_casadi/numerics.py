"""Shared numerics: the one classical Runge-Kutta step, and validation of user vectors.

Every fixed-step integration of the toolkit (the reference's unactuated row, the
full-order closed loop, the zero dynamics of the Poincaré map, its variational
equation, the virtual-constraint zero dynamics) takes its steps with :func:`rk4_step`,
so the schemes are the same by construction.
"""
from __future__ import annotations

import hashlib
import math
import os
import subprocess
import tempfile

import numpy as np

__all__ = ["rk4_step", "as_vector", "as_number", "jit_options", "compiled",
           "cached_library"]


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
    for the first, :func:`biped_casadi.caching.claimed`).  The C source is generated in a
    temporary folder.

    Parameters
    ----------
    f : casadi.Function
        An SX Function.
    flags : str
        The C compiler's optimisation flag.

    Returns
    -------
    casadi.Function
        The compiled Function (``casadi.external``), or ``f`` itself when no C compiler
        is available or the cache folder cannot be written.
    """
    import casadi as ca
    key = hashlib.sha256((f.serialize() + flags + ca.__version__).encode()).hexdigest()[:16]

    def build(tmp, out):
        cg = ca.CodeGenerator(f"{f.name()}.c", {"with_header": False})
        cg.add(f)
        c = cg.generate(tmp + os.sep)
        subprocess.run(["gcc", flags, "-fPIC", "-shared", c, "-o", out, "-lm"], check=True,
                       capture_output=True)

    try:
        so = cached_library(f"{f.name()}_{key}.so", build)
    except (OSError, subprocess.CalledProcessError):
        return f
    return ca.external(f.name(), str(so))


def cached_library(filename: str, build):
    """A shared library in the cache folder's ``compiled/``, built once per name.

    Two processes asking for the same one: the second waits for the first
    (:func:`biped_casadi.caching.claimed`); the library appears atomically.

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
    OSError, subprocess.CalledProcessError
        When the folder cannot be written or the build fails.
    """
    from .caching import cache_dir, claimed
    root = cache_dir() / "compiled"
    so = root / filename
    root.mkdir(parents=True, exist_ok=True)
    with claimed(so):
        if not so.is_file():
            with tempfile.TemporaryDirectory() as tmp:
                out = str(so) + f".tmp{os.getpid()}"
                build(tmp, out)
                os.replace(out, so)
    return so


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
