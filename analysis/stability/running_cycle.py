"""The closed loop of a running gait under its tracking controller: the stride map
stance -> flight -> stance, its fixed point, its exact Jacobian and a perturbed run.

:func:`running_cycle` builds the :class:`~analysis.stability.hybrid_cycle.HybridCycle`
of a :class:`~biped_casadi.control.running.RunningController`:

- stance: x = (q, dq) (2 nq numbers, the stride map's state), the robot's
  ``forward_dynamics`` under the law's torques (clipped when the controller saturates),
  t the time since landing; guard the normal ground force Fz of ``takeoff_guard``
  (the law switches to the flight's where it reaches 0 going down); constraints Fz >= 0
  (from landing on: a landing the foot cannot stay on is refused at once; at the crossing
  Fz is 0 to round-off), the friction cone mu Fz -/+ Fx >= 0 (with a slack near takeoff,
  below), the swing foot above the ground and, without saturation, ``|u|`` <= the torque
  limit; reset the identity;
- push-off: the same state and stance dynamics under the flight law (on the extended
  state of ``takeoff``, the foot at rest), t the time since the law's switch; guard Fz
  under those torques; constraints the cone, the swing foot and the torque limit; reset
  ``takeoff``.  Where the stance ends off the reference's time, the flight law's first
  torques differ from the stance law's last, and under them the ground may still push
  the foot (Fz > 0): the foot then stays on the ground until that force reaches 0,
  instead of being freed at the switch with a downward acceleration.  Where Fz <= 0 at
  the switch (at the fixed point, and whenever the flight law pulls the foot up) the
  domain is empty (``Domain.may_be_empty``) and the foot leaves there;
- flight: x = (qe, dqe) (2 nq + 4), ``flight_dynamics``, t the time since takeoff
  (the flight law's clock: the time since the law's switch, t plus the push-off's
  duration, or with ``flight_clock='stride'`` the stance's clock continued, t plus the
  time since landing less T_stance; parameters set at entry from the time the stride
  ran, ``Domain.clock_from``);
  guard the swing foot's height (landing where it reaches 0 going down); constraints
  the other foot (the one that pushed off) above the ground and the torque limit;
  exit constraints the landing's normal impulse >= 0 and inside the friction cone, the
  other foot moving up after the impact; reset ``landing_swing`` (impact and
  relabelling) into the next stance state.

The RK4 step of each phase divides the phase's collocation interval into
``steps_per_interval`` steps, so that on the reference orbit the kinks of the piecewise
polynomial reference fall on RK4 nodes.  Every constraint of the phases (the normal
force, the friction cone, the feet's heights, the torque limit) and the guards are
checked between the nodes too, on the RK4 step from the node before
(:mod:`analysis.stability.hybrid_cycle`): a margin that dips below zero and rises again
within one step is a violation (the cone, the pushing foot, a torque), and a guard that
does is the phase's end at its first root (the stance force reaching 0: the switch to
the flight law, or the takeoff; the swing foot: the landing).

Friction near takeoff.  Fz and Fx reach zero together only on the optimised orbit;
off it (and at the closed loop's fixed point, which is not the collocation's) Fx is a
little off zero where Fz vanishes, and mu Fz - ``|Fx|`` turns negative in the last instant
before the foot leaves.  The cone constraints carry a slack ``friction_slack`` (N): the
excess ``|Fx|`` - mu Fz may reach it (default 1 % of the robot's weight, the margin of
:func:`gait_opt.running_checks.check_running` between the collocation points).  The
pinned foot keeps that Fx to the instant Fz vanishes; freed there it starts with the
acceleration Fx took away, downward for one sign of Fx, and the flight's check of the
pushing foot stops such a stride (a real foot would have slid before it left).

:func:`running_stability` finds the fixed point near the gait's first stance state
and its eigenvalues; :func:`finite_difference_jacobian` checks the exact Jacobian;
:func:`simulate_running` iterates the map from a perturbed state, recording each
stride's deviation and the margins of the constraints, and stops at the first stride the
robot cannot run (with the reason).
"""
from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from biped_casadi.control.running import FLIGHT_CLOCKS, RunningController
from biped_casadi.control.running_step import check_rk4_steps
from biped_casadi.results import Result

