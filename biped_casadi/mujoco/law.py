"""The control law a MuJoCo run calls: the C code of ``biped export`` compiled once and
kept in the cache, or the same law evaluated in Python.

The C library is the export of :mod:`biped_casadi.control.export` (the same files
``biped export`` writes) built with ``gcc -O2 -shared -fPIC`` into the cache folder's
``compiled/``, named by the digest of the generated sources: a design is compiled once
per machine, and another export (a changed gait, gains, code generator) gets a library of
its own.
"""
from __future__ import annotations

from pathlib import Path

from ..caching import digest
from ..control.compiled import (CompiledController, CompilerError, PythonTwin,
                                build_library, find_c_compiler)
from ..control.design import Design
from ..control.export import c_sources, exported_law
from ..numerics import cached_library

__all__ = ["LAWS", "control_law", "compiled_law"]

#: the laws a run may call: the exported C code, or the same law in Python
LAWS = ("c", "python")


def compiled_law(design: Design, exported=None) -> Path:
    """The shared library of a design's exported C law, built once and cached.

    Parameters
    ----------
    design : Design
        The design on its gait.
    exported : ExportedLaw, optional
        Its :func:`~biped_casadi.control.export.exported_law` when already made.

    Returns
    -------
    Path
        ``compiled/mujoco-law-<digest>.so`` in the cache folder.

    Raises
    ------
    CompilerError
        No C compiler, or the build failed (naming the library).
    OSError
        The cache folder cannot be written (naming the library or the folder).
    """
    law = exported if exported is not None else exported_law(design)
    files = c_sources(law)
    sources = {k: v for k, v in files.items() if k.endswith((".c", ".h")) and "/" not in k}

    filename = f"mujoco-law-{digest(sources)[:24]}.so"

    def build(tmp, out):
        for name, text in sources.items():
            (Path(tmp) / name).write_text(text, encoding="utf-8")
        try:
            build_library(tmp, out)
        except CompilerError as e:          # a failed compilation names the library
            if find_c_compiler() is None:
                raise
            raise CompilerError(f"{Path(tmp).parent / filename}: {e}") from None

    return cached_library(filename, build)


def control_law(design: Design, law: str = "c"):
    """The numeric law a run calls: the compiled export, or its Python twin.

    Parameters
    ----------
    design : Design
        The design on its gait.
    law : {'c', 'python'}
        'c': the exported C code through ctypes (:func:`compiled_law`); 'python': the
        same law evaluated by CasADi from Python, one state at a time
        (:class:`~biped_casadi.control.compiled.PythonTwin`).

    Returns
    -------
    CompiledController or PythonTwin
        With ``step_start(q, dq)`` and ``torque(tau, q, dq, p) -> (code, u)``.

    Raises
    ------
    ValueError
        Naming ``law`` when it is neither, ``controller`` for a design singular on its
        gait.
    """
    if law not in LAWS:
        raise ValueError(f"law must be one of {', '.join(LAWS)}, got {law!r}")
    ctrl = design.controller_for()
    exported = exported_law(ctrl)
    if law == "python":
        return PythonTwin(ctrl, exported)
    return CompiledController(compiled_law(design, exported), ctrl)
