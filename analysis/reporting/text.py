"""Results as short texts, one place for each, shared by the command line and the viewer:
the eigenvalues of A^z and max|lambda| as ``biped eig`` prints them, and how a run walked
(its status and the step ``biped simulate`` names)."""
from __future__ import annotations

import math

__all__ = ["EIG_DIGITS", "number_text", "eigenvalues_text", "walk_text"]

#: significant digits of every eigenvalue and max|lambda| shown
EIG_DIGITS = 8


def number_text(x: float) -> str:
    """A real number with :data:`EIG_DIGITS` significant digits ('inf', 'nan' as such).

    Parameters
    ----------
    x : float
        The number (max|lambda|, an eigenvalue of the virtual constraints' map).

    Returns
    -------
    str
    """
    return f"{x:.{EIG_DIGITS}g}"


def eigenvalues_text(eigenvalues) -> str:
    """Complex eigenvalues as ``re+imj``, comma separated, as ``biped eig`` prints them.

    Each part has :data:`EIG_DIGITS` significant digits.

    Parameters
    ----------
    eigenvalues : sequence of complex
        The eigenvalues of A^z.

    Returns
    -------
    str
    """
    return ", ".join(f"{e.real:.{EIG_DIGITS}g}{e.imag:+.{EIG_DIGITS}g}j" for e in eigenvalues)


def walk_text(res) -> str:
    """How a run walked, in one line.

    ``ok: 10 of 10 steps valid, final error 1.3e-05``, or the status of its first invalid
    state and the simulator's message, which names the step counted from 1 (step 1 is
    the first, row 1 of ``biped simulate``'s table): ``slipped: step 6: ...``.

    Parameters
    ----------
    res : WalkOutcome
        A run (:class:`~biped_casadi.simulation.SimulationResult`).

    Returns
    -------
    str
    """
    if res.status != "ok":
        return f"{res.status}: {res.message}" if res.message else res.status
    err = res.final_error
    tail = f", final error {err:.2g}" if math.isfinite(err) else ""
    return f"ok: {res.n_steps} of {res.n_steps} steps valid{tail}"