from .hybrid_cycle import Domain, HybridCycle, HybridCycleError, entry_function

__all__ = ["running_cycle", "RunningCycle", "running_stability", "RunningStability",
           "finite_difference_jacobian", "simulate_running", "RunningRun", "StrideRecord",
           "require_running_cycle", "FLIGHT_CLOCKS"]

#: RK4 steps per collocation interval at most (more only costs time)
MAX_STEPS_PER_INTERVAL = 1000
#: and by default
STEPS_PER_INTERVAL = 8


def _phase_constraints(c: RunningController, u, extra, names):
    """The torque limit (without saturation; a robot without one has none) after the
    phase's own constraints."""
    lim = c.torque_limit
    if c.saturate or not np.isfinite(lim):
        return extra, names
    cons = ca.vertcat(extra, lim - u, lim + u)
    nu = c.model.nu
    return cons, names + tuple(f"torque u{i + 1} <= {lim:g} N m" for i in range(nu)) \
        + tuple(f"torque u{i + 1} >= -{lim:g} N m" for i in range(nu))


def _real(name, v, low=0.0, strict=True, top=None) -> float:
    """``v`` as a float if it is a finite number above ``low`` (at least, unless
    ``strict``) and at most ``top``, else a ValueError naming ``name``."""
    ok = not isinstance(v, bool) and isinstance(v, (int, float, np.integer, np.floating)) \
        and np.isfinite(v) and (v > low if strict else v >= low) and (top is None or v <= top)
    if not ok:
        raise ValueError(f"{name} must be a finite number {'>' if strict else '>='} {low:g}"
                         + (f" and <= {top:g}" if top is not None else "") + f", got {v!r}")
    return float(v)


def _count(name, v, low=0, top=None) -> int:
    """``v`` if it is an integer from ``low`` to ``top``, else a ValueError naming it."""
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low \
            or (top is not None and v > top):
        raise ValueError(f"{name} must be an integer from {low}" + (
            f" to {top}" if top is not None else " up") + f", got {v!r}")
    return int(v)


def require_running_cycle(cycle, name: str = "cycle"):
    """Refuse anything but the stride map of :func:`running_cycle`.

    Parameters
    ----------
    cycle : object
        What was given.
    name : str
        The argument's name in the message.

    Raises
    ------
    TypeError
        Naming ``name`` and the type given.
    """
    if not (isinstance(cycle, HybridCycle) and isinstance(getattr(cycle, "controller", None),
                                                          RunningController)):
        raise TypeError(f"{name} must be a running cycle (running_cycle(controller)), got "
                        f"{type(cycle).__name__}")


def _state(name, v, n: int) -> np.ndarray:
    """``v`` as (n,) finite floats, else a ValueError naming ``name``."""
    try:
        x = np.asarray(v, dtype=float).ravel()
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be {n} numbers, got {v!r}") from None
    if x.size != n or not np.all(np.isfinite(x)):
        raise ValueError(f"{name} must be {n} finite numbers (the landing state q, dq), got "
                         f"{x.size} number(s)" + ("" if x.size != n else " not all finite"))
    return x


def _start(n: int, gains, clock_origin: float | None = None) -> ca.Function:
    """Entry of a domain: X0 = x, p = the gains; with ``clock_origin`` (the domains under
    the flight law), also the law's clock at entry, s - ``clock_origin`` (s the time since
    the domain's ``clock_from`` entry: the switch to the flight law, or the landing)."""
    x = ca.SX.sym("x", n)
    k = ca.DM(np.asarray(gains, float))
    if clock_origin is None:
        return ca.Function("running_start", [x], [x, k])
    s = ca.SX.sym("s")
    return ca.Function("running_start", [x, s], [x, ca.vertcat(k, s - clock_origin)])


