"""The RK4 step a running controller's gains allow.

Near the reference the law's output error e = M (q^d - q) obeys, frozen at a state of the
reference, dd e = -A (Kp e + Kd de) (torques B u through D ddq = B u: A = M D^-1 B in
stance, Me De^-1 Be in flight, the extended coordinates; A = I for the computed torque).
RK4 with step h multiplies a mode of rate lambda by P(h lambda) = 1 + z + z^2/2 + z^3/6
+ z^4/24 each step, where the flow multiplies it by e^z: where |P| > max(1, |e^z|) at a
reference node RK4 makes the error grow, by that factor a step, whatever the state, and
the run diverges (Kp = 1e300 in stance: a state not finite after one step).  A mode that
grows in the flow itself (an output whose A has a negative eigenvalue, as a large M1
gives in flight) is the law's, not the step's: RK4 follows it (|P| = e^z to round-off
for small z) and it is not refused.  :func:`check_rk4_steps` refuses such gains before a run, naming the
gain and the largest that the step supports with the other kept.

Before a step is optimised, its nodes are unknown, but its RK4 steps are bounded below
(the shortest phase the optimisation allows over its intervals and RK4 steps), and
RK4's stability region lies within :data:`RK4_REACH` of 0.  With scalar gains the modes
of a node are the roots of s^2 + Kd a s + Kp a = 0 over the eigenvalues a of A: one has
``|s|`` >= sqrt(Kp rho) and one ``|s|`` >= Kd rho / 2, rho the spectral radius of A.
:func:`rk4_gain_bounds` gives the gains beyond which, at every step from h on, a mode
leaves the region at every configuration of the robot (rho at least half its smallest
over configurations spread over the joints' range; exactly 1 for the computed torque):
such gains fail the check whatever step is optimised.
"""
from __future__ import annotations

import numpy as np

from ..model import flight_model

__all__ = ["check_rk4_steps", "rk4_growth", "rk4_gain_bounds", "RK4_REACH"]

#: |P| above this is growth (round-off of stable modes on the region's edge stays below)
_GROWTH = 1.0 + 1e-9


#: ``|P(z)|`` <= 1 implies ``|z|`` <= this: RK4's stability region lies within it (its
#: farthest points, 2.9601..., are on the lobes beside the imaginary axis; rounded up)
RK4_REACH = 2.961

#: configurations over which :func:`rk4_gain_bounds` takes the smallest spectral radius
_CONFIGURATIONS = 2000


def _matrices(model, fl, M, law: str, phase: str, Q) -> list:
    """A at the configurations Q (a column each: q in stance, qe in flight)."""
    nu = model.nu
    if law == "computed_torque":
        return [np.eye(nu)]
    D = model.D if phase == "stance" else fl.De
    B = np.asarray(model.B if phase == "stance" else fl.Be, dtype=float)
    Me = np.hstack([M, np.zeros((nu, Q.shape[0] - model.nq))])
    return [Me @ np.linalg.solve(np.asarray(D(q), dtype=float), B) for q in Q.T]


def _output_matrices(controller, phase: str) -> list:
    """A at the reference's nodes of a phase (the module docstring)."""
    c = controller
    X = np.asarray(getattr(c.gait, f"x_{phase}"), dtype=float)
    return _matrices(c.model, c.fl, c.M, c.law, phase, X[:X.shape[0] // 2])


def rk4_gain_bounds(model, phase: str, h: float, law: str = "pd", M1=None) -> tuple:
    """Scalar gains beyond which RK4 amplifies a phase's output error at every step from
    ``h`` on, whatever the reference (module docstring).

    Parameters
    ----------
    model : BipedModel
        The robot.
    phase : {'stance', 'flight'}
    h : float
        The smallest step, s.
    law : {'pd', 'computed_torque'}
    M1 : array_like, optional
        (nu,) the output's column on q1 (default zeros).

    Returns
    -------
    (float, float)
        Kp beyond the first, or Kd beyond the second (the other whatever it is), fail
        :func:`check_rk4_steps` at any step of at least ``h``.
    """
    nu, nq = model.nu, model.nq
    M = np.hstack([np.zeros((nu, 1)) if M1 is None else np.reshape(M1, (nu, 1)),
                   np.eye(nu)])
    fl = flight_model(model)
    Q = np.random.default_rng(0).uniform(-np.pi, np.pi, (nq if phase == "stance" else fl.ne,
                                                         _CONFIGURATIONS))
    rho = 1.0 if law == "computed_torque" else 0.5 * min(
        float(np.max(np.abs(np.linalg.eigvals(A)))) for A in _matrices(model, fl, M, law,
                                                                        phase, Q))
    return (RK4_REACH / h) ** 2 / rho, 2 * RK4_REACH / (h * rho)


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
        The largest ``|P(z)| / max(1, |e^z|)`` over the modes z = h lambda: above 1, RK4
        makes the output error grow by that factor a step beyond what the frozen dynamics
        does.
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
            p = np.abs(1 + z * (1 + z / 2 * (1 + z / 3 * (1 + z / 4))))
            worst = max(worst, float(np.max(p / np.maximum(1.0, np.exp(z.real)))))
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
