"""The closed loop of a running gait under its tracking controller: the stride map
stance -> flight -> stance, its fixed point, its exact Jacobian and a perturbed run.

:func:`running_cycle` builds the :class:`~analysis.stability.hybrid_cycle.HybridCycle`
of a :class:`~biped_casadi.control.running.RunningController`:

- stance: x = (q, dq) (2 nq numbers, the stride map's state), the foot pinned, the
  robot's ``forward_dynamics`` under the law's torques (clipped when the controller
  saturates), t the time since landing; guard the friction cone's margin
  mu Fz - ``|Fx|`` of ``takeoff_guard`` (the foot starts to slide where it reaches 0
  going down: off the optimised orbit always before Fz vanishes, below); constraints
  Fz >= 0 and the cone mu Fz -/+ Fx >= 0 (from landing on: a landing the foot cannot
  stay on, or would slide from at once, is refused), the swing foot above the ground
  and, without saturation, ``|u|`` <= the torque limit; reset ``takeoff`` into the
  flight coordinates (the foot at rest);
- slide: x = (qe, dqe) (2 nq + 4), the foot held on the ground vertically only
  (``sliding_dynamics`` of the flight model: the constrained Lagrangian with one contact
  constraint, z of the foot 0, and the Coulomb force Fx = sigma mu Fz at the foot),
  under the stance law (which sees q, dq), t the time since the slide began (the law's
  clock the time since landing); sigma, -sign of the foot's velocity, or at rest the
  sign of the Fx the pinned foot needs, fixed for the slide (the foot slips against
  it); a guard of two parts (``Domain.guard_parts``), the normal force Fz (the law
  switches to the flight's where it reaches 0 going down: reset the identity, the
  stick and the second slide skipped) and the slip velocity -sigma dx_st against the
  friction force (the slip stops: reset its velocity to 0, the stick next), the first
  to reach 0 ending the slide; constraints that slip velocity >= 0, the swing foot
  above the ground and the torque limit;
- stick: the foot pinned again where its slip stopped (the stance's dynamics in the
  flight coordinates, the foot's place kept), under the same law; guard the cone's
  margin, to the next slide; constraints Fz >= 0, the swing foot above the ground and
  the torque limit.  Skipped where the slide ended at Fz = 0; empty where the margin is
  <= 0 at entry: the pinned foot would need more than mu Fz the other way, and the next
  slide starts against that force;
- slide again: as the slide to Fz = 0, but its slip must not stop (stick-slip beyond
  slide -> stick -> slide under one law is not modelled: such a stride is refused with
  that reason, :data:`~analysis.stability.running_domains.SLIP_STOP`); skipped where
  the slide ended at Fz = 0, empty where Fz <= 0 at entry;
- push-off, push-off stick, push-off slide again: the same three under the flight law
  (t the time since the law's switch).  Where the stance ends off the
  reference's time, the flight law's first torques differ from the stance law's last,
  and under them the ground may still push the foot (Fz > 0): the foot then stays on
  the ground, sliding (sticking again where its slip stops), until that force reaches
  0.  Where Fz <= 0 at the switch (at the fixed point, and whenever the flight law
  pulls the foot up) the push-off is empty (``Domain.may_be_empty``) and the foot
  leaves there;
- flight: x = (qe, dqe) (2 nq + 4), ``flight_dynamics``, t the time since takeoff
  (the flight law's clock: the time since the law's switch, t plus the push-off's
  duration, or with ``flight_clock='stride'`` the stance's clock continued, t plus the
  time since landing less T_stance; parameters set at entry from the time the stride
  ran, ``Domain.clock_from``);
  guard the swing foot's height (landing where it reaches 0 going down; the flight
  starts where the foot left, moving as it slid); constraints
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
little off zero where Fz vanishes, so a pinned foot would need more friction than
mu Fz in the last instant before it leaves.  The foot slides instead, from where
``|Fx|`` reaches mu Fz to the takeoff, with Fx on the cone's edge, and leaves with
Fx = 0 (the slide's duration and distance are in each :class:`StrideRecord`).  With
``sliding=False`` the model before sliding: the foot pinned to the takeoff, under the
stance law to its Fz = 0, then under the flight law while that law's Fz is > 0 (the
push-off, in stance coordinates, reset ``takeoff``), the cone constraints carrying a
slack ``friction_slack`` (N, default 1 % of the robot's weight): the excess
``|Fx|`` - mu Fz may reach it, and the foot is freed with the acceleration that Fx
took away.

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
from functools import partial

import casadi as ca
import numpy as np

from biped_casadi.control.running import FLIGHT_CLOCKS, RunningController
from biped_casadi.control.running_step import check_rk4_steps
from biped_casadi.results import Result

from . import running_domains as rd
from .hybrid_cycle import (HybridCycle, HybridCycleError, entry_function,
                           finite_difference_jacobian)

__all__ = ["running_cycle", "RunningCycle", "running_stability", "RunningStability",
           "finite_difference_jacobian", "simulate_running", "RunningRun", "StrideRecord",
           "require_running_cycle", "FLIGHT_CLOCKS"]

#: RK4 steps per collocation interval at most (more only costs time)
MAX_STEPS_PER_INTERVAL = 1000
#: and by default
STEPS_PER_INTERVAL = 8
#: the names of the domains on the ground after the pinned stance, under each law
_GROUND_NAMES = dict(stance=("slide", "stick", "slide again"),
                     flight=("push-off", "push-off stick", "push-off slide again"))


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


class RunningCycle(HybridCycle):
    """The running stride map of :func:`running_cycle`, retunable.

    A :class:`~analysis.stability.hybrid_cycle.HybridCycle` whose domains take the gains
    k = (Kp, Kd, M1) as their parameters p, so that :meth:`retuned` changes them without
    building the domains' Functions again.

    Parameters
    ----------
    domains : sequence of Domain
        The domains as :func:`running_cycle` builds them (it also sets
        the attributes below).

    Attributes
    ----------
    controller : RunningController
        The law at the cycle's gains.
    mu, friction_slack : float
        The friction coefficient and the cone's slack near takeoff, N (0 with sliding).
    sliding : bool
        Whether the stance foot slides where it reaches the cone (module docstring).
    laws : tuple of str
        Each domain's law, 'stance' or 'flight'.
    kinds : tuple of str
        Each domain's contact: 'stance' (pinned, the stride's start), 'slide', 'stick'
        (pinned again where a slip stopped), 'push-off' (pinned, without sliding) or
        'flight'.
    starts : list of callable
        Each domain's start at given gains (:meth:`retuned`).
    flight_clock : str
        As :func:`running_cycle`.
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
        new.domains = [dataclasses.replace(d, start=make(c.gains))
                       for d, make in zip(self.domains, self.starts)]
        new._fns = []
        for d, f in zip(new.domains, self._fns):
            g = copy.copy(f)
            g.entry = entry_function(d)
            new._fns.append(g)
        return new