class RunningCycle(HybridCycle):
    """The running stride map of :func:`running_cycle`, retunable.

    A :class:`~analysis.stability.hybrid_cycle.HybridCycle` whose domains take the gains
    k = (Kp, Kd, M1) as their parameters p, so that :meth:`retuned` changes them without
    building the domains' Functions again.

    Parameters
    ----------
    domains : sequence of Domain
        Stance, push-off and flight, as :func:`running_cycle` builds them (it also sets
        the attributes below).

    Attributes
    ----------
    controller : RunningController
        The law at the cycle's gains.
    mu, friction_slack : float
        The friction coefficient and the cone's slack near takeoff, N.
    """

    @property
    def rk4_steps(self) -> dict:
        """The RK4 step of each phase's law, s: ``{'stance': h, 'flight': h}``."""
        return dict(stance=self.domains[0].h, flight=self.domains[-1].h)

    def retuned(self, Kp=None, Kd=None, M1=None) -> "RunningCycle":
        """The same cycle at other gains (None keeps the current ones).

        Parameters
        ----------
        Kp, Kd, M1
            As :class:`~biped_casadi.control.running.RunningController`.

        Returns
        -------
        RunningCycle
            Shares every Function but the domains' entries.

        Raises
        ------
        ValueError
            Gains whose output error RK4 amplifies at the cycle's steps, as
            :func:`running_cycle` refuses them
            (:func:`~biped_casadi.control.running_step.check_rk4_steps`).
        """
        c = self.controller.with_gains(Kp, Kd, M1)
        check_rk4_steps(c, self.rk4_steps)
        new = copy.copy(self)
        new.controller = c
        new.domains = [dataclasses.replace(d, start=_start(d.n, c.gains, origin))
                       for d, origin in zip(self.domains, self.clock_origins)]
        new._fns = []
        for d, f in zip(new.domains, self._fns):
            g = copy.copy(f)
            g.entry = entry_function(d)
            new._fns.append(g)
        return new


