"""Batched closed-loop walking of the time-varying controller on its hybrid zero dynamics.

Why it is exact.  From every step start the full-order closed loop of the time-varying
controller IS its hybrid zero dynamics (:mod:`biped_casadi.control.zero_dynamics`): the
state of a scenario is (q_u, dq_u) and tau, q_a follows from the outputs (eq. 10), the
torques from eq. (12), the ground reaction from Newton's law for the centre of mass.
The output gains (Kp, Kd, eps) do not enter: the walker is the closed loop of every
gain, and agrees with the full-order :class:`~biped_casadi.simulation.full_order.Simulator`
to its integration accuracy (``tests/test_robust.py`` measures it).

Why it is fast.  One compiled step serves every design and every perturbation: the
output matrix M1 and the rejoin time t_c of v_c are runtime inputs, like the step's
(y_i, dy_i).  The reference q^d(tau) is the same for every scenario at the same tau, so
it is tabulated once per chunk of the step and shared by the whole batch.  A chunk of
T/4 is one ``mapaccum`` of RK4 nodes mapped over the active scenarios; the strike and
the impact time come from the stepping kernel (:mod:`biped_casadi.simulation.kernel`),
as in the full-order simulator.

Validity.  Every node and every impact is checked with
:mod:`biped_casadi.simulation.validity` (the same conditions as the full-order simulator,
torque limit included); between the nodes, as in the simulator, the swing foot's minima
where its vertical velocity turns upward (below the ground: a scuff behind the stance
foot, the strike in front of it) and the stance force, friction cone and torques where
the screen of the nodes says they may dip (:mod:`biped_casadi.simulation.margins`: the
steps of the whole batch screened at once, the flagged ones refined by Newton's method
on rates taken by AD, its Functions built once).  A scenario stops at its first invalid
state; one between two nodes is named so in its message.

Terrain.  ``walk(..., terrain=...)`` gives every scenario its ground heights, one per step
(:mod:`biped_casadi.simulation.terrain`): step k strikes at z_sw = h_k, and v_c still
starts from the outputs at each step start, so the walker stays exact on uneven ground.
"""
from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import casadi as ca
import numpy as np

from ..caching import cached
from ..control.output_law import SECTION, check_M1, decoupling_denominator
from ..control.reference import require_reference, require_same_robot
from ..control.zero_dynamics import denominator_samples, zero_dynamics
from ..numerics import FastCall, as_rows, compiled, rk4_step
from ..simd import kernels
from .kernel import (CHUNKS_PER_STEP, Diagnostics, call_batched, locate_strike, mapped,
                     strike, threads)
from .margins import MarginCheck, dip_function, foot_dips
from .options import SimulationOptions
from .outcome import OutcomeRecorder, WalkBatch
from .terrain import ground_levels, step_heights
from .validity import (Limits, between_message, first_violation, impact_violation,
                       node_violations, start_violation, strike_violation)

__all__ = ["ZeroDynamicsWalker", "zero_dynamics_walker"]



def _scenarios(*arrays_and_rejoin) -> int:
    """The number of scenarios n of row arrays and rejoin times that broadcast along them
    (each has 1 or n rows); rejoin checked in (0, SECTION]."""
    *arrays, rejoin = arrays_and_rejoin
    r = np.asarray(rejoin, dtype=float) if not isinstance(rejoin, str) else np.array(np.nan)
    if r.ndim > 1 or not np.all((r > 0) & (r <= SECTION)):
        raise ValueError(f"rejoin must be a number or (n,) numbers in (0, {SECTION}], "
                         f"got {rejoin!r:.60}")
    sizes = [len(a) for a in arrays] + [r.size]
    n = max(sizes)
    if any(k not in (1, n) for k in sizes):
        raise ValueError(f"scenarios: every argument has 1 or n rows, got {sizes}")
    return n

