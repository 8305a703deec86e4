"""Full-order hybrid closed-loop simulation of walking (paper eq. 9; docs: theory §1 impact, §4
guard).

State (q, dq, tau), 2 nq + 1 numbers, plus the controller's reference state r (a function of
tau alone, see :mod:`biped_casadi.control`).  In single support the robot follows
eq. (1), D(q) ddq + H(q, dq) = B u, with the controller's torque u; the step ends when
the swing foot reaches the ground in front of the stance foot while moving down
(z_sw = 0, x_sw > 0, dz_sw < 0); the impact map with relabelling (eq. 2-3) starts the
next step with tau = 0.

Integration: classical RK4 with a fixed step h = T / ``rk4_steps`` (T the reference step
duration), evaluated in blocks of nodes, T first and then quarters of T, each block one
CasADi call (``mapaccum``, the nodes' diagnostics included); the
impact (a strike beyond ``model.scuff_zone``: anywhere in front of the stance foot for
legs with knees) is located inside its RK4 interval by Newton's method on the length of the last
RK4 step, z_sw(RK4(x_k, eta)) = 0, so the event is exact to round-off for the discrete
scheme.  With the default 2000 steps per T the scheme is the gait's own (docs: theory §2), and
the unperturbed closed loop repeats the reference to ~1e-11.

Every node is checked, in time order, and the run stops at the first invalid state
with one of the statuses of :data:`STATUSES` (the logs end with that state).  Between
the nodes, where the swing foot's vertical velocity goes from <= 0 to > 0 its lowest
point is found by Newton's method (the strike's); below the ground it is the strike (the
first root before it, beyond ``model.scuff_zone``) or a scuff.  The stance force, the
friction cone and the torques are screened between the nodes and their minima located
where they may dip (:mod:`~biped_casadi.simulation.margins`; by their rates, or for a
compiled law from sampled values); the fall and the singularity at the nodes only
(:mod:`~biped_casadi.simulation.validity` says why):

- ``fell``: hip lower than ``min_hip_height`` or torso past horizontal (leaning more than
  ``max_torso_angle`` from its upright angle, the robot's ``torso_upright``);
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

Uneven ground (``run(..., terrain=...)``, :mod:`biped_casadi.simulation.terrain`): step k
ends where the swing foot strikes z_sw = h_k, and every condition above is measured from
the ground under the foot.  Model error (``plant``): the controller computes its torques
with its own model while the robot moves, strikes and meets the ground as the plant
does (its D, H, kinematics, ground reaction and impact map).  With
``SimulationOptions.saturate`` the torques the plant receives are clipped at the limit
and the run reports the time spent saturated instead of stopping at 'torque_limit'.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..caching import cached
from ..control.design import Design
from ..control.output_law import SECTION
from ..control.saturation import beyond_limit, clip_torques
from ..numerics import FastCall, as_vector, compiled, rk4_step
from ..results import internal
from .compiled_loop import compiled_closed_loop
from .kernel import (CHUNKS_PER_STEP, SUB_STEPS, Diagnostics, locate_strike, strike,
                     swing_foot_dip)
from .margins import MarginCheck, dip_function
from .options import SimulationOptions
from .outcome import STATUSES, OutcomeRecorder, StepRecord, WalkOutcome
from .perturbation import perturbed_initial_state
from .terrain import ground_levels, step_heights
from .validity import (STRIKE_MESSAGE, Limits, between_message, first_violation,
                       impact_message, impact_violation, node_message, node_violations,
                       start_violation, strike_violation)

__all__ = ["SimulationOptions", "StepRecord", "SimulationResult", "Simulator", "simulate",
           "simulator", "perturbed_initial_state", "STATUSES"]


@dataclass
class SimulationResult(WalkOutcome):
    """A full-order closed-loop run: its outcome, step records and logs.

    The outcome fields are those of every run (:class:`WalkOutcome`): ``status`` 'ok'
    when every step was valid (``ok``), the per-step errors, the validity margins.
    ``success`` means the run was simulated.  The logs have one row per RK4 node, in time
    order (an impact appears as its pre-impact node followed by the post-impact node at
    the same t; torques and reactions at the pre-impact node are the single-support
    values), and are left out of ``to_dict()``.

    Parameters
    ----------
    status, message, n_steps, fail_step, qu_error, dqu_error, duration : see WalkOutcome
        How the run ended, and the per-step errors and durations.
    peak_torque, min_normal_force, max_friction_ratio, max_impulse_ratio : see WalkOutcome
        The validity margins over the run.
    saturated_time : float
        Time the torques spent clipped at the limit, s (see WalkOutcome).
    controller : dict
        The controller's ``describe()``.
    options : SimulationOptions
        The options of the run.
    steps : list of StepRecord
        One record per completed step.
    failure_time : float
        Time of the first invalid state, s (NaN when 'ok').
    reference : dict
        ``T`` and the reference's (q_u^d, dq_u^d)(T) (``qu_T``, ``dqu_T``).
    t, tau : numpy.ndarray
        (N,) time since the start of the run and since the start of the step, s.
    step : numpy.ndarray
        (N,) 0-based index of the step each node belongs to.
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
    """
    controller: dict
    options: SimulationOptions
    steps: list
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

    @property
    def impact_times(self) -> np.ndarray:
        """Time of every impact since the start of the run, s."""
        return np.array([s.t_impact for s in self.steps])

    @property
    def section_errors(self) -> np.ndarray:
        """(n_steps, 2): (q_u, dq_u) - reference at tau = 0.75 T; NaN where not reached."""
        return np.array([s.section_error if s.section_error is not None else [np.nan, np.nan]
                         for s in self.steps]).reshape(-1, 2)


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
    controller : Design, TimeVaryingController or VirtualConstraintController
        The control law (and through it the model and the reference); or a
        :class:`~biped_casadi.control.compiled.CompiledController`, an exported law's
        compiled library, whose closed loop is made of numeric calls
        (:mod:`biped_casadi.simulation.compiled_loop`).
    options : SimulationOptions, optional
        Default ``SimulationOptions()``.
    plant : BipedModel, optional
        The robot that moves (default: the controller's model).  The controller keeps
        computing its torques with its own model: a plant with other masses, inertias or
        lengths is a model error.  Same joints and torques as the controller's model.
    """

    def __init__(self, controller, options: SimulationOptions | None = None, plant=None):
        self.options = options if options is not None else SimulationOptions()
        if not isinstance(self.options, SimulationOptions):
            raise ValueError(f"options must be a SimulationOptions, got "
                             f"{type(self.options).__name__}")
        if isinstance(controller, Design):
            controller = controller.controller_for()
        if not (hasattr(controller, "reference") and hasattr(controller, "model")):
            raise TypeError("controller: a TimeVaryingController, VirtualConstraintController "
                            f"or Design is needed, got {type(controller).__name__}")
        self.controller = controller
        self.model = controller.model
        self.plant = self.model if plant is None else plant
        if getattr(self.plant, "nq", None) != self.model.nq or \
                getattr(self.plant, "nu", None) != self.model.nu:
            raise ValueError(f"plant must be a robot model with the controller's "
                             f"{self.model.nq} joints and {self.model.nu} torques")
        self.gait = controller.reference
        self.T = self.gait.T
        self.h = self.T / self.options.rk4_steps
        controller.gains.check_step(self.h)
        self.chunk = self.options.rk4_steps // CHUNKS_PER_STEP
        self.schema = Diagnostics(self.model.nu, outputs=True)
        self.limits = Limits.of(self.options, self.plant, self.gait)
        self.margin, self._margins = MarginCheck(self.limits, self.schema), None
        self._build()
        ref = self.controller.singularity()
        self._den_scale = max(abs(ref.min_value), abs(ref.max_value))
        self._ref_T = self.gait.state_at(self.T)
        self._ref_s = self.gait.state_at(SECTION * self.T)

    @property
    def torque_limit(self):
        """The bound on the runs' ``|u_i|``, N m (a float, or per torque: a tuple).

        One per torque where the robot's joints' limits differ (:attr:`Limits.torque_limit`).
        """
        return self.limits.torque_limit

    @property
    def cache_key(self):
        """What the simulator depends on: controller, options and plant."""
        return (self.controller.cache_key, self.options, self.plant.cache_key)

    def applied_torque(self, u):
        """The torques the plant receives for the law's torques ``u``.

        Clipped at the torque limit when the options saturate (a NaN stays NaN:
        :func:`~biped_casadi.control.saturation.clip_torques`), else ``u`` itself.

        Parameters
        ----------
        u : casadi.SX or casadi.MX
            The law's torques.

        Returns
        -------
        tuple
            (applied torques, whether any ``|u_i|`` exceeds the limit: a CasADi
            expression, or 0 when nothing is clipped).
        """
        if not self.options.saturate:
            return u, 0
        U = self.limits.torque_limit
        return clip_torques(u, U), beyond_limit(u, U)

    # ------------------------------------------------------------------ build
    def _build(self):
        m, c = self.plant, self.controller
        if getattr(c, "numeric_law", False):    # a compiled library: numeric calls only
            self.rk4 = None
            (self.step_block, self.quarter_block, self.diagnostics, self.event,
             self._impact_map, self.dip) = compiled_closed_loop(
                c, m, self.schema, self.limits, self.options.saturate,
                (CHUNKS_PER_STEP * self.chunk, self.chunk))
            return
        nq = m.nq
        nx = 2 * nq + c.n_ref
        X = ca.SX.sym("X", nx)
        tau = ca.SX.sym("tau")
        p = ca.SX.sym("p", c.n_par)
        h = ca.SX.sym("h")

        def rhs(Xv, stage):
            q, dq, r = Xv[:nq], Xv[nq:2 * nq], Xv[2 * nq:]
            u, _, _, _, dr, _ = c.law(q, dq, tau + stage * h, r, p)
            ddq = m.forward_dynamics(q, dq, self.applied_torque(u)[0])     # the plant, eq. (1)
            return ca.vertcat(dq, ddq, dr)

        Xn = ca.cse(rk4_step(rhs, X, h))
        #: one RK4 step of the closed loop (SX: also called symbolically, by the step map)
        self.rk4 = ca.Function("closed_loop_rk4", [X, tau, h, p], [Xn, tau + h],
                               ["X", "tau", "h", "p"], ["X_next", "tau_next"])
        q, dq, r = X[:nq], X[nq:2 * nq], X[2 * nq:]
        u, y, dy, den, _, inr = c.law(q, dq, tau, r, p)
        ua, sat = self.applied_torque(u)
        Fx, Fz = m.ground_reaction(q, dq, ua)
        diag = ca.cse(self.schema.vector(m, q, dq, ua, Fx, Fz, den, y, dy, inr, sat))
        diagnostics = ca.Function("closed_loop_diagnostics", [X, tau, p], [diag],
                                  ["X", "tau", "p"], ["diag"])
        self._margins = ca.Function("margins", [X, tau, p],
                                    [self.margin.values(ua, Fx, Fz, ca)])
        eta = ca.SX.sym("eta")
        Xe, _ = self.rk4(X, tau, eta, p)
        ze = m.swing_foot(Xe[:nq])[1]
        dze = ca.jacobian(ze, eta)
        event = ca.Function("impact_event", [X, tau, eta, p], [ze, dze, Xe],
                            ["X", "tau", "eta", "p"], ["z_sw", "dz_deta", "X_event"])
        dip = dip_function(self.rk4, lambda Xv, t, pv: m.swing_foot(Xv[:nq]))
        # a block of n RK4 nodes and their diagnostics in one call: the first block of a
        # step spans T (where most steps end), then quarters of T
        blocks = []
        for n in (CHUNKS_PER_STEP * self.chunk, self.chunk):
            Xm, tm, hm = ca.MX.sym("X", nx), ca.MX.sym("tau"), ca.MX.sym("h")
            pm = ca.MX.sym("p", p.numel())
            Xs, ts = self.rk4.mapaccum(f"closed_loop_{n}", n, [0, 1], [0, 1])(Xm, tm, hm, pm)
            Dg = diagnostics.map(n)(Xs, ts, pm)
            blocks.append(ca.Function(f"closed_loop_block_{n}", [Xm, tm, hm, pm], [Xs, ts, Dg],
                                      ["X", "tau", "h", "p"], ["X_nodes", "tau_nodes", "diag"]))
        fs = blocks + [diagnostics, event, m.impact_full, dip]
        if self.options.jit:      # compiled once per content (one library), kept in the cache
            fs = compiled(fs, "-O1")
        # called through their buffers: a plain call's conversions cost more than a block
        (self.step_block, self.quarter_block, self.diagnostics, self.event, self._impact_map,
         self.dip) = (FastCall(f) for f in fs)

    # ---------------------------------------------------------------- checks
    def _first_failure(self, D, X, z_prev=None, den_sign=1.0, ground=None):
        """Index, status and message of the first invalid node of a block, or None.
        D: diagnostics (rows x n), X: states (nx x n), z_prev: swing-foot heights at the
        previous nodes (a foot already below the ground cannot strike), den_sign: the
        sign of the decoupling denominator at the start of the step, ground: (ahead,
        behind) ground heights."""
        rows = self.schema.rows(D, np.all(np.isfinite(X), 0))
        masks = node_violations(rows, self.limits, self._den_scale, den_sign, z_prev, ground)
        first, which = first_violation(masks)
        if which == "":
            return None
        j = int(first)
        node = {k: (v[..., j] if isinstance(v, np.ndarray) else v) for k, v in rows.items()}
        return j, str(which), node_message(str(which), node, self.limits, self._den_scale)

    # ------------------------------------------------------------------ run
    def run(self, q0, dq0, steps: int | None = None, terrain=None) -> SimulationResult:
        """Simulate ``steps`` steps (default: options.steps) from (q0, dq0) at tau = 0.

        Parameters
        ----------
        q0, dq0 : array_like
            Initial state (the start of a step).
        steps : int, optional
            Number of steps (impacts).
        terrain : Terrain or array_like, optional
            Ground heights h_k, one per step (:mod:`biped_casadi.simulation.terrain`);
            default flat.

        Returns
        -------
        SimulationResult
            Status, step records and logs.
        """
        nq = self.model.nq
        q = as_vector(q0, nq, "q0")
        dq = as_vector(dq0, nq, "dq0")
        steps = self.options.steps if steps is None else steps
        if isinstance(steps, np.integer):
            steps = int(steps)
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
            raise ValueError(f"steps must be a positive integer, got {steps!r}")
        heights = step_heights(terrain, 1, steps)[0]
        log = _Log(self.schema.size, self.h)
        rec = OutcomeRecorder(1, steps)
        records: list[StepRecord] = []
        walk = dict(t0=0.0, stance_x=0.0, rec=rec, heights=heights, log=log)
        failure = None
        for k in range(steps):
            rec.scenario_steps += 1
            failure, event = self._single_support(k, q, dq, walk, log)
            if failure is not None:
                break
            failure, record = self._impact(k, event, walk, log)
            if record is not None:
                records.append(record)
            if failure is not None:
                break
            walk["t0"] += record.duration
            walk["stance_x"] += record.step_length
            q, dq = record.q_plus, record.dq_plus
        t_fail = math.nan
        if failure is not None:
            status, message, t_fail = failure
            if not message.startswith("step"):
                message = f"step {k + 1}: {message}"      # step 1: the first (k = 0)
            rec.fail([0], [status], k, [message])
        return log.result(rec, self.controller.describe(), self.options, records, t_fail,
                          dict(T=self.T, qu_T=self._ref_T[0], dqu_T=self._ref_T[1]),
                          self.schema)

    def _single_support(self, k, q, dq, walk, log):
        """Integrate step ``k`` from its start to the swing foot's strike.  Returns
        (failure, event): failure (status, message, time) or None; event (X-, tau-)."""
        o, c, T, h, S = self.options, self.controller, self.T, self.h, self.schema
        t0, sx = walk["t0"], walk["stance_x"]
        hk, behind = (float(v) for v in ground_levels(walk["heights"], k))
        ground = walk["ground"] = (hk, behind)
        start = c.step_start(q, dq)
        p = start.p
        X = np.r_[q, dq, start.r]
        if start.problem:
            log.add(t0, np.zeros(1), k, X[:, None], np.full((S.size, 1), np.nan), sx)
            return ("out_of_range", start.problem, t0), None
        D0 = self.diagnostics(X, 0.0, p)[0]
        walk["den_sign"] = sign = 1.0 if S.row(D0, "den")[0] >= 0 else -1.0
        fail = self._first_failure(D0, X[:, None], den_sign=sign, ground=ground)
        z0 = S.row(D0, "zsw")[0]
        if fail is None and start_violation(z0, self.limits, behind) != "":
            fail = (0, "scuffed", f"swing foot below the ground at the start of step {k + 1} "
                                  f"(z_sw = {z0:.3g} m, ground {behind:.3g} m)")
        log.add(t0, np.zeros(1), k, X[:, None], D0, sx, walk["rec"], S)
        if fail is not None:
            return (fail[1], fail[2], t0), None
        walk["p"], walk["section"], walk["w"] = p, None, self.margin.at_nodes(D0)
        z_prev, dz_prev = z0, S.row(D0, "dzsw")[0]
        n = CHUNKS_PER_STEP
        i_section = int(round(SECTION * n)) * self.chunk - 1   # node at 0.75 T, 1st block
        end = o.horizon * T + 1e-12
        ci = 0                                           # quarters of T done
        while ci < int(math.ceil(o.horizon * n)):
            tau0, first = ci * T / n, ci == 0
            block = self.step_block if first else self.quarter_block
            Xs, taus, Dg = block(X, tau0, h, p)
            taus = taus.ravel()
            span = T if first else T / n
            if tau0 + span > end:                          # last partial block
                keep = taus <= end
                Xs, taus, Dg = Xs[:, keep], taus[keep], Dg[:, keep]
            zs = S.row(Dg, "zsw")
            zprev = np.r_[z_prev, zs[:-1]]
            hits = strike(zs, zprev, S.row(Dg, "xsw"), self.plant.scuff_zone, ground)
            i_strike = int(np.argmax(hits)) if hits.any() else Xs.shape[1]
            dzs = S.row(Dg, "dzsw")
            dip = self._dip(X, tau0, p, Xs, taus, zprev, np.r_[dz_prev, dzs[:-1]], dzs, ground,
                            i_strike)
            i_strike = i_strike if dip is None else dip[0]
            fail = self._first_failure(Dg[:, :i_strike], Xs[:, :i_strike], zprev[:i_strike],
                                       den_sign=sign, ground=ground)
            stop = i_strike if fail is None else fail[0] + 1
            W = np.vstack([walk["w"], self.margin.at_nodes(Dg[:, :stop])])
            walk["w"] = W[-3:]
            dense = self._between(W, p, ([(X, tau0)] + list(zip(Xs.T, taus)))[:stop],
                                  t0, k, Xs, taus, Dg, sx, walk)
            if dense is not None:
                return dense, None
            if fail is not None:
                j = fail[0]
                log.add(t0, taus[:j + 1], k, Xs[:, :j + 1], Dg[:, :j + 1], sx, walk["rec"], S)
                return (fail[1], fail[2], t0 + taus[j]), None
            if first and i_strike > i_section:   # the step passed the section, tau = 0.75 T
                walk["section"] = np.array([Xs[0, i_section], Xs[self.model.nq, i_section]])
            if i_strike < Xs.shape[1]:
                Xa = X if i_strike == 0 else Xs[:, i_strike - 1]
                ta = tau0 if i_strike == 0 else taus[i_strike - 1]
                za = z_prev if i_strike == 0 else zs[i_strike - 1]
                log.add(t0, taus[:i_strike], k, Xs[:, :i_strike], Dg[:, :i_strike], sx,
                        walk["rec"], S)
                if dip is not None and dip[1] != "strike":
                    return self._log_stop(walk, k, dip[4], ta + dip[3], "scuffed", dip[2]), None
                event = self._locate(Xa, ta, za - hk, (zs[i_strike] if dip is None else dip[2])
                                     - hk, p, hk, None if dip is None else dip[3])
                W = np.vstack([walk["w"], self.margin.at_nodes(
                    self.diagnostics(event[0], event[1], p)[0])])
                return self._between(W, p, [(Xa, ta)], t0, k, Xs, taus, Dg, sx, walk,
                                     event[1] - ta), event
            log.add(t0, taus, k, Xs, Dg, sx, walk["rec"], S)
            X, z_prev, dz_prev = Xs[:, -1], zs[-1], dzs[-1]
            ci += n if first else 1
        return ("no_impact", f"step {k + 1}: no valid impact of the swing foot within "
                             f"{o.horizon:g} T = {o.horizon * T:.4f} s", t0 + o.horizon * T), None

    def _impact(self, k, event, walk, log):
        """Check the pre-impact state, apply the impact map (eq. 2-3) and check the
        impulse.  Returns (failure or None, StepRecord or None)."""
        S, nq = self.schema, self.model.nq
        t0, sx, p = walk["t0"], walk["stance_x"], walk["p"]
        X_m, tau_m = event
        Dm = self.diagnostics(X_m, tau_m, p)[0]
        log.add(t0, np.array([tau_m]), k, X_m[:, None], Dm, sx, walk["rec"], S)
        fail = self._first_failure(Dm, X_m[:, None], den_sign=walk["den_sign"],
                                   ground=walk["ground"])
        if fail is not None:
            return (fail[1], fail[2], t0 + tau_m), None
        q_m, dq_m = X_m[:nq], X_m[nq:2 * nq]
        dz = S.row(Dm, "dzsw")[0]
        q_p, dq_p, F, _, v_old = (v.ravel() for v in self._impact_map(q_m, dq_m))
        if strike_violation(dz) != "":
            return ("scuffed", STRIKE_MESSAGE, t0 + tau_m), None
        section = walk["section"]
        record = StepRecord(index=k, t_start=t0, t_impact=t0 + tau_m, duration=tau_m,
                            q_minus=q_m, dq_minus=dq_m, q_plus=q_p, dq_plus=dq_p, impulse=F,
                            qu_error=float(q_m[0] - self._ref_T[0]),
                            dqu_error=float(dq_m[0] - self._ref_T[1]),
                            section=section,
                            section_error=None if section is None else section - self._ref_s,
                            step_length=float(S.row(Dm, "xsw")[0]),
                            ground_height=float(walk["ground"][0]))
        walk["rec"].impact([0], k, record.qu_error, record.dqu_error, tau_m, F[None, :])
        finite = bool(np.all(np.isfinite(np.r_[q_p, dq_p, F])))
        which = str(impact_violation(F, v_old[1], finite, self.limits))
        if which:
            msg = impact_message(which, F, v_old[1], self.limits)
            return (which, f"step {k + 1}: {msg}", t0 + tau_m), record
        return None, record

    def _locate(self, Xa, ta, za, zb, p, height=0.0, h=None):
        """Pre-impact state: the RK4 step length eta in (0, h] (default the step) with z_sw =
        ``height`` (:func:`~biped_casadi.simulation.kernel.locate_strike`; za, zb measured
        from there, zb at eta = h)."""
        def event(eta):
            z, dz, _ = self.event(Xa, ta, eta[0], p)
            return z.ravel() - height, dz.ravel()

        eta = float(locate_strike(event, self.h if h is None else h, za, zb)[0])
        _, _, Xe = self.event(Xa, ta, eta, p)
        return Xe.ravel(), ta + eta

    def _between(self, W, p, starts, t0, k, Xs, taus, Dg, sx, walk, last=None):
        """Force, friction and torques between the nodes (:mod:`.margins`) in the steps
        from ``starts`` ((X, tau) each; W the margins at their nodes and up to three
        before), the last ``last`` long (default h): None, or the failure (status,
        message, time), the nodes before it logged."""
        if not starts:
            return None
        steps = [(Xa, ta, self.h, p) for Xa, ta in starts[:-1]] + \
            [(*starts[-1], self.h if last is None else last, p)]
        if self._margins is None:         # a numeric law, no derivatives: sampled margins
            found = self.margin.first_dip(self._sampled_margins, W, steps, SUB_STEPS)
        else:
            found = self.margin.first_dip(self.margin.build(self.rk4, self._margins), W, steps)
        if found is None:
            return None
        j, eta, status = found
        if last is None:
            walk["log"].add(t0, taus[:j], k, Xs[:, :j], Dg[:, :j], sx, walk["rec"], self.schema)
        Xe = self.event(steps[j][0], steps[j][1], eta, p)[2].ravel()
        D = self.diagnostics(Xe, steps[j][1] + eta, p)[0]
        return self._log_stop(walk, k, Xe, steps[j][1] + eta, status,
                              self.margin.message(status, D, self._den_scale))

    def _sampled_margins(self, X, tau, eta, p):
        """The margins at the end of the RK4 step of length eta from (X, tau) (a numeric
        law's closed loop, :meth:`_between`)."""
        Xe = self.event(X, tau, eta, p)[2].ravel()
        return self.margin.at_nodes(self.diagnostics(Xe, tau + eta, p)[0])[0]

    def _log_stop(self, walk, k, Xe, te, status, message):
        """Log the state Xe at tau = te of step k, where the run stops: (status, message,
        time)."""
        walk["log"].add(walk["t0"], np.array([te]), k, Xe[:, None],
                        self.diagnostics(Xe, te, walk["p"])[0], walk["stance_x"], walk["rec"],
                        self.schema)
        return status, message, walk["t0"] + te

    def _dip(self, X, tau0, p, Xs, taus, z_prev, dz_a, dz_b, ground, stop):
        """The swing foot between the nodes of a block before node ``stop`` (module
        docstring; :func:`~biped_casadi.simulation.kernel.swing_foot_dip`): None, or (j,
        kind, z, eta, X) inside the step that ends at node j: 'strike' with z_sw at the
        minimum, or 'scuffed' with the message; eta into that step, X the state there.
        z_prev, dz_a, dz_b: per step, the height and its rate at its first node, the rate
        at its last."""
        lim = self.limits
        found = swing_foot_dip(
            lambda Xa, ta, eta: self.dip(Xa, ta, eta, p), self.h,
            lambda j: (X, tau0) if j == 0 else (Xs[:, j - 1], taus[j - 1]),
            z_prev[:stop], dz_a[:stop], dz_b[:stop], ground, self.plant.scuff_zone,
            lim.scuffing_ignored, lim.ground_tolerance)
        if found is None:
            return None
        j, kind, eta, z, x, Xe = found
        return j, kind, z if kind == "strike" else between_message(
            "scuffed", dict(xsw=x, zsw=z), lim), eta, Xe