def running_cycle(controller: RunningController, mu: float | None = None,
                  steps_per_interval: int = STEPS_PER_INTERVAL, friction_slack: float | None = None,
                  time_limits: float = 2.0, tolerance: float = 1e-9,
                  flight_clock: str = "takeoff") -> RunningCycle:
    """The stride map of a running gait under a tracking controller (module docstring).

    Parameters
    ----------
    controller : RunningController
        The law, its gait and robot.
    mu : float, optional
        Friction coefficient of the ground (default the gait's ``options.mu``, else 0.6).
    steps_per_interval : int
        RK4 steps per collocation interval of each phase.
    friction_slack : float, optional
        How far ``|Fx|`` may exceed mu Fz in stance, N (default 1 % of the weight).
    time_limits : float
        Each phase must end within this many times its reference duration.
    tolerance : float
        Round-off allowed below zero in every constraint (its own unit).
    flight_clock : {'takeoff', 'stride'}
        The flight reference's clock (:data:`FLIGHT_CLOCKS`): 'takeoff' (the default)
        restarts it at 0 at the law's switch (the takeoff, or the push-off's start when
        the ground still pushes the foot); 'stride' continues the stance's, t - T_stance
        with t the time since landing, so that a takeoff earlier or later than the
        reference's does not shift the flight reference (the law's torque is continuous
        through the takeoff where the gait's is).

    Returns
    -------
    RunningCycle
        Stance, push-off and flight; its state is the stance state (q, dq) at landing.
    """
    c = controller
    if not isinstance(c, RunningController):
        raise TypeError(f"controller must be a RunningController, got {type(c).__name__}")
    m, fl, g = c.model, c.fl, c.gait
    nq, ne, nu = m.nq, fl.ne, m.nu
    if mu is None:
        mu = float(getattr(getattr(g, "options", None), "mu", 0.6))
    mu = _real("mu", mu)
    if flight_clock not in FLIGHT_CLOCKS:
        raise ValueError(f"flight_clock must be one of {', '.join(FLIGHT_CLOCKS)}, got "
                         f"{flight_clock!r}")
    origin = float(g.T_stance) if flight_clock == "stride" else 0.0
    clock_from = 0 if flight_clock == "stride" else 1     # landing, or the law's switch
    _count("steps_per_interval", steps_per_interval, 1, MAX_STEPS_PER_INTERVAL)
    _real("time_limits", time_limits, 1.0)
    _real("tolerance", tolerance, strict=False)
    weight = m.description.total_mass * m.description.gravity
    slack = 0.01 * weight if friction_slack is None else _real("friction_slack",
                                                              friction_slack, strict=False)
    t, k = ca.SX.sym("t"), ca.SX.sym("k", 3 * nu)

    # ---- stance
    X = ca.SX.sym("X", 2 * nq)
    q, dq = X[:nq], X[nq:]
    u = c.stance_law_k(q, dq, t, k)
    ua = c.applied(u)
    f_st = ca.Function("running_stance", [X, t, k],
                       [ca.vertcat(dq, m.forward_dynamics(q, dq, ua))])
    Fz, Fx = fl.takeoff_guard(q, dq, ua)
    g_st = ca.Function("normal_force", [X, t, k], [Fz])
    cons, names = _phase_constraints(
        c, u, ca.vertcat(Fz, *_on_ground(m, mu, slack, q, Fz, Fx)),
        ("stance normal force",) + _ON_GROUND)
    c_st = ca.Function("stance_constraints", [X, t, k], [cons])
    x = ca.SX.sym("x", 2 * nq)
    h_st = float(g.T_stance) / (c.stance.n_intervals * steps_per_interval)
    h_fl = float(g.T_flight) / (c.flight.n_intervals * steps_per_interval)
    check_rk4_steps(c, dict(stance=h_st, flight=h_fl))
    stance = Domain("stance", 2 * nq, f_st, g_st, ca.Function("switch", [x], [x]), h_st,
                    time_limits * float(g.T_stance),
                    start=_start(2 * nq, c.gains), constraints=c_st, constraint_names=names,
                    guard_name="stance normal force", tolerance=tolerance,
                    dense_constraints=names, dense_guard=True)
    pushoff = _pushoff_domain(c, mu, slack, h_fl, time_limits * float(g.T_stance), tolerance,
                              origin, clock_from)

    # ---- flight
    Y = ca.SX.sym("Y", 2 * ne)
    qe, dqe = Y[:ne], Y[ne:]
    kf = ca.SX.sym("k", 3 * nu + 1)              # the gains, then the law's clock at entry
    uf = c.flight_law_k(qe, dqe, t + kf[-1], kf[:-1])
    f_fl = ca.Function("running_flight", [Y, t, kf],
                       [ca.vertcat(dqe, fl.flight_dynamics(qe, dqe, c.applied(uf)))])
    feet = fl.feet(qe)
    g_fl = ca.Function("swing_foot_height", [Y, t, kf], [feet[1, 1]])
    cons, names = _phase_constraints(c, uf, feet[1, 0], ("other foot height",))
    c_fl = ca.Function("flight_constraints", [Y, t, kf], [cons])
    y = ca.SX.sym("y", 2 * ne)
    qp, dqp, F, _, v_other, _ = fl.landing_swing(y[:ne], y[ne:])
    r_fl = ca.Function("landing", [y], [ca.vertcat(qp, dqp)])
    e_fl = ca.Function("landing_checks", [y],
                       [ca.vertcat(F[1], mu * F[1] - F[0], mu * F[1] + F[0], v_other[1])])
    flight = Domain("flight", 2 * ne, f_fl, g_fl, r_fl, h_fl, time_limits * float(g.T_flight),
                    start=_start(2 * ne, c.gains, origin), constraints=c_fl,
                    constraint_names=names,
                    exit_constraints=e_fl,
                    exit_constraint_names=("landing normal impulse",
                                           "landing impulse in the cone (Fx <= mu Fz)",
                                           "landing impulse in the cone (-Fx <= mu Fz)",
                                           "other foot's lift-off velocity"),
                    guard_name="swing foot height", tolerance=tolerance,
                    dense_constraints=names, dense_guard=True, clock_from=clock_from)
    cyc = RunningCycle([stance, pushoff, flight])
    cyc.controller, cyc.mu, cyc.friction_slack = c, mu, slack
    cyc.clock_origins, cyc.flight_clock = (None, origin, origin), flight_clock
    return cyc


