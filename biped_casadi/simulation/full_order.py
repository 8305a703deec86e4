"""Full-order hybrid closed-loop simulation of walking (paper eq. 9; SPEC §1 impact, §4
guard).

State (q, dq, tau), 2 nq + 1 numbers, plus the controller's reference state r (a function of
tau alone, see :mod:`biped_casadi.control`).  In single support the robot follows
eq. (1), D(q) ddq + H(q, dq) = B u, with the controller's torque u; the step ends when
the swing foot reaches the ground in front of the stance foot while moving down
(z_sw = 0, x_sw > 0, dz_sw < 0); the impact map with relabelling (eq. 2-3) starts the
next step with tau = 0.

Integration: classical RK4 with a fixed step h = T / ``rk4_steps`` (T the reference step
duration), evaluated a quarter step at a time in one CasADi call (``mapaccum``); the
impact (a strike beyond ``model.scuff_zone``: anywhere in front of the stance foot for
legs with knees) is located inside its RK4 interval by Newton's method on the length of the last
RK4 step, z_sw(RK4(x_k, eta)) = 0, so the event is exact to round-off for the discrete
scheme.  With the default 2000 steps per T the scheme is the gait's own (SPEC §2), and
the unperturbed closed loop repeats the reference to ~1e-11.

Every node is checked, in time order, and the run stops at the first invalid state
with one of the statuses of :data:`STATUSES` (the logs end with that state):

- ``fell``: hip lower than ``min_hip_height`` or torso past horizontal;
- ``scuffed``: swing foot below the ground where it cannot strike (behind the stance
  foot), or the old stance foot not lifting off after an impact; for legs without knees
  (``model.scuffing_ignored``) the swing foot may pass below the ground during the step
  (scuffing ignored, as in Grizzle, Abba & Plestan 2001) and the step ends at its first
  downward crossing of the ground beyond ``model.scuff_zone`` in front of the stance
  foot;
- ``negative_normal_force`` / ``slipped``: stance reaction F_z < ``min_normal_force``
  or |F_x| > mu F_z, in single support and for the impact impulse;
- ``singular``: the controller's decoupling denominator vanishes or changes sign
  (eq. 23-24 for the time-varying controller);
- ``no_impact``: no valid impact within ``horizon`` T; ``out_of_range``: the state left
  the range where the controller's reference is defined (or a step cannot start, e.g.
  the phase variable moving backwards); ``diverged``: not finite.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import casadi as ca
import numpy as np

from ..caching import cached
from ..numerics import as_vector, jit_options, rk4_step
from ..control.output_law import SECTION
from ..results import Result, internal, json_safe
from .validity import first_violation, impact_violation, node_violations

__all__ = ["SimulationOptions", "StepRecord", "SimulationResult", "Simulator", "simulate",
           "simulator", "perturbed_initial_state", "STATUSES", "PAPER_PERTURBATION"]

STATUSES = ("ok", "fell", "scuffed", "negative_normal_force", "slipped", "torque_limit",
            "singular", "no_impact", "out_of_range", "diverged")

#: the perturbation of paper §V-C: 0.01 rad on every joint, 0.1 rad/s on every velocity
PAPER_PERTURBATION = (0.01, 0.1)

@dataclass(frozen=True)
class SimulationOptions:
    """Options of :func:`simulate` and :class:`Simulator`; all have defaults.

    Parameters
    ----------
    steps : int
        Number of steps (impacts) to simulate.
    rk4_steps : int
        RK4 steps per reference step duration T (a positive multiple of 8).
    mu : float
        Friction coefficient for the stance foot and the impact impulse.
    min_normal_force : float
        Lowest admissible stance normal force, N.
    min_hip_height : float or None
        The robot has fallen when the hip is lower, m; None (default): 0.5625 leg length
        (0.45 m for RABBIT), see :meth:`fall_height`.
    max_torso_angle : float
        The robot has also fallen when the torso leans more than this from the
        vertical, rad.
    horizon : float
        A step without a valid impact within ``horizon`` T ends the run ('no_impact').
    ground_tolerance : float
        How far below the ground (m) the swing foot may graze behind the stance foot
        before the run counts as scuffed (round-off at lift-off).
    singular_tolerance : float
        The run stops as singular where the controller's decoupling denominator
        (D11 - D12 M1 for the time-varying controller, eq. 23-24) changes sign or falls
        below this fraction of its largest magnitude on the reference (the torques grow
        like its inverse).
    torque_limit : float or None
        The run stops ('torque_limit') where some ``|u_i|`` exceeds it, N m; None
        (default): the robot's own limit (``model.params.torque_limit``).
    min_liftoff_speed : float
        The old stance foot must leave the ground after an impact with at least this
        upward speed, m/s (default 0: any upward speed).
    jit : bool
        Compile the closed loop to C (CasADi JIT, needs a C compiler; a few seconds
        once per controller, then about 5 times faster).
    """
    steps: int = 10
    rk4_steps: int = 2000
    mu: float = 0.6
    min_normal_force: float = 0.0
    min_hip_height: float | None = None
    max_torso_angle: float = math.pi / 2
    horizon: float = 2.0
    ground_tolerance: float = 1e-9
    singular_tolerance: float = 0.01
    torque_limit: float | None = None
    min_liftoff_speed: float = 0.0
    jit: bool = False

    def __post_init__(self):
        if not isinstance(self.steps, int) or self.steps < 1:
            raise ValueError(f"steps must be a positive integer, got {self.steps!r}")
        if not isinstance(self.rk4_steps, int) or self.rk4_steps < 8 or self.rk4_steps % 8:
            raise ValueError(f"rk4_steps must be a positive multiple of 8, got {self.rk4_steps!r}")
        for name in ("mu", "max_torso_angle", "horizon") + (
                ("min_hip_height",) if self.min_hip_height is not None else ()):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        if self.torque_limit is not None and not (
                isinstance(self.torque_limit, (int, float)) and self.torque_limit > 0):
            raise ValueError(f"torque_limit must be a positive number or None, "
                             f"got {self.torque_limit!r}")
        for name in ("min_normal_force", "ground_tolerance", "singular_tolerance",
                     "min_liftoff_speed"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ValueError(f"{name} must be a non-negative number, got {v!r}")
        if self.horizon <= SECTION:
            raise ValueError(f"horizon must exceed {SECTION} (the Poincaré section), "
                             f"got {self.horizon!r}")

    def to_dict(self) -> dict:
        """The options by name.

        Returns
        -------
        dict
            Field name -> value.
        """
        return asdict(self)

    def fall_height(self, model) -> float:
        """The hip height below which ``model`` has fallen, m.

        Parameters
        ----------
        model : BipedModel
            The robot (its leg length sets the default).

        Returns
        -------
        float
            ``min_hip_height``, or 0.5625 leg length when it is None (0.45 m for
            RABBIT).
        """
        if self.min_hip_height is not None:
            return float(self.min_hip_height)
        return float(0.5625 * model.description.leg_length)


@dataclass
class StepRecord:
    """One completed step, from tau = 0 to its impact.

    qu_error, dqu_error: q_u - q_u^d(T) and dq_u - dq_u^d(T) just before the impact;
    section: (q_u, dq_u) at tau = 0.75 T (None if the impact came earlier) and
    section_error its difference from the reference's (q_u^d, dq_u^d)(0.75 T)."""
    index: int
    t_start: float
    t_impact: float
    duration: float
    q_minus: np.ndarray
    dq_minus: np.ndarray
    q_plus: np.ndarray
    dq_plus: np.ndarray
    impulse: np.ndarray
    qu_error: float
    dqu_error: float
    section: np.ndarray | None
    section_error: np.ndarray | None
    step_length: float

    def to_dict(self) -> dict:
        """Every field in plain JSON types."""
        return json_safe(asdict(self))


