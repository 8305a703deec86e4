"""The feet of a running step above their bounds between the collocation points.

The running step's NLP (:mod:`gait_opt.running`) bounds the feet at its points: in
stance the swing foot above the clearance profile ``clearance 4 s (1 - s)`` (s = t / Ts),
in flight both feet above the ground (the pushing foot from the first point after
takeoff, the landing foot up to the last point before touchdown).  Between the points
the Hermite-Simpson interpolant of the state can dip below: ODRI's Bolt at 1 m/s pushed
its foot 5.5e-5 m into the ground in the first flight interval (the foot leaves the
ground at rest, at zero acceleration, and its midpoint rides the bound), and passed its
swing foot 2.5 mm below the profile mid-stance.

:func:`foot_dips` finds each interval's deepest dip on the dense grid of the checks
(:func:`gait_opt.running_checks.dense`: 20 samples per interval), located more finely
around its sample; :func:`clearance_rows` bounds that foot in the NLP at the dense
grid's samples of every interval of that phase and at the dip's time (the interpolant
is a function of the interval's points), and
:func:`gait_opt.running_solve.within_path_limits` solves the step again from the one
found, in the loop that lowers a torque's bound.  A step without a dip adds no row.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from biped_casadi.control.running import phase_derivatives
from biped_casadi.model import flight_model

__all__ = ["hermite_simpson", "foot_heights", "foot_dips", "clearance_rows", "FOOT_TOL",
           "DENSE"]

#: a foot at most this below its bound, m, holds it (``RunningReport.violations``' tol)
FOOT_TOL = 1e-7
#: dense samples per Hermite-Simpson interval (the checks')
DENSE = 20
#: finer samples between a dip's two neighbouring dense samples
REFINE = 40
#: the foot bounds: (phase, foot) -> the name a dip is given
FEET = {("stance", "swing"): "swing foot above the clearance profile in stance",
        ("flight", "stance"): "pushing foot above the ground in flight",
        ("flight", "swing"): "landing foot above the ground in flight"}


def hermite_simpson(t_nodes, X, F, U, t):
    """The Hermite-Simpson interpolant of a collocated phase at times ``t``.

    On each interval the state is the cubic whose derivative is the quadratic through
    the dynamics at the ends and the midpoint (Kelly 2017, eq. 4.10); the torque is the
    quadratic through its three values.

    Parameters
    ----------
    t_nodes : array_like
        (2 n + 1,) times of the ends and midpoints, s (even indices: interval ends).
    X, F, U : array_like
        (nx, 2 n + 1) states, their time derivatives and (nu, 2 n + 1) torques there.
    t : array_like
        Times in [t_nodes[0], t_nodes[-1]], s.

    Returns
    -------
    tuple of numpy.ndarray
        (x, u): (nx, len(t)) and (nu, len(t)).
    """
    tn, X, F, U = (np.asarray(a, dtype=float) for a in (t_nodes, X, F, U))
    t = np.atleast_1d(np.asarray(t, dtype=float))
    n = (tn.size - 1) // 2
    k = np.clip(np.searchsorted(tn[::2], t, side="right") - 1, 0, n - 1)
    i0 = 2 * k
    h = tn[i0 + 2] - tn[i0]
    tau = t - tn[i0]
    s = tau / h
    f0, fm, f1 = F[:, i0], F[:, i0 + 1], F[:, i0 + 2]
    x = (X[:, i0] + f0 * tau + 0.5 * (-3 * f0 + 4 * fm - f1) * tau * s
         + (2 * f0 - 4 * fm + 2 * f1) / 3 * tau * s * s)
    u0, um, u1 = U[:, i0], U[:, i0 + 1], U[:, i0 + 2]
    u = u0 * (1 - s) * (1 - 2 * s) + um * 4 * s * (1 - s) + u1 * s * (2 * s - 1)
    return x, u


def foot_heights(model, opts, phase: str, x, frac) -> dict:
    """The feet's heights above their bounds in one phase (>= 0: the bound holds).

    Parameters
    ----------
    model : BipedModel
        The robot.
    opts : RunningOptions
        The problem (``clearance``, filled in by ``for_model``).
    phase : str
        'stance' (x = (q, dq)) or 'flight' (x = (qe, dqe)).
    x : numpy.ndarray or casadi.MX
        States as columns.
    frac : numpy.ndarray
        Each column's time as a fraction of the phase (the stance profile's s).

    Returns
    -------
    dict
        foot ('swing' in stance; 'stance' and 'swing' in flight) -> heights less the
        bound, m, a row of ``x``'s columns.
    """
    N = x.shape[1]
    if phase == "stance":
        _, z = model.swing_foot.map(N)(x[:model.nq, :])
        s = np.asarray(frac, dtype=float).reshape(1, -1)
        return {"swing": z - ca.DM(opts.clearance * 4 * s * (1 - s))}
    fl = flight_model(model)
    feet = fl.feet.map(N)(x[:fl.ne, :])            # 2 x 2N: (stance, swing) pairs
    return {"stance": feet[1, 0::2], "swing": feet[1, 1::2]}


def _gait_phase(model, gait, phase):
    """(times of the points, X, F, U) of one phase of a running step."""
    t, X, U = ((gait.t_stance, gait.x_stance, gait.u_stance) if phase == "stance" else
               (gait.t_flight, gait.x_flight, gait.u_flight))
    return t, X, phase_derivatives(model, phase, X, U), U


def foot_dips(model, gait, per_interval: int = DENSE, tol: float = FOOT_TOL) -> list:
    """Where a running step's feet dip below their bounds between its points.

    On every interval of each phase: the smallest height above the bound
    (:func:`foot_heights`) at the dense grid's samples inside it (its ends are points,
    bounded by the NLP), then at :data:`REFINE` samples between that sample's
    neighbours, on the Hermite-Simpson interpolant (:func:`hermite_simpson`, the
    dynamics of the checks).

    Parameters
    ----------
    model : BipedModel
        The robot.
    gait : RunningGait
        The step.
    per_interval : int
        Dense samples per interval.
    tol : float
        Dips at most this deep, m, are not counted.

    Returns
    -------
    list of dict
        One per interval and foot that dips deeper than ``tol``: ``phase``, ``foot``
        (the bound's name), ``interval`` (0-based), ``s`` (the deepest sample's fraction
        of the interval) and ``depth`` (m below the bound there).
    """
    out, opts = [], gait.options
    for phase in ("stance", "flight"):
        tn, X, F, U = _gait_phase(model, gait, phase)
        n, T = (tn.size - 1) // 2, tn[-1]
        t = np.linspace(tn[0], T, per_interval * n + 1)
        x, _ = hermite_simpson(tn, X, F, U, t)
        for foot, h in foot_heights(model, opts, phase, x, t / T).items():
            h = np.array(h).ravel().reshape(-1)
            for k in range(n):
                inner = h[k * per_interval + 1:(k + 1) * per_interval]
                j = int(np.argmin(inner)) + 1
                if -inner[j - 1] <= tol:
                    continue
                s = np.linspace(j - 1, j + 1, REFINE + 1) / per_interval
                tk = tn[2 * k] + s * (tn[2 * k + 2] - tn[2 * k])
                xk, _ = hermite_simpson(tn, X, F, U, tk)
                hk = np.array(foot_heights(model, opts, phase, xk, tk / T)[foot]).ravel()
                i = int(np.argmin(hk))
                out.append(dict(phase=phase, foot=FEET[phase, foot], interval=k,
                                s=float(s[i]), depth=float(-hk[i])))
    return out


def clearance_rows(con, model, opts, phases: dict, points, per_interval: int = DENSE) -> None:
    """Bound the feet that dipped at ``points`` between the points of the NLP.

    A foot that dipped below its bound in a phase is held above it there at the dense
    grid's samples inside every interval of that phase, and at each dip's own time, on
    the interpolant.  A bound at the dip's time alone moved the dip a little along its
    interval at every re-solve (RABBIT at 1.5 m/s with a 0.2 m clearance on 4 + 3
    intervals: 1.0e-4, 2.0e-5, 5.5e-6, 1.2e-6 m in four solves), and bounds on the
    dipping interval alone moved it to the next (ODRI's Bolt at 1 m/s, 16 + 10: from
    stance interval 6 to 5, from flight interval 0 to 1).

    Parameters
    ----------
    con : LabelledConstraints
        The running step's problem (rows labelled 'feet above their bounds between the
        points').
    model : BipedModel
        The robot.
    opts : RunningOptions
        The problem.
    phases : dict
        'stance' and 'flight' -> (X, F, U, T): the phase's states, their derivatives,
        torques (points as columns) and duration.
    points : sequence of dict
        Dips (:func:`foot_dips`): the foot named by ``foot`` on interval ``interval``,
        at fraction ``s`` of it.
    per_interval : int
        Dense samples per interval.
    """
    names = {name: key for key, name in FEET.items()}
    inner = set(np.arange(1, per_interval) / per_interval)
    where = {}
    for p in points:
        phase, foot = names[p["foot"]]
        n = (phases[phase][0].shape[1] - 1) // 2
        for k in range(n):
            where.setdefault((phase, foot, k), set(inner))
        where[phase, foot, int(p["interval"])].add(float(p["s"]))
    for (phase, foot, k), fractions in sorted(where.items()):
        X, F, _, T = phases[phase]
        S = ca.DM(sorted(fractions)).T
        n = (X.shape[1] - 1) // 2
        f0, fm, f1 = F[:, 2 * k], F[:, 2 * k + 1], F[:, 2 * k + 2]
        x = ca.repmat(X[:, 2 * k], 1, S.shape[1]) + T / n * (
            ca.mtimes(f0, S) + ca.mtimes(0.5 * (-3 * f0 + 4 * fm - f1), S ** 2)
            + ca.mtimes((2 * f0 - 4 * fm + 2 * f1) / 3, S ** 3))
        frac = (k + np.array(S).ravel()) / n
        h = foot_heights(model, opts, phase, x, frac)[foot]
        con.add("feet above their bounds between the points", "m", ca.vec(h) >= 0)