class ZeroDynamicsWalker:
    """The hybrid zero dynamics of the time-varying controller as a batched simulator.

    Parameters
    ----------
    model : BipedModel
        The robot.
    gait : Reference
        The reference step, made for ``model``.
    options : SimulationOptions, optional
        Validity thresholds (mu, torque limit, ...) and ``horizon``, as the full-order
        simulator's; ``rk4_steps`` and ``jit`` below replace its integration settings.
    rk4_steps : int
        RK4 steps per reference step duration T (a multiple of 8).
    jit : bool
        Compile the step to C (needs a C compiler; a few seconds once, then faster).
    """

    def __init__(self, model, gait, options: SimulationOptions | None = None,
                 rk4_steps: int = 400, jit: bool = False):
        require_same_robot(model, gait)
        if isinstance(rk4_steps, bool) or not isinstance(rk4_steps, int) or rk4_steps < 8 \
                or rk4_steps % 8:
            raise ValueError(f"rk4_steps must be a positive multiple of 8, got {rk4_steps!r}")
        self.options = options if options is not None else SimulationOptions()
        if not isinstance(self.options, SimulationOptions):
            raise ValueError(f"options must be a SimulationOptions, got "
                             f"{type(self.options).__name__}")
        if self.options.saturate:
            raise ValueError("options: saturate needs the full-order simulator (the walker is "
                             "the zero dynamics, exact only with the law's own torques)")
        self.model, self.gait = model, gait
        self.nq, self.nu = model.nq, model.nu
        self.T = gait.T
        self.rk4_steps, self.jit = rk4_steps, jit
        self.h = self.T / rk4_steps
        self.K = rk4_steps // CHUNKS_PER_STEP
        self.limits = Limits.of(self.options, model, gait)
        self.schema = Diagnostics(self.nu, outputs=False)
        self.margin, self._dense_fns = MarginCheck(self.limits, self.schema), None
        self.zd = zero_dynamics(model)
        self.horizon = min(self.options.horizon, (gait.t_max - self.h) / self.T)
        self.n_chunks = int(math.ceil(self.horizon * CHUNKS_PER_STEP))
        self.ref_T = gait.state_at(self.T)
        self._R0 = np.concatenate(gait.evaluate(0.0))
        # the reference where a walk's first step starts: tau = 0 or the section
        self._R_start = {0.0: self._R0[:, None],
                         SECTION * self.T: np.concatenate(gait.evaluate(SECTION * self.T))[:, None]}
        self._table()
        self._build()

    @property
    def cache_key(self):
        """What the walker depends on: the gait's key, the options, rk4_steps and jit."""
        return (self.gait.cache_key, self.options, self.rk4_steps, self.jit)

    # ---------------------------------------------------------------- build
    def _table(self):
        """The reference (q^d, dq^d, ddq^d) at the three RK4 stage times of every node,
        one (9 nq x K) block per chunk of T/4."""
        nq = self.nq
        j = np.arange(self.n_chunks * self.K)
        tt = np.minimum(np.stack([j * self.h, (j + 0.5) * self.h, (j + 1) * self.h]),
                        self.gait.t_max)
        qd, dqd, ddqd = self.gait.evaluate(tt.ravel())
        R = np.vstack([qd, dqd, ddqd]).reshape(3 * nq, 3, -1).transpose(1, 0, 2)
        R = R.reshape(9 * nq, -1)                            # (stage 0; 1/2; 1) x nodes
        self._rtab = [R[:, c * self.K:(c + 1) * self.K] for c in range(self.n_chunks)]

    def _diagnostics(self, x, tau, R, P):
        q, dq, _, u, Fx, Fz, den = self.zd.point(x, tau, R, P)
        return self.schema.vector(self.model, q, dq, u, Fx, Fz, den)

    def _build(self):
        m, zd, nq = self.model, self.zd, self.nq
        x, tau, h = ca.SX.sym("x", 2), ca.SX.sym("tau"), ca.SX.sym("h")
        k1 = ca.SX.sym("k1", 2)
        P = ca.SX.sym("P", zd.n_par)
        R3 = ca.SX.sym("R3", 9 * nq)
        stage = {0.0: R3[:3 * nq], 0.5: R3[3 * nq:6 * nq], 1.0: R3[6 * nq:]}
        # RK4 with the first stage given: it is the rhs at the previous node's end, where
        # the diagnostics are evaluated too, so the two share their subexpressions
        xn = rk4_step(lambda xv, c: k1 if c == 0.0 else zd.rhs(xv, tau + c * h, stage[c], P),
                      x, h)
        out = ca.cse(ca.vertcat(xn, zd.rhs(xn, tau + h, stage[1.0], P),
                                self._diagnostics(xn, tau + h, stage[1.0], P)))
        def jit(f):          # compiled once per content, kept in the cache folder
            return compiled(f, "-O2") if self.jit else f
        self.node = ca.Function("zd_node", [x, tau, k1, h, R3, P],
                                [out[:2], tau + h, out[2:4], out[4:]],
                                ["x", "tau", "k1", "h", "R3", "P"],
                                ["x_next", "tau_next", "k1_next", "diag"])
        # diagnostics and the rhs at a state with the reference given explicitly (step
        # start, impact)
        R1 = ca.SX.sym("R", 3 * nq)
        both = ca.cse(ca.vertcat(self._diagnostics(x, tau, R1, P), zd.rhs(x, tau, R1, P)))
        self.diag = ca.Function("zd_diag", [x, tau, R1, P], [both[:-2], both[-2:]])
        # the last RK4 step, of length eta, with the reference state integrated
        # alongside from the node: one call per Newton iterate
        # (the reference's parameters theta are an input: one Function for every gait)
        along = zd.along(self.gait, parametric=True)
        self._reference_fn, self._theta = self.gait.symbolic_parametric()
        z = ca.SX.sym("z", along.size1_in(0))
        th = ca.SX.sym("theta", along.size1_in(3))
        eta = ca.SX.sym("eta")
        ze = rk4_step(lambda zv, c: along(zv, tau + c * eta, P, th)[0], z, eta)
        _, q_e, dq_e = along(ze, tau + eta, P, th)
        z_e = m.swing_foot(q_e)[1]
        self.event = ca.Function("zd_event", [z, tau, eta, P, th],
                                 [z_e, ca.jacobian(z_e, eta), ze[:2], q_e, dq_e])
        # impact (eq. 2-3) at the event's state (its reference integrated alongside, so
        # that the foot is exactly at the strike height) and the next step's start (eq. 17)
        # (the reference at tau = 0 is an input: these Functions are the robot's alone)
        qi, dqi, R0 = ca.SX.sym("q", nq), ca.SX.sym("dq", nq), ca.SX.sym("R0", 3 * nq)
        q_p, dq_p, F, _, v_old = m.impact_full(qi, dqi)
        x_p, y_n, dy_n = zd.step_start(q_p, dq_p, R0, P[:self.nu])
        self.impact = ca.Function("zd_impact", [qi, dqi, P, R0],
                                  [x_p, y_n, dy_n, F, v_old[1]])
        qs, dqs, M1s = ca.SX.sym("q", nq), ca.SX.sym("dq", nq), ca.SX.sym("M1", self.nu)
        self.start = ca.Function("zd_start", [qs, dqs, M1s, R0],
                                 list(zd.step_start(qs, dqs, R0, M1s)))
        # four scenarios per SIMD vector where the machine allows (biped_casadi.simd), else
        # CasADi's compiled (jit) or interpreted Functions, mapped.  The reference and its
        # parameters enter as inputs, so every gait of the robot (with the same Bezier
        # degree) shares the kernels, compiled once; in two libraries compiled side by
        # side, the step ends' at -O1 (they run once a step)
        self._simd = None
        if self.jit:
            with ThreadPoolExecutor(2) as pool:
                nodes = pool.submit(kernels, {
                    "chunk": (self.node, 3, ["const", "node", "sample"]),
                    "diag": (self.diag, 0, ["sample"] * 4)}, "zd_walker_nodes")
                ends = pool.submit(kernels, {
                    "event": (self.event, 0, ["sample"] * 4 + ["const"]),
                    "reference": (self._reference_fn, 0, ["sample"] * 2 + ["const"]),
                    "impact": (self.impact, 0, ["sample"] * 3 + ["const"]),
                    "start": (self.start, 0, ["sample"] * 3 + ["const"])},
                    "zd_walker_ends", "-O1")
                nodes, ends = nodes.result(), ends.result()
            self._simd = None if nodes is None or ends is None else {**nodes, **ends}
        node = self.node
        if self.jit and self._simd is None:
            node, self.diag = jit(self.node), jit(self.diag)
        acc = node.mapaccum("zd_chunk", self.K, [0, 1, 2], [0, 1, 2])
        xc, tc0, kc = ca.MX.sym("x", 2), ca.MX.sym("tau"), ca.MX.sym("k1", 2)
        Pc, Rt = ca.MX.sym("P", zd.n_par), ca.MX.sym("R", 9 * nq, self.K)
        X, TAU, K1, DG = acc(xc, tc0, kc, self.h, Rt, Pc)
        self.chunk = ca.Function("zd_chunk_fn", [xc, tc0, kc, Pc, Rt], [X, TAU, K1, DG])

    def _batch(self, name: str, *args) -> list:
        """``name`` over the scenarios (:func:`~biped_casadi.simulation.kernel.call_batched`)."""
        return call_batched(self._simd, self._mapped, name, *args)

    @cached(maxsize=64)
    def _mapped(self, name: str, n: int) -> ca.Function:
        """``name`` mapped over n scenarios (:func:`~biped_casadi.simulation.kernel.mapped`)."""
        return mapped(getattr(self, name), n)

    def _chunk(self, x, tau, k1, P, R):
        """K RK4 nodes of m scenarios from (x, tau), the rhs there k1, with parameters P,
        reference table R: the states (2, m, K), times (m, K), rhs (2, m, K) and
        diagnostics (rows, m, K) after each."""
        m = len(x)
        if self._simd is not None:
            X, T, K1, D = self._simd["chunk"](x.T, tau[None, :], k1.T, [self.h], R, P.T,
                                              K=self.K, threads=threads())
            return X, T[0], K1, D
        X, T, K1, D = (np.array(v) for v in self._mapped("chunk", m)(
            x.T, tau[None, :], k1.T, P.T, R))
        return (X.reshape(2, m, self.K), T.reshape(m, self.K), K1.reshape(2, m, self.K),
                D.reshape(-1, m, self.K))

    def _reference(self, tau):
        """(q^d, dq^d, ddq^d) stacked, (3 nq, n) for the taus."""
        tau = np.minimum(np.atleast_1d(np.asarray(tau, float)), self.gait.t_max)
        if self._simd is not None and tau.size > 1:
            qd, dqd, ddqd, _ = self._batch("reference", tau[None, :], self.gait.states(tau),
                                           self._theta)
        else:
            qd, dqd, ddqd = self.gait.evaluate(tau)
        return np.vstack([qd, dqd, ddqd])

    # ----------------------------------------------------------- scenarios
    def scenarios(self, q0, dq0, M1s, rejoin):
        """Initial (q_u, dq_u) and step parameters P of scenarios from full start states.

        The arrays broadcast along the n scenarios.

        Parameters
        ----------
        q0, dq0 : array_like
            (n, nq) start configurations (rad) and velocities (rad/s) at tau = 0.
        M1s : array_like
            (n, nu) output matrices, one per scenario (or one, broadcast).
        rejoin : float or array_like
            (n,) rejoin times of v_c, fraction of T.

        Returns
        -------
        x0 : numpy.ndarray
            (n, 2) initial (q_u, dq_u), rad and rad/s.
        P : numpy.ndarray
            (n, 3 nu + 1) step parameters (M1, t_c, y_i, dy_i) of
            :meth:`ZeroDynamics.params`.
        """
        nq = self.model.nq
        q0, dq0, M1s = (as_rows(a, k, name) for a, k, name in (
            (q0, nq, "q0"), (dq0, nq, "dq0"), (M1s, self.nu, "M1s")))
        n = _scenarios(q0, dq0, M1s, rejoin)
        q0, dq0, M1s = (np.broadcast_to(a, (n, a.shape[1])) for a in (q0, dq0, M1s))
        for i in range(min(n, len(M1s))):
            check_M1(M1s[i], self.nu)
        tc = np.broadcast_to(np.asarray(rejoin, float), (n,)) * self.T
        x0, y, dy = self._batch("start", q0.T, dq0.T, M1s.T, self._R0)
        return x0.T, self.zd.params(M1s, tc, y.T, dy.T).reshape(n, -1)

    def den_scale(self, M1s) -> np.ndarray:
        """Per design, the largest ``|D11 - D12 M1|`` along the reference.

        It is the scale of the threshold below which the controller counts as singular.

        Parameters
        ----------
        M1s : array_like
            (n, nu) output matrices (or one (nu,)).

        Returns
        -------
        numpy.ndarray
            (n,) the maximum over the reference of ``|D11 - D12 M1|``.
        """
        D11, D12 = denominator_samples(self.gait)
        d = decoupling_denominator(D11, D12, np.atleast_2d(M1s).T)
        return np.max(np.abs(d), axis=1)

    # ------------------------------------------------------------------ walk
    def walk(self, q0, dq0, M1s, rejoin=0.5, steps: int = 10, terrain=None) -> WalkBatch:
        """Walk every scenario from its full start state at tau = 0.

        Parameters
        ----------
        q0, dq0 : array_like
            (n, nq) start states (the start of a step).
        M1s : array_like
            (n, nu) output matrices (or one, broadcast).
        rejoin : float or array_like
            Rejoin time of v_c as a fraction of T, per scenario.
        steps : int
            Steps (impacts) to walk.
        terrain : Terrain or array_like, optional
            Ground heights: one :class:`~biped_casadi.simulation.terrain.Terrain` for
            every scenario, or an (n, steps) array; default flat.

        Returns
        -------
        WalkBatch
        """
        x0, P = self.scenarios(q0, dq0, M1s, rejoin)
        return self._walk(x0, P, steps, tau0=0.0, terrain=terrain)

    def walk_from_section(self, x, M1s, rejoin=0.5, steps: int = 10,
                          terrain=None) -> WalkBatch:
        """Walk from zero-dynamics states at the Poincaré section tau = 0.75 T.

        The states lie on the zero-dynamics manifold at the section (v_c = 0 there); a
        walk is ``steps`` applications of the restricted Poincaré map, with every state
        checked on the way.

        Parameters
        ----------
        x : array_like
            (n, 2) states (q_u, dq_u) at the section, rad and rad/s.
        M1s : array_like
            (n, nu) output matrices (or one, broadcast).
        rejoin : float or array_like
            Rejoin time of v_c as a fraction of T, per scenario.
        steps : int
            Steps (impacts) to walk.
        terrain : Terrain or array_like, optional
            Ground heights (see :meth:`walk`); default flat.

        Returns
        -------
        WalkBatch
        """
        x, M1s = as_rows(x, 2, "x"), as_rows(M1s, self.nu, "M1s")
        n, nu = _scenarios(x, M1s, rejoin), self.nu
        x = np.broadcast_to(x, (n, 2))
        M1s = np.broadcast_to(M1s, (n, nu))
        tc = np.broadcast_to(np.asarray(rejoin, float), (n,)) * self.T
        P = self.zd.params(M1s, tc, np.zeros((n, nu)), np.zeros((n, nu))).reshape(n, -1)
        return self._walk(x.copy(), P, steps, tau0=SECTION * self.T, terrain=terrain)

    def walk_step(self, q0, dq0, M1s, rejoin=0.5):
        """One step from full start states, and the states just before its impact.

        For chaining walkers of different gaits (a speed profile,
        :func:`~biped_casadi.simulation.speed_profile.walk_profile`).

        Parameters
        ----------
        q0, dq0 : array_like
            (n, nq) start states (the start of a step).
        M1s : array_like
            (n, nu) output matrices (or one, broadcast).
        rejoin : float or array_like
            Rejoin time of v_c as a fraction of T, per scenario.

        Returns
        -------
        batch : WalkBatch
            The step's outcome (one step).
        q_minus, dq_minus : numpy.ndarray
            (n, nq) the state before the impact of the scenarios whose step was valid
            (NaN for the others).
        """
        x0, P = self.scenarios(q0, dq0, M1s, rejoin)
        ends = np.full((len(x0), 2 * self.nq), np.nan)
        batch = self._walk(x0, P, 1, tau0=0.0, ends=ends)
        return batch, ends[:, :self.nq], ends[:, self.nq:]

    def _walk(self, x, P, steps, tau0, terrain=None, ends=None):
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
            raise ValueError(f"steps must be a positive integer, got {steps!r}")
        n = len(x)
        heights = step_heights(terrain, n, steps)
        P = np.array(P, float)
        run = OutcomeRecorder(n, steps)
        scale = self.den_scale(P[:, :self.nu])
        alive = np.ones(n, bool)
        for k in range(steps):
            idx = np.flatnonzero(alive)
            if idx.size == 0:
                break
            run.scenario_steps += idx.size
            start = tau0 if k == 0 else 0.0
            ahead, behind = ground_levels(heights, k)
            ground = (ahead[idx], behind[idx])
            struck = self._single_support(k, idx, x, P, scale, run, alive, start, ground)
            if struck is not None:
                self._impact(k, struck, x, P, scale, run, alive, ahead, ends)
        return run.batch()

    def _check(self, Dg, sign, scale, zprev=None, ground=None):
        """First failing node (index along the last axis, status) of diagnostics
        (rows, m, K) of m scenarios, on the ground (ahead, behind) of each (m,)."""
        if ground is not None:
            ground = (ground[0][:, None], ground[1][:, None])
        masks = node_violations(self.schema.rows(Dg), self.limits, scale[:, None],
                                sign[:, None], zprev, ground)
        return first_violation(masks)

    def _track(self, run, idx, Dg, mask=None):
        S = self.schema
        run.track(idx, S.row(Dg, "u"), S.row(Dg, "Fx"), S.row(Dg, "Fz"), mask)

    def _single_support(self, k, idx, x, P, scale, run, alive, tau0, ground):
        """Integrate step k of the scenarios ``idx`` from ``tau0`` to the strike on the
        ground (ahead, behind) of each; records failures; returns the struck scenarios'
        (indices, state and tau of the node before the strike, z_sw there and after, the
        denominator's sign, the length of the strike's RK4 step, the torques and reactions
        at the three nodes before it) or None."""
        S, m = self.schema, idx.size
        Pk = P[idx]
        R0 = np.repeat(self._R_start[tau0], m, axis=1)
        D0, k1 = self._batch("diag", x[idx].T, np.full((1, m), tau0), R0, Pk.T)
        sign = np.where(S.row(D0, "den") >= 0, 1.0, -1.0)
        zsw0 = S.row(D0, "zsw")
        _, which = self._check(D0[:, :, None], sign, scale[idx], ground=ground)
        if tau0 == 0:
            which = np.where(which == "", start_violation(zsw0, self.limits, ground[1]), which)
        self._track(run, idx, D0[:, :, None])
        bad = which != ""
        run.fail(idx[bad], which[bad], k)
        alive[idx[bad]] = False
        st = dict(live=~bad, x=x[idx].copy(), tau=np.full(m, tau0), k1=k1.T.copy(),
                  z=zsw0.copy(), dz=S.row(D0, "dzsw").copy(), P=Pk, sign=sign,
                  scale=scale[idx], r=self.margin.rows(D0)[..., None],
                  before=np.full((m, 2), np.nan), t_before=np.zeros(m), z_a=np.zeros(m),
                  z_b=np.zeros(m), h=np.full(m, self.h), struck=np.zeros(m, bool))
        st["r_before"] = np.full(st["r"].shape[:2] + (3,), np.nan)
        c0 = int(round(tau0 / (self.T / CHUNKS_PER_STEP)))
        for ci in range(c0, self.n_chunks):
            li = np.flatnonzero(st["live"])
            if li.size == 0:
                break
            self._advance(k, ci, li, idx, st, ground, run, alive)
        struck = st["struck"]
        missing = alive[idx] & ~struck
        run.fail(idx[missing], "no_impact", k)
        alive[idx[missing]] = False
        si = np.flatnonzero(struck & alive[idx])
        if si.size == 0:
            return None
        return (idx[si], st["before"][si], st["t_before"][si], st["z_a"][si], st["z_b"][si],
                sign[si], st["h"][si], st["r_before"][:, si])

    def _advance(self, k, ci, li, idx, st, ground, run, alive):
        """Chunk ci of the live scenarios ``li`` (of ``idx``) of step k: failures recorded,
        strikes and the next chunk's start into ``st``."""
        S = self.schema
        Xs, Ts, K1, Dg = self._chunk(st["x"][li], st["tau"][li], st["k1"][li], st["P"][li],
                                     self._rtab[ci])
        if (ci + 1) / CHUNKS_PER_STEP > self.horizon + 1e-12:  # last partial chunk
            keep = Ts[0] <= self.horizon * self.T + 1e-12
            Xs, Ts, K1, Dg = Xs[:, :, keep], Ts[:, keep], K1[:, :, keep], Dg[:, :, keep]
        K = Ts.shape[1]
        zs, dzs = S.row(Dg, "zsw"), S.row(Dg, "dzsw")
        zp = np.concatenate([st["z"][li][:, None], zs[:, :-1]], axis=1)
        gl = (ground[0][li], ground[1][li])
        hits = strike(zs, zp, S.row(Dg, "xsw"), self.model.scuff_zone,
                      (gl[0][:, None], gl[1][:, None]))
        i_strike = np.where(hits.any(axis=1), np.argmax(hits, axis=1), K)

        refs = {}

        def node(i, j):             # the first node of step j of scenario i
            g = li[i]
            X, t = (st["x"][g], st["tau"][g]) if j == 0 else (Xs[:, i, j - 1], Ts[i, j - 1])
            if "r" not in refs:     # the reference's state at the nodes (shared by all)
                refs["r"] = self.gait.states(np.r_[st["tau"][li[0]], Ts[0, :-1]])
            return np.r_[X, refs["r"][:, j]], t, np.r_[st["P"][g], self._theta]

        feet = foot_dips(self._dip, self.h, node, zp,
                         np.concatenate([st["dz"][li][:, None], dzs[:, :-1]], axis=1), dzs,
                         i_strike, gl, self.model.scuff_zone, self.limits)
        end = {}                              # a dip's strike: its z_sw and step length
        for i, (j, kind, eta, z, _, _) in feet.items():
            i_strike[i] = j                   # the nodes from the dip's on do not count
            if kind == "strike":
                end[i] = z, eta
        first, which = self._check(Dg, st["sign"][li], st["scale"][li], zp, gl)
        failed = (which != "") & (first < i_strike)
        upto = np.where(failed, first + 1, i_strike)
        message = np.full(li.size, "", dtype=object)
        R = np.concatenate([st["r"][:, li], self.margin.rows(Dg)], axis=2)   # history first
        dips = self._margin_dips(R, K, upto, self._between, node)
        for i, (j, eta, status) in dips.items():          # before the nodes' failures
            D = self._state_at(*node(i, j), eta)
            self._track(run, idx[li[[i]]], D[:, :, None])
            failed[i], which[i], upto[i] = True, status, j
            message[i] = f"step {k + 1}: " + self.margin.message(status, D, st["scale"][li[i]])
        for i, (j, kind, eta, z, xf, _) in feet.items():
            if kind == "scuffed" and not failed[i]:
                failed[i], which[i], upto[i] = True, "scuffed", j
                message[i] = f"step {k + 1}: " + between_message(
                    "scuffed", dict(xsw=xf, zsw=z), self.limits)
        self._track(run, idx[li], Dg, np.arange(K)[None, :] < upto[:, None])
        run.fail(idx[li[failed]], which[failed], k, message[failed])
        alive[idx[li[failed]]] = False
        hit = ~failed & (i_strike < K)
        n0 = R.shape[2] - K                  # nodes before the chunk's
        if hit.any():                        # the rows at the three nodes before the strike
            hi_ = np.flatnonzero(hit)
            c = i_strike[hi_, None] + n0 + np.arange(-3, 0)
            Rb = R[:, hi_[:, None], np.maximum(c, 0)]
            Rb[:, c < 0] = np.nan
            st["r_before"][:, li[hi_]] = Rb
        for i in np.flatnonzero(hit):
            s_, g_ = i_strike[i], li[i]
            st["before"][g_] = st["x"][g_] if s_ == 0 else Xs[:, i, s_ - 1]
            st["t_before"][g_] = st["tau"][g_] if s_ == 0 else Ts[i, s_ - 1]
            st["z_a"][g_] = zp[i, s_]
            st["z_b"][g_], st["h"][g_] = end.get(i, (zs[i, s_], self.h))
            st["struck"][g_] = True
        cont = ~failed & ~hit
        st["live"][li[~cont]] = False
        g = li[cont]
        st["x"][g], st["tau"][g], st["k1"][g] = Xs[:, cont, -1].T, Ts[cont, -1], K1[:, cont, -1].T
        st["z"][g], st["dz"][g] = zs[cont, -1], dzs[cont, -1]
        r = np.full(st["r"].shape[:2] + (3,), np.nan)
        r[:, g] = R[:, cont, -3:]
        st["r"] = r

    def _margin_dips(self, R, K, upto, between, node) -> dict:
        """The margins' first dips in the first ``upto`` steps of a chunk, R the rows
        (:meth:`MarginCheck.rows <biped_casadi.simulation.margins.MarginCheck.rows>`) at
        its nodes and up to three before them: screened for the scenarios whose rows say
        a margin may come near its bound (:meth:`~biped_casadi.simulation.margins.
        MarginCheck.near`)."""
        nn = np.flatnonzero(self.margin.near(R) & (upto > 0))
        if nn.size == 0:
            return {}

        def step(i, j):
            X, t, p = node(nn[i], j)
            return X, t, self.h, p

        return {int(nn[i]): got for i, got in self.margin.first_dips(
            between, self.margin.of_rows(R[:, nn]), K, step, upto[nn]).items()}

    def _dense(self):
        """The margins (:class:`~biped_casadi.simulation.margins.MarginCheck`) and the
        swing foot on the last RK4 step of length eta from a node (z, tau) (z: (q_u, dq_u)
        and the reference state; p: (P, theta)), with their rates in eta; built at first
        use, then shared by every batch."""
        if self._dense_fns is None:
            zd, npar = self.zd, self.zd.n_par
            along = zd.along(self.gait, parametric=True)
            z, tau, eta = ca.SX.sym("z", along.size1_in(0)), ca.SX.sym("tau"), ca.SX.sym("eta")
            pp = ca.SX.sym("p", npar + along.size1_in(3))
            ze = rk4_step(lambda zv, c: along(zv, tau + c * eta, pp[:npar], pp[npar:])[0], z,
                          eta)
            rk4 = ca.Function("zd_rk4", [z, tau, eta, pp], [ze, tau + eta])

            def point(Z, t, p):
                qd, dqd, ddqd, _ = self._reference_fn(t, Z[2:], p[npar:])
                return zd.point(Z[:2], t, ca.vertcat(qd, dqd, ddqd), p[:npar])

            def margins(Z, t, p):
                return self.margin.values(*point(Z, t, p)[3:6], lib=ca)

            fs = [self.margin.function(rk4, margins),
                  dip_function(rk4, lambda Z, t, p: self.model.swing_foot(point(Z, t, p)[0]))]
            self._dense_fns = tuple(FastCall(f) for f in fs)
        return self._dense_fns

    def _between(self, *args):
        """The margins between two nodes and their rates (:meth:`_dense`, built at first
        use)."""
        return self._dense()[0](*args)

    def _dip(self, *args):
        """The swing foot between two nodes and its rates (:meth:`_dense`)."""
        return self._dense()[1](*args)

    def _state_at(self, z, tau, p, eta):
        """The diagnostics (rows, 1) at the end of the RK4 step of length eta from the
        node (z, tau) (:meth:`_dense`'s arguments)."""
        P = p[:self.zd.n_par]
        xe = np.array(self.event(z, tau, eta, P, self._theta)[2])
        return np.array(self.diag(xe, tau + eta, self._reference(tau + eta), P)[0])

    def _impact(self, k, struck, x, P, scale, run, alive, ahead, ends=None):
        """Locate the impact of the struck scenarios (z_sw = their h_k, ``ahead``), check
        the pre-impact state and the impulse, apply the impact map and the next step's
        start; the valid ones' pre-impact states (q, dq) into the rows of ``ends``."""
        gi, xa, ta, za, zb, sign, h_end, r_before = struck
        S, nu, m = self.schema, self.nu, gi.size
        Ps = P[gi]
        hk = ahead[gi]
        za_r = np.vstack([xa.T, self.gait.states(ta)])

        def event(eta):
            z, dz, *_ = self._batch("event", za_r, ta[None, :], eta[None, :], Ps.T,
                                    self._theta)
            return z.ravel() - hk, dz.ravel()

        eta = locate_strike(event, h_end, za - hk, zb - hk)
        _, _, xe, qe, dqe = self._batch("event", za_r, ta[None, :], eta[None, :], Ps.T,
                                        self._theta)
        xe = xe.T
        tm = ta + eta
        Rm = self._reference(tm)
        Dm, _ = self._batch("diag", xe.T, tm[None, :], Rm, Ps.T)
        _, which = self._check(Dm[:, :, None], sign, scale[gi],
                               ground=(hk, np.zeros(m)))
        message, dipped = np.full(m, "", dtype=object), np.zeros(m, bool)
        Rm = np.concatenate([r_before, self.margin.rows(Dm)[..., None]], 2)
        nn = np.flatnonzero(self.margin.near(Rm))         # those the screen may flag

        def step(i, j):                                    # from the last node to the impact
            return za_r[:, i], ta[i], eta[i], np.r_[Ps[i], self._theta]

        dips = {int(nn[i]): got for i, got in self.margin.first_dips(
            self._between, self.margin.of_rows(Rm[:, nn]), 1, lambda i, j: step(nn[i], j),
            np.ones(nn.size, int)).items()} if nn.size else {}
        for i, (_, e, status) in dips.items():
            D = self._state_at(*step(i, 0)[:2], step(i, 0)[3], e)
            self._track(run, gi[[i]], D[:, :, None])
            which[i], dipped[i] = status, True
            message[i] = f"step {k + 1}: " + self.margin.message(status, D, scale[gi[i]])
        self._track(run, gi, Dm[:, :, None], ~dipped[:, None])
        which = np.where(which == "", strike_violation(S.row(Dm, "dzsw")), which)
        xn, yn, dyn, F, vl = self._batch("impact", qe, dqe, Ps.T, self._R0)
        F, vl = F.T, vl.ravel()
        rec = np.flatnonzero(which == "")          # a valid strike: the step is complete
        err = xe - self.ref_T[None, :]
        run.impact(gi[rec], k, err[rec, 0], err[rec, 1], tm[rec], F[rec])
        finite = np.all(np.isfinite(np.c_[xn.T, yn.T, dyn.T, F]), axis=1)
        which = np.where(which == "", impact_violation(F, vl, finite, self.limits), which)
        bad = which != ""
        run.fail(gi[bad], which[bad], k, message[bad])
        alive[gi[bad]] = False
        go = ~bad
        if ends is not None:
            ends[gi[go]] = np.c_[qe.T, dqe.T][go]
        x[gi[go]] = xn.T[go]
        P[gi[go], nu + 1:2 * nu + 1] = yn.T[go]
        P[gi[go], 2 * nu + 1:] = dyn.T[go]


@cached(maxsize=4)
def zero_dynamics_walker(gait, options: SimulationOptions | None = None,
                         rk4_steps: int = 400, jit: bool = False) -> ZeroDynamicsWalker:
    """The :class:`ZeroDynamicsWalker` of a gait and options, built once (memoised).

    Parameters
    ----------
    gait : Reference
        The reference step, made for ``model``.
    options : SimulationOptions, optional
        Validity thresholds and horizon.
    rk4_steps : int
        RK4 steps per reference step duration T (a multiple of 8).
    jit : bool
        Compile the step to C.

    Returns
    -------
    ZeroDynamicsWalker
        The same object for the same arguments.
    """
    model = require_reference(gait).model
    return ZeroDynamicsWalker(model, gait, options, rk4_steps, jit)