@dataclass
class SimulationResult(Result):
    """A closed-loop run: status, completed steps, validity margins and logs.

    ``success`` (and ``ok``) means status 'ok': every step was valid.  The extremes are
    taken over the whole run up to its end.  The logs have one row per RK4 node, in time
    order (an impact appears as its pre-impact node followed by the post-impact node at
    the same t; torques and reactions at the pre-impact node are the single-support
    values), and are left out of ``to_dict()``.

    Parameters
    ----------
    status : str
        One of :data:`STATUSES`.
    message : str
        What went wrong, naming the step (empty when 'ok').
    controller : dict
        The controller's ``describe()``.
    options : SimulationOptions
        The options of the run.
    steps : list of StepRecord
        One record per completed step (impact times, states before and after the
        impact, the impulse, ``qu_error``/``dqu_error`` before the impact).
    peak_torque : float
        max ``|u_i|``, N m.
    min_normal_force : float
        Smallest stance normal force F_z, N.
    max_friction_ratio : float
        max ``|F_x|/F_z`` in single support.
    max_impulse_ratio : float
        max ``|F_x|/F_z`` of the impact impulses.
    failure_time : float
        Time of the first invalid state, s (NaN when 'ok').
    reference : dict
        ``T`` and the reference's (q_u^d, dq_u^d)(T) (``qu_T``, ``dqu_T``).
    t, tau : numpy.ndarray
        (N,) time since the start of the run and since the start of the step, s.
    step : numpy.ndarray
        (N,) index of the step each node belongs to.
    q, dq : numpy.ndarray
        (N, nq) configuration (rad) and velocity (rad/s).
    u, y, dy : numpy.ndarray
        (N, nu) torques (N m), outputs and their rates.
    Fx, Fz : numpy.ndarray
        (N,) stance reaction, N.
    denominator : numpy.ndarray
        (N,) the controller's singularity measure (D11 - D12 M1 for the time-varying
        controller).
    stance_x : numpy.ndarray
        (N,) world x of the stance foot, m.
    failed_step : int or None
        Index of the step where the run failed (None when it did not).
    """
    status: str
    message: str
    controller: dict
    options: SimulationOptions
    steps: list
    peak_torque: float
    min_normal_force: float
    max_friction_ratio: float
    max_impulse_ratio: float
    failure_time: float
    reference: dict
    t: np.ndarray = internal()
    tau: np.ndarray = internal()
    step: np.ndarray = internal()
    q: np.ndarray = internal()
    dq: np.ndarray = internal()
    u: np.ndarray = internal()
    y: np.ndarray = internal()
    dy: np.ndarray = internal()
    Fx: np.ndarray = internal()
    Fz: np.ndarray = internal()
    denominator: np.ndarray = internal()
    stance_x: np.ndarray = internal()
    failed_step: int | None = None

    SUCCESS = ("ok",)

    @property
    def ok(self) -> bool:
        """Same as ``success``."""
        return self.success

    @property
    def impact_times(self) -> np.ndarray:
        """Time of every impact since the start of the run, s."""
        return np.array([s.t_impact for s in self.steps])

    @property
    def qu_errors(self) -> np.ndarray:
        """q_u - q_u^d(T) just before each impact."""
        return np.array([s.qu_error for s in self.steps])

    @property
    def dqu_errors(self) -> np.ndarray:
        """dq_u - dq_u^d(T) just before each impact."""
        return np.array([s.dqu_error for s in self.steps])

    @property
    def section_errors(self) -> np.ndarray:
        """(n_steps, 2): (q_u, dq_u) - reference at tau = 0.75 T; NaN where not reached."""
        return np.array([s.section_error if s.section_error is not None else [np.nan, np.nan]
                         for s in self.steps]).reshape(-1, 2)

    def steps_to_converge(self, tol: float = 1e-3):
        """The step from which the unactuated errors stay below ``tol`` to the end.

        Parameters
        ----------
        tol : float
            Bound on max(``|q_u err|``, ``|dq_u err|``) just before each impact (rad,
            rad/s).

        Returns
        -------
        int or None
            1-based index of that step, None if the run never gets there.
        """
        errs = [max(abs(s.qu_error), abs(s.dqu_error)) for s in self.steps]
        for k in range(len(errs)):
            if all(e < tol for e in errs[k:]):
                return k + 1
        return None


