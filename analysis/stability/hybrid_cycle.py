"""The stride map over a cycle of domains and its exact Jacobian: walking is the cycle of
one domain, running the cycle stance -> flight -> stance.

A domain is a smooth piece of a hybrid system: a closed-loop vector field, a guard whose
downward zero crossing ends it, a reset into the next domain's state (possibly of
another dimension) and validity constraints that must hold along it (:class:`Domain`).
A cycle of domains D_0 -> D_1 -> ... -> D_(k-1) -> D_0 (:class:`HybridCycle`) has the
stride map

    x_0  ->  P(x_0) = Delta_(k-1)( ... Delta_0(phi_0(x_0)) ... ),

phi_i the flow of domain i from its entry to its guard.  P is evaluated by the same
operations as the step-to-step map of the walking closed loop
(:mod:`analysis.stability.step_map`): fixed-step RK4 from the domain's entry, a crossing
where the guard goes from >= 0 at one node to < 0 at the next (and an optional arming
function is positive there), the crossing time inside that RK4 interval as the length
eta of the last RK4 step with g(RK4(X_N, eta)) = 0, by the safeguarded Newton of
:func:`~biped_casadi.simulation.kernel.locate_strike`.  The Jacobian dP/dx_0 is exact for
this discrete scheme: forward algorithmic differentiation through every RK4 step, the
domain's entry and reset, and the crossing time by the implicit function theorem,

    d eta = -(g_X dX_N + g_p dp) / (g_X dX/d eta + g_t),

the saltation term of each guard.

Guard parts.  A domain's guard may have named parts g = (g_1, ..., g_m) (e.g. a sliding
foot's normal force and its slip velocity): the domain ends where the first of them
crosses zero going down, each located as above and the earliest taken, and the pass
says which part fired (:attr:`DomainPass.part`).  The reset may depend on that part
(one per part), and so may the domains that follow: a part may end the next few domains
at their entry (``Domain.skip``).  The part is a discrete choice fixed at the point of
evaluation, as the sequence of domains is: the Jacobian is that of the part that fired,
its saltation term from that part's gradient, exact.

Between the nodes.  A domain may name outputs that must hold on the continuous solution,
not only at its nodes: constraints (``dense_constraints``, e.g. a foot's height above the
ground, a contact force's friction margin) and its guard (``dense_guard``), checked on
the RK4 step from each node (:mod:`analysis.stability.between_nodes`): a constraint below
``-tolerance`` there is violated; a guard below 0 there is a crossing, the first root
before that minimum (a foot that touches the ground and rises again within one step has
landed).  Every minimum found is recorded (:attr:`DomainPass.dips`).

Domain i's state x has ``n`` numbers (what the resets map); it integrates an augmented
state X = (x, r) of ``nX`` numbers (r: a controller's internal states, e.g. the
time-varying controller's reference state) with parameters p fixed for the domain (its
step constants, eq. 17), both set at entry by ``start(x) -> (X0, p)``, or by
``start(x, s) -> (X0, p)`` when they depend on s, the time the stride has run before the
domain began (0 in the first domain): a law whose clock runs on through the stride.  Time
t restarts at 0 in each domain; s and its gradient are carried through the Jacobian.

The domains of the walking and running robot are built in
:mod:`analysis.stability.cycle_domains`: walking is the cycle of one domain, and its
stride map is :class:`~analysis.stability.step_map.StepMap`'s S.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from biped_casadi.numerics import rk4_step
from biped_casadi.simulation.kernel import locate_strike

from .between_nodes import minima, watch
from .cycle_results import DomainPass, StrideLinearisation, StrideValue
from .hybrid_domain import Domain, HybridCycleError

__all__ = ["Domain", "HybridCycle", "HybridCycleError", "DomainPass", "StrideValue",
           "StrideLinearisation", "entry_function", "finite_difference_jacobian"]


class _Compiled:
    """A domain's Functions for one number of seeds (the cycle's first state)."""

    def __init__(self, d: Domain, ns: int):
        nX, npar = d.nX, d.n_par
        X, t, h, p = ca.SX.sym("X", nX), ca.SX.sym("t"), ca.SX.sym("h"), ca.SX.sym("p", npar)
        J, Jp = ca.SX.sym("J", nX, ns), ca.SX.sym("Jp", npar, ns)

        def rhs(Xv, stage):
            return d.vector_field(Xv, t + stage * h, p)

        cse = ca.cse if d.common_subexpressions else (lambda e: e)
        Xn = cse(rk4_step(rhs, X, h))
        rk4 = ca.Function(f"{_ident(d.name)}_rk4", [X, t, h, p], [Xn, t + h])
        self._d, self._rk4, self._lazy = d, rk4, {}    # built at first use, shared by copies

        def node(Yv, sv):
            a = d.arming(Yv, sv, p) if d.arming is not None else ca.SX(1)
            c = d.constraints(Yv, sv, p) if d.constraints is not None else ca.SX(0, 1)
            return d.guard(Yv, sv, p), a, c

        Xr, tr = rk4(X, t, h, p)
        self.node = ca.Function("node", [X, t, p], list(node(X, t)))
        self.step = ca.Function("step", [X, t, h, p], [Xr, tr, *node(Xr, tr)])
        Jn = ca.jtimes(Xr, X, J) + (ca.jtimes(Xr, p, Jp) if npar else 0)
        self.step_sens = ca.Function("step_sens", [X, J, t, h, p, Jp],
                                     [Xr, cse(Jn), tr, *node(Xr, tr)])
        eta = ca.SX.sym("eta")
        Xe, te = rk4(X, t, eta, p)
        ge = d.guard(Xe, te, p)
        self.event = ca.Function("event", [X, t, eta, p], [ge, ca.jacobian(ge, eta)])
        Je = ca.jtimes(Xe, X, J) + (ca.jtimes(Xe, p, Jp) if npar else 0)
        Y, s = ca.SX.sym("Y", nX), ca.SX.sym("s")
        gY = d.guard(Y, s, p)
        grads = ca.Function("guard_gradients", [Y, s, p],
                            [ca.jacobian(gY, Y), ca.jacobian(gY, p), ca.jacobian(gY, s)])
        gX, gp, gt = grads(Xe, te, p)
        self.last = ca.Function("last", [X, J, t, eta, p, Jp],
                                [Xe, cse(Je), ca.jacobian(Xe, eta), gX, gp, gt,
                                 node(Xe, te)[2]])
        self.entry = entry_function(d)
        x = ca.SX.sym("x", d.n)
        e = d.exit_constraints(x) if d.exit_constraints is not None else ca.SX(0, 1)
        e = e[0] if isinstance(e, (list, tuple)) else e
        built = {}                      # one Function per distinct reset
        for r in d.resets:
            if id(r) not in built:
                xp = r(x)
                xp = xp[0] if isinstance(xp, (list, tuple)) else xp
                built[id(r)] = ca.Function("reset", [x], [xp, ca.jacobian(xp, x), e])
        #: ``reset(x) -> (x+, dx+/dx, exit constraints)`` of each part of the guard
        self.resets = [built[id(r)] for r in d.resets]

    def _watched_outputs(self):
        """Symbols (Y, s, p) and the watched outputs W(Y, s, p)."""
        d = self._d
        Y, s, p = ca.SX.sym("Y", d.nX), ca.SX.sym("s"), ca.SX.sym("p", d.n_par)
        m = len(d.part_names)
        out = [d.guard(Y, s, p)[i] if i < m else d.constraints(Y, s, p)[i - m]
               for _, i in d.watched]
        return Y, s, p, ca.Function("watched", [Y, s, p], [ca.vertcat(*out)])

    @property
    def rate(self) -> ca.Function:
        """``rate(X, t, p)``: the watched outputs' rates along the flow (built when a step
        is first refined)."""
        if "rate" not in self._lazy:
            Y, s, p, W = self._watched_outputs()
            w = W(Y, s, p)
            self._lazy["rate"] = ca.Function(
                "rate", [Y, s, p], [ca.jtimes(w, Y, self._d.vector_field(Y, s, p))
                                    + ca.jacobian(w, s)])
        return self._lazy["rate"]

    @property
    def between(self) -> ca.Function:
        """``between(X, t, eta, p) -> (W, dW/deta, d2W/deta2)`` on the RK4 step of length
        eta from the node (X, t) (built when a minimum is first located)."""
        if "between" not in self._lazy:
            X, t, p, W = self._watched_outputs()
            eta = ca.SX.sym("eta")
            We = W(*self._rk4(X, t, eta, p)[:2], p)
            dW = ca.jacobian(We, eta)
            self._lazy["between"] = ca.Function("between", [X, t, eta, p],
                                                [We, dW, ca.jacobian(dW, eta)])
        return self._lazy["between"]


def entry_function(d: Domain) -> ca.Function:
    """``entry(x, s) -> (X0, p, dX0/dx, dp/dx, dX0/ds, dp/ds)`` of a domain: its start at the
    state x and the stride's time s (module docstring), with the derivatives."""
    x, s = ca.SX.sym("x", d.n), ca.SX.sym("s")
    if d.start is None:
        X0, p0 = x, ca.SX(0, 1)
    else:
        X0, p0 = d.start(x, s) if d.start.n_in() == 2 else d.start(x)
    return ca.Function("entry", [x, s], [X0, p0, ca.jacobian(X0, x), ca.jacobian(p0, x),
                                         ca.jacobian(X0, s), ca.jacobian(p0, s)])