#: the constraints while the stance foot is on the ground, after its normal force
_ON_GROUND = ("friction cone (Fx <= mu Fz)", "friction cone (-Fx <= mu Fz)",
              "swing foot height")


def _on_ground(m, mu, slack, q, Fz, Fx) -> tuple:
    """The friction cone with its slack and the swing foot's height (:data:`_ON_GROUND`)."""
    return mu * Fz - Fx + slack, mu * Fz + Fx + slack, m.swing_foot(q)[1]


def _pushoff_domain(c: RunningController, mu, slack, h, t_max, tolerance, origin,
                    clock_from) -> Domain:
    """The push-off (module docstring): the stance foot on the ground under the flight
    law, while the ground still pushes it."""
    m, fl, nq, nu = c.model, c.fl, c.model.nq, c.model.nu
    X, t = ca.SX.sym("X", 2 * nq), ca.SX.sym("t")
    q, dq = X[:nq], X[nq:]
    kf = ca.SX.sym("k", 3 * nu + 1)              # the gains, then the law's clock at the switch
    qe, dqe = fl.takeoff(q, dq)
    u = c.flight_law_k(qe, dqe, t + kf[-1], kf[:-1])
    ua = c.applied(u)
    Fz, Fx = fl.takeoff_guard(q, dq, ua)
    cons, names = _phase_constraints(c, u, ca.vertcat(*_on_ground(m, mu, slack, q, Fz, Fx)),
                                     _ON_GROUND)
    x = ca.SX.sym("x", 2 * nq)
    qe, dqe = fl.takeoff(x[:nq], x[nq:])
    return Domain("push-off", 2 * nq,
                  ca.Function("running_pushoff", [X, t, kf],
                              [ca.vertcat(dq, m.forward_dynamics(q, dq, ua))]),
                  ca.Function("normal_force", [X, t, kf], [Fz]),
                  ca.Function("takeoff", [x], [ca.vertcat(qe, dqe)]), h, t_max,
                  start=_start(2 * nq, c.gains, origin),
                  constraints=ca.Function("pushoff_constraints", [X, t, kf], [cons]),
                  constraint_names=names, guard_name="stance normal force",
                  tolerance=tolerance, dense_constraints=names, dense_guard=True,
                  clock_from=clock_from, may_be_empty=True)


# ------------------------------------------------------------------ fixed point
@dataclass
class RunningStability(Result):
    """The fixed point of a running gait's stride map and its eigenvalues.

    Parameters
    ----------
    fixed_point : numpy.ndarray
        (2 nq,) x* = (q, dq) at landing, P(x*) = x*.
    residual : float
        max ``|P(x*) - x*|``.
    distance : float
        max ``|x* - x_collocated(0)|``, the gap between the closed loop's orbit (RK4 of the
        exact dynamics) and the collocated one (rad, rad/s: the largest entry).
    A : numpy.ndarray
        (2 nq, 2 nq) the exact Jacobian dP/dx at x*.
    eigenvalues : numpy.ndarray
        Of A, by decreasing modulus.
    spectral_radius : float
        max ``|eigenvalue|``.
    durations : numpy.ndarray
        (stance, flight) at x*, s.
    stable : bool
        spectral radius < 1.
    newton_start_residual : float
        max ``|P(x0) - x0|`` at the collocated start.
    status, message : str
        'stable', 'unstable', or 'failed' (no fixed point found; message says why).
    """

    fixed_point: np.ndarray
    residual: float
    distance: float
    A: np.ndarray
    eigenvalues: np.ndarray
    spectral_radius: float
    durations: np.ndarray
    stable: bool
    newton_start_residual: float
    status: str = "stable"
    message: str = ""

    SUCCESS = ("stable", "unstable")