class _Log:
    """Accumulates per-node logs (and folds each block into the run's outcome)."""

    def __init__(self, ndiag, h=0.0):
        self.parts = []
        self.ndiag = ndiag
        self.h = h

    def add(self, t0, taus, k, X, D, stance_x, rec=None, schema=None):
        taus = np.asarray(taus, dtype=float).ravel()
        if taus.size == 0:
            return
        self.parts.append((t0 + taus, taus, np.full(taus.size, k), X.T, D.T,
                           np.full(taus.size, stance_x)))
        if rec is not None:
            rec.track([0], schema.row(D, "u")[:, None, :], schema.row(D, "Fx")[None, :],
                      schema.row(D, "Fz")[None, :], saturated=schema.row(D, "saturated")[None, :],
                      dt=self.h)

    def result(self, rec, controller, options, records, t_fail, reference, S):
        if self.parts:
            t, tau, st, X, D, sx = (np.concatenate([p[i] for p in self.parts])
                                     for i in range(6))
        else:
            t = tau = sx = np.zeros(0)
            st = np.zeros(0, int)
            X, D = np.zeros((0, 0)), np.zeros((0, self.ndiag))
        nu = S.nu
        nq, nx = nu + 1, 2 * (nu + 1)
        X = X[:, :nx] if X.size else np.zeros((0, nx))
        return SimulationResult(
            **rec.outcome(0), controller=controller, options=options, steps=records,
            failure_time=t_fail, reference=reference,
            t=t, tau=tau, step=st.astype(int), q=X[:, :nq], dq=X[:, nq:nx],
            u=D[:, S.index["u"]], y=D[:, S.index["y"]], dy=D[:, S.index["dy"]],
            Fx=D[:, S.index["Fx"]], Fz=D[:, S.index["Fz"]], denominator=D[:, S.index["den"]],
            stance_x=sx)