def _ident(name: str) -> str:
    return "".join(ch if ch.isalnum() else "_" for ch in name) or "domain"


def _col(v) -> np.ndarray:
    return np.array(v, float).ravel()


class HybridCycle:
    """The stride map of a cycle of domains (module docstring).

    Parameters
    ----------
    domains : sequence of Domain
        D_0, ..., D_(k-1); domain i's reset maps into domain i+1's state, the last
        domain's into the first's.

    Raises
    ------
    HybridCycleError
        A reset gives a state of another size than the next domain takes, a part skips
        past the cycle's end or a domain whose reset depends on its part (one line,
        naming the domain).
    """

    def __init__(self, domains):
        self.domains = list(domains)
        if not self.domains or not all(isinstance(d, Domain) for d in self.domains):
            raise ValueError("a cycle needs at least one Domain")
        k = len(self.domains)
        for i, d in enumerate(self.domains):
            nxt = self.domains[(i + 1) % k]
            if d.n_next != nxt.n:
                raise HybridCycleError(d.name, "dimension",
                                       f"its reset gives {d.n_next} numbers, domain "
                                       f"'{nxt.name}' takes {nxt.n}")
        for i, d in enumerate(self.domains):
            if isinstance(d.clock_from, bool) or not isinstance(d.clock_from, int) \
                    or not 0 <= d.clock_from <= i:
                raise HybridCycleError(d.name, "dimension",
                                       f"clock_from must be a domain's index from 0 to {i}, "
                                       f"got {d.clock_from!r}")
        for i, d in enumerate(self.domains):
            for name, n_skip in zip(d.part_names, d.skips):
                if i + n_skip >= k:
                    raise HybridCycleError(d.name, "dimension",
                                           f"its part '{name}' skips {n_skip} domains, past "
                                           f"the cycle's end")
                for o in self.domains[i + 1:i + 1 + n_skip]:
                    if len(set(map(id, o.resets))) > 1:
                        raise HybridCycleError(d.name, "dimension",
                                               f"its part '{name}' skips domain '{o.name}', "
                                               f"whose reset depends on its part")
        self.n = self.domains[0].n
        self._fns = [_Compiled(d, self.n) for d in self.domains]

    def __repr__(self):
        return "HybridCycle(" + " -> ".join(d.name for d in self.domains) + ")"

    # ---------------------------------------------------------------- one domain
    def _check(self, d: Domain, c, t, names):
        c = _col(c)
        if not np.all(np.isfinite(c)):
            raise HybridCycleError(d.name, "not_finite", f"state not finite at t = {t:.6g} s")
        bad = np.flatnonzero(c < -d.tolerance)
        if bad.size:
            j = int(bad[0])
            raise HybridCycleError(d.name, "constraint",
                                   f"{names[j]} violated at t = {t:.6g} s ({c[j]:.3g} < 0)")

    def _dips(self, d: Domain, t, between, eta_max, dips):
        """Record the minima before ``eta_max`` into ``dips``; a constraint below
        -tolerance there is violated."""
        m = len(d.part_names)
        for eta, j, v in between:
            if eta >= eta_max:
                break
            name, k = d.watched[j]
            dips.append((t + eta, name, v))
            if k >= m and not v >= -d.tolerance:
                raise HybridCycleError(d.name, "constraint",
                                       f"{name} violated at t = {t + eta:.6g} s ({v:.3g} < 0, "
                                       f"between two RK4 nodes)")

    @staticmethod
    def _crossings(d: Domain, g_prev, g, a, h, between) -> list:
        """The guard's parts that cross zero going down in a step: (part, its value at the
        step's first node, the bracket's end eta, its value there), the bracket's end the
        part's first minimum below 0 between the nodes, else the step's end."""
        if not a > 0:
            return []
        out = []
        for k in range(g.size):
            hi, g_hi = next(((e, v) for e, j, v in between if d.watched[j][1] == k and v < 0),
                            (h, g[k]))
            if g_prev[k] >= 0 > g_hi:
                out.append((k, g_prev[k], hi, g_hi))
        return out

    def _integrate(self, d: Domain, f, X, p, J, Jp, record):
        """RK4 from the entry state X to the step that crosses the guard: (the node before
        it, its time, its J, the crossing parts (:meth:`_crossings`), the minima in that
        last step, the minima before, times, nodes)."""
        t, h = 0.0, d.h
        g_prev, _, c = f.node(X, t, p)
        g_prev, c = _col(g_prev), _col(c)
        self._check(d, c, t, d.constraint_names)
        times, nodes = ([t], [X]) if record else (None, None)
        dips = []
        w = [watch(d, g_prev, c)]               # the watched values at the last nodes
        for _ in range(d.max_steps):
            if J is not None:
                Xn, Jn, tn, g, a, c = f.step_sens(X, J, t, h, p, Jp)
            else:
                Xn, tn, g, a, c = f.step(X, t, h, p)
            g, a, c = _col(g), float(a), _col(c)
            if not np.all(np.isfinite(g)):
                raise HybridCycleError(d.name, "not_finite",
                                       f"state not finite at t = {float(tn):.6g} s")
            w = w[-3:] + [watch(d, g, c)]
            between = minima(d, f, X, t, h, p, Xn, w) if d.watched else []
            crossing = self._crossings(d, g_prev, g, a, h, between)
            if crossing:
                return X, t, J, crossing, between, dips, times, nodes
            self._dips(d, t, between, np.inf, dips)
            self._check(d, c, float(tn), d.constraint_names)
            X, t, g_prev = _col(Xn), float(tn), g
            if J is not None:
                J = np.array(Jn)
            if record:
                times.append(t)
                nodes.append(X)
        raise HybridCycleError(d.name, "no_crossing",
                               f"{d.guard_name} not crossed going down within the time "
                               f"limit {d.t_max:.6g} s ({d.max_steps} RK4 steps of "
                               f"{h:.4g} s)")

    @staticmethod
    def _locate(f, X, t, p, crossing) -> tuple:
        """The part that reaches 0 first in the last step and the step's length eta there
        (each crossing part's root by the safeguarded Newton, the earliest taken)."""
        best = None
        for k, g_a, hi, g_hi in crossing:
            def event(eta_, k=k):
                ge, dge = f.event(X, t, float(eta_[0]), p)
                return np.array([float(ge[k])]), np.array([float(dge[k])])

            eta = float(locate_strike(event, hi, g_a, g_hi)[0])
            if best is None or eta < best[1]:
                best = (k, eta)
        return best

    def _domain(self, i, x, Jx, derivatives, record, s=0.0, ds=None, skipped=False):
        """Domain i from its state x (with dx/dx0 = Jx) and the stride's time s (with
        ds/dx0 = ds), or empty where an earlier part skips it: the pass, the next state and
        its Jacobian, the duration's gradient, the domains its part skips."""
        d, f = self.domains[i], self._fns[i]
        X, p, XJ, pJ, Xs, ps_ = (np.array(v) for v in f.entry(x, s))
        X, p = X.ravel(), p.ravel()
        X0 = X
        J = Jp = None
        if derivatives:
            J, Jp = XJ @ Jx, pJ @ Jx
            if ds is not None:
                J, Jp = J + Xs @ ds[None, :], Jp + ps_ @ ds[None, :]
        ns = self.n
        if skipped:
            return self._empty(d, f, X0, p, J, derivatives, record, None)
        if d.may_be_empty:
            ended = np.flatnonzero(_col(f.node(X, 0.0, p)[0]) <= 0)
            if ended.size:
                return self._empty(d, f, X0, p, J, derivatives, record, int(ended[0]))
        X, t, J, crossing, between, dips, times, nodes = \
            self._integrate(d, f, X, p, J, Jp, record)
        k, eta = self._locate(f, X, t, p, crossing)
        self._dips(d, t, between, eta, dips)
        Xe, Je, Xeta, gX, gp, gt, ce = f.last(X, J if derivatives else np.zeros((d.nX, ns)),
                                              t, eta, p,
                                              Jp if derivatives else np.zeros((d.n_par, ns)))
        Xe = _col(Xe)
        self._check(d, ce, t + eta, d.constraint_names)
        xm = Xe[:d.n]
        xp, R, e = f.resets[k](xm)
        self._check(d, e, t + eta, d.exit_constraint_names)
        xp = _col(xp)
        if record:
            times.append(t + eta)
            nodes.append(Xe)
        ps = DomainPass(d.name, X0, p, t + eta, xm, xp,
                        None if not record else np.array(times),
                        None if not record else np.array(nodes).T, dips, d.part_names[k])
        if not derivatives:
            return ps, xp, None, None, d.skips[k]
        Je, Xeta = np.array(Je), np.array(Xeta)
        gX, gp, gt = (np.array(v)[k:k + 1] for v in (gX, gp, gt))       # the part that fired
        slope = (gX @ Xeta).item() + gt.item()
        deta = -(gX @ Je + (gp @ Jp if d.n_par else 0)) / slope        # (1, ns)
        dxm = (Je + Xeta @ deta)[:d.n]
        return ps, xp, np.array(R) @ dxm, deta.ravel(), d.skips[k]

    def _empty(self, d: Domain, f, X, p, J, derivatives, record, k):
        """A domain that ends at its entry (``may_be_empty``, its part k at or below 0
        there; or skipped, k None): duration 0, the reset of the entry state."""
        xm = X[:d.n]
        xp, R, e = f.resets[0 if k is None else k](xm)
        self._check(d, e, 0.0, d.exit_constraint_names)
        xp = _col(xp)
        ps = DomainPass(d.name, X, p, 0.0, xm, xp, None if not record else np.zeros(1),
                        None if not record else X[:, None].copy(),
                        part=None if k is None else d.part_names[k])
        skip = 0 if k is None else d.skips[k]
        if not derivatives:
            return ps, xp, None, None, skip
        return ps, xp, np.array(R) @ J[:d.n], np.zeros(self.n), skip

    def _pass(self, x0, derivatives: bool, record: bool):
        x = np.asarray(x0, float).ravel()
        if x.size != self.n:
            raise ValueError(f"the cycle's state has {self.n} numbers, got {x.size}")
        Jx = np.eye(self.n)
        passes, grads = [], []
        s, ds = 0.0, np.zeros(self.n)
        entries = []                      # (s, ds) at each domain's entry
        skip = 0                          # the domains still to skip
        for i, d in enumerate(self.domains):
            entries.append((s, ds))
            s0, ds0 = entries[d.clock_from]
            ps, x, Jx, dT, more = self._domain(i, x, Jx, derivatives, record, s - s0,
                                               ds - ds0, skipped=skip > 0)
            skip = max(skip - 1, more)
            passes.append(ps)
            grads.append(dT)
            s += ps.duration
            if derivatives:
                ds = ds + dT
        return passes, x, Jx, grads

    # ---------------------------------------------------------------- the map
    def stride(self, x0, record: bool = False) -> StrideValue:
        """One application P(x_0) (no derivatives).

        Parameters
        ----------
        x0 : array_like
            (n,) the first domain's state at entry.
        record : bool
            Keep every domain's RK4 nodes (:class:`DomainPass`).

        Returns
        -------
        StrideValue

        Raises
        ------
        HybridCycleError
            A guard not crossed within its domain's time limit, a constraint violated, a
            state that diverged (one line naming the domain).
        """
        passes, x, _, _ = self._pass(x0, False, record)
        return StrideValue(np.asarray(x0, float).ravel(), x,
                           np.array([ps.duration for ps in passes]), passes,
                           message=" -> ".join(f"{ps.name} {ps.duration:.4g} s"
                                               for ps in passes))

    def linearise(self, x0, record: bool = False) -> StrideLinearisation:
        """P(x_0) and its exact Jacobian dP/dx_0 (forward AD, saltation at each guard).

        Parameters
        ----------
        x0 : array_like
            (n,) the first domain's state at entry.
        record : bool
            Keep every domain's RK4 nodes.

        Returns
        -------
        StrideLinearisation

        Raises
        ------
        HybridCycleError
            As :meth:`stride`.
        """
        x0 = np.asarray(x0, float).ravel()
        passes, x, A, grads = self._pass(x0, True, record)
        ev = np.linalg.eigvals(A)
        ev = ev[np.argsort(-np.abs(ev), kind="stable")]
        res = float(np.max(np.abs(x - x0)))
        return StrideLinearisation(
            state=x0, next_state=x, A=A, durations=np.array([ps.duration for ps in passes]),
            duration_gradients=np.array(grads), eigenvalues=ev, residual=res, passes=passes,
            message=f"stride map linearised (spectral radius {np.max(np.abs(ev)):.4g}, "
                    f"fixed-point residual {res:.2g})")

    def fixed_point(self, x0, tol: float = 1e-11, max_iter: int = 12) -> StrideLinearisation:
        """A periodic orbit of the cycle, P(x*) = x*, by Newton with the exact A.

        Parameters
        ----------
        x0 : array_like
            (n,) start of the iteration.
        tol : float
            Stop when ``max |P(x) - x| < tol``.
        max_iter : int
            Newton steps at most.

        Returns
        -------
        StrideLinearisation
            At the last iterate (``residual`` says how well the orbit closes).

        Raises
        ------
        HybridCycleError
            As :meth:`stride`, at an iterate.
        """
        lin = self.linearise(x0)
        for _ in range(max_iter):
            if lin.residual < tol:
                break
            r = lin.next_state - lin.state
            lin = self.linearise(lin.state + np.linalg.solve(np.eye(self.n) - lin.A, r))
        return lin