def running_stability(cycle: HybridCycle, x0=None, tol: float = 1e-11,
                      max_iter: int = 12) -> RunningStability:
    """The fixed point of the running stride map and the eigenvalues of its Jacobian.

    Newton with the exact Jacobian from the gait's first stance state.

    Parameters
    ----------
    cycle : HybridCycle
        From :func:`running_cycle`.
    x0 : array_like, optional
        Newton's start (default the collocated first stance state).
    tol, max_iter : float, int
        As :meth:`HybridCycle.fixed_point`.

    Returns
    -------
    RunningStability
        status 'failed' (NaN figures) when a stride leaves the robot's validity or
        Newton does not reach ``100 tol``.
    """
    require_running_cycle(cycle)
    _real("tol", tol)
    _count("max_iter", max_iter)
    xc = np.asarray(cycle.controller.gait.x_stance, float)[:, 0]
    n = cycle.n
    x0 = xc if x0 is None else _state("x0", x0, n)
    nan = np.full(n, np.nan)
    try:
        start = cycle.stride(x0)
        r0 = float(np.max(np.abs(start.next_state - x0)))
        lin = cycle.fixed_point(x0, tol=tol, max_iter=max_iter)
    except (HybridCycleError, np.linalg.LinAlgError) as e:
        return RunningStability(nan, np.nan, np.nan, np.full((n, n), np.nan), nan, np.nan,
                                np.full(2, np.nan), False, np.nan, "failed", str(e))
    rho = lin.spectral_radius
    status = "stable" if rho < 1 else "unstable"
    ok = lin.residual < 100 * tol
    return RunningStability(
        fixed_point=lin.state, residual=lin.residual,
        distance=float(np.max(np.abs(lin.state - xc))), A=lin.A,
        eigenvalues=lin.eigenvalues, spectral_radius=rho, durations=_phases(lin.durations),
        stable=bool(rho < 1), newton_start_residual=r0,
        status=status if ok else "failed",
        message=(f"fixed point {lin.residual:.1e} from closing, "
                 f"{np.max(np.abs(lin.state - xc)):.1e} from the collocated state; "
                 f"spectral radius {rho:.4g}" if ok else
                 f"Newton did not close the orbit (residual {lin.residual:.1e})"))


def finite_difference_jacobian(cycle: HybridCycle, x, step: float = 1e-6) -> np.ndarray:
    """dP/dx by central differences of the stride map (2 n strides).

    Parameters
    ----------
    cycle : HybridCycle
        The map.
    x : array_like
        Where, (n,).
    step : float
        The difference step.

    Returns
    -------
    numpy.ndarray
        (n, n).
    """
    x = np.asarray(x, float).ravel()
    J = np.zeros((cycle.n, x.size))
    for j in range(x.size):
        e = np.zeros(x.size)
        e[j] = step
        J[:, j] = (cycle.stride(x + e).next_state - cycle.stride(x - e).next_state) / (2 * step)
    return J


