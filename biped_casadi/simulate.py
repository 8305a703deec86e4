"""Full-order hybrid closed-loop simulation of walking (paper eq. 9; SPEC §1 impact, §4
guard).

State (q, dq, tau), 11 numbers, plus the controller's reference state r (a function of
tau alone, see :mod:`biped_casadi.controllers`).  In single support the robot follows
eq. (1), D(q) ddq + H(q, dq) = B u, with the controller's torque u; the step ends when
the swing foot reaches the ground in front of the stance foot while moving down
(z_sw = 0, x_sw > 0, dz_sw < 0); the impact map with relabelling (eq. 2-3) starts the
next step with tau = 0.

Integration: classical RK4 with a fixed step h = T / ``rk4_steps`` (T the reference step
duration), evaluated a quarter step at a time in one CasADi call (``mapaccum``); the
impact is located inside its RK4 interval by Newton's method on the length of the last
RK4 step, z_sw(RK4(x_k, eta)) = 0, so the event is exact to round-off for the discrete
scheme.  With the default 2000 steps per T the scheme is the gait's own (SPEC §2), and
the unperturbed closed loop repeats the reference to ~1e-11.

Every node is checked, in time order, and the run stops at the first invalid state
with one of the statuses of :data:`STATUSES` (the logs end with that state):

- ``fell``: hip lower than ``min_hip_height`` or torso past horizontal;
- ``scuffed``: swing foot below the ground where it cannot strike (behind the stance
  foot), or the old stance foot not lifting off after an impact;
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
from dataclasses import asdict, dataclass, field

import casadi as ca
import numpy as np

__all__ = ["SimulationOptions", "StepRecord", "SimulationResult", "Simulator", "simulate",
           "perturbed_initial_state", "STATUSES", "SECTION", "PAPER_PERTURBATION",
           "plot_fig5", "plot_fig6", "animate", "fig5_fig6"]

STATUSES = ("ok", "fell", "scuffed", "negative_normal_force", "slipped", "singular",
            "no_impact", "out_of_range", "diverged")
#: Poincaré section tau = 0.75 T (SPEC §4)
SECTION = 0.75

# rows of the per-node diagnostics vector
_U, _Y, _DY = slice(0, 4), slice(4, 8), slice(8, 12)
_DEN, _FX, _FZ, _INR, _XSW, _ZSW, _DZSW, _HIP, _TORSO = range(12, 21)
_NDIAG = 21


@dataclass(frozen=True)
class SimulationOptions:
    """Options of :func:`simulate`; all have defaults.

    steps: number of steps (impacts) to simulate.
    rk4_steps: RK4 steps per reference step duration T (a multiple of 4).
    mu: friction coefficient for the stance foot and the impact impulse.
    min_normal_force: lowest admissible stance normal force, N.
    min_hip_height: the robot has fallen when the hip is lower, m.
    max_torso_angle: ... or when the torso leans more than this from the vertical, rad.
    horizon: a step without a valid impact within horizon * T ends the run (no_impact).
    ground_tolerance: how far below the ground (m) the swing foot may graze behind the
        stance foot before the run counts as scuffed (round-off at lift-off).
    singular_tolerance: the run stops as singular where the controller's decoupling
        denominator (D11 - D12 M1 for the time-varying controller, eq. 23-24) changes
        sign or falls below this fraction of its largest magnitude on the reference
        (the torques grow like its inverse).
    jit: compile the closed loop to C (CasADi JIT, needs a C compiler; a few seconds
        once per controller, then about 5 times faster).
    """
    steps: int = 10
    rk4_steps: int = 2000
    mu: float = 0.6
    min_normal_force: float = 0.0
    min_hip_height: float = 0.45
    max_torso_angle: float = math.pi / 2
    horizon: float = 2.0
    ground_tolerance: float = 1e-9
    singular_tolerance: float = 0.01
    jit: bool = False

    def __post_init__(self):
        if not isinstance(self.steps, int) or self.steps < 1:
            raise ValueError(f"steps must be a positive integer, got {self.steps!r}")
        if not isinstance(self.rk4_steps, int) or self.rk4_steps < 8 or self.rk4_steps % 8:
            raise ValueError(f"rk4_steps must be a positive multiple of 8, got {self.rk4_steps!r}")
        for name in ("mu", "min_hip_height", "max_torso_angle", "horizon"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        for name in ("min_normal_force", "ground_tolerance", "singular_tolerance"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ValueError(f"{name} must be a non-negative number, got {v!r}")
        if self.horizon <= SECTION:
            raise ValueError(f"horizon must exceed {SECTION} (the Poincaré section), "
                             f"got {self.horizon!r}")

    def to_dict(self) -> dict:
        return asdict(self)


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
        arr = lambda a: None if a is None else np.asarray(a).tolist()    # noqa: E731
        return dict(index=self.index, t_start=self.t_start, t_impact=self.t_impact,
                    duration=self.duration, qu_error=self.qu_error, dqu_error=self.dqu_error,
                    section=arr(self.section), section_error=arr(self.section_error),
                    step_length=self.step_length, q_minus=arr(self.q_minus),
                    dq_minus=arr(self.dq_minus), q_plus=arr(self.q_plus),
                    dq_plus=arr(self.dq_plus), impulse=arr(self.impulse))


@dataclass
class SimulationResult:
    """A closed-loop run: status, completed steps and logs at every RK4 node.

    Logs (one row per node, in time order; an impact appears as its pre-impact node
    followed by the post-impact node at the same t): t, tau, step (index of the step
    the node belongs to), q, dq (N x 5), u, y, dy (N x 4), Fx, Fz (stance reaction),
    denominator (controller singularity measure), stance_x (world x of the stance
    foot).  Torques and reactions at the pre-impact node are the single-support values.
    """
    status: str
    message: str
    controller: dict
    options: SimulationOptions
    steps: list
    t: np.ndarray
    tau: np.ndarray
    step: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    u: np.ndarray
    y: np.ndarray
    dy: np.ndarray
    Fx: np.ndarray
    Fz: np.ndarray
    denominator: np.ndarray
    stance_x: np.ndarray
    failure_time: float = math.nan
    reference: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def impact_times(self) -> np.ndarray:
        return np.array([s.t_impact for s in self.steps])

    @property
    def qu_errors(self) -> np.ndarray:
        return np.array([s.qu_error for s in self.steps])

    @property
    def dqu_errors(self) -> np.ndarray:
        return np.array([s.dqu_error for s in self.steps])

    @property
    def section_errors(self) -> np.ndarray:
        """(n_steps, 2): (q_u, dq_u) - reference at tau = 0.75 T; NaN where not reached."""
        return np.array([s.section_error if s.section_error is not None else [np.nan, np.nan]
                         for s in self.steps]).reshape(-1, 2)

    def summary(self) -> dict:
        """The JSON of ``biped simulate --json``."""
        return dict(status=self.status, message=self.message, controller=self.controller,
                    steps=[dict(t_impact=s.t_impact, qu_error=s.qu_error,
                                dqu_error=s.dqu_error, duration=s.duration,
                                step_length=s.step_length) for s in self.steps],
                    peak_torque=float(np.max(np.abs(self.u))) if self.u.size else math.nan,
                    min_normal_force=float(np.min(self.Fz)) if self.Fz.size else math.nan,
                    max_friction_ratio=float(np.max(np.abs(self.Fx) / np.maximum(self.Fz, 1e-300)))
                    if self.Fz.size else math.nan,
                    failure_time=None if math.isnan(self.failure_time) else self.failure_time)

    def to_dict(self) -> dict:
        d = self.summary()
        d["steps"] = [s.to_dict() for s in self.steps]
        d["options"] = self.options.to_dict()
        return d


def perturbed_initial_state(gait, q_error=0.0, dq_error=0.0):
    """(q, dq) = (q^d(0) + q_error, dq^d(0) + dq_error); the errors are a number added to
    every joint (paper §V-C: 0.01 rad and 0.1 rad/s) or 5-vectors."""
    def err(e, name):
        a = np.broadcast_to(np.asarray(e, dtype=float), (5,)) if np.ndim(e) == 0 else np.asarray(e, float)
        if a.shape != (5,) or not np.all(np.isfinite(a)):
            raise ValueError(f"{name} must be a finite number or 5 finite numbers, got {e!r}")
        return a
    return gait.q(0.0) + err(q_error, "q_error"), gait.dq(0.0) + err(dq_error, "dq_error")


class Simulator:
    """The closed loop of one controller, its CasADi Functions built once.

    ``run(q0, dq0, steps)`` simulates from the initial state (taken as the start of a
    step, tau = 0: the time-varying controller's y_i, dy_i are computed from it).
    """

    def __init__(self, controller, options: SimulationOptions | None = None):
        self.options = options if options is not None else SimulationOptions()
        if not isinstance(self.options, SimulationOptions):
            raise ValueError(f"options must be a SimulationOptions, got "
                             f"{type(self.options).__name__}")
        self.controller = controller
        self.model = controller.model
        self.gait = controller.gait
        self.T = self.gait.T
        self.h = self.T / self.options.rk4_steps
        self.chunk = self.options.rk4_steps // 8
        self._build()
        ref = self.controller.singularity()
        self._den_scale = max(abs(ref.min_value), abs(ref.max_value))
        self._den_sign = 1.0          # sign of the denominator at the start of the step
        self._ref_T = self.gait.state_at(self.T)
        self._ref_s = self.gait.state_at(SECTION * self.T)

    # ------------------------------------------------------------------ build
    def _build(self):
        m, c = self.model, self.controller
        nx = 10 + c.n_ref
        X = ca.SX.sym("X", nx)
        tau = ca.SX.sym("tau")
        p = ca.SX.sym("p", c.n_par)
        h = ca.SX.sym("h")

        def rhs(Xv, tv):
            q, dq, r = Xv[:5], Xv[5:10], Xv[10:]
            u, _, _, _, dr, _ = c.law(q, dq, tv, r, p)
            ddq = m.forward_dynamics(q, dq, u)          # the plant, eq. (1)
            return ca.vertcat(dq, ddq, dr)

        k1 = rhs(X, tau)
        k2 = rhs(X + h / 2 * k1, tau + h / 2)
        k3 = rhs(X + h / 2 * k2, tau + h / 2)
        k4 = rhs(X + h * k3, tau + h)
        Xn = ca.cse(X + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4))
        jit = dict(jit=True, compiler="shell", jit_options=dict(flags=["-O1"])) \
            if self.options.jit else {}
        self.rk4 = ca.Function("closed_loop_rk4", [X, tau, h, p], [Xn, tau + h],
                               ["X", "tau", "h", "p"], ["X_next", "tau_next"], jit)
        acc = self.rk4.mapaccum("closed_loop_chunk", self.chunk, [0, 1], [0, 1])
        self.advance = acc

        q, dq, r = X[:5], X[5:10], X[10:]
        u, y, dy, den, _, inr = c.law(q, dq, tau, r, p)
        Fx, Fz = m.ground_reaction(q, dq, u)
        xs, zs = m.swing_foot(q)
        _, dzs = m.swing_foot_velocity(q, dq)
        P = m.points(q)
        phi3 = q[0] + q[1] + q[2]
        diag = ca.cse(ca.vertcat(u, y, dy, den, Fx, Fz, inr, xs, zs, dzs, P[1, 2], phi3))
        self.diagnostics = ca.Function("closed_loop_diagnostics", [X, tau, p], [diag],
                                       ["X", "tau", "p"], ["diag"], jit)
        self.diagnostics_chunk = self.diagnostics.map(self.chunk)
        eta = ca.SX.sym("eta")
        Xe, _ = self.rk4(X, tau, eta, p)
        ze = m.swing_foot(Xe[:5])[1]
        self.event = ca.Function("impact_event", [X, tau, eta, p], [ze, ca.jacobian(ze, eta), Xe],
                                 ["X", "tau", "eta", "p"], ["z_sw", "dz_deta", "X_event"])

    # ---------------------------------------------------------------- checks
    def _first_failure(self, D, X, z_prev=None):
        """Index and (status, message) of the first invalid node of a block, or None.
        D: diagnostics (_NDIAG x n), X: states (nx x n), z_prev: swing-foot heights at
        the previous nodes (a foot already below the ground cannot strike)."""
        o = self.options
        n = D.shape[1]
        bad = {}
        finite = np.all(np.isfinite(D), 0) & np.all(np.isfinite(X), 0)
        bad["diverged"] = ~finite
        with np.errstate(invalid="ignore"):
            bad["out_of_range"] = finite & (D[_INR] < 0.5)
            den = D[_DEN] * self._den_sign
            bad["singular"] = finite & (den <= o.singular_tolerance * self._den_scale)
            bad["fell"] = finite & ((D[_HIP] < o.min_hip_height) |
                                    (np.abs(D[_TORSO]) > o.max_torso_angle))
            behind = D[_XSW] <= 0
            if z_prev is not None:
                behind = behind | (np.asarray(z_prev) < 0)
            bad["scuffed"] = finite & (D[_ZSW] < -o.ground_tolerance) & behind
            bad["negative_normal_force"] = finite & (D[_FZ] < o.min_normal_force)
            bad["slipped"] = finite & (np.abs(D[_FX]) > o.mu * D[_FZ])
        first, which = n, None
        for k, mask in bad.items():          # dict order = priority at the same node
            if mask.any():
                i = int(np.argmax(mask))
                if i < first:
                    first, which = i, k
        if which is None:
            return None
        j = first
        msg = {
            "diverged": "the state is not finite",
            "out_of_range": "the state left the range where the controller's reference is "
                            "defined",
            "singular": f"controller singular: decoupling denominator {D[_DEN, j]:.4g} "
                        f"(below {o.singular_tolerance:g} of {self._den_scale:.4g}, "
                        "eq. 23-24)",
            "fell": f"fell: hip height {D[_HIP, j]:.4f} m, torso angle {D[_TORSO, j]:.4f} rad",
            "scuffed": f"swing foot below the ground where it cannot strike (behind the "
                       f"stance foot, or already under the ground): x_sw = {D[_XSW, j]:.4f} m, "
                       f"z_sw = {D[_ZSW, j]:.3g} m",
            "negative_normal_force": f"stance normal force F_z = {D[_FZ, j]:.4g} N",
            "slipped": f"stance foot slips: |F_x| / F_z = "
                       f"{abs(D[_FX, j]) / max(D[_FZ, j], 1e-300):.4f} > mu = {o.mu}",
        }[which]
        return j, which, msg

    # ------------------------------------------------------------------ run
    def run(self, q0, dq0, steps: int | None = None) -> SimulationResult:
        """Simulate ``steps`` steps (default: options.steps) from (q0, dq0) at tau = 0."""
        from .controllers import _vector
        q = _vector(q0, 5, "q0")
        dq = _vector(dq0, 5, "dq0")
        if steps is None:
            steps = self.options.steps
        if not isinstance(steps, int) or steps < 1:
            raise ValueError(f"steps must be a positive integer, got {steps!r}")
        o, c, m, T, h = self.options, self.controller, self.model, self.T, self.h
        log = _Log()
        records: list[StepRecord] = []
        status, message, t_fail = "ok", "", math.nan
        t0 = 0.0
        stance_x = 0.0
        n_chunks = int(math.ceil(o.horizon * 8))
        for k in range(steps):
            start = c.step_start(q, dq)
            p = start.p
            X = np.r_[q, dq, start.r]
            if start.problem:
                log.add(t0, np.zeros(1), k, X[:, None], np.full((_NDIAG, 1), np.nan), stance_x)
                status, message, t_fail = "out_of_range", start.problem, t0
                break
            D0 = np.array(self.diagnostics(X, 0.0, p))
            self._den_sign = 1.0 if D0[_DEN, 0] >= 0 else -1.0
            fail = self._first_failure(D0, X[:, None])
            if fail is None and D0[_ZSW, 0] < -o.ground_tolerance:
                fail = (0, "scuffed", f"swing foot below the ground at the start of step {k} "
                                      f"(z_sw = {D0[_ZSW, 0]:.3g} m)")
            log.add(t0, np.zeros(1), k, X[:, None], D0, stance_x)
            if fail is not None:
                status, message, t_fail = fail[1], fail[2], t0
                break
            section = None
            event = None
            z_prev = D0[_ZSW, 0]
            for ci in range(n_chunks):
                tau0 = ci * T / 8
                Xs, taus = (np.array(v) for v in self.advance(X, tau0, h, p))
                taus = taus.ravel()
                Dg = np.array(self.diagnostics_chunk(Xs, taus[None, :], p))
                if tau0 + T / 8 > o.horizon * T + 1e-12:      # last partial chunk
                    keep = taus <= o.horizon * T + 1e-12
                    Xs, taus, Dg = Xs[:, keep], taus[keep], Dg[:, keep]
                zs = Dg[_ZSW]
                zprev = np.r_[z_prev, zs[:-1]]
                with np.errstate(invalid="ignore"):
                    strike = (zs < 0) & (Dg[_XSW] > 0) & (zprev >= 0)
                i_strike = int(np.argmax(strike)) if strike.any() else Xs.shape[1]
                fail = self._first_failure(Dg[:, :i_strike], Xs[:, :i_strike], zprev[:i_strike])
                if fail is not None:
                    j = fail[0]
                    log.add(t0, taus[:j + 1], k, Xs[:, :j + 1], Dg[:, :j + 1], stance_x)
                    status, message, t_fail = fail[1], fail[2], t0 + taus[j]
                    break
                if i_strike < Xs.shape[1]:
                    Xa = X if i_strike == 0 else Xs[:, i_strike - 1]
                    ta = tau0 if i_strike == 0 else taus[i_strike - 1]
                    za = z_prev if i_strike == 0 else zs[i_strike - 1]
                    zb = zs[i_strike]
                    log.add(t0, taus[:i_strike], k, Xs[:, :i_strike], Dg[:, :i_strike], stance_x)
                    event = self._locate(Xa, ta, za, zb, p)
                    break
                log.add(t0, taus, k, Xs, Dg, stance_x)
                if abs(tau0 + T / 8 - SECTION * T) < 1e-12 * T:
                    section = np.array([Xs[0, -1], Xs[5, -1]])
                X, z_prev = Xs[:, -1], zs[-1]
            if status != "ok":
                break
            if event is None:
                status = "no_impact"
                message = (f"step {k}: no valid impact of the swing foot within "
                           f"{o.horizon:g} T = {o.horizon * T:.4f} s")
                t_fail = t0 + o.horizon * T
                break
            X_m, tau_m = event
            Dm = np.array(self.diagnostics(X_m, tau_m, p))
            log.add(t0, np.array([tau_m]), k, X_m[:, None], Dm, stance_x)
            fail = self._first_failure(Dm, X_m[:, None])
            if fail is None and not Dm[_DZSW, 0] < 0:
                fail = (0, "scuffed", "the swing foot reaches the ground without moving down")
            if fail is not None:
                status, message, t_fail = fail[1], fail[2], t0 + tau_m
                break
            q_m, dq_m = X_m[:5], X_m[5:10]
            q_p, dq_p, F, _, v_old = (np.array(v).ravel() for v in m.impact_full(q_m, dq_m))
            x_step = float(Dm[_XSW, 0])
            rec = StepRecord(index=k, t_start=t0, t_impact=t0 + tau_m, duration=tau_m,
                             q_minus=q_m, dq_minus=dq_m, q_plus=q_p, dq_plus=dq_p, impulse=F,
                             qu_error=float(q_m[0] - self._ref_T[0]),
                             dqu_error=float(dq_m[0] - self._ref_T[1]),
                             section=section,
                             section_error=None if section is None else section - self._ref_s,
                             step_length=x_step)
            impact_fail = None
            if not np.all(np.isfinite(np.r_[q_p, dq_p, F])):
                impact_fail = ("diverged", "the impact map is not finite")
            elif F[1] < o.min_normal_force:
                impact_fail = ("negative_normal_force",
                               f"impact impulse has normal component {F[1]:.4g} N s")
            elif abs(F[0]) > o.mu * F[1]:
                impact_fail = ("slipped", f"impact impulse outside the friction cone: "
                                          f"|F_x| / F_z = {abs(F[0]) / F[1]:.4f} > mu = {o.mu}")
            elif not v_old[1] > 0:
                impact_fail = ("scuffed", f"the old stance foot does not lift off after the "
                                          f"impact (vertical velocity {v_old[1]:.4g} m/s)")
            records.append(rec)
            if impact_fail is not None:
                status, message = impact_fail
                message = f"step {k}: {message}"
                t_fail = t0 + tau_m
                break
            t0 += tau_m
            stance_x += x_step
            q, dq = q_p, dq_p
        if status != "ok" and not message.startswith("step"):
            message = f"step {len(records)}: {message}"
        return log.result(status, message, c.describe(), o, records, t_fail,
                          reference=dict(T=T, qu_T=self._ref_T[0], dqu_T=self._ref_T[1]))

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

    def __init__(self):
        self.parts = []

    def add(self, t0, taus, k, X, D, stance_x):
        taus = np.asarray(taus, dtype=float).ravel()
        if taus.size == 0:
            return
        self.parts.append((t0 + taus, taus, np.full(taus.size, k), X[:10].T, D.T,
                           np.full(taus.size, stance_x)))

    def result(self, status, message, controller, options, records, t_fail, reference):
        if self.parts:
            t, tau, st, X, D, sx = (np.concatenate([p[i] for p in self.parts])
                                     for i in range(6))
        else:
            t = tau = sx = np.zeros(0)
            st = np.zeros(0, int)
            X, D = np.zeros((0, 10)), np.zeros((0, _NDIAG))
        return SimulationResult(status=status, message=message, controller=controller,
                                options=options, steps=records, t=t, tau=tau,
                                step=st.astype(int), q=X[:, :5], dq=X[:, 5:10], u=D[:, _U],
                                y=D[:, _Y], dy=D[:, _DY], Fx=D[:, _FX], Fz=D[:, _FZ],
                                denominator=D[:, _DEN], stance_x=sx, failure_time=t_fail,
                                reference=reference)


def simulate(controller, q0=None, dq0=None, options: SimulationOptions | None = None,
             steps: int | None = None) -> SimulationResult:
    """Simulate the closed loop of ``controller`` from (q0, dq0) (default: the reference
    state at tau = 0).  The :class:`Simulator` (its CasADi Functions) is cached per
    controller object and options."""
    options = options if options is not None else SimulationOptions()
    cache = controller.__dict__.setdefault("_simulators", {})
    sim = cache.get(options)
    if sim is None:
        sim = cache[options] = Simulator(controller, options)
    g = controller.gait
    q0 = g.q(0.0) if q0 is None else q0
    dq0 = g.dq(0.0) if dq0 is None else dq0
    return sim.run(q0, dq0, steps)


# ===================================================== figures and animation
#: the perturbation of paper §V-C: 0.01 rad on every joint, 0.1 rad/s on every velocity
PAPER_PERTURBATION = (0.01, 0.1)


def _label(res: SimulationResult) -> str:
    c = res.controller
    if c.get("controller") == "tv":
        return "time-varying, M1 = [" + ", ".join(f"{v:.4g}" for v in c["M1"]) + "]"
    return "virtual constraints"


def plot_fig5(results, path, title: str | None = None):
    """Paper Fig. 5: q_u - q_u^d(T) (and dq_u - dq_u^d(T)) just before each impact, for
    one or several runs; written to ``path`` (PNG)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    results = results if isinstance(results, (list, tuple)) else [results]
    fig, ax = plt.subplots(2, 1, figsize=(6.4, 5.6), sharex=True)
    for res, mk in zip(results, "os^dv"):
        k = np.arange(1, len(res.steps) + 1)
        lab = _label(res) + ("" if res.ok else f" ({res.status} at t = {res.failure_time:.3f} s)")
        ax[0].plot(k, res.qu_errors, mk + "-", label=lab)
        ax[1].plot(k, res.dqu_errors, mk + "-", label=lab)
    ax[0].set_ylabel(r"$q_u - q_u^d(T)$ [rad]")
    ax[1].set_ylabel(r"$\dot q_u - \dot q_u^d(T)$ [rad/s]")
    ax[1].set_xlabel("step (error just before its impact)")
    for a in ax:
        a.axhline(0, color="0.6", lw=0.8)
        a.grid(alpha=0.3)
    ax[0].legend(fontsize=8)
    fig.suptitle(title or "Fig. 5: error of the unactuated variable at the end of each step")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_fig6(results, gait, path, title: str | None = None):
    """Paper Fig. 6: swing-leg torques u3 (swing hip) and u4 (swing knee) against time,
    with the reference torques u^d(tau) of each step dashed; written to ``path``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    results = results if isinstance(results, (list, tuple)) else [results]
    fig, ax = plt.subplots(2, 1, figsize=(7.2, 5.6), sharex=True)
    for res in results:
        for i, j in enumerate((2, 3)):
            ax[i].plot(res.t, res.u[:, j], lw=1.0, label=_label(res))
    # reference torques, restarted at each step of the first run
    res = results[0]
    for k in np.unique(res.step):
        sel = res.step == k
        tau = np.clip(res.tau[sel], 0, gait.t_max)
        ud = gait.u(tau)
        for i, j in enumerate((2, 3)):
            ax[i].plot(res.t[sel], ud[j], "k--", lw=0.8, label="reference $u^d$" if k == 0 else None)
    ax[0].set_ylabel("u3, swing hip [N m]")
    ax[1].set_ylabel("u4, swing knee [N m]")
    ax[1].set_xlabel("t [s]")
    for a in ax:
        a.grid(alpha=0.3)
    ax[0].legend(fontsize=8)
    fig.suptitle(title or "Fig. 6: torques of the swing leg")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def animate(res: SimulationResult, model, path, fps: int = 25, max_steps: int | None = None):
    """Stick-figure animation of a run (GIF with matplotlib's PillowWriter): the ground,
    the footprints of every stance foot, the stance leg (blue), the swing leg (red) and
    the torso, in real time at ``fps`` frames per second."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.animation import FuncAnimation, PillowWriter
    if not isinstance(fps, int) or fps < 1:
        raise ValueError(f"fps must be a positive integer, got {fps!r}")
    if res.t.size == 0:
        raise ValueError("res: the run has no logged states to animate")
    sel = np.ones(res.t.size, bool) if max_steps is None else res.step < max_steps
    t, q, step, sx = res.t[sel], res.q[sel], res.step[sel], res.stance_x[sel]
    frames = np.searchsorted(t, np.arange(t[0], t[-1] + 1e-12, 1.0 / fps))
    frames = np.unique(np.clip(frames, 0, t.size - 1))
    P = np.array(model.points.map(t.size)(q.T)).reshape(2, 6, t.size, order="F")
    P[0] += sx[None, :]
    landed = [s.step_length for s in res.steps if max_steps is None or s.index < max_steps]
    prints = np.r_[0.0, np.cumsum(landed)]       # the first stance foot and every landing
    fig, ax = plt.subplots(figsize=(7.5, 3.6))
    x_lo, x_hi = P[0].min() - 0.3, P[0].max() + 0.3
    ax.set_xlim(x_lo, x_hi)
    ax.set_ylim(-0.08, 1.55)
    ax.set_aspect("equal")
    ax.axhline(0, color="0.3", lw=1.5)
    ax.fill_between([x_lo, x_hi], -0.08, 0, color="0.85")
    ax.plot(prints, np.zeros_like(prints), "k^", ms=6, label="footprints")
    stance, = ax.plot([], [], "-o", color="tab:blue", lw=3, ms=4)
    swing, = ax.plot([], [], "-o", color="tab:red", lw=3, ms=4)
    torso, = ax.plot([], [], "-", color="0.2", lw=4)
    text = ax.text(0.01, 0.95, "", transform=ax.transAxes, va="top", fontsize=9)
    ax.set_title(f"{_label(res)}: {res.status}", fontsize=10)

    def draw(i):
        k = frames[i]
        X, Z = P[0, :, k], P[1, :, k]
        stance.set_data(X[[0, 1, 2]], Z[[0, 1, 2]])
        swing.set_data(X[[2, 4, 5]], Z[[2, 4, 5]])
        torso.set_data(X[[2, 3]], Z[[2, 3]])
        text.set_text(f"t = {t[k]:.2f} s, step {step[k] + 1}")
        return stance, swing, torso, text

    anim = FuncAnimation(fig, draw, frames=len(frames), blit=True)
    anim.save(str(path), writer=PillowWriter(fps=fps))
    plt.close(fig)
    return path


def fig5_fig6(model, gait, M1, steps: int = 10, out=".", animate_steps: int | None = 4,
              perturbation=PAPER_PERTURBATION, options: SimulationOptions | None = None) -> dict:
    """Paper §V-C end to end: time-varying control with ``M1`` and virtual constraints
    from the same perturbed initial state; Fig. 5, Fig. 6 and a stick-figure GIF of the
    time-varying run into ``out``.  Returns {"summary": ..., "figures": {name: path}}."""
    from pathlib import Path
    from .controllers import TimeVaryingController, VirtualConstraintController
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    opts = options if options is not None else SimulationOptions(steps=steps)
    q0, dq0 = perturbed_initial_state(gait, *perturbation)
    tv = simulate(TimeVaryingController(model, gait, M1), q0, dq0, opts)
    vc = simulate(VirtualConstraintController(model, gait), q0, dq0, opts)
    figs = {"fig5": str(plot_fig5([tv, vc], out / "fig5_qu_error.png")),
            "fig6": str(plot_fig6([tv, vc], gait, out / "fig6_swing_torques.png"))}
    if animate_steps:
        figs["animation"] = str(animate(tv, model, out / "walk_tv.gif", max_steps=animate_steps))
    summary = dict(perturbation=list(perturbation), tv=tv.summary(), vc=vc.summary())
    return {"summary": summary, "figures": figs}