def _domains_run(cycle: HybridCycle, value) -> tuple:
    """The sequence of domains a stride ran: each domain's name, whether it lasted, the
    guard's part that ended it (None: skipped) and, where it lasted, its discrete
    parameters (``Domain.discrete_parameters``, e.g. a slide's direction)."""
    return tuple((p.name, p.duration > 0, p.part,
                  tuple(p.parameters[list(d.discrete_parameters)].tolist())
                  if p.duration > 0 else ())
                 for d, p in zip(cycle.domains, value.passes))


def finite_difference_jacobian(cycle: HybridCycle, x, step: float = 1e-6, shrink: int = 3,
                               return_steps: bool = False):
    """dP/dx by central differences of the stride map, each step within x's domains.

    2 n strides, more where a step leaves x's sequence of domains.  P is smooth only
    among the states whose strides run the same domains: where x + e or x - e runs
    another sequence (a domain that lasts on one side and is empty on the other, such as
    a push-off of a few ns at a fixed point near the states where it is empty; another
    part of a guard ending a domain; or a lasting domain's other discrete choice,
    ``Domain.discrete_parameters``, such as a slide the other way), P has a kink between
    them, or a jump in curvature, and their difference mixes the two pieces (an error
    of the order of the jump in slope, however small the step beyond the kink, or
    growing with the step).  Such a column's step is divided by 10, at most ``shrink``
    times, until both sides run x's sequence.

    Parameters
    ----------
    cycle : HybridCycle
        The map.
    x : array_like
        Where, (n,).
    step : float
        The difference step (> 0).
    shrink : int
        How many times a column's step may be divided by 10 (>= 0).
    return_steps : bool
        Also return the step each column used.

    Returns
    -------
    numpy.ndarray or tuple
        (n, n); with ``return_steps``, (J, steps), steps (n,).

    Raises
    ------
    HybridCycleError
        Kind 'edge': a column whose strides at x +- e run another sequence of domains
        than x's even at ``step`` / 10 ** ``shrink`` (x on the edge of a domain, named);
        or as :meth:`HybridCycle.stride`.
    """
    if isinstance(step, bool) or not isinstance(step, (int, float, np.integer, np.floating)) \
            or not np.isfinite(step) or step <= 0:
        raise ValueError(f"step must be a finite number > 0, got {step!r}")
    if isinstance(shrink, bool) or not isinstance(shrink, (int, np.integer)) or shrink < 0:
        raise ValueError(f"shrink must be an integer from 0 up, got {shrink!r}")
    x = np.asarray(x, float).ravel()
    base = _domains_run(cycle, cycle.stride(x))
    J, steps = np.zeros((cycle.n, x.size)), np.zeros(x.size)
    for j in range(x.size):
        for i in range(shrink + 1):
            e = np.zeros(x.size)
            e[j] = step / 10 ** i
            sides = cycle.stride(x + e), cycle.stride(x - e)
            other = [r for s in sides for r, r0 in zip(_domains_run(cycle, s), base)
                     if r != r0]
            if not other:
                break
        else:
            name, lasted, part, choice = other[0]
            raise HybridCycleError(name, "edge", f"x is on its edge: column {j}'s strides at "
                                   f"x +- {e[j]:.1e} run another sequence of domains than x's "
                                   f"({'lasting' if lasted else 'empty'}, {part}"
                                   + (f", discrete parameters {choice}" if choice else "")
                                   + ")")
        J[:, j] = (sides[0].next_state - sides[1].next_state) / (2 * e[j])
        steps[j] = e[j]
    return (J, steps) if return_steps else J