def running_cycle(controller: RunningController, mu: float | None = None,
                  steps_per_interval: int = STEPS_PER_INTERVAL, friction_slack: float | None = None,
                  time_limits: float = 2.0, tolerance: float = 1e-9,
                  flight_clock: str = "takeoff", sliding: bool = True) -> RunningCycle:
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
        How far ``|Fx|`` may exceed mu Fz with the foot pinned, N.  With ``sliding`` it
        must be 0 (the default: the foot slides where the cone is reached); without, the
        default is 1 % of the weight (the model before sliding).
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
    sliding : bool
        Let the stance foot slide where it needs more friction than the ground gives
        (the default; module docstring); False: the model before sliding, the foot
        pinned to the takeoff with the cone's slack ``friction_slack``.

    Returns
    -------
    RunningCycle
        Stance, slide, stick, slide again, push-off, push-off stick, push-off slide
        again and flight (with ``sliding``; the sticks and the second slides empty unless
        a slip stops); without ``sliding``, stance, push-off and flight.  Its state is the stance state (q, dq) at landing.
    """
    c = controller
    if not isinstance(c, RunningController):
        raise TypeError(f"controller must be a RunningController, got {type(c).__name__}")
    m, g = c.model, c.gait
    if mu is None:
        mu = float(getattr(getattr(g, "options", None), "mu", 0.6))
    mu = _real("mu", mu)
    if flight_clock not in FLIGHT_CLOCKS:
        raise ValueError(f"flight_clock must be one of {', '.join(FLIGHT_CLOCKS)}, got "
                         f"{flight_clock!r}")
    if not isinstance(sliding, (bool, np.bool_)):
        raise ValueError(f"sliding must be True or False, got {sliding!r}")
    _count("steps_per_interval", steps_per_interval, 1, MAX_STEPS_PER_INTERVAL)
    _real("time_limits", time_limits, 1.0)
    _real("tolerance", tolerance, strict=False)
    weight = m.description.total_mass * m.description.gravity
    slack = (0.0 if sliding else 0.01 * weight) if friction_slack is None else \
        _real("friction_slack", friction_slack, strict=False)
    if sliding and slack:
        raise ValueError(f"friction_slack must be 0 with sliding (the foot slides where it "
                         f"reaches the cone; sliding=False pins it), got {friction_slack!r}")
    h_st = float(g.T_stance) / (c.stance.n_intervals * steps_per_interval)
    h_fl = float(g.T_flight) / (c.flight.n_intervals * steps_per_interval)
    check_rk4_steps(c, dict(stance=h_st, flight=h_fl))
    t_st, tol = time_limits * float(g.T_stance), tolerance
    origin = float(g.T_stance) if flight_clock == "stride" else 0.0
    k = len(rd.GROUND_PHASES)
    switch = 1 + k if sliding else 1             # the push-off: where the flight law starts
    clock_from = 0 if flight_clock == "stride" else switch
    n, ne = 2 * m.nq, 2 * c.fl.ne
    domains = [rd.stance_domain(c, mu, slack, h_st, t_st, tol, sliding)]
    starts = [partial(rd.start, n)]
    if sliding:
        for law, h, o, cf, names in (("stance", h_st, 0.0, 0, _GROUND_NAMES["stance"]),
                                     ("flight", h_fl, origin, clock_from,
                                      _GROUND_NAMES["flight"])):
            ds, ss = rd.ground_domains(c, law, mu, h, t_st, tol, o, cf, names)
            domains += ds
            starts += ss
    else:
        domains.append(rd.pushoff_domain(c, mu, slack, h_fl, t_st, tol, origin, clock_from))
        starts.append(partial(rd.start, n, clock_origin=origin))
    domains.append(rd.flight_domain(c, mu, h_fl, time_limits * float(g.T_flight), tol,
                                    origin, clock_from))
    starts.append(partial(rd.start, ne, clock_origin=origin))
    cyc = RunningCycle(domains)
    cyc.controller, cyc.mu, cyc.friction_slack, cyc.sliding = c, mu, slack, bool(sliding)
    cyc.starts, cyc.flight_clock = starts, flight_clock
    cyc.laws = ("stance",) + (("stance",) * k + ("flight",) * k if sliding else ("flight",)) \
        + ("flight",)
    cyc.kinds = ("stance",) + (rd.GROUND_PHASES * 2 if sliding else ("push-off",)) \
        + ("flight",)
    return cyc


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
    slip : float
        How long the stance foot slid before it left the ground, s (0 without sliding).
    slide : float
        How far it slid, m (signed, forward positive; 0 without sliding).
    restick : float
        How long it stuck again after a slip stopped, s (0 without sliding).
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
    slip: float = 0.0
    slide: float = 0.0
    restick: float = 0.0


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
    """(stance, flight) from the domains' durations: the stance foot is on the ground in
    every domain but the flight, the last."""
    return np.array([float(np.sum(durations[:-1])), durations[-1]])


def _lowest(nodes, ps, name: str) -> float:
    """The lowest of an output at the nodes of a pass and at its minima between them."""
    return float(min([np.min(nodes), *(v for _, n, v in ps.dips if n == name)]))


def _ground_pass(cycle, ps, phase: str):
    """The torques the law asked for and the swing foot's heights at the nodes of a pass
    with the stance foot on the ground after the pinned stance (a slide, a push-off)."""
    c = cycle.controller
    fl, nq, ne = c.fl, c.model.nq, c.fl.ne
    X, t = ps.nodes, ps.times
    N = t.size
    if X.shape[0] == 2 * nq:                     # the foot pinned: stance coordinates
        qe, dqe = (np.array(v) for v in fl.takeoff.map(N)(X[:nq], X[nq:]))
    else:
        qe, dqe = X[:ne], X[ne:]
    tt = t[None, :] + ps.parameters[-1]
    u = np.array(c.stance_law.map(N)(qe[:nq], dqe[:nq], tt) if phase == "stance"
                 else c.flight_law.map(N)(qe, dqe, tt))
    zsw = np.array(fl.feet.map(N)(qe))[1, 1::2]
    return u, zsw


def _margins(cycle: HybridCycle, passes) -> dict:
    """The constraints' margins along a recorded stride."""
    c = cycle.controller
    m, fl = c.model, c.fl
    nq, ne = m.nq, fl.ne
    st, fli = passes[0], passes[-1]
    Xs, ts = st.nodes, st.times
    N = ts.size
    us = np.array(c.stance_law.map(N)(Xs[:nq], Xs[nq:], ts[None, :]))
    ua = np.array(c.applied(ca.DM(us)))
    Fz, Fx = (np.array(v).ravel() for v in fl.takeoff_guard.map(N)(Xs[:nq], Xs[nq:], ua))
    weight = m.description.total_mass * m.description.gravity
    loaded = Fz > 0.01 * weight
    zsw = np.array(m.swing_foot.map(N)(Xs[:nq])[1]).ravel()
    ground = [(ps, *_ground_pass(cycle, ps, law))
              for ps, law in zip(passes[1:-1], cycle.laws[1:-1])]
    Yf, tf = fli.nodes, fli.times
    Nf = tf.size
    uf = np.array(c.flight_law.map(Nf)(Yf[:ne], Yf[ne:], tf[None, :] + fli.parameters[-1]))
    feet = np.array(fl.feet.map(Nf)(Yf[:ne]))
    y = fli.exit_state
    F = np.array(fl.landing_swing(y[:ne], y[ne:])[2]).ravel()
    timed = [(ts, us), *((ps.times, u) for ps, u, _ in ground), (tf, uf)]
    U = np.reshape(c.torque_limit, (-1, 1))       # (1, 1), or per torque (nu, 1)
    return dict(fz_min=float(Fz[:-1].min()),
                friction_ratio_max=float(np.max(np.abs(Fx[loaded]) / Fz[loaded], initial=0.0)),
                friction_excess_max=float(np.max(np.abs(Fx) - cycle.mu * Fz)),
                torque_max=float(max(np.abs(u).max() for _, u in timed)),
                saturated_time=sum(_time_above(tt, np.max(np.abs(uu) - U, axis=0))
                                   for tt, uu in timed)
                if np.all(np.isfinite(U)) else 0.0,                    # no limit: never
                swing_min=min(_lowest(zsw, st, "swing foot height"),
                              *(_lowest(z, ps, "swing foot height") for ps, _, z in ground)),
                other_foot_min=_lowest(feet[1, 0::2], fli, "other foot height"),
                landing_impulse_ratio=float(abs(F[0]) / F[1]) if F[1] > 0 else float("inf"),
                slip=_time_in(cycle, passes, "slide"), restick=_time_in(cycle, passes, "stick"),
                slide=float(fli.entry[nq]))


def _time_in(cycle, passes, kind: str) -> float:
    """How long the stride's domains of one contact kind (``RunningCycle.kinds``) ran."""
    return float(sum(ps.duration for ps, k in zip(passes, cycle.kinds) if k == kind))


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
                                 pushoff=float(sum(
                                     d for d, law in zip(sv.durations[1:-1], cycle.laws[1:-1])
                                     if law == "flight")),
                                 **_margins(cycle, sv.passes)))
    d = np.array(devs)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = d[1:] / d[:-1]
    if status == "ok":
        msg = (f"{len(recs)} strides, deviation {d[0]:.2e} -> {d[-1]:.2e}")
    return RunningRun(start=np.asarray(start, float).ravel(), fixed_point=xs, strides=recs,
                      deviations=d, contraction=ratio, status=status, message=msg)
