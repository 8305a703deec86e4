"""Choose the output's column M1 of a running gait's tracking controller (the paper's
method, v = [M1, I] q with M1 chosen so that the stride map is stable, on the running
cycle stance -> flight -> stance).

:func:`choose_running_m1` minimises the spectral radius of the exact stride Jacobian at
the closed loop's fixed point (:func:`~analysis.stability.running_cycle.running_stability`)
over the nu components of M1, and optionally the PD gains Kp and Kd (one number each,
searched on a log scale), by a derivative-free method (scipy's Nelder-Mead or Powell) on
that exact radius.  The gains are the cycle's parameters, so every evaluation is a
:meth:`~analysis.stability.running_cycle.RunningCycle.retuned` cycle (milliseconds) and
a Newton solve (about 0.5 s on RABBIT).

A point where Newton does not close the orbit, where a stride leaves the robot's validity
(a constraint violated: friction cone, torque limit, a foot below the ground, no takeoff
or landing within the time limit), or whose fixed point is farther than ``max_distance``
from the collocated landing state (another orbit than the gait's) is infeasible: it is
recorded with the reason and given the value ``INFEASIBLE`` (larger than any radius met),
so the simplex moves away from it.

The spectral radius is not smooth where two eigenvalues of the same modulus cross (it
is at the best designs: a real eigenvalue that meets another and leaves as a complex
pair), which is why a derivative-free method is used; the result is a local minimum near
the start.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from biped_casadi.control.output_law import check_M1_range
from biped_casadi.results import Result
from analysis.stability.running_cycle import require_running_cycle, running_stability

__all__ = ["choose_running_m1", "RunningM1Choice", "M1Evaluation", "INFEASIBLE",
           "METHODS"]

#: the objective's value at an infeasible point (any radius met is far below it)
INFEASIBLE = 1e3

#: the scipy methods the search can use
METHODS = ("nelder-mead", "powell")


@dataclass
class M1Evaluation:
    """One evaluation of the search.

    Parameters
    ----------
    M1 : list of float
        The output's column on q1.
    Kp, Kd : float or list of float
        The gains (units of the law): one number when the same for every output.
    spectral_radius : float
        At the fixed point (NaN when infeasible).
    status : str
        'stable', 'unstable' or 'infeasible'.
    message : str
        Why infeasible (the fixed point's message otherwise).
    distance : float
        The fixed point's distance from the collocated landing state (NaN if none).
    seconds : float
        Wall time of the evaluation.
    """

    M1: list
    Kp: float
    Kd: float
    spectral_radius: float
    status: str
    message: str
    distance: float
    seconds: float

    def to_dict(self) -> dict:
        """The evaluation in plain JSON types.

        Returns
        -------
        dict
            Its fields (NaN as None).
        """
        from biped_casadi.results import json_safe
        return json_safe(dict(M1=self.M1, Kp=self.Kp, Kd=self.Kd,
                              spectral_radius=self.spectral_radius, status=self.status,
                              message=self.message, distance=self.distance,
                              seconds=self.seconds))


@dataclass
class RunningM1Choice(Result):
    """The output design of :func:`choose_running_m1`.

    Parameters
    ----------
    M1 : numpy.ndarray
        (nu,) the chosen column.
    Kp, Kd : float or list of float
        The gains at the choice (the start's unless ``tune_gains``).
    spectral_radius : float
        Of the exact stride Jacobian at the chosen design's fixed point.
    start_M1 : numpy.ndarray
        Where the search began.
    start_radius : float
        The spectral radius there (NaN when the start is infeasible).
    start_status : str
        'stable', 'unstable' or 'infeasible'.
    stability : RunningStability
        The fixed point and eigenvalues at the choice (a fresh
        :func:`running_stability` of the retuned cycle).
    evaluations : list of M1Evaluation
        Every distinct point evaluated, in order.
    n_evaluations, n_infeasible : int
        Their number, and how many were infeasible.
    method : str
        The scipy method.
    tune_gains : bool
        Whether Kp and Kd were searched too.
    optimizer_message : str
        What scipy said when it stopped (converged, or the evaluation cap).
    seconds : float
        Wall time of the search.
    status, message : str
        'stable' (the chosen radius < 1), 'unstable' (>= 1: no stable design found near
        the start) or 'failed' (no feasible point at all).
    """

    M1: np.ndarray
    Kp: float
    Kd: float
    spectral_radius: float
    start_M1: np.ndarray
    start_radius: float
    start_status: str
    stability: object = field(default=None, metadata={"dict": False})
    evaluations: list = field(default_factory=list, metadata={"dict": False})
    n_evaluations: int = 0
    n_infeasible: int = 0
    method: str = "nelder-mead"
    tune_gains: bool = False
    optimizer_message: str = ""
    seconds: float = 0.0
    status: str = "stable"
    message: str = ""

    SUCCESS = ("stable",)


def _g(v):
    """A gain as one number when it is the same for every output, else a list."""
    v = np.atleast_1d(np.asarray(v, float)).ravel()
    return float(v[0]) if np.ptp(v) == 0 else v.tolist()


def _evaluate(cycle, M1, Kp, Kd, max_distance):
    """The spectral radius at one design, or the reason it is infeasible."""
    t0 = time.perf_counter()
    try:
        r = running_stability(cycle.retuned(Kp=Kp, Kd=Kd, M1=M1))
    except ValueError as e:                   # a gain the controller refuses
        return M1Evaluation(list(map(float, M1)), _g(Kp), _g(Kd), math.nan,
                            "infeasible", str(e), math.nan, time.perf_counter() - t0), None
    dt = time.perf_counter() - t0
    if r.status == "failed":
        status, msg = "infeasible", r.message
    elif not (r.distance <= max_distance):
        status, msg = "infeasible", (f"the fixed point is {r.distance:.2e} from the collocated "
                                     f"landing state (more than {max_distance:g}): another "
                                     "orbit than the gait's")
    else:
        status, msg = r.status, r.message
    rho = r.spectral_radius if status != "infeasible" else math.nan
    return M1Evaluation(list(map(float, M1)), _g(Kp), _g(Kd), float(rho), status, msg,
                        float(r.distance), dt), r


def _check_options(method, max_evaluations, progress, **positive):
    """ValueError (TypeError for a progress that is not callable) naming a bad option of
    :func:`choose_running_m1`."""
    if progress is not None and not callable(progress):
        raise TypeError(f"progress must be a function of one line of text, got {progress!r}")
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    if isinstance(max_evaluations, bool) or not isinstance(max_evaluations, (int, np.integer)) \
            or max_evaluations < 1:
        raise ValueError(f"max_evaluations must be a positive integer, got {max_evaluations!r}")
    for name, v in positive.items():
        if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) \
                or not (math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a positive number, got {v!r}")


class _Cap(Exception):
    """The evaluation cap was reached (ends the optimiser's run)."""


class _Objective:
    """The spectral radius as a function of z = M1 (and log Kp, log Kd): each distinct
    point evaluated once, every evaluation recorded, the best feasible one kept."""

    def __init__(self, cycle, Kp0, Kd0, tune_gains, cap, max_distance, say):
        self.cycle, self.Kp0, self.Kd0, self.tune_gains = cycle, Kp0, Kd0, tune_gains
        self.cap, self.max_distance, self.say = cap, max_distance, say
        self.nu = cycle.controller.model.nu
        self.evals, self.cache, self.best = [], {}, {"f": math.inf, "key": None}

    def unpack(self, z):
        z, nu = np.asarray(z, float), self.nu
        if self.tune_gains:          # a gain that overflows is refused (infeasible) later
            with np.errstate(over="ignore"):
                return z[:nu], float(np.exp(z[nu])), float(np.exp(z[nu + 1]))
        return z[:nu], self.Kp0, self.Kd0

    def __call__(self, z):
        key = tuple(np.round(np.asarray(z, float), 12))
        if key in self.cache:
            return self.cache[key]
        if len(self.evals) >= self.cap:
            raise _Cap
        M1, Kp, Kd = self.unpack(z)
        ev, _ = _evaluate(self.cycle, M1, Kp, Kd, self.max_distance)
        self.evals.append(ev)
        val = ev.spectral_radius if ev.status != "infeasible" else INFEASIBLE
        self.cache[key] = val
        best = self.best
        if val < best["f"]:
            best.update(f=val, key=key, ev=ev)
        if len(self.evals) % 10 == 0:
            self.say(f"  {len(self.evals)} evaluations, best spectral radius {best['f']:.4g} "
                     "at M1 " + " ".join(f"{v:.4g}" for v in best["ev"].M1)
                     + (f", Kp {best['ev'].Kp:.4g}, Kd {best['ev'].Kd:.4g}"
                        if self.tune_gains else ""))
        return val


def _search(f, z0, nu, method, initial_step, gain_step, xatol, fatol, cap) -> str:
    """Run the optimiser on ``f`` from ``z0``; its message."""
    from scipy.optimize import minimize         # (its import: 0.3 s of every command's)
    try:
        if method == "nelder-mead":
            simplex = [z0]
            for i in range(z0.size):
                z = z0.copy()
                z[i] += initial_step if i < nu else gain_step
                simplex.append(z)
            res = minimize(f, z0, method="Nelder-Mead",
                           options=dict(initial_simplex=np.array(simplex), xatol=xatol,
                                        fatol=fatol, maxfev=10 * cap))
        else:
            res = minimize(f, z0, method="Powell",
                           options=dict(xtol=xatol, ftol=fatol, maxfev=10 * cap))
        return str(res.message)
    except _Cap:
        return f"stopped at the evaluation cap ({cap})"


def choose_running_m1(cycle, start=None, tune_gains: bool = False,
                      max_evaluations: int = 200, method: str = "nelder-mead",
                      initial_step: float = 0.1, gain_step: float = 0.3,
                      xatol: float = 1e-3, fatol: float = 1e-4,
                      max_distance: float = 1e-2, progress=None) -> RunningM1Choice:
    """Minimise the stride map's spectral radius over M1 (and optionally Kp, Kd).

    Parameters
    ----------
    cycle : RunningCycle
        From :func:`~analysis.stability.running_cycle.running_cycle`; its controller's
        law, gains and M1 are the search's start unless ``start`` is given.
    start : array_like, optional
        (nu,) the first M1 (default the cycle's own).
    tune_gains : bool
        Also search Kp and Kd (one number each for every output; log scale).
    max_evaluations : int
        Distinct stride-map fixed points solved at most (the start included).
    method : str
        'nelder-mead' (default) or 'powell' (scipy.optimize.minimize).
    initial_step : float
        Nelder-Mead's first simplex: the start plus this much on each component of M1.
    gain_step : float
        The same for log(Kp) and log(Kd) with ``tune_gains``.
    xatol, fatol : float
        Nelder-Mead's stopping tolerances (on the parameters, on the radius); Powell's
        xtol and ftol.
    max_distance : float
        A fixed point farther than this from the collocated landing state (largest
        entry, rad or rad/s) is not the gait's orbit: infeasible.
    progress : callable, optional
        Called with one line at the start, every 10 evaluations and at the end.

    Returns
    -------
    RunningM1Choice
        The best feasible point evaluated, with a fresh analysis there.

    Raises
    ------
    ValueError
        A bad option (method, evaluation cap, steps, start of the wrong size).
    """
    require_running_cycle(cycle)
    method = str(method).lower()
    _check_options(method, max_evaluations, progress, initial_step=initial_step,
                   gain_step=gain_step, xatol=xatol, fatol=fatol, max_distance=max_distance)
    c = cycle.controller
    nu = c.model.nu
    try:
        m0 = np.array(c.M1 if start is None else start, float).ravel()
    except (TypeError, ValueError):
        m0 = np.zeros(0)
    if m0.size != nu or not np.all(np.isfinite(m0)):
        raise ValueError(f"start must be {nu} finite numbers, got {start!r}")
    check_M1_range(m0, "start")
    if tune_gains and (np.ptp(c.Kp) > 0 or np.ptp(c.Kd) > 0 or c.Kp[0] <= 0 or c.Kd[0] <= 0):
        raise ValueError("tune_gains needs one positive Kp and Kd for every output, got "
                         f"Kp {c.Kp.tolist()}, Kd {c.Kd.tolist()}")
    Kp0, Kd0 = c.Kp.copy(), c.Kd.copy()
    say = progress or (lambda s: None)
    t_start = time.perf_counter()
    f = _Objective(cycle, Kp0, Kd0, tune_gains, max_evaluations, max_distance, say)
    evals, best = f.evals, f.best
    z0 = m0.copy()
    if tune_gains:
        z0 = np.r_[z0, math.log(Kp0[0]), math.log(Kd0[0])]
    say(f"choosing M1{' and the gains' if tune_gains else ''} ({method}, at most "
        f"{max_evaluations} evaluations of about 0.5 s) from M1 "
        + " ".join(f"{v:g}" for v in m0))
    f(z0)
    first = evals[0]
    opt_msg = _search(f, z0, nu, method, initial_step, gain_step, xatol, fatol,
                      max_evaluations)
    n_bad = sum(e.status == "infeasible" for e in evals)
    seconds = time.perf_counter() - t_start
    if best["key"] is None or best["f"] >= INFEASIBLE:
        say(f"no feasible design among {len(evals)} evaluations")
        return RunningM1Choice(
            M1=m0, Kp=_g(Kp0), Kd=_g(Kd0), spectral_radius=math.nan,
            start_M1=m0, start_radius=math.nan, start_status=first.status, stability=None,
            evaluations=evals, n_evaluations=len(evals), n_infeasible=n_bad, method=method,
            tune_gains=bool(tune_gains), optimizer_message=opt_msg, seconds=seconds, status="failed",
            message=f"no feasible design among {len(evals)} evaluations (the start: "
                    f"{first.message})")
    M1 = np.asarray(best["ev"].M1, float)
    Kp, Kd = best["ev"].Kp, best["ev"].Kd
    stab = running_stability(cycle.retuned(Kp=Kp, Kd=Kd, M1=M1))
    rho = float(stab.spectral_radius)
    status = "stable" if rho < 1 else "unstable"
    msg = (f"M1 {' '.join(f'{v:.4g}' for v in M1)}"
           + (f", Kp {Kp:.4g}, Kd {Kd:.4g}" if tune_gains else "")
           + f": spectral radius {rho:.4g} (start {first.spectral_radius:.4g}); "
             f"{len(evals)} evaluations ({n_bad} infeasible), {seconds:.1f} s")
    say("chose " + msg)
    return RunningM1Choice(
        M1=M1, Kp=Kp, Kd=Kd, spectral_radius=rho, start_M1=m0,
        start_radius=first.spectral_radius, start_status=first.status, stability=stab,
        evaluations=evals, n_evaluations=len(evals), n_infeasible=n_bad, method=method,
        tune_gains=bool(tune_gains), optimizer_message=opt_msg, seconds=seconds, status=status, message=msg)
