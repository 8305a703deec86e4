"""A periodic running gait: two domains (stance, flight) by direct collocation.

One running step of a planar point-foot biped (docs: howto/running.md) is a single
support phase on the stance foot, a takeoff when the normal ground force reaches zero,
a flight phase with both feet off the ground, and the landing of the swing foot, a
rigid impact followed by the relabelling E, which starts the next step on the other
leg.  A periodic gait returns, after the relabelling, to the state it started from.

Transcription.  Each phase has its own duration (a decision variable) and its own grid
of ``n`` Hermite-Simpson intervals in the separated form: states and torques at the
interval ends and midpoints, the midpoint interpolation condition and Simpson's rule
for every interval (Betts; Kelly 2017).  The stance state is x = (q, dq) with the
model's ``forward_dynamics``; the flight state is the extended (qe, dqe), qe = (q, x_st,
z_st), with ``flight_dynamics`` of :func:`biped_casadi.model.flight_model`.  The edges
are the exact Functions of the flight model: ``takeoff`` (the stance state embedded,
base at the foot, at rest) when ``takeoff_guard`` gives Fz = 0 at the last stance
point, and ``landing_swing`` (impact and relabelling) when the swing foot reaches the
ground; periodicity ties its output to the first stance state.

Constraints: |u| <= the model's torque limit at every point (and at the quarter points
of every interval; a torque whose quadratic peaks above it between them has its bound
lowered by the excess and the step solved again), the torque's rate bounded, the torques continuous through takeoff
(so that the stance and flight accelerations agree there and the foot leaves the
ground smoothly, docs: howto/running.md); in stance Fz >= 0 and
|Fx| <= (mu - mu_margin) Fz, the swing foot above a parabolic clearance profile; in flight both feet
above the ground (a foot that dips below its bound between the points is bounded at
the dense grid's samples and the step solved again, in the torques' loop); no knee
hyperextension; at landing the swing foot moving down, the
impulse inside the cone of mu - mu_margin and the other foot moving up after the impact; the
average speed: step length (the landing foot's x in the stance frame) = v (Ts + Tf).

Cost: as the walking optimiser's default (:mod:`gait_opt.transcription`), the integral
of u'u over the step divided by the step length, by Simpson's rule on both phases.

Solved with CasADi's ``Opti`` and IPOPT (exact Hessian of the expanded SX graph).
"""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

from biped_casadi.files import write_text_atomic
from biped_casadi.model import flight_model
from biped_casadi.option_checks import FieldChecks

from .options import leg_scale
from .running_cache import cached_running
from .running_clearance import clearance_rows, foot_dips, hermite_simpson
from .running_file import check_running_file, running_problem
from .running_solve import (STALL_WINDOW, LabelledConstraints, solve_running, torque_rows,
                            within_path_limits)
from .transcription import torso_lean_bound

__all__ = ["RunningOptions", "RunningGait", "optimize_running", "running_guess",
           "hermite_simpson", "CLEARANCE", "TRAILING_CLEARANCE", "MIN_STEP_LENGTH",
           "MU_MARGIN"]

#: length-valued defaults on RABBIT's legs (0.8 m), m; on another robot times its leg
#: length over RABBIT's (:func:`gait_opt.options.leg_scale`, exactly 1.0 for RABBIT)
CLEARANCE = 0.03
TRAILING_CLEARANCE = 0.03
MIN_STEP_LENGTH = 0.05
#: friction kept below mu in every cone of the running step (RunningOptions.mu_margin)
MU_MARGIN = 0.05