def perturbed_initial_state(gait, q_error=0.0, dq_error=0.0):
    """A perturbed start (q, dq) = (q^d(0) + q_error, dq^d(0) + dq_error).

    Parameters
    ----------
    gait : Reference
        The reference; its state at tau = 0 is perturbed.
    q_error, dq_error : float or array_like
        A number added to every joint (paper §V-C: 0.01 rad and 0.1 rad/s) or one
        number per joint.

    Returns
    -------
    tuple of numpy.ndarray
        (q, dq), each (nq,).
    """
    nq = gait.model.nq

    def err(e, name):
        if np.ndim(e) == 0:
            return np.full(nq, float(as_vector([e], 1, name)[0]))
        return as_vector(e, nq, name)
    return gait.q(0.0) + err(q_error, "q_error"), gait.dq(0.0) + err(dq_error, "dq_error")


# rows of the per-node diagnostics vector (nu = number of torques)
def _rows(nu):
    U, Y, DY = slice(0, nu), slice(nu, 2 * nu), slice(2 * nu, 3 * nu)
    names = ("DEN", "FX", "FZ", "INR", "XSW", "ZSW", "DZSW", "HIP", "TORSO")
    return U, Y, DY, dict(zip(names, range(3 * nu, 3 * nu + len(names)))), 3 * nu + len(names)


