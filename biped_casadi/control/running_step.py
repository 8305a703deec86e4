"""The RK4 step a running controller's gains allow.

Near the reference the law's output error e = M (q^d - q) obeys, frozen at a state of the
reference, dd e = -A (Kp e + Kd de) (torques B u through D ddq = B u: A = M D^-1 B in
stance, Me De^-1 Be in flight, the extended coordinates; A = I for the computed torque).
RK4 with step h multiplies a mode of rate lambda by P(h lambda) = 1 + z + z^2/2 + z^3/6
+ z^4/24 each step: where |P| > 1 at a reference node the error grows by that factor a
step whatever the state, and the run diverges (Kp = 1e300 in stance: a state not finite
after one step).  :func:`check_rk4_steps` refuses such gains before a run, naming the
gain and the largest that the step supports with the other kept.
"""
from __future__ import annotations

import numpy as np

__all__ = ["check_rk4_steps", "rk4_growth"]

#: |P| above this is growth (round-off of stable modes on the region's edge stays below)
_GROWTH = 1.0 + 1e-9


def _output_matrices(controller, phase: str) -> list:
    """A at the reference's nodes of a phase (the module docstring)."""
    c, m, nu = controller, controller.model, controller.model.nu
    if c.law == "computed_torque":
        return [np.eye(nu)]
    X = np.asarray(getattr(c.gait, f"x_{phase}"), dtype=float)
    n = X.shape[0] // 2
    D = m.D if phase == "stance" else c.fl.De
    B = np.asarray(m.B if phase == "stance" else c.fl.Be, dtype=float)
    M = np.hstack([c.M, np.zeros((nu, n - m.nq))])
    return [M @ np.linalg.solve(np.asarray(D(x[:n]), dtype=float), B) for x in X.T]


def rk4_growth(matrices, h: float, Kp, Kd) -> float:
    """The largest |P(h lambda)| of the frozen output error dynamics (module docstring).

    Parameters
    ----------
    matrices : list of numpy.ndarray
        A at the reference's nodes, (nu, nu) each.
    h : float
        The RK4 step, s.
    Kp, Kd : array_like
        (nu,) the gains.

    Returns
    -------
    float
        Above 1: RK4 amplifies the output error by that factor a step.
    """
    Kp, Kd = np.asarray(Kp, dtype=float), np.asarray(Kd, dtype=float)
    worst = 0.0
    with np.errstate(all="ignore"):
        for A in matrices:
            nu = A.shape[0]
            C = np.block([[np.zeros((nu, nu)), np.eye(nu)], [-A * Kp, -A * Kd]])
            if not np.all(np.isfinite(C)):
                return np.inf
            z = h * np.linalg.eigvals(C)
            worst = max(worst, float(np.max(np.abs(1 + z * (1 + z / 2 * (1 + z / 3 * (
                1 + z / 4)))))))
    return worst


def _largest(matrices, h: float, gains: dict, name: str) -> float | None:
    """The largest scale of gain ``name`` (the other kept) whose RK4 does not diverge, as
    its largest entry; None when no positive value does."""
    def grows(scale):
        g = dict(gains, **{name: gains[name] * scale})
        return rk4_growth(matrices, h, g["Kp"], g["Kd"]) > _GROWTH

    lo, hi = -300.0, 0.0                             # log10 of the scale
    if grows(10.0**lo):
        return None
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if grows(10.0**mid) else (mid, hi)
    return float(np.max(gains[name]) * 10.0**lo)


def check_rk4_steps(controller, steps: dict) -> None:
    """Refuse gains whose output error RK4 amplifies at a phase's step (module docstring).

    Parameters
    ----------
    controller : RunningController
        The law and its gains.
    steps : dict
        The RK4 step of each phase, s: ``{'stance': h_st, 'flight': h_fl}``.

    Raises
    ------
    ValueError
        One line naming the phase, the step, the gain and the largest it supports.
    """
    c = controller
    gains = dict(Kp=np.asarray(c.Kp, dtype=float), Kd=np.asarray(c.Kd, dtype=float))
    for phase, h in steps.items():
        A = _output_matrices(c, phase)
        growth = rk4_growth(A, h, gains["Kp"], gains["Kd"])
        if not growth > _GROWTH:
            continue
        bounds = [(n, _largest(A, h, gains, n)) for n in ("Kp", "Kd") if np.max(gains[n]) > 0]
        bounds = [(n, b) for n, b in bounds if b is not None]
        now = ", ".join(f"{n} {np.max(g):g}" for n, g in gains.items())
        if bounds:           # the gain that needs the smallest change
            name, top = max(bounds, key=lambda nb: nb[1] / np.max(gains[nb[0]]))
            fix = f"{name} at most {top:.3g} with the other kept"
        else:
            fix = "neither gain at this size: lower both"
        raise ValueError(
            f"the gains ({now}) make the {phase}'s output error grow "
            + (f"by {growth:.3g} each" if np.isfinite(growth) else "without bound at an")
            + f" RK4 step of {h:.3g} s (the run would diverge): the step supports {fix}")