@dataclass(frozen=True)
class RunningOptions:
    """The running-gait problem; every field has a default.

    Parameters
    ----------
    speed : float
        Average forward speed, m/s: step length / (stance + flight duration).
    n_stance, n_flight : int
        Hermite-Simpson intervals of the stance and of the flight phase.
    mu : float
        Friction coefficient of the ground (stance force and landing impulse).
    mu_margin : float
        Every cone of the problem (stance force, its rates at takeoff, landing impulse) is
        ``|Fx| <= (mu - mu_margin) Fz``, 0 <= mu_margin < mu: without it the impulse lands
        on the cone's edge from 2 m/s on (RABBIT), and a perturbed closed loop slips there.
    torque_limit : float or None
        Bound on every joint torque, N m; None: the model's (RABBIT: 150; :meth:`limit`).
    clearance : float or None
        Swing-foot clearance in stance, m: z_sw >= clearance 4 s (1 - s), s = t / Ts.
        None: 0.03 m times the robot's leg length over RABBIT's 0.8 m (:meth:`for_model`).
    min_strike_speed : float
        The landing foot's downward speed at touchdown, at least, m/s.
    min_liftoff_speed : float
        The other foot's upward speed just after the landing impact, at least, m/s.
    stance_time_bounds, flight_time_bounds : tuple of float
        (low, high) bounds on the phase durations, s.
    trailing_clearance : float or None
        Height of the trailing foot (the one that pushed off) when the swing foot
        touches down, at least, m: without it the optimum grazes the ground with both
        feet, a walk with a vanishing flight.  None: 0.03 m times the leg length over
        RABBIT's, as ``clearance``.
    torso_lean_max : float
        ``|torso angle from upright|`` <= this at every point, rad (unbounded, the optimum
        leans the torso to the horizontal).
    stance_knee_max, swing_knee_min : float
        No hyperextension: q2 <= stance_knee_max and q5 >= swing_knee_min, rad (legs of
        two links; ignored for legs without knees).
    knee_flexion_max : float
        Knees bent by at most this, rad: q2 >= -knee_flexion_max, q5 <= knee_flexion_max
        (without it the optimiser folds a knee through itself, the links being lines).
        Every other joint stays within pi of upright, as in the walking problem.
    torque_rate_max : float or None
        Bound on ``|du/dt|`` between neighbouring points of a phase, N m/s (None: none).
        It gives the takeoff condition its meaning: with torques free to jump, Fz = 0
        at the last stance point is met by the last point's torque alone (in the limit
        of a fine grid, a jump at one instant that moves nothing), whereas the foot
        should unload as the torques evolve.
    takeoff_cone_rate : bool
        The friction cone at takeoff on the ground force's rate: there Fz = Fx = 0 (the
        cone's apex) and the point condition says nothing about the direction in which
        the force vanishes; without it the force between the last points left the cone
        by up to 0.93 N (RABBIT at 1.5 m/s, 32 + 20 intervals, 3 ms before takeoff).
    cone_quarter_points : bool
        The friction cone also at every stance interval's quarter points, on the
        Hermite-Simpson interpolant (the dense check's state and torque); it cuts what
        is left between the points away from takeoff (RABBIT at 2.5 m/s, 32 + 20: 0.65
        to 0.10 N) and makes the solve two to three times slower.
    ipopt : dict
        Extra IPOPT options.
    stall_window : int or None
        End a search whose constraint violation made no progress over this many
        iterations (:func:`gait_opt.running_solve.stalled`); None: IPOPT alone.
    """

    speed: float = 1.5
    n_stance: int = 16
    n_flight: int = 10
    mu: float = 0.6
    mu_margin: float = MU_MARGIN
    torque_limit: float | None = None
    clearance: float | None = None
    min_strike_speed: float = 0.05
    min_liftoff_speed: float = 0.05
    stance_time_bounds: tuple = (0.05, 0.8)
    flight_time_bounds: tuple = (0.02, 0.4)
    trailing_clearance: float | None = None
    torso_lean_max: float = 0.3
    stance_knee_max: float = 0.0
    swing_knee_min: float = 0.0
    knee_flexion_max: float = 2.0
    torque_rate_max: float | None = 2000.0
    takeoff_cone_rate: bool = True
    cone_quarter_points: bool = False
    ipopt: dict = field(default_factory=dict)
    stall_window: int | None = STALL_WINDOW

    def __post_init__(self):
        c = FieldChecks(self, "RunningOptions.{}", positive="a finite number > {low:g}",
                        nonnegative="a finite number >= {low:g}", at_most=None,
                        integer="an integer from {low} to {high}",
                        pair="(low, high) seconds with 0 < low < high", flag="True or False",
                        none=" or None")
        c.numbers(("speed", "mu", "torso_lean_max", "knee_flexion_max"))
        c.numbers(("min_strike_speed", "min_liftoff_speed", "mu_margin"), strict=False)
        if self.mu_margin >= self.mu:
            raise ValueError(f"RunningOptions.mu_margin must be below mu ({self.mu:g}), "
                             f"got {self.mu_margin!r}")
        c.numbers(("clearance", "trailing_clearance"), strict=False, none=True)
        c.numbers(("torque_limit", "torque_rate_max"), none=True)
        c.integers(("n_stance", "n_flight"), 2, 200)
        c.pairs(("stance_time_bounds", "flight_time_bounds"), kinds=(tuple, list))
        c.flags(("takeoff_cone_rate", "cone_quarter_points"))
        c.integers(("stall_window",), 1, none=True, phrase="an integer >= {low}")
        if not isinstance(self.ipopt, dict):
            c.fail("ipopt", "a dict", self.ipopt)

    def for_model(self, model) -> "RunningOptions":
        """These options with the length-valued defaults filled in for the robot.

        ``clearance`` and ``trailing_clearance``, when None: :data:`CLEARANCE` and
        :data:`TRAILING_CLEARANCE` (RABBIT's) times :func:`~gait_opt.options.leg_scale`,
        the robot's leg length over RABBIT's, exactly 1.0 for RABBIT (so its values are
        the constants bit for bit).  Values given are kept.

        Parameters
        ----------
        model : BipedModel
            The robot.

        Returns
        -------
        RunningOptions
        """
        k = leg_scale(model)
        fill = {name: value * k for name, value in (("clearance", CLEARANCE),
                                                    ("trailing_clearance", TRAILING_CLEARANCE))
                if getattr(self, name) is None}
        return dataclasses.replace(self, **fill) if fill else self

    def limit(self, model):
        """The torque bound for ``model``.

        Parameters
        ----------
        model : BipedModel
            The robot.

        Returns
        -------
        float or tuple of float
            ``torque_limit``, else the model's ``description.torque_bound``, N m.
        """
        b = model.description.torque_bound if self.torque_limit is None else self.torque_limit
        return b if isinstance(b, tuple) else float(b)