class Simulator:
    """The full-order hybrid closed loop of one controller, its CasADi Functions built once.

    Implements eq. (9): the state X = (q, dq, tau) (with the controller's reference
    state), X' = f_e(X) + g_e(X) u(X) in single support (eq. 1 with the controller's
    torque, tau' = 1) and X+ = Delta_e(X-) on the switching surface (the impact map
    and relabelling of eq. 2-3, tau+ = 0), every contact condition checked on the way.
    ``run(q0, dq0, steps)`` simulates from the initial state (taken as the start of a
    step, tau = 0: the time-varying controller's y_i, dy_i are computed from it).

    Parameters
    ----------
    controller : TimeVaryingController or VirtualConstraintController
        The control law (and through it the model and the reference).
    options : SimulationOptions, optional
        Default ``SimulationOptions()``.
    """

    def __init__(self, controller, options: SimulationOptions | None = None):
        self.options = options if options is not None else SimulationOptions()
        if not isinstance(self.options, SimulationOptions):
            raise ValueError(f"options must be a SimulationOptions, got "
                             f"{type(self.options).__name__}")
        self.controller = controller
        self.model = controller.model
        self.gait = controller.reference
        self.T = self.gait.T
        self.h = self.T / self.options.rk4_steps
        eps = controller.gains.eps
        if eps < 2 * self.h:        # RK4 is stable for h / eps < 2.78 on the output PD
            raise ValueError(f"gain eps = {eps:g} s is below twice the integration step "
                             f"h = T / rk4_steps = {self.h:.3g} s: the output dynamics would "
                             f"be integrated unstably (use eps >= {2 * self.h:.2g} or more "
                             "rk4_steps)")
        self.chunk = self.options.rk4_steps // 8
        self._U, self._Y, self._DY, self._R, self._ndiag = _rows(self.model.nu)
        o = self.options
        self.torque_limit = float(o.torque_limit if o.torque_limit is not None
                                  else self.model.params.torque_limit)
        self.min_hip_height = o.fall_height(self.model)
        self._build()
        ref = self.controller.singularity()
        self._den_scale = max(abs(ref.min_value), abs(ref.max_value))
        self._ref_T = self.gait.state_at(self.T)
        self._ref_s = self.gait.state_at(SECTION * self.T)

    # ------------------------------------------------------------------ build
    def _build(self):
        m, c = self.model, self.controller
        nq = m.nq
        nx = 2 * nq + c.n_ref
        X = ca.SX.sym("X", nx)
        tau = ca.SX.sym("tau")
        p = ca.SX.sym("p", c.n_par)
        h = ca.SX.sym("h")

        def rhs(Xv, stage):
            q, dq, r = Xv[:nq], Xv[nq:2 * nq], Xv[2 * nq:]
            u, _, _, _, dr, _ = c.law(q, dq, tau + stage * h, r, p)
            ddq = m.forward_dynamics(q, dq, u)          # the plant, eq. (1)
            return ca.vertcat(dq, ddq, dr)

        Xn = ca.cse(rk4_step(rhs, X, h))
        jit = jit_options("-O1") if self.options.jit else {}
        self.rk4 = ca.Function("closed_loop_rk4", [X, tau, h, p], [Xn, tau + h],
                               ["X", "tau", "h", "p"], ["X_next", "tau_next"], jit)
        self.advance = self.rk4.mapaccum("closed_loop_chunk", self.chunk, [0, 1], [0, 1])

        q, dq, r = X[:nq], X[nq:2 * nq], X[2 * nq:]
        u, y, dy, den, _, inr = c.law(q, dq, tau, r, p)
        Fx, Fz = m.ground_reaction(q, dq, u)
        xs, zs = m.swing_foot(q)
        _, dzs = m.swing_foot_velocity(q, dq)
        P = m.points(q)
        torso = m.torso_angle(q)
        diag = ca.cse(ca.vertcat(u, y, dy, den, Fx, Fz, inr, xs, zs, dzs, P[1, m.hip_index],
                                 torso))
        self.diagnostics = ca.Function("closed_loop_diagnostics", [X, tau, p], [diag],
                                       ["X", "tau", "p"], ["diag"], jit)
        self.diagnostics_chunk = self.diagnostics.map(self.chunk)
        eta = ca.SX.sym("eta")
        Xe, _ = self.rk4(X, tau, eta, p)
        ze = m.swing_foot(Xe[:nq])[1]
        self.event = ca.Function("impact_event", [X, tau, eta, p], [ze, ca.jacobian(ze, eta), Xe],
                                 ["X", "tau", "eta", "p"], ["z_sw", "dz_deta", "X_event"])

    # ---------------------------------------------------------------- checks
    def _rows(self, D, X):
        """The named rows of a diagnostics block, for :mod:`biped_casadi.simulation.validity`."""
        R = self._R
        return dict(finite=np.all(np.isfinite(D), 0) & np.all(np.isfinite(X), 0),
                    in_range=D[R["INR"]], den=D[R["DEN"]], Fx=D[R["FX"]], Fz=D[R["FZ"]],
                    xsw=D[R["XSW"]], zsw=D[R["ZSW"]], hip=D[R["HIP"]], torso=D[R["TORSO"]],
                    u=D[self._U])

    def _first_failure(self, D, X, z_prev=None, den_sign=1.0):
        """Index and (status, message) of the first invalid node of a block, or None.
        D: diagnostics (rows x n), X: states (nx x n), z_prev: swing-foot heights at the
        previous nodes (a foot already below the ground cannot strike), den_sign: the
        sign of the decoupling denominator at the start of the step."""
        masks = node_violations(self._rows(D, X), self.options, self.torque_limit,
                                self._den_scale, den_sign, z_prev,
                                min_hip_height=self.min_hip_height,
                                scuffing_ignored=self.model.scuffing_ignored)
        first, which = first_violation(masks)
        if which == "":
            return None
        return int(first), str(which), self._failure_message(str(which), D[:, int(first)])

    def _failure_message(self, which, d):
        o, R = self.options, self._R
        return {
            "diverged": "the state is not finite",
            "out_of_range": "the state left the range where the controller's reference is "
                            "defined",
            "singular": f"controller singular: decoupling denominator {d[R['DEN']]:.4g} "
                        f"(below {o.singular_tolerance:g} of {self._den_scale:.4g}, "
                        "eq. 23-24)",
            "fell": f"fell: hip height {d[R['HIP']]:.4f} m, torso angle {d[R['TORSO']]:.4f} rad",
            "scuffed": f"swing foot below the ground where it cannot strike (behind the "
                       f"stance foot, or already under the ground): x_sw = {d[R['XSW']]:.4f} m, "
                       f"z_sw = {d[R['ZSW']]:.3g} m",
            "negative_normal_force": f"stance normal force F_z = {d[R['FZ']]:.4g} N",
            "slipped": f"stance foot slips: |F_x| / F_z = "
                       f"{abs(d[R['FX']]) / max(d[R['FZ']], 1e-300):.4f} > mu = {o.mu}",
            "torque_limit": f"torque limit exceeded: |u| = {np.max(np.abs(d[self._U])):.4g} "
                            f"N m > {self.torque_limit:g} N m",
        }[which]

    def _impact_failure(self, F, dq_plus, q_plus, v_old):
        """Status and message when the impact itself is invalid, else None."""
        o = self.options
        finite = bool(np.all(np.isfinite(np.r_[q_plus, dq_plus, F])))
        which = str(impact_violation(F, v_old[1], finite, o))
        if not which:
            return None
        return which, {
            "diverged": "the impact map is not finite",
            "negative_normal_force": f"impact impulse has normal component {F[1]:.4g} N s",
            "slipped": (f"impact impulse outside the friction cone: |F_x| / F_z = "
                        f"{abs(F[0]) / F[1]:.4f} > mu = {o.mu}"),
            "scuffed": (f"the old stance foot does not lift off after the impact "
                        f"(vertical velocity {v_old[1]:.4g} m/s, needs more than "
                        f"{o.min_liftoff_speed:g})"),
        }[which]

    # ------------------------------------------------------------------ run
    def run(self, q0, dq0, steps: int | None = None) -> SimulationResult:
        """Simulate ``steps`` steps (default: options.steps) from (q0, dq0) at tau = 0.

        Parameters
        ----------
        q0, dq0 : array_like
            Initial state (the start of a step).
        steps : int, optional
            Number of steps (impacts).

        Returns
        -------
        SimulationResult
            Status, step records and logs.
        """
        nq = self.model.nq
        q = as_vector(q0, nq, "q0")
        dq = as_vector(dq0, nq, "dq0")
        steps = self.options.steps if steps is None else steps
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
            raise ValueError(f"steps must be a positive integer, got {steps!r}")
        log = _Log(self._ndiag)
        records: list[StepRecord] = []
        walk = dict(t0=0.0, stance_x=0.0)
        failure = None
        for k in range(steps):
            failure, event = self._single_support(k, q, dq, walk, log)
            if failure is not None:
                break
            failure, rec = self._impact(k, event, walk, log)
            if rec is not None:
                records.append(rec)
            if failure is not None:
                break
            walk["t0"] += rec.duration
            walk["stance_x"] += rec.step_length
            q, dq = rec.q_plus, rec.dq_plus
        status, message, t_fail = failure if failure is not None else ("ok", "", math.nan)
        if status != "ok" and not message.startswith("step"):
            message = f"step {len(records)}: {message}"
        res = log.result(status, message, self.controller.describe(), self.options, records,
                         t_fail, dict(T=self.T, qu_T=self._ref_T[0], dqu_T=self._ref_T[1]),
                         self._U, self._R)
        res.failed_step = k if failure is not None else None
        return res

    def _single_support(self, k, q, dq, walk, log):
        """Integrate step ``k`` from its start to the swing foot's strike.  Returns
        (failure, event): failure (status, message, time) or None; event (X-, tau-)."""
        o, c, T, h, R = self.options, self.controller, self.T, self.h, self._R
        t0, sx = walk["t0"], walk["stance_x"]
        start = c.step_start(q, dq)
        p = start.p
        X = np.r_[q, dq, start.r]
        if start.problem:
            log.add(t0, np.zeros(1), k, X[:, None], np.full((self._ndiag, 1), np.nan), sx)
            return ("out_of_range", start.problem, t0), None
        D0 = np.array(self.diagnostics(X, 0.0, p))
        walk["den_sign"] = sign = 1.0 if D0[R["DEN"], 0] >= 0 else -1.0
        fail = self._first_failure(D0, X[:, None], den_sign=sign)
        if fail is None and D0[R["ZSW"], 0] < -o.ground_tolerance:
            fail = (0, "scuffed", f"swing foot below the ground at the start of step {k} "
                                  f"(z_sw = {D0[R['ZSW'], 0]:.3g} m)")
        log.add(t0, np.zeros(1), k, X[:, None], D0, sx)
        if fail is not None:
            return (fail[1], fail[2], t0), None
        walk["p"], walk["section"] = p, None
        z_prev = D0[R["ZSW"], 0]
        for ci in range(int(math.ceil(o.horizon * 8))):
            tau0 = ci * T / 8
            Xs, taus = (np.array(v) for v in self.advance(X, tau0, h, p))
            taus = taus.ravel()
            Dg = np.array(self.diagnostics_chunk(Xs, taus[None, :], p))
            if tau0 + T / 8 > o.horizon * T + 1e-12:      # last partial chunk
                keep = taus <= o.horizon * T + 1e-12
                Xs, taus, Dg = Xs[:, keep], taus[keep], Dg[:, keep]
            zs = Dg[R["ZSW"]]
            zprev = np.r_[z_prev, zs[:-1]]
            with np.errstate(invalid="ignore"):
                strike = (zs < 0) & (Dg[R["XSW"]] > self.model.scuff_zone) & (zprev >= 0)
            i_strike = int(np.argmax(strike)) if strike.any() else Xs.shape[1]
            fail = self._first_failure(Dg[:, :i_strike], Xs[:, :i_strike], zprev[:i_strike],
                                       den_sign=sign)
            if fail is not None:
                j = fail[0]
                log.add(t0, taus[:j + 1], k, Xs[:, :j + 1], Dg[:, :j + 1], sx)
                return (fail[1], fail[2], t0 + taus[j]), None
            if i_strike < Xs.shape[1]:
                Xa = X if i_strike == 0 else Xs[:, i_strike - 1]
                ta = tau0 if i_strike == 0 else taus[i_strike - 1]
                za = z_prev if i_strike == 0 else zs[i_strike - 1]
                log.add(t0, taus[:i_strike], k, Xs[:, :i_strike], Dg[:, :i_strike], sx)
                return None, self._locate(Xa, ta, za, zs[i_strike], p)
            log.add(t0, taus, k, Xs, Dg, sx)
            if abs(tau0 + T / 8 - SECTION * T) < 1e-12 * T:
                walk["section"] = np.array([Xs[0, -1], Xs[self.model.nq, -1]])
            X, z_prev = Xs[:, -1], zs[-1]
        return ("no_impact", f"step {k}: no valid impact of the swing foot within "
                             f"{o.horizon:g} T = {o.horizon * T:.4f} s", t0 + o.horizon * T), None

    def _impact(self, k, event, walk, log):
        """Check the pre-impact state, apply the impact map (eq. 2-3) and check the
        impulse.  Returns (failure or None, StepRecord or None)."""
        m, R, nq = self.model, self._R, self.model.nq
        t0, sx, p = walk["t0"], walk["stance_x"], walk["p"]
        X_m, tau_m = event
        Dm = np.array(self.diagnostics(X_m, tau_m, p))
        log.add(t0, np.array([tau_m]), k, X_m[:, None], Dm, sx)
        fail = self._first_failure(Dm, X_m[:, None], den_sign=walk["den_sign"])
        if fail is None and not Dm[R["DZSW"], 0] < 0:
            fail = (0, "scuffed", "the swing foot reaches the ground without moving down")
        if fail is not None:
            return (fail[1], fail[2], t0 + tau_m), None
        q_m, dq_m = X_m[:nq], X_m[nq:2 * nq]
        q_p, dq_p, F, _, v_old = (np.array(v).ravel() for v in m.impact_full(q_m, dq_m))
        section = walk["section"]
        rec = StepRecord(index=k, t_start=t0, t_impact=t0 + tau_m, duration=tau_m,
                         q_minus=q_m, dq_minus=dq_m, q_plus=q_p, dq_plus=dq_p, impulse=F,
                         qu_error=float(q_m[0] - self._ref_T[0]),
                         dqu_error=float(dq_m[0] - self._ref_T[1]),
                         section=section,
                         section_error=None if section is None else section - self._ref_s,
                         step_length=float(Dm[R["XSW"], 0]))
        bad = self._impact_failure(F, dq_p, q_p, v_old)
        if bad is not None:
            return (bad[0], f"step {k}: {bad[1]}", t0 + tau_m), rec
        return None, rec

    def _locate(self, Xa, ta, za, zb, p):
        """Pre-impact state: the RK4 step length eta in (0, h] with z_sw = 0 (Newton with
        bisection safeguard)."""
        lo, hi = 0.0, self.h
        eta = self.h * za / (za - zb) if za > zb else self.h
        for _ in range(60):
            z, dz, _ = self.event(Xa, ta, eta, p)
            z, dz = float(z), float(dz)
            if z > 0:
                lo = eta
            else:
                hi = eta
            if abs(z) < 1e-15:
                break
            new = eta - z / dz if dz != 0 else 0.5 * (lo + hi)
            if not lo < new < hi:
                new = 0.5 * (lo + hi)
            if abs(new - eta) < 1e-17:
                eta = new
                break
            eta = new
        _, _, Xe = self.event(Xa, ta, eta, p)
        return np.array(Xe).ravel(), ta + eta