# ------------------------------------------------------------------ simulation
@dataclass
class StrideRecord:
    """One stride of a closed-loop run (SI units).

    Parameters
    ----------
    deviation : float
        max ``|x_k - x*|`` at the stride's start (landing).
    next_deviation : float
        max ``|x_(k+1) - x*|`` after it.
    durations : tuple of float
        (stance, flight), s: the stance foot's time on the ground (to the law's switch
        and the push-off after it) and the flight's.
    pushoff : float
        How long the ground still pushed the stance foot after the law switched to the
        flight's, s (0: the foot left at the switch).
    fz_min : float
        Smallest normal force at the stance RK4 nodes before the takeoff crossing, N.
    friction_ratio_max : float
        Largest ``|Fx|`` / Fz at the stance nodes where Fz > 1 % of the weight.
    friction_excess_max : float
        Largest ``|Fx|`` - mu Fz at the stance nodes and the crossing, N (<= 0: in the cone).
    torque_max : float
        Largest ``|u|`` the law asked for in both phases, N m.
    saturated_time : float
        How long the law asked for more than the torque limit in some joint, s (both
        phases; between RK4 nodes the excess is interpolated linearly).  Without
        saturation such a stride stops, so a completed one has 0; with it the motors gave
        their limit for that long.
    swing_min : float
        Lowest swing-foot height in stance, m (at the RK4 nodes and at its minima between
        them, :attr:`~analysis.stability.hybrid_cycle.DomainPass.dips`).
    other_foot_min : float
        Lowest height of the pushing foot in flight, m (likewise).
    landing_impulse_ratio : float
        ``|Fx|`` / Fz of the landing impulse.
    """

    deviation: float
    next_deviation: float
    durations: tuple
    pushoff: float
    fz_min: float
    friction_ratio_max: float
    friction_excess_max: float
    torque_max: float
    saturated_time: float
    swing_min: float
    other_foot_min: float
    landing_impulse_ratio: float


@dataclass
class RunningRun(Result):
    """A closed-loop run from a perturbed state.

    Parameters
    ----------
    start : numpy.ndarray
        The perturbed first state.
    fixed_point : numpy.ndarray
        x*.
    strides : list of StrideRecord
        Each completed stride.
    deviations : numpy.ndarray
        max ``|x_k - x*|``, k = 0 .. completed strides.
    contraction : numpy.ndarray
        deviations[k + 1] / deviations[k].
    status, message : str
        'ok' (every stride completed and valid) or 'stopped' (the message says at which
        stride and why: a constraint, the guard not reached, a diverged state).
    """

    start: np.ndarray
    fixed_point: np.ndarray
    strides: list = field(default_factory=list)
    deviations: np.ndarray = field(default_factory=lambda: np.zeros(0))
    contraction: np.ndarray = field(default_factory=lambda: np.zeros(0))
    status: str = "ok"
    message: str = ""

    SUCCESS = ("ok",)


def _time_above(t, e) -> float:
    """How long the piecewise linear interpolant of ``e`` over the times ``t`` is > 0."""
    t, e = np.asarray(t, float), np.asarray(e, float)
    a, b, dt = e[:-1], e[1:], np.diff(t)
    both = (a > 0) & (b > 0)
    one = (a > 0) != (b > 0)
    pos = np.where(a > 0, a, b)
    frac = np.divide(pos, np.abs(b - a), out=np.zeros_like(pos), where=one)
    return float(np.sum(dt[both]) + np.sum(dt[one] * frac[one]))


def _phases(durations) -> np.ndarray:
    """(stance, flight) from the three domains' durations: the stance foot is on the
    ground in the stance and the push-off."""
    return np.array([durations[0] + durations[1], durations[2]])


def _lowest(nodes, ps, name: str) -> float:
    """The lowest of an output at the nodes of a pass and at its minima between them."""
    return float(min([np.min(nodes), *(v for _, n, v in ps.dips if n == name)]))