# ----------------------------------------------------------------- interpolation
def _simpson(T, values):
    """Simpson's rule over one phase: values at ends and midpoints, (2 n + 1,)."""
    n = (values.shape[1] - 1) // 2
    w = np.zeros(2 * n + 1)
    w[0:-1:2] += 1
    w[2::2] += 1
    w[1::2] += 4
    return T / (6 * n) * ca.mtimes(values, ca.DM(w))


# ----------------------------------------------------------------- the gait
@dataclass
class RunningGait:
    """One step of a periodic running gait: stance, takeoff, flight, landing.

    Times start at 0 in each phase; the stance phase's states are (q, dq) in the stance
    frame (foot at the origin), the flight phase's (qe, dqe), qe = (q, x_st, z_st), in
    the same frame; the landing foot's x is the step length and the origin of the next
    step, whose state is the relabelled landing state.

    Parameters
    ----------
    robot : str
        The robot's name (its description's).
    options : RunningOptions
        The problem solved.
    T_stance, T_flight : float
        Phase durations, s.
    x_stance : numpy.ndarray
        (2 nq, 2 n_stance + 1) stance states at interval ends and midpoints.
    u_stance : numpy.ndarray
        (nu, 2 n_stance + 1) stance torques, N m.
    x_flight : numpy.ndarray
        (2 nq + 4, 2 n_flight + 1) flight states.
    u_flight : numpy.ndarray
        (nu, 2 n_flight + 1) flight torques, N m.
    step_length : float
        The landing foot's x in the stance frame, m.
    cost : float
        Integral of u'u over the step / step length, N^2 m s.
    solver_stats : dict
        IPOPT's return status, iterations and wall time.
    """

    robot: str
    options: RunningOptions
    T_stance: float
    T_flight: float
    x_stance: np.ndarray
    u_stance: np.ndarray
    x_flight: np.ndarray
    u_flight: np.ndarray
    step_length: float
    cost: float
    solver_stats: dict = field(default_factory=dict)

    @property
    def T(self) -> float:
        """Step duration (stance + flight), s."""
        return self.T_stance + self.T_flight

    @property
    def speed(self) -> float:
        """Average speed achieved, m/s."""
        return self.step_length / self.T

    @property
    def t_stance(self) -> np.ndarray:
        """Times of the stance points (ends and midpoints), s."""
        return np.linspace(0.0, self.T_stance, self.x_stance.shape[1])

    @property
    def t_flight(self) -> np.ndarray:
        """Times of the flight points from takeoff, s."""
        return np.linspace(0.0, self.T_flight, self.x_flight.shape[1])

    @property
    def success(self) -> bool:
        """IPOPT reported success."""
        return bool(self.solver_stats.get("success", False))

    def save(self, path) -> Path:
        """Write the gait as JSON.

        Parameters
        ----------
        path : str or Path
            The file.

        Returns
        -------
        Path
            The file written.
        """
        body = {k: (v.tolist() if isinstance(v, np.ndarray) else v)
                for k, v in dataclasses.asdict(self).items()}
        body["kind"] = "running gait"
        return write_text_atomic(Path(path), json.dumps(body, indent=1, default=str))

    @classmethod
    def load(cls, path) -> "RunningGait":
        """Read a gait written by :meth:`save`.

        Parameters
        ----------
        path : str or Path
            The file.

        Returns
        -------
        RunningGait

        Raises
        ------
        ValueError
            One line naming the file: unreadable, not a running gait, or malformed.
        """
        try:
            body = json.loads(Path(path).read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
            raise ValueError(f"{path}: cannot read a running gait ({e})") from None
        if not isinstance(body, dict) or body.pop("kind", None) != "running gait":
            raise ValueError(f"{path}: not a running gait")
        try:
            _check_keys(body, cls, "key")
            if not isinstance(body["options"], dict):
                raise ValueError(f"'options' must be an object, got {body['options']!r}")
            _check_keys(body["options"], RunningOptions, "option")
            o = {k: tuple(v) if isinstance(v, list) else v for k, v in body.pop("options").items()}
            # a file written before the takeoff cone condition (the margin) was without it
            o.setdefault("takeoff_cone_rate", False)
            o.setdefault("mu_margin", 0.0)
            arrays = ("x_stance", "u_stance", "x_flight", "u_flight")
            return check_running_file(cls(options=RunningOptions(**o), **{
                k: np.array(v, dtype=float) if k in arrays else v for k, v in body.items()}))
        except (ValueError, TypeError, AttributeError) as e:    # ValueError: our own words
            why = e if isinstance(e, ValueError) else f"{type(e).__name__}: {e}"
            raise ValueError(f"{path}: a malformed running gait ({why})") from None


def _check_keys(body: dict, kind, what: str):
    """ValueError naming the keys of a running gait file's object that the dataclass
    ``kind`` lacks, or the ones it needs (no default) that the object lacks."""
    fields = dataclasses.fields(kind)
    need = [f.name for f in fields if f.default is f.default_factory is dataclasses.MISSING]
    for how, names in (("missing", [n for n in need if n not in body]),
                       ("unknown", sorted(set(body) - {f.name for f in fields}))):
        if names:
            raise ValueError(f"{how} {what}(s) " + ", ".join(map(repr, names)))


# ----------------------------------------------------------------- the guess
def _pose_absolute(phi):
    """q from the absolute link angles (legs of two links: RABBIT's layout)."""
    phi = np.asarray(phi, dtype=float)
    return np.r_[phi[0], np.diff(phi)]


def running_guess(model, opts: RunningOptions) -> dict:
    """A hand-made initial guess of a running step.

    Three poses (landing, takeoff, touchdown) in absolute link angles, joints linear in
    time between them, a ballistic base in flight.  The poses (stance tibia and femur leaning back at landing, forward at takeoff; the
    swing leg trailing, then reaching forward) close through the relabelling; the
    durations follow from the hip's travel at ``opts.speed`` with a 0.1 s flight.

    Parameters
    ----------
    model : BipedModel
        The robot (legs of two links).
    opts : RunningOptions
        The problem.

    Returns
    -------
    dict
        ``T_stance``, ``T_flight``, ``x_stance``, ``u_stance``, ``x_flight``,
        ``u_flight`` (the shapes of :class:`RunningGait`).
    """
    if model.nq != 5:
        raise ValueError("running_guess: legs of two links (nq = 5) only")
    fl = flight_model(model)
    A = _pose_absolute([-0.3, -0.45, 0.1, 0.35, 0.6])        # just after landing
    B = _pose_absolute([0.35, 0.25, 0.1, -0.25, -0.05])       # takeoff
    C = _pose_absolute([0.6, 0.35, 0.1, -0.45, -0.3])         # touchdown (flight frame)
    hip = lambda q: float(np.array(model.points(q))[0, model.hip_index])   # noqa: E731
    Ts = (hip(B) - hip(A)) / opts.speed
    Tf = 0.1
    # base position at touchdown: the hip moves on at the speed; the swing foot at z = 0
    zero = np.zeros(2)
    feet_C = np.array(fl.feet(np.r_[C, zero]))
    xb = hip(B) + opts.speed * Tf - hip(C)
    zb = -feet_C[1, 1]
    ns, nf = 2 * opts.n_stance + 1, 2 * opts.n_flight + 1
    s = np.linspace(0, 1, ns)
    q_s = A[:, None] + s[None, :] * (B - A)[:, None]
    dq_s = np.repeat(((B - A) / Ts)[:, None], ns, axis=1)
    s = np.linspace(0, 1, nf)
    qe_B, qe_C = np.r_[B, zero], np.r_[C, xb, zb]
    q_f = qe_B[:, None] + s[None, :] * (qe_C - qe_B)[:, None]
    dq_f = np.repeat(((qe_C - qe_B) / Tf)[:, None], nf, axis=1)
    # the base rises and falls: the ballistic parabola g t (Tf - t) / 2 above the line
    g = model.description.gravity
    q_f[-1] += 0.5 * g * Tf ** 2 * s * (1 - s)
    return dict(T_stance=Ts, T_flight=Tf, x_stance=np.vstack([q_s, dq_s]),
                u_stance=np.zeros((model.nu, ns)), x_flight=np.vstack([q_f, dq_f]),
                u_flight=np.zeros((model.nu, nf)))


# ----------------------------------------------------------------- transcription
def _phase(con, name, f, nx, nu, n, T_bounds):
    """Variables of one phase (``name``: stance or flight) and its Hermite-Simpson
    defects: (T, X, U, F)."""
    opti = con.opti
    T = opti.variable()
    X = opti.variable(nx, 2 * n + 1)
    U = opti.variable(nu, 2 * n + 1)
    con.add(f"{name} duration bounds", "s", opti.bounded(T_bounds[0], T, T_bounds[1]))
    F = f.map(2 * n + 1)(X, U)
    h = T / n
    x0, xm, x1 = X[:, 0:-1:2], X[:, 1::2], X[:, 2::2]
    f0, fm, f1 = F[:, 0:-1:2], F[:, 1::2], F[:, 2::2]
    defects = f"collocation defects of {name} (the dynamics)"
    con.add(defects, "", ca.vec(xm - (x0 + x1) / 2 - h / 8 * (f0 - f1)) == 0)
    con.add(defects, "", ca.vec(x1 - x0 - h / 6 * (f0 + 4 * fm + f1)) == 0)
    return T, X, U, F


def _dynamics(model, fl):
    """Right-hand sides x' = f(x, u) of both phases, as Functions."""
    n, ne = model.nq, fl.ne
    x, u = ca.SX.sym("x", 2 * n), ca.SX.sym("u", model.nu)
    fs = ca.Function("stance_rhs", [x, u],
                     [ca.vertcat(x[n:], model.forward_dynamics(x[:n], x[n:], u))])
    xe = ca.SX.sym("xe", 2 * ne)
    ff = ca.Function("flight_rhs", [xe, u],
                     [ca.vertcat(xe[ne:], fl.flight_dynamics(xe[:ne], xe[ne:], u))])
    return fs, ff


def _posture(con, model, opts, Q):
    """Knees between straight and ``knee_flexion_max``, the other joints within pi of
    upright; the torso within ``torso_lean_max`` of upright."""
    bounded = con.opti.bounded
    con.add("torso lean bound", "rad",
            bounded(*torso_lean_bound(model, Q, opts.torso_lean_max)))
    up = model.description.upright_q
    for i in range(1, model.nq):
        if i in model.stance_knees:
            lo, hi = -opts.knee_flexion_max, opts.stance_knee_max
        elif i in model.swing_knees:
            lo, hi = opts.swing_knee_min, opts.knee_flexion_max
        else:
            lo, hi = up[i] - np.pi, up[i] + np.pi
        con.add("joint range (knees, hips)", "rad", bounded(lo, ca.vec(Q[i, :]), hi))


def _quarter_points(X, F, U, T, n):
    """The Hermite-Simpson interpolant (:func:`hermite_simpson`) at the quarter points
    s = 1/4 and 3/4 of every interval: (states, torques), 2 n columns each."""
    h = T / n
    x0, f0, fm, f1 = X[:, 0:-1:2], F[:, 0:-1:2], F[:, 1::2], F[:, 2::2]
    u0, um, u1 = U[:, 0:-1:2], U[:, 1::2], U[:, 2::2]
    xs, us = [], []
    for s in (0.25, 0.75):
        tau = s * h
        xs.append(x0 + f0 * tau + 0.5 * (-3 * f0 + 4 * fm - f1) * tau * s
                  + (2 * f0 - 4 * fm + 2 * f1) / 3 * tau * s * s)
        us.append(u0 * (1 - s) * (1 - 2 * s) + um * 4 * s * (1 - s) + u1 * s * (2 * s - 1))
    return ca.horzcat(*xs), ca.horzcat(*us)


def _cone_at_quarter_points(con, model, fl, opts, Xs, Fs, Us, Ts):
    """The friction cone at the quarter points of every stance interval, on the state
    and torque of the Hermite-Simpson interpolant (what the dense check measures)."""
    n = model.nq
    xq, uq = _quarter_points(Xs, Fs, Us, Ts, opts.n_stance)
    Fz, Fx = fl.takeoff_guard.map(xq.shape[1])(xq[:n, :], xq[n:, :], uq)
    cone = "friction cone at the quarter points"
    con.add(cone, "N", ca.vec((opts.mu - opts.mu_margin) * Fz - Fx) >= 0)
    con.add(cone, "N", ca.vec((opts.mu - opts.mu_margin) * Fz + Fx) >= 0)


def _cone_at_takeoff(con, model, fl, opts, Xs, Fs, Us, Ts):
    """The friction cone at takeoff, on the forces' rates.  At the last point Fz = Fx =
    0, the cone's apex, where the point condition says nothing about the direction in
    which the force vanishes; the force just before takeoff is -dF/dt dt, inside the
    cone when mu dFz/dt + |dFx/dt| <= 0.  dF/dt along the interpolant: x' = f at the
    last point, u' of the last interval's quadratic torque."""
    n, N = model.nq, Xs.shape[1]
    x, u = ca.SX.sym("x", 2 * n), ca.SX.sym("u", model.nu)
    dx, du = ca.SX.sym("dx", 2 * n), ca.SX.sym("du", model.nu)
    force = ca.vertcat(*fl.takeoff_guard(x[:n], x[n:], u))
    rate = ca.Function("force_rate", [x, u, dx, du],
                       [ca.jtimes(force, ca.vertcat(x, u), ca.vertcat(dx, du))])
    du_end = (Us[:, N - 3] - 4 * Us[:, N - 2] + 3 * Us[:, N - 1]) / (Ts / opts.n_stance)
    dF = rate(Xs[:, -1], Us[:, -1], Fs[:, -1], du_end)
    cone = "friction cone on the force's rate at takeoff"
    con.add(cone, "N/s", (opts.mu - opts.mu_margin) * dF[0] + dF[1] <= 0)
    con.add(cone, "N/s", (opts.mu - opts.mu_margin) * dF[0] - dF[1] <= 0)


def _stance_constraints(con, model, fl, opts, Xs, Us, Fs=None, Ts=None):
    """Ground force, friction cone, swing-foot clearance and posture along stance; Fz =
    0 at takeoff (and so Fx = 0, the cone's apex); the cone on the forces' rates there
    (``opts.takeoff_cone_rate``) and at the quarter points (``opts.cone_quarter_points``)."""
    n, N = model.nq, Xs.shape[1]
    Fz, Fx = fl.takeoff_guard.map(N)(Xs[:n, :], Xs[n:, :], Us)
    con.add("normal ground force Fz >= 0 in stance", "N", ca.vec(Fz[:-1]) >= 0)
    con.add("Fz = 0 at takeoff", "N", Fz[-1] == 0)
    cone = "friction cone in stance"
    con.add(cone, "N", ca.vec((opts.mu - opts.mu_margin) * Fz - Fx) >= 0)
    con.add(cone, "N", ca.vec((opts.mu - opts.mu_margin) * Fz + Fx) >= 0)
    if opts.takeoff_cone_rate:
        _cone_at_takeoff(con, model, fl, opts, Xs, Fs, Us, Ts)
    if opts.cone_quarter_points:
        _cone_at_quarter_points(con, model, fl, opts, Xs, Fs, Us, Ts)
    _, zsw = model.swing_foot.map(N)(Xs[:n, :])
    s = np.linspace(0, 1, N)
    con.add("swing-foot clearance in stance", "m",
            ca.vec(zsw) >= ca.DM(opts.clearance * 4 * s * (1 - s)))
    _posture(con, model, opts, Xs[:n, :])
    return Fz, Fx


def _flight_constraints(con, model, fl, opts, Xf):
    """Both feet above the ground in flight; touchdown of the swing foot moving down."""
    ne, N = fl.ne, Xf.shape[1]
    feet = fl.feet.map(N)(Xf[:ne, :])             # 2 x 2N: (stance, swing) pairs
    z_st, z_sw = feet[1, 0::2], feet[1, 1::2]
    con.add("stance foot above the ground in flight", "m", ca.vec(z_st[1:]) >= 0)
    con.add("swing foot above the ground in flight", "m", ca.vec(z_sw[:-1]) >= 0)
    con.add("touchdown of the swing foot", "m", z_sw[-1] == 0)
    con.add("trailing-foot clearance at touchdown", "m", z_st[-1] >= opts.trailing_clearance)
    v_end = fl.feet_velocity(Xf[:ne, -1], Xf[ne:, -1])
    con.add("swing foot's strike speed", "m/s", v_end[1, 1] <= -opts.min_strike_speed)
    _posture(con, model, opts, Xf[:model.nq, :])


def _edges(con, model, fl, opts, Xs, Xf):
    """Takeoff embedding, landing with relabelling and periodicity, impulse cone and
    lift-off of the other foot; returns the landing foot's position."""
    n, ne = model.nq, fl.ne
    qe0, dqe0 = fl.takeoff(Xs[:n, -1], Xs[n:, -1])
    con.add("takeoff state", "", Xf[:, 0] - ca.vertcat(qe0, dqe0) == 0)
    q_plus, dq_plus, F, _, v_other, p_foot = fl.landing_swing(Xf[:ne, -1], Xf[ne:, -1])
    con.add("periodicity through the landing", "", ca.vertcat(q_plus, dq_plus) - Xs[:, 0] == 0)
    impulse = "landing impulse (upward, in the friction cone)"
    con.add(impulse, "N s", F[1] >= 0)
    con.add(impulse, "N s", (opts.mu - opts.mu_margin) * F[1] - F[0] >= 0)
    con.add(impulse, "N s", (opts.mu - opts.mu_margin) * F[1] + F[0] >= 0)
    con.add("other foot's lift-off speed", "m/s", v_other[1] >= opts.min_liftoff_speed)
    return p_foot


def optimize_running(model, opts: RunningOptions | None = None, guess: dict | None = None,
                     verbose: bool = False, *, cache: bool = False, cache_dir=None,
                     progress=None) -> RunningGait:
    """Optimise one periodic running step (stance, takeoff, flight, landing).

    Parameters
    ----------
    model : BipedModel
        The robot (legs of two links for the built-in guess).
    opts : RunningOptions, optional
        The problem; default ``RunningOptions()`` (1.5 m/s).
    guess : dict or RunningGait, optional
        An initial guess with the fields of :func:`running_guess` (a previous gait on
        the same grids works: a warm start); default :func:`running_guess`.
    verbose : bool
        IPOPT's iteration log.
    cache : bool
        Reuse the step kept in the on-disk cache for the same robot, options and code
        (:mod:`gait_opt.running_cache`), and keep a converged new one there; a kept
        step is returned whatever ``guess``.
    cache_dir : str or Path, optional
        That cache's folder (default :func:`biped_casadi.cache_dir`).
    progress : callable, optional
        Called with one line of text before a solve.

    Returns
    -------
    RunningGait
        The last iterate, whatever IPOPT's status (``gait.success`` tells); with
        ``cache``, ``gait.solver_stats['cache']`` is 'hit' or says why it was solved.
        A torque that peaks above its limit between the points has its bound lowered
        by the excess, a foot that dips below its bound there is bounded at the dense
        grid's samples of that phase and the dip's time, and the step is solved again
        from the one found (without the stall watch), at most three times
        (:func:`gait_opt.running_solve.within_path_limits`:
        ``solver_stats['tightenings']``).
    """
    opts = running_problem(model, opts, guess, RunningOptions)
    if cache:
        return cached_running(model, opts, cache_dir, progress,
                              lambda: optimize_running(model, opts, guess, verbose),
                              RunningGait.load)
    if progress is not None:
        progress(f"optimising a running step of {model.description.name} at "
                 f"{opts.speed:g} m/s (about 10 s) ...")
    return within_path_limits(
        lambda start, umax, points: _solve_step(
            model, opts, guess if start is None else start, verbose, umax, points,
            watch=start is None),
        opts.limit(model), lambda gait: foot_dips(model, gait))


def _solve_step(model, opts, guess, verbose, umax, points=(), watch=True) -> RunningGait:
    """The running step's NLP under the torque bound ``umax``, the feet also bounded
    where ``points`` dipped (:func:`gait_opt.running_clearance.clearance_rows`), built
    and solved once (``watch``: the stall watch of ``solve_running``)."""
    fl = flight_model(model)
    n, nu = model.nq, model.nu
    if guess is None:
        guess = running_guess(model, opts)
    elif isinstance(guess, RunningGait):
        guess = {k: getattr(guess, k) for k in ("T_stance", "T_flight", "x_stance",
                                                  "u_stance", "x_flight", "u_flight")}
    opti = ca.Opti()
    con = LabelledConstraints(opti)
    fs, ff = _dynamics(model, fl)
    Ts, Xs, Us, Fs = _phase(con, "stance", fs, 2 * n, nu, opts.n_stance,
                            opts.stance_time_bounds)
    Tf, Xf, Uf, Ff = _phase(con, "flight", ff, 2 * fl.ne, nu, opts.n_flight,
                            opts.flight_time_bounds)
    for U, T, n_int in ((Us, Ts, opts.n_stance), (Uf, Tf, opts.n_flight)):
        torque_rows(con, opts, U, umax, T, n_int)
    _stance_constraints(con, model, fl, opts, Xs, Us, Fs, Ts)
    _flight_constraints(con, model, fl, opts, Xf)
    p_foot = _edges(con, model, fl, opts, Xs, Xf)
    clearance_rows(con, model, opts, {"stance": (Xs, Fs, Us, Ts), "flight": (Xf, Ff, Uf, Tf)},
                   points)
    # torques continuous through takeoff: with a jump, the stance force under the flight's
    # first torques could be positive (the ground would hold the foot down)
    con.add("torques continuous through takeoff", "N m", Uf[:, 0] - Us[:, -1] == 0)
    con.add("step length = speed x (stance + flight)", "m",
            p_foot[0] - opts.speed * (Ts + Tf) == 0)
    con.add("minimum step length", "m", p_foot[0] >= MIN_STEP_LENGTH * leg_scale(model))
    effort = _simpson(Ts, ca.sum1(Us ** 2)) + _simpson(Tf, ca.sum1(Uf ** 2))
    opti.minimize(1e-3 * effort / p_foot[0])
    for var, key in ((Ts, "T_stance"), (Tf, "T_flight"), (Xs, "x_stance"), (Us, "u_stance"),
                     (Xf, "x_flight"), (Uf, "u_flight")):
        opti.set_initial(var, guess[key])
    val, stats = solve_running(con, opts, verbose, model, watch)  # last iterate if failed
    return RunningGait(robot=model.description.name, options=opts,
                       T_stance=float(val(Ts)), T_flight=float(val(Tf)),
                       x_stance=np.array(val(Xs)), u_stance=np.array(val(Us)).reshape(nu, -1),
                       x_flight=np.array(val(Xf)), u_flight=np.array(val(Uf)).reshape(nu, -1),
                       step_length=float(val(p_foot[0])), cost=float(val(effort / p_foot[0])),
                       solver_stats=stats)