class _Log:
    """Accumulates per-node logs."""

    def __init__(self, ndiag):
        self.parts = []
        self.ndiag = ndiag

    def add(self, t0, taus, k, X, D, stance_x):
        taus = np.asarray(taus, dtype=float).ravel()
        if taus.size == 0:
            return
        self.parts.append((t0 + taus, taus, np.full(taus.size, k), X.T, D.T,
                           np.full(taus.size, stance_x)))

    def result(self, status, message, controller, options, records, t_fail, reference, U, R):
        nx = None
        if self.parts:
            t, tau, st, X, D, sx = (np.concatenate([p[i] for p in self.parts])
                                     for i in range(6))
        else:
            t = tau = sx = np.zeros(0)
            st = np.zeros(0, int)
            X, D = np.zeros((0, 0)), np.zeros((0, self.ndiag))
        nq = (U.stop - U.start) + 1
        nx = 2 * nq
        X = X[:, :nx] if X.size else np.zeros((0, nx))
        u = D[:, U]
        Fx, Fz = D[:, R["FX"]], D[:, R["FZ"]]
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = np.abs(Fx) / np.maximum(Fz, 1e-300)
        imp = [abs(r.impulse[0]) / r.impulse[1] if r.impulse[1] > 0 else math.inf
               for r in records]
        return SimulationResult(
            status=status, message=message, controller=controller, options=options,
            steps=records,
            peak_torque=_nan_extreme(np.nanmax, np.abs(u)),
            min_normal_force=_nan_extreme(np.nanmin, Fz),
            max_friction_ratio=_nan_extreme(np.nanmax, ratio),
            max_impulse_ratio=float(max(imp)) if imp else math.nan,
            failure_time=t_fail, reference=reference,
            t=t, tau=tau, step=st.astype(int), q=X[:, :nq], dq=X[:, nq:nx], u=u,
            y=D[:, slice(U.stop, 2 * U.stop)], dy=D[:, slice(2 * U.stop, 3 * U.stop)],
            Fx=Fx, Fz=Fz, denominator=D[:, R["DEN"]], stance_x=sx)