def _margins(cycle: HybridCycle, passes) -> dict:
    """The constraints' margins along a recorded stride."""
    c = cycle.controller
    m, fl = c.model, c.fl
    nq, ne = m.nq, fl.ne
    st, po, fli = passes
    Xs, ts = st.nodes, st.times
    N = ts.size
    us = np.array(c.stance_law.map(N)(Xs[:nq], Xs[nq:], ts[None, :]))
    ua = np.array(c.applied(ca.DM(us)))
    Fz, Fx = (np.array(v).ravel() for v in fl.takeoff_guard.map(N)(Xs[:nq], Xs[nq:], ua))
    weight = m.description.total_mass * m.description.gravity
    loaded = Fz > 0.01 * weight
    zsw = np.array(m.swing_foot.map(N)(Xs[:nq])[1]).ravel()
    Xp, tp = po.nodes, po.times
    qe, dqe = fl.takeoff.map(tp.size)(Xp[:nq], Xp[nq:])
    up = np.array(c.flight_law.map(tp.size)(qe, dqe, tp[None, :] + po.parameters[-1]))
    zsp = np.array(m.swing_foot.map(tp.size)(Xp[:nq])[1]).ravel()
    Yf, tf = fli.nodes, fli.times
    Nf = tf.size
    uf = np.array(c.flight_law.map(Nf)(Yf[:ne], Yf[ne:], tf[None, :] + fli.parameters[-1]))
    feet = np.array(fl.feet.map(Nf)(Yf[:ne]))
    y = fli.exit_state
    F = np.array(fl.landing_swing(y[:ne], y[ne:])[2]).ravel()
    return dict(fz_min=float(Fz[:-1].min()),
                friction_ratio_max=float(np.max(np.abs(Fx[loaded]) / Fz[loaded], initial=0.0)),
                friction_excess_max=float(np.max(np.abs(Fx) - cycle.mu * Fz)),
                torque_max=float(max(np.abs(us).max(), np.abs(up).max(), np.abs(uf).max())),
                saturated_time=sum(_time_above(tt, np.abs(uu).max(axis=0) - c.torque_limit)
                                   for tt, uu in ((ts, us), (tp, up), (tf, uf)))
                if np.isfinite(c.torque_limit) else 0.0,               # no limit: never
                swing_min=min(_lowest(zsw, st, "swing foot height"),
                              _lowest(zsp, po, "swing foot height")),
                other_foot_min=_lowest(feet[1, 0::2], fli, "other foot height"),
                landing_impulse_ratio=float(abs(F[0]) / F[1]) if F[1] > 0 else float("inf"))


def simulate_running(cycle: HybridCycle, x_star, start, strides: int = 20) -> RunningRun:
    """Iterate the stride map from ``start``, stopping at the first invalid stride.

    Records each stride's deviation from x* and the margins of its constraints.

    Parameters
    ----------
    cycle : HybridCycle
        From :func:`running_cycle`.
    x_star : array_like
        The fixed point the deviations are measured from.
    start : array_like
        The first state (x* perturbed).
    strides : int
        How many strides at most.

    Returns
    -------
    RunningRun
        status 'ok' when every stride completed with every constraint met; 'stopped'
        otherwise, with the stride and the reason (the domain, the constraint, the time)
        in the message.
    """
    require_running_cycle(cycle)
    xs, x = _state("x_star", x_star, cycle.n), _state("start", start, cycle.n)
    _count("strides", strides)
    devs = [float(np.max(np.abs(x - xs)))]
    recs = []
    status, msg = "ok", ""
    for k in range(strides):
        try:
            sv = cycle.stride(x, record=True)
        except HybridCycleError as e:
            status, msg = "stopped", f"stride {k + 1}: {e}"
            break
        x = sv.next_state
        if not np.all(np.isfinite(x)):
            status, msg = "stopped", f"stride {k + 1}: the state is not finite"
            break
        devs.append(float(np.max(np.abs(x - xs))))
        recs.append(StrideRecord(deviation=devs[-2], next_deviation=devs[-1],
                                 durations=tuple(_phases(sv.durations).tolist()),
                                 pushoff=float(sv.durations[1]),
                                 **_margins(cycle, sv.passes)))
    d = np.array(devs)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = d[1:] / d[:-1]
    if status == "ok":
        msg = (f"{len(recs)} strides, deviation {d[0]:.2e} -> {d[-1]:.2e}")
    return RunningRun(start=np.asarray(start, float).ravel(), fixed_point=xs, strides=recs,
                      deviations=d, contraction=ratio, status=status, message=msg)
