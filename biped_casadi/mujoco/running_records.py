"""The records of a running run in MuJoCo (:mod:`biped_casadi.mujoco.running`): each
stride, the run, the decay of its deviation and MuJoCo's stride map fitted from its
landing states."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..results import Result, json_safe

__all__ = ["RunningStride", "MujocoRun", "decay_rate", "RunningMapFit", "fit_running_map",
           "reference_fit"]


@dataclass
class RunningStride:
    """One stride in MuJoCo, landing to landing (SI units).

    Parameters
    ----------
    index : int
        0-based.
    t_landing : float
        MuJoCo's time at the landing that starts it, s.
    stance, flight : float
        The phases' durations, s.
    step_length : float
        The landing foot's x less the previous landing foot's, m.
    speed : float
        step_length / (stance + flight), m/s.
    landing_state : list of float
        The rigid landing map of MuJoCo's state at the stride's closing touchdown: the next
        stance state (q, dq), as the exact stride map's.
    deviation : float
        max ``|landing_state - x*|`` (rad, rad/s).
    peak_torque : float
        Largest ``|u|`` commanded over the stride, N m.
    clipped_time : float
        Time with a commanded torque beyond the limit (MuJoCo clips it), s.
    slip : float
        The stance foot's sliding in the stance, m.
    fz_max : float
        Largest normal force on the stance foot, N (MuJoCo's soft landing shows here).
    bounce_time : float
        Time the stance foot spent off the floor early in the stance (a bounce off the
        landing, before ``min_stance`` of the gait's stance), s.
    takeoff_guard_gap : float
        Where the flight clock started (the rigid model's takeoff guard on MuJoCo's
        states) less MuJoCo's first zero-force state, s; NaN when the clock started at
        MuJoCo's contact (``takeoff_clock='contact'``, or the guard had not crossed).
    """

    index: int
    t_landing: float
    stance: float
    flight: float
    step_length: float
    speed: float
    landing_state: list
    deviation: float
    peak_torque: float
    clipped_time: float
    slip: float
    fz_max: float
    bounce_time: float = 0.0
    takeoff_guard_gap: float = math.nan

    def to_dict(self) -> dict:
        """The stride's figures by name.

        Returns
        -------
        dict
        """
        return dict(self.__dict__)


@dataclass
class MujocoRun(Result):
    """A run of the running controller in MuJoCo.

    Parameters
    ----------
    status, message : str
        'ran' or the reason it stopped (:data:`RUN_OUTCOMES`), and a summary line.
    n_strides : int
        Strides asked for.
    strides : list of RunningStride
        The completed strides.
    start : list of float
        The stance state the run started from.
    fixed_point : list of float
        x*, the exact map's fixed point the deviations are measured from.
    deviations : list of float
        max ``|x_k - x*|``: the start's, then each stride's landing state's.
    gait : dict
        The gait's ``T_stance``, ``T_flight``, ``speed``, ``step_length``.
    controller : dict
        ``law``, ``Kp``, ``Kd``, ``M1``, ``saturate``.
    settings : dict
        MuJoCo's settings.
    torque_limit : float or tuple of float
        N m: the motors' limit, or one per torque u1 .. u_nu where the joints' limits
        differ.
    mujoco_steps : int
        MuJoCo steps taken.
    wall_time : float
        s.
    t, qpos, qvel, phase : numpy.ndarray
        The log with ``log=True`` (every MuJoCo state; phase 0 stance, 1 flight), else
        empty; not in ``to_dict()``.
    stance_leg : numpy.ndarray
        The stance leg at each logged state (0: a, 1: b).
    """

    status: str
    message: str
    n_strides: int
    strides: list
    start: list
    fixed_point: list
    deviations: list
    gait: dict
    controller: dict
    settings: dict
    torque_limit: float | tuple
    mujoco_steps: int
    wall_time: float
    t: np.ndarray = field(default_factory=lambda: np.zeros(0), metadata={"dict": False})
    qpos: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)), metadata={"dict": False})
    qvel: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)), metadata={"dict": False})
    phase: np.ndarray = field(default_factory=lambda: np.zeros(0), metadata={"dict": False})
    stance_leg: np.ndarray = field(default_factory=lambda: np.zeros(0),
                                   metadata={"dict": False})

    SUCCESS = ("ran",)

    @property
    def strides_run(self) -> int:
        """Completed strides."""
        return len(self.strides)

    @property
    def landing_states(self) -> np.ndarray:
        """(strides + 1, 2 nq): the start, then each stride's landing state."""
        return np.array([self.start] + [s.landing_state for s in self.strides], float)

    def to_dict(self) -> dict:
        """Plain JSON types, with the run's summary figures.

        Returns
        -------
        dict
            The fields, ``strides_run``, the mean speed and durations over the last two
            thirds of the strides and the decay of the deviation (:func:`decay_rate`).
        """
        d = super().to_dict()
        d["strides_run"] = self.strides_run
        late = self.strides[len(self.strides) // 3:]
        for k in ("speed", "stance", "flight"):
            d[f"mean_{k}"] = float(np.mean([getattr(s, k) for s in late])) if late \
                else math.nan
        d["decay"] = decay_rate(self)
        return json_safe(d)


def decay_rate(run: MujocoRun, skip: int = 1) -> dict:
    """How fast a run's landing states settle, per stride.

    Two distances per landing state: from the exact fixed point x* (``deviations``) and
    from MuJoCo's own cycle, the mean landing state over the last third of the run.  The
    rate is exp of the slope of a least-squares line through log(distance to MuJoCo's
    cycle) over the strides from ``skip`` on while that distance is above three times the
    cycle's spread (the jitter: the largest distance of a last-third landing state from
    the mean; below it the deviation is the time grid's noise, not the map's modes).

    Parameters
    ----------
    run : MujocoRun
        The run.
    skip : int
        Strides left out at the start (the first stride moves a perturbation onto the map's
        modes).

    Returns
    -------
    dict
        ``rate`` (NaN when fewer than three strides are above the floor), ``strides_fitted``,
        ``cycle_offset`` (max ``|mean - x*|``: MuJoCo's cycle against the exact one),
        ``jitter``, ``to_cycle`` (the distances to MuJoCo's cycle).
    """
    X = run.landing_states
    xs = np.asarray(run.fixed_point, float)
    nan = dict(rate=math.nan, strides_fitted=0, cycle_offset=math.nan, jitter=math.nan,
               to_cycle=[])
    if len(X) < 6:
        return nan
    tail = X[len(X) - max(2, (len(X) - 1) // 3):]
    mean = tail.mean(axis=0)
    jitter = float(np.max(np.abs(tail - mean)))
    d = np.max(np.abs(X - mean), axis=1)
    k = np.arange(len(d))
    ok = (k >= skip) & (d > 3 * jitter)
    # the fit stops at the first stride below the floor
    last = skip
    while last < len(d) and ok[last]:
        last += 1
    sel = np.arange(skip, last)
    rate = math.nan
    if sel.size >= 3:
        slope = np.polyfit(sel, np.log(d[sel]), 1)[0]
        rate = float(math.exp(slope))
    return dict(rate=rate, strides_fitted=int(sel.size),
                cycle_offset=float(np.max(np.abs(mean - xs))), jitter=jitter,
                to_cycle=d.tolist())


@dataclass
class RunningMapFit(Result):
    """MuJoCo's running stride map fitted from the landing states of a run.

    Parameters
    ----------
    status, message : str
        'ok', or 'failed' (too few strides for the fit).
    A : list
        The (n, n) Lambda of the least-squares fit x_{k+1} = c + Lambda x_k.
    eigenvalues : list
        Its eigenvalues by decreasing modulus.
    max_abs : float
        Their largest modulus.
    max_abs_spread : float
        Standard deviation of max|lambda| over 200 bootstrap resamples of the pairs
        (seeded).
    relative_residual : float
        RMS residual over the RMS spread of x_{k+1}, the largest over the components:
        the share of the next landing state the map does not explain (MuJoCo's jitter).
    pairs : int
        (x_k, x_{k+1}) pairs fitted.
    reference_max_abs, reference_max_abs_spread : float
        With a ``reference`` map (the exact stride map's Jacobian): the mean and standard
        deviation of the max|lambda| the same fit returns on runs of that linear map
        driven by this fit's own residuals (resampled; as many runs and pairs as
        fitted).  What the fit would report if MuJoCo's map were the reference: compare
        ``max_abs`` with this, not with the reference's own radius (NaN without one).
    reference_radius : float
        The reference's own max|lambda| (NaN without one).
    """

    status: str
    message: str
    A: list
    eigenvalues: list
    max_abs: float
    max_abs_spread: float
    relative_residual: float
    pairs: int
    reference_max_abs: float = math.nan
    reference_max_abs_spread: float = math.nan
    reference_radius: float = math.nan

    SUCCESS = ("ok",)


def _pairs(runs, skip):
    """The (x_k, x_{k+1}) pairs of each run, from landing state ``skip`` on."""
    P0, P1 = [], []
    for r in runs:
        X = r.landing_states[skip:]
        if len(X) > 1:
            P0.append(X[:-1])
            P1.append(X[1:])
    return P0, P1


def _lstsq_map(X0, X1):
    """(c, Lambda, residuals) of the least-squares fit x_{k+1} = c + Lambda x_k."""
    Phi = np.column_stack([np.ones(len(X0)), X0])
    coef = np.linalg.lstsq(Phi, X1, rcond=None)[0]
    return coef[0], coef[1:].T, X1 - Phi @ coef


def _radius(L) -> float:
    return float(np.max(np.abs(np.linalg.eigvals(L))))


def reference_fit(reference, residuals, lengths, rng, replicas: int = 50) -> tuple:
    """The max|lambda| the least-squares fit returns when the map is ``reference``.

    Runs of x_{k+1} = reference x_k + e_k (deviations from the fixed point), each as long
    as a fitted run, e_k drawn with replacement from ``residuals`` (centred), then the
    same fit.  The fit of a 10 x 10 map on a few hundred noisy strides is biased: the
    noise excites few directions of the state, and the largest modulus of eigenvalues
    estimated with noise lies above the true one.

    Parameters
    ----------
    reference : array_like
        (n, n) the map, e.g. the exact stride map's Jacobian.
    residuals : array_like
        (m, n) the fit's residuals (MuJoCo's stride-to-stride noise).
    lengths : sequence of int
        Pairs per run.
    rng : numpy.random.Generator
        The draws.
    replicas : int
        Fits averaged.

    Returns
    -------
    tuple of float
        (mean, standard deviation) of the fitted max|lambda| over the replicas.
    """
    A = np.asarray(reference, float)
    E = np.asarray(residuals, float)
    E = E - E.mean(axis=0)
    out = []
    for _ in range(replicas):
        P0, P1 = [], []
        for n in lengths:
            x = np.zeros((n + 1, A.shape[0]))
            e = E[rng.integers(0, len(E), n)]
            for k in range(n):
                x[k + 1] = A @ x[k] + e[k]
            P0.append(x[:-1])
            P1.append(x[1:])
        out.append(_radius(_lstsq_map(np.vstack(P0), np.vstack(P1))[1]))
    return float(np.mean(out)), float(np.std(out))


def fit_running_map(runs, skip: int = 1, seed: int = 0, reference=None) -> RunningMapFit:
    """MuJoCo's stride map from runs: a least-squares fit of x_{k+1} = c + Lambda x_k.

    At stiff contact MuJoCo's landing states do not repeat: each stride adds a jitter of
    tenths of a rad/s (the contact's chatter, the time grid) that a perturbation meets
    after a stride or two, so a decay cannot be read off one perturbed run.  The jitter
    keeps the state moving about MuJoCo's cycle; over a long run the pairs of
    consecutive landing states determine the linear map as an autoregression does (the
    jitter enters as noise independent of x_k).  The estimate of max|lambda| is biased
    upward at a few hundred strides (:func:`reference_fit`): give ``reference`` to
    measure the bias.

    Parameters
    ----------
    runs : MujocoRun or list of MujocoRun
        Runs of one loop (their completed strides).
    skip : int
        Landing states left out at the start of each run (the start itself, a transient).
    seed : int
        Of the bootstrap and of the reference's runs.
    reference : array_like, optional
        (n, n) a map to calibrate the fit against (the exact stride map's Jacobian,
        ``running_stability(cycle).A``): fills ``reference_max_abs`` and its spread.

    Returns
    -------
    RunningMapFit
    """
    runs = [runs] if isinstance(runs, MujocoRun) else list(runs)
    P0, P1 = _pairs(runs, skip)
    n = len(runs[0].start) if runs else 0
    if not P0 or sum(len(p) for p in P0) < 3 * (n + 1):
        m = sum(len(p) for p in P0)
        return RunningMapFit("failed", f"{m} pairs of landing states: at least {3 * (n + 1)} "
                             "are needed to fit the stride map", [], [], math.nan, math.nan,
                             math.nan, m)
    X0, X1 = np.vstack(P0), np.vstack(P1)
    _, Lam, res = _lstsq_map(X0, X1)
    spread = X1.std(axis=0)
    rel = float(np.max(np.sqrt(np.mean(res ** 2, axis=0)) / np.where(spread > 0, spread,
                                                                       np.inf)))
    ev = np.linalg.eigvals(Lam)
    ev = ev[np.argsort(-np.abs(ev))]
    rng = np.random.default_rng(seed)
    mx = []
    for _ in range(200):
        i = rng.integers(0, len(X0), len(X0))
        mx.append(_radius(_lstsq_map(X0[i], X1[i])[1]))
    top = float(np.abs(ev[0]))
    msg = (f"MuJoCo's stride map from {len(X0)} pairs: max |lambda| {top:.3g} +- "
           f"{np.std(mx):.2g}, relative residual {rel:.2g}")
    ref = (math.nan, math.nan, math.nan)
    if reference is not None:
        A = np.asarray(reference, float)
        if A.shape != (n, n) or not np.all(np.isfinite(A)):
            raise ValueError(f"reference must be a finite ({n}, {n}) matrix, got {A.shape}")
        ref = reference_fit(A, res, [len(p) for p in P0], rng) + (_radius(A),)
        msg += (f"; the same fit on the reference map ({ref[2]:.3g}) with these residuals "
                f"gives {ref[0]:.3g} +- {ref[1]:.2g}")
    return RunningMapFit("ok", msg, Lam.tolist(), [complex(e) for e in ev], top,
                         float(np.std(mx)), rel, int(len(X0)), *ref)