@cached(maxsize=8)
def simulator(controller, options: SimulationOptions | None = None, plant=None) -> Simulator:
    """The :class:`Simulator` of a controller, options and plant, built once.

    Memoised by the controller's content, the options and the plant.

    Parameters
    ----------
    controller : Design, TimeVaryingController or VirtualConstraintController
        The control law.
    options : SimulationOptions, optional
        Default ``SimulationOptions()``.
    plant : BipedModel, optional
        The robot that moves (default: the controller's model).

    Returns
    -------
    Simulator
    """
    return Simulator(controller, options if options is not None else SimulationOptions(),
                     plant)


def simulate(controller, q0=None, dq0=None, options: SimulationOptions | None = None,
             steps: int | None = None, terrain=None, plant=None) -> SimulationResult:
    """Simulate the closed loop of ``controller`` from (q0, dq0).

    Parameters
    ----------
    controller : Design, TimeVaryingController or VirtualConstraintController
        The control law (a :class:`~biped_casadi.Design` on its gait, or its
        controller).
    q0, dq0 : array_like, optional
        Initial state (the start of a step, tau = 0), rad and rad/s; default the
        reference at tau = 0.
    options : SimulationOptions, optional
        Default ``SimulationOptions()``.
    steps : int, optional
        Overrides ``options.steps``.
    terrain : Terrain or array_like, optional
        Ground heights, one per step (default flat).
    plant : BipedModel, optional
        The robot that moves, when it differs from the controller's model.

    Returns
    -------
    SimulationResult
        Status, step records and logs.
    """
    if isinstance(controller, Design):
        controller = controller.controller_for()
    if not hasattr(controller, "reference"):
        raise TypeError("controller: a TimeVaryingController, VirtualConstraintController "
                        f"or Design is needed, got {type(controller).__name__}")
    sim = simulator(controller, options if options is not None else SimulationOptions(), plant)
    g = controller.reference
    q0 = g.q(0.0) if q0 is None else q0
    dq0 = g.dq(0.0) if dq0 is None else dq0
    return sim.run(q0, dq0, steps, terrain)
