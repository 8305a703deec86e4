"""The gait sensitivity norm (Hobbelen & Wisse, T-RO 2007), exactly.

The step-to-step map of the full-order closed loop, linearised at the periodic walk on
flat ground (:mod:`analysis.stability.step_map`, exact Jacobians by AD),

    ds_(k+1) = A ds_k + B e_k,      dg_k = C ds_k + D e_k,

with e_k a disturbance of step k (the ground height h_k, m, or a horizontal push P_k on
the torso at the step's start, N s) and g_k the step's indicators (step time, s, and
step length, m).  For disturbances i.i.d. with unit variance the indicators' stationary
covariance is C X C' + D D' with X = A X A' + B B' (a discrete Lyapunov equation); the
gait sensitivity norm of a disturbance is the 2-norm of that response,

    GSN = sqrt(trace(C X C' + D D')),

and each indicator's own part is the square root of its diagonal entry: on ground of
standard deviation sigma, ``sigma * gsn[ground_height][step_time]`` is the RMS deviation
of the step time (:func:`predicted_rms` also gives the transient from the periodic
walk).  Hobbelen & Wisse take the same norm by finite differences of a simulator; here
every Jacobian is exact.

The map is linearised at the periodic walk itself, on flat ground (h = 0), so that the
eigenvalues of A are the step map's at its fixed point: for the time-varying controller
its two non-zero ones are those of A^z (:func:`analysis.poincare_eigenvalues`), for
virtual constraints its one non-zero one is :func:`analysis.vc_eigenvalue`, to the two
discretisations' accuracy (RABBIT: 1e-9 against A^z on a finer grid; TALOS and JVRC-1:
1.4e-8 and 2.8e-8 against ``biped eig``'s default variational A^z, 5.8e-9 against its
``--method ad`` on JVRC-1).  Linearising anywhere else moves
them: where the law is sensitive, by a lot (TALOS's gait at 0.5 m/s under M1 = [-2.5,
7.5, -5, 2.5]: max |eigenvalue| 0.6177 at h = 0, 0.6084 at h = 10 µm, a slope of about
-950 per m).  The periodic walk strikes on a node of the RK4 grid (at tau = T), so the
strike lands on one side of it or the other by round-off.  The two sides' first
derivatives agree (within 5e-8 relative on RABBIT's gaits with 800 RK4 steps, h = +-1e-9
m); their second derivatives do not where the reference continues past T with a jump in
its third derivative or the virtual constraints have a knot at the impact phase, so
central differences of the simulator across the node are accurate to the step times
that jump only (RABBIT's robust gait, steps of 1e-6 m: 1.5e-5 relative, against 1e-8
away from the node; ``tests/test_terrain.py`` checks them there).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from biped_casadi.results import Result, internal

from ..stability.step_map import DISTURBANCES, INDICATORS, StepLinearisation, step_map

__all__ = ["GaitSensitivity", "gait_sensitivity", "gsn_of", "predicted_rms"]


@dataclass
class GaitSensitivity(Result):
    """The gait sensitivity norm of a controller (module docstring).

    ``success`` means it was computed; ``status`` is 'stable', or 'unstable' (spectral
    radius >= 1: the norm is infinite).

    Parameters
    ----------
    gsn : dict
        Disturbance ('ground_height' per m, 'torso_push' per N s) -> {'step_time': s per
        unit, 'step_length': m per unit, 'total': the norm}.
    spectral_radius : float
        max ``|eigenvalue|`` of A at the periodic walk (module docstring: that of A^z, or
        the virtual constraints' eigenvalue).
    eigenvalues : list
        The largest eigenvalues of A ([re, im] pairs, by decreasing magnitude).
    step_time, step_length : float
        The periodic walk's, s and m.
    fixed_point_residual : float
        ``max |S(s*) - s*|``.
    status : str
        'stable' or 'unstable'.
    message : str
        In words.
    linearisation : StepLinearisation
        A, B, C, D (left out of ``to_dict()``).
    """

    gsn: dict
    spectral_radius: float
    eigenvalues: list
    step_time: float
    step_length: float
    fixed_point_residual: float
    status: str
    message: str = ""
    linearisation: StepLinearisation = internal(default=None)

    SUCCESS = ("stable", "unstable")


def _stationary(A, BB):
    from scipy.linalg import solve_discrete_lyapunov
    return solve_discrete_lyapunov(A, BB)


def gsn_of(lin: StepLinearisation) -> dict:
    """The gait sensitivity norms of a linearised step map.

    Parameters
    ----------
    lin : StepLinearisation
        A, B, C, D.

    Returns
    -------
    dict
        Disturbance -> {indicator: RMS response per unit disturbance, 'total': the
        norm}; inf everywhere when A is not stable.
    """
    out = {}
    stable = lin.spectral_radius < 1
    for j, name in enumerate(lin.disturbances):
        if not stable:
            out[name] = {**{i: math.inf for i in lin.indicators}, "total": math.inf}
            continue
        b, d = lin.B[:, j:j + 1], lin.D[:, j:j + 1]
        X = _stationary(lin.A, b @ b.T)
        cov = lin.C @ X @ lin.C.T + d @ d.T
        out[name] = {i: float(np.sqrt(max(cov[k, k], 0.0))) for k, i in enumerate(lin.indicators)}
        out[name]["total"] = float(np.sqrt(max(np.trace(cov), 0.0)))
    return out


def predicted_rms(lin: StepLinearisation, sigma: float, steps: int, transient: int = 0,
                  disturbance: str = "ground_height", indicator: str = "step_time") -> float:
    """The predicted RMS deviation of an indicator on walks from the periodic walk.

    Over steps ``transient..steps-1``, with disturbances of standard deviation
    ``sigma``.

    The covariance of the state follows X_(k+1) = A X_k A' + sigma^2 b b' from X_0 = 0;
    step k's indicator has variance c X_k c' + sigma^2 d^2.

    Parameters
    ----------
    lin : StepLinearisation
        The linearised map.
    sigma : float
        Standard deviation of the disturbance.
    steps : int
        Steps walked.
    transient : int
        First step counted.
    disturbance, indicator : str
        Which column and row.

    Returns
    -------
    float
        The predicted RMS.
    """
    j, i = lin.disturbances.index(disturbance), lin.indicators.index(indicator)
    b, d, c = lin.B[:, j:j + 1], float(lin.D[i, j]), lin.C[i:i + 1]
    X = np.zeros_like(lin.A)
    var = []
    for k in range(steps):
        if k >= transient:
            var.append((c @ X @ c.T).item() + d * d)
        X = lin.A @ X @ lin.A.T + b @ b.T
    return float(sigma * np.sqrt(np.mean(var))) if var else math.nan


def gait_sensitivity(controller, options=None, plant=None) -> GaitSensitivity:
    """The exact gait sensitivity norm of a controller's full-order closed loop.

    Parameters
    ----------
    controller : Design, TimeVaryingController or VirtualConstraintController
        The control law (any controller of the law interface).
    options : SimulationOptions, optional
        The simulator's (its ``rk4_steps`` fix the discrete map).
    plant : BipedModel, optional
        The robot that moves (model error; default the controller's model).

    Returns
    -------
    GaitSensitivity
    """
    sm = step_map(controller, options, plant)
    fp = sm.fixed_point()
    lin = sm.linearise(fp.state)
    norms = gsn_of(lin)
    rho = lin.spectral_radius
    status = "stable" if rho < 1 else "unstable"
    ev = [[float(e.real), float(e.imag)] for e in lin.eigenvalues[:3]]
    g = norms[DISTURBANCES[0]]
    msg = (f"GSN (ground height): step time {g[INDICATORS[0]]:.4g} s/m, step length "
           f"{g[INDICATORS[1]]:.4g} m/m; (torso push): "
           f"{norms[DISTURBANCES[1]]['total']:.4g} per N s; spectral radius {rho:.4g}")
    return GaitSensitivity(gsn=norms, spectral_radius=rho, eigenvalues=ev,
                           step_time=fp.step_time, step_length=fp.step_length,
                           fixed_point_residual=fp.residual, status=status, message=msg,
                           linearisation=lin)