def _nan_extreme(fn, a) -> float:
    """``fn`` (nanmax or nanmin) of ``a``; NaN when nothing finite was logged (a run that
    diverged at once), without numpy's warning."""
    return float(fn(a)) if np.any(~np.isnan(a)) else math.nan


@cached(maxsize=8)
def simulator(controller, options: SimulationOptions | None = None) -> Simulator:
    """The :class:`Simulator` of a controller and options, built once (memoised by
    the controller's content and the options)."""
    return Simulator(controller, options if options is not None else SimulationOptions())


def simulate(controller, q0=None, dq0=None, options: SimulationOptions | None = None,
             steps: int | None = None) -> SimulationResult:
    """Simulate the closed loop of ``controller`` from (q0, dq0).

    Parameters
    ----------
    controller : TimeVaryingController or VirtualConstraintController
        The control law.
    q0, dq0 : array_like, optional
        Initial state (the start of a step, tau = 0), rad and rad/s; default the
        reference at tau = 0.
    options : SimulationOptions, optional
        Default ``SimulationOptions()``.
    steps : int, optional
        Overrides ``options.steps``.

    Returns
    -------
    SimulationResult
        Status, step records and logs.
    """
    sim = simulator(controller, options if options is not None else SimulationOptions())
    g = controller.reference
    q0 = g.q(0.0) if q0 is None else q0
    dq0 = g.dq(0.0) if dq0 is None else dq0
    return sim.run(q0, dq0, steps)
