"""The co-design NLP in the design variables alone (every scenario walked from the design
at each evaluation, the exact Jacobian condensed from the steps' sensitivities), and its
IPOPT solve through CasADi callbacks."""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from biped_casadi.numerics import ipopt_solver, iteration_stop

from .functions import _ks
from .transcription import Transcription, _Rows


class _Dense:
    """Constraint rows with a dense Jacobian in the design (the reduced NLP)."""

    def __init__(self, nd):
        self.nd, self.g, self.J, self.lo, self.hi, self.names = nd, [], [], [], [], []

    def add(self, value, jac, lo, hi, name):
        value = np.atleast_1d(np.asarray(value, float))
        m = value.size
        self.g.append(value)
        self.J.append(np.asarray(jac, float).reshape(m, self.nd))
        self.lo.append(np.broadcast_to(lo, (m,)).astype(float))
        self.hi.append(np.broadcast_to(hi, (m,)).astype(float))
        self.names += [name] * m if isinstance(name, str) else list(name)

    def ks(self, v, dv, rho, name):
        """One row bounding max(v) <= 0 (KS); v (m, p), dv (m, nd, p)."""
        flat = np.asarray(v).reshape(-1)
        dflat = np.moveaxis(dv, 1, -1).reshape(-1, self.nd)
        val, wts = _ks(flat[:, None], rho)
        self.add(val[0], wts[:, 0] @ dflat, -np.inf, 0.0, name)

    def chunked_ks(self, kinds, names, chunk, n_chunks, rho, tag):
        """For every chunk of ``chunk`` nodes (``n_chunks`` of them; a chunk past the last
        node is the last node), one KS row per kind, in the order (chunk, kind).

        ``kinds``: per kind (v (r, p), dv (r, nd, p)) over the p nodes."""
        p = kinds[0][0].shape[-1]
        c = np.arange(n_chunks)
        lo = np.minimum(c * chunk, p - 1)
        hi = np.where(c * chunk >= p, p, np.minimum((c + 1) * chunk, p))
        idx = lo[:, None] + np.arange(chunk)[None, :]            # (n_chunks, chunk)
        valid = idx < hi[:, None]
        idx = np.minimum(idx, p - 1)
        vals, grads = [], []
        for v, dv in kinds:
            r = v.shape[0]
            g = np.where(valid[None], v[:, idx], -np.inf)         # (r, n_chunks, chunk)
            flat = g.transpose(0, 2, 1).reshape(r * chunk, n_chunks)
            val, w = _ks(flat, rho)                               # (n_chunks,), (r chunk, n_chunks)
            w = w.reshape(r, chunk, n_chunks)
            grads.append(np.einsum("rlc,rdcl->cd", w, dv[:, :, idx]))
            vals.append(val)
        value = np.stack(vals, axis=1).reshape(-1)                # (n_chunks kinds,)
        jac = np.stack(grads, axis=1).reshape(-1, self.nd)
        self.add(value, jac, -np.inf, 0.0,
                 [f"{k} {tag} chunk {ci}" for ci in range(n_chunks) for k in names])

    def stack(self):
        return (np.concatenate(self.g), np.vstack(self.J), np.concatenate(self.lo),
                np.concatenate(self.hi))


class Reduced:
    """The co-design NLP in the design variables only (single shooting per scenario).

    Every evaluation walks every scenario with the walker's rule from the design (the
    strike of every step found as the walker finds it), so each iterate is a closed-loop
    trajectory and the strike times are implicit functions of the design; the exact
    Jacobian is condensed from the per-step sensitivities of :class:`Transcription`
    (implicit-function theorem for the strike time).  Decision vector d = (G, M1,
    rejoin, s), G = (alpha, T, r0) when the gait is free.

    Parameters
    ----------
    tr : Transcription
        The scenarios and their rule (its brackets are not used).
    """

    #: pad of a step's tabulated nodes past the previous bracket
    PAD = 6

    def __init__(self, tr: Transcription):
        self.tr = tr
        self.nd = tr.n_design
        self.bracket_guess = np.full((tr.K, tr.S), int(1.05 * tr.N))
        self._last = None
        self.s_weight = 1.0
        self.weights = np.zeros(tr.S)
        #: per scenario: its fixed scale (NaN: the variable s), its steps (at most tr.S),
        #: its error bound (inf: none) and the first step it applies to (0-based; the
        #: bound holds from there to the scenario's last step; default: the last step)
        self.scales = np.full(tr.K, np.nan)
        self.steps = np.full(tr.K, tr.S)
        self.tols = np.full(tr.K, np.inf)
        self.tol_from = np.full(tr.K, tr.S - 1)
        #: (callable M1 -> ((tr A^z, its gradient), (det A^z, its gradient)), bound) or None
        self.jury = None
        self.failures = []
        self.evaluations = 0

    def columns(self, TL):
        """(nc, nd): a scenario-step's columns as functions of the design."""
        tr = self.tr
        C = np.zeros((tr.nc, self.nd))
        C[:tr.nl] = TL
        C[tr.nl:tr.nl + tr.nu, tr.i_M1] = np.eye(tr.nu)
        C[tr.nl + tr.nu, tr.i_rejoin] = 1.0
        if tr.free:
            C[tr.nc - tr.nG:, tr.i_G] = np.eye(tr.nG)
        return C

    def evaluate(self, d):
        """(f, grad f, g, dg/dd, lo, hi) at the design d (cached for the last d)."""
        d = np.asarray(d, float)
        if self._last is not None and np.array_equal(self._last[0], d):
            return self._last[1]
        self.evaluations += 1
        try:
            res = self._evaluate(d)
        except _NoStrike:
            res = None
        if res is None:
            ng = self._ng if hasattr(self, "_ng") else 1
            nan = np.full(ng, np.nan)
            res = (np.nan, np.full(self.nd, np.nan), nan, np.full((ng, self.nd), np.nan),
                   self._lo if hasattr(self, "_lo") else nan,
                   self._hi if hasattr(self, "_hi") else nan)
        self._last = (d.copy(), res)
        return res

    def _evaluate(self, d):
        """Walk every scenario from the design d step by step, each step's rows and end
        error in the NLP, then the Jury and the gait's rows: (f, grad f, g, dg/dd, lo, hi)."""
        tr = self.tr
        alpha, T, r0, M1, rejoin, s = tr.unpack(d)
        tab = tr.table(d)
        rows = _Dense(self.nd)
        f, grad = -self.s_weight * s, np.zeros(self.nd)
        grad[tr.i_s] = -self.s_weight
        c = self._constants(tab)
        Ls, TLs = self._starts(s, M1, tab)
        info = []
        for j in range(int(self.steps.max())):
            act = [k for k in range(tr.K) if self.steps[k] > j]
            XA, SSA, diagA, ddiagA, PA, dP, hits = self._walk_steps(tab, Ls, act, j, M1,
                                                                    rejoin, T, alpha)
            for i, k in enumerate(act):
                tag = f"k{k} j{j}"
                if hits[i] is None:
                    self.failures.append((k, j, "no strike"))
                    raise _NoStrike(tag)
                nodes = (XA[i], SSA[i], diagA[i], ddiagA[i], PA[i], dP)
                f, step_info, Ls[k], TLs[k] = self._step(rows, tab, nodes, hits[i], TLs[k],
                                                         k, j, T, alpha, c, f, grad)
                info.append(step_info)
        if self.jury is not None:
            self._jury_rows(rows, M1)
        if tr.free:
            self._free_gait_rows(rows, d, tab)
        self.info = info
        g, J, lo, hi = rows.stack()
        self.names = rows.names
        self._ng, self._lo, self._hi = g.size, lo, hi
        return f, grad, g, J, lo, hi

    def _constants(self, tab):
        """What every step uses: the margined limits, the end target rT and its columns,
        the number of KS chunks and the nodes' times."""
        tr, st, nd = self.tr, self.tr.st, self.nd
        U = np.asarray(st.torque_limit, float) - st.torque_margin    # (or per torque u_i)
        mu, mg, rho = st.mu - st.mu_margin, tr.mg, st.ks_rho
        rT = tab["r"][:, 2 * tr.N]
        drT = np.zeros((2, nd))
        if tr.free:
            drT[:, tr.i_G] = tab["dr"][:, :, 2 * tr.N]
        n_chunks = int(math.ceil((tr.n_max + 2) / st.chunk))
        t_nodes = np.arange(tr.n_max + 2) / tr.N
        return dict(U=U, mu=mu, mg=mg, rho=rho, rT=rT, drT=drT, n_chunks=n_chunks,
                    t_nodes=t_nodes)

    def _starts(self, s, M1, tab):
        """Every scenario's first start variables L and their columns TL in the design."""
        tr, nu, nd, nl = self.tr, self.tr.nu, self.nd, self.tr.nl
        dR0 = np.zeros((3 * tr.nq, nd))
        if tr.free:
            dR0[:, tr.i_G] = tab["dR"][:, :, 0]
        Ls, TLs = [], []
        for k in range(tr.K):
            sk = s if not np.isfinite(self.scales[k]) else float(self.scales[k])
            so, sJ = tr.start_fn(np.r_[sk, M1, tab["R"][:, 0]], tr.dirs[k])
            so, sJ = np.array(so).ravel(), np.array(sJ)
            TL = np.zeros((nl, nd))
            if not np.isfinite(self.scales[k]):
                TL[:, tr.i_s] = sJ[:nl, 0]
            TL[:, tr.i_M1] = sJ[:nl, 1:1 + nu]
            TL += sJ[:nl, 1 + nu:] @ dR0
            Ls.append(so[:nl])
            TLs.append(TL)
        return Ls, TLs

    def _walk_steps(self, tab, Ls, act, j, M1, rejoin, T, alpha):
        """Step j of the active scenarios over enough nodes (from the bracket guess, 32
        more at a time) for each to strike: their nodes and strikes (None: no strike)."""
        tr = self.tr
        n_try = min(max(int(self.bracket_guess[k, j]) for k in act) + self.PAD,
                    tr.n_max - 1)
        while True:
            XA, SSA, diagA, ddiagA, PA, dP = tr.nodes(tab, np.array([Ls[k] for k in act]),
                                                      n_try, M1, rejoin, T)
            hits = [tr.strike_in(tab, XA[i], diagA[i], n_try, PA[i], T, alpha)
                    for i in range(len(act))]
            if all(h is not None for h in hits) or n_try >= tr.n_max - 1:
                break
            n_try = min(n_try + 32, tr.n_max - 1)
        return XA, SSA, diagA, ddiagA, PA, dP, hits

    def _step(self, rows, tab, nodes, hit, TL, k, j, T, alpha, c, f, grad):
        """Scenario k's step j from its nodes and strike: the strike and its columns in the
        design (the strike time an implicit function), the step's rows, its end error in
        the objective (grad updated in place); returns (f, its info, next L, next TL)."""
        tr, nu, nc = self.tr, self.tr.nu, self.tr.nc
        tag = f"k{k} j{j}"
        X, SS, diag, ddiag, P, dP = nodes
        n, eta = hit
        self.bracket_guess[k, j] = n
        out, Jl = tr.finish(tab, X[:, n], SS[:, :, n], n, eta, P, dP, T, alpha)
        diag, ddiag, out, Jl = tr._with_last(diag[:, :n + 1], ddiag[:, :, :n + 1],
                                             out, Jl)
        C = self.columns(TL)
        r = tr.rows
        dz = Jl[r["zsw"]]
        deta = -(dz[:nc] @ C) / dz[nc]                     # implicit function
        Ctot = np.vstack([C, deta[None]])                  # (nc + 1, nd)
        D = lambda J_: J_ @ Ctot                           # noqa: E731
        dd = np.einsum("mcp,cd->mdp", ddiag, Ctot)         # (9, nd, p)
        u = diag[:nu]
        self._path_rows(rows, diag, dd, n, tag, c)
        F = self._strike_rows(rows, out, Jl, D, tag, c)
        err = out[r["x"]] - c["rT"]
        derr = D(Jl[r["x"]]) - c["drT"]
        wj = self.weights[j]
        if wj:
            f += wj * float(err @ err)
            grad += 2 * wj * err @ derr
        if j >= min(self.tol_from[k], self.steps[k] - 1):
            tol = self.tols[k]
            if np.isfinite(tol):
                rows.add(err, derr, -tol, tol, f"final_error {tag}")
        step_info = dict(k=k, j=j, err=err.copy(), te=(n + eta) * T / tr.N,
                         peak_u=float(np.abs(u).max()), impulse=F.tolist())
        return f, step_info, out[r["next"]], D(Jl[r["next"]])

    def _path_rows(self, rows, diag, dd, n, tag, c):
        """A step's path rows: per chunk of nodes one KS row each of torque, normal force,
        friction and the denominator, and the swing foot's clearance."""
        tr, st, nu = self.tr, self.tr.st, self.tr.nu
        U, mu, mg, rho = c["U"], c["mu"], c["mg"], c["rho"]
        u, Fx, Fz, zsw, den = diag[:nu], diag[nu], diag[nu + 1], diag[nu + 3], diag[nu + 4]
        du, dFx, dFz, dzsw, dden = (dd[:nu], dd[nu], dd[nu + 1], dd[nu + 3], dd[nu + 4])
        # per chunk of nodes (past the strike: the last point), one KS row each
        # of torque, normal force, friction and the denominator
        sc = tr.den_sign / tr.den_scale
        Uu, Ud = (U, U) if np.ndim(U) == 0 else (U[:, None], U[:, None, None])
        rows.chunked_ks(
            [(np.vstack([u / Uu - 1, -u / Uu - 1]), np.concatenate([du / Ud, -du / Ud])),
             (((st.normal_force_min * mg - Fz) / mg)[None], (-dFz / mg)[None]),
             (np.vstack([Fx - mu * Fz, -Fx - mu * Fz]) / mg,
              np.stack([dFx - mu * dFz, -dFx - mu * dFz]) / mg),
             ((st.den_margin - sc * den)[None], (-sc * dden)[None])],
            ("torque", "normal", "friction", "denominator"), st.chunk, c["n_chunks"], rho,
            tag)
        # the swing foot lifts at the start and stays clear mid-step
        tn = c["t_nodes"][:n + 1]
        lift = np.flatnonzero((tn > 0) & (tn < 0.1))
        mid = np.flatnonzero((tn >= 0.1) & (tn <= 0.9))
        if lift.size:
            vref = st.lift_scale * tn[lift]    # m (lift_scale: 0.375 leg per unit of tau/T)
            rows.ks((-zsw[lift] / vref)[None], (-dzsw[:, lift] / vref)[None], rho,
                    f"clearance {tag} lift-off")
        else:                              # no node inside (0, 0.1 T): nothing to bound
            rows.add(-1.0, np.zeros(rows.nd), -np.inf, 0.0, f"clearance {tag} lift-off")
        # a step that strikes before 0.1 T has no mid-step nodes: its last node (at the
        # ground) must then be clear, which the step cannot be, so the row stays violated
        mid = mid if mid.size else np.array([len(tn) - 1])
        h = st.clearance_scale             # m: the row's unit (0.0625 leg, RABBIT 0.05)
        rows.ks(((st.clearance_mid - zsw[mid]) / h)[None],
                (-dzsw[:, mid] / h)[None], rho, f"clearance {tag} mid-step")

    def _strike_rows(self, rows, out, Jl, D, tag, c):
        """A step's strike rows (swing foot speed and position, the impulse in its cone,
        the old stance foot lifting off); returns the impulse F."""
        st, r, mu = self.tr.st, self.tr.rows, c["mu"]
        rows.add(out[r["dzsw"]], D(Jl[r["dzsw"]]), -np.inf, -st.strike_speed_min,
                 f"strike_speed {tag}")
        rows.add(out[r["xsw"]], D(Jl[r["xsw"]]), st.strike_front_min, np.inf,
                 f"strike_front {tag}")
        F, dF = out[r["F"]], D(Jl[r["F"]])
        rows.add(F[1], dF[1], st.impulse_min, np.inf, f"impulse_normal {tag}")
        rows.add(np.r_[mu * F[1] - F[0], mu * F[1] + F[0]],
                 np.vstack([mu * dF[1] - dF[0], mu * dF[1] + dF[0]]), 0.0, np.inf,
                 f"impulse_cone {tag}")
        rows.add(out[r["vold"]], D(Jl[r["vold"]]), st.liftoff_min, np.inf,
                 f"liftoff {tag}")
        return F

    def _jury_rows(self, rows, M1):
        """Jury's conditions on A^z's trace and determinant, the eigenvalues within lam."""
        nd, i_M1 = self.nd, self.tr.i_M1
        fn, lam = self.jury
        (trA, dtr), (det, ddet) = fn(M1)
        rows.add(np.r_[det - lam**2, -det - lam**2],
                 np.vstack([_on(nd, i_M1, ddet), _on(nd, i_M1, -ddet)]),
                 -np.inf, 0.0, "jury det")
        rows.add(np.r_[trA - lam - det / lam, -trA - lam - det / lam],
                 np.vstack([_on(nd, i_M1, dtr - ddet / lam),
                            _on(nd, i_M1, -dtr - ddet / lam)]),
                 -np.inf, 0.0, "jury trace")

    def _free_gait_rows(self, rows, d, tab):
        """The gait's own rows (free gait), their sparse Jacobian made dense."""
        tr, nd = self.tr, self.nd
        w_rows = _Rows()
        tr._gait_rows(w_rows, d, tab)
        gv, lo, hi, ri, ci, vals = w_rows.stack()
        Jg = np.zeros((gv.size, nd))
        np.add.at(Jg, (ri, ci), vals)
        rows.add(gv, Jg, lo, hi, w_rows.names)

    def bounds(self, M1_box: float = 40.0):
        """Bounds of the design vector (those of :meth:`Transcription.bounds`)."""
        return self.tr.bounds(M1_box)


class NoStrikeAtStart(ValueError):
    """A scenario of the NLP does not strike from the starting design (lower its s)."""


class _NoStrike(Exception):
    """A scenario's step found no strike within the horizon."""


def _on(nd, idx, v):
    out = np.zeros(nd)
    out[idx] = np.asarray(v, float).ravel()
    return out


# ------------------------------------------------------------------ IPOPT
class _Oracle(ca.Callback):
    """f, g (with their Jacobians on request) or (f, grad f) / (g, dg) of a
    :class:`Reduced`, for IPOPT through CasADi."""

    def __init__(self, name, nlp, kind, sp, opts=None):
        ca.Callback.__init__(self)
        self.nlp, self.kind, self.sp = nlp, kind, sp
        self.nd, self.ng = nlp.nd, sp.size1()
        self.construct(name, opts or {})

    def get_n_in(self):
        return 1 if self.kind in ("f", "g") else 2

    def get_n_out(self):
        return 1 if self.kind in ("f", "g", "df", "dg") else 2

    def get_sparsity_in(self, i):
        if i == 0:
            return ca.Sparsity.dense(self.nd, 1)
        if self.kind in ("df", "dg"):
            return ca.Sparsity.dense(1, 1) if self.kind == "df" else ca.Sparsity.dense(self.ng, 1)
        return ca.Sparsity(0, 1)

    def get_sparsity_out(self, i):
        k = self.kind
        if k == "f" or (k == "grad_f" and i == 0):
            return ca.Sparsity.dense(1, 1)
        if k in ("grad_f", "df"):
            return ca.Sparsity.dense(1, self.nd)
        if k == "g" or (k == "jac_g" and i == 0):
            return ca.Sparsity.dense(self.ng, 1)
        return self.sp

    def has_jacobian(self):
        return self.kind in ("f", "g")

    def get_jacobian(self, name, inames, onames, opts):
        self._jac = _Oracle(name, self.nlp, "df" if self.kind == "f" else "dg", self.sp, opts)
        return self._jac

    def eval(self, arg):
        f, grad, g, J, _, _ = self.nlp.evaluate(np.array(arg[0]).ravel())
        k = self.kind
        if k == "f":
            return [f]
        if k == "g":
            return [g]
        if k == "df":
            return [grad[None, :]]
        if k == "grad_f":
            return [f, grad[None, :]]
        Jd = ca.DM(J)
        return [Jd] if k == "dg" else [g, Jd]


@dataclass
class NLPSolve:
    """One IPOPT solve of the reduced co-design NLP.

    Parameters
    ----------
    d : numpy.ndarray
        The design at IPOPT's last iterate.
    lam_g : numpy.ndarray
        The constraints' multipliers there.
    status : str
        IPOPT's return status.
    success : bool
        IPOPT's own success flag.
    iterations : int
        IPOPT iterations.
    time : float
        Wall time, s.
    evaluations : int
        Walks of every scenario (evaluations of the constraints).
    """

    d: np.ndarray
    lam_g: np.ndarray
    status: str
    success: bool
    iterations: int
    time: float
    evaluations: int


def solve_nlp(nlp: "Reduced", d0, lb, ub, ipopt: dict | None = None,
              max_evaluations: int | None = None) -> NLPSolve:
    """IPOPT (L-BFGS Hessian, exact constraint Jacobian) on the reduced NLP from d0.

    Parameters
    ----------
    nlp : Reduced
        The NLP functions.
    d0 : array_like
        Starting design.
    lb, ub : array_like
        Bounds of the design.
    ipopt : dict, optional
        Extra IPOPT options.
    max_evaluations : int, optional
        Stop after this many evaluations of the NLP (status 'User_Requested_Stop').

    Returns
    -------
    NLPSolve
    """
    d0 = np.asarray(d0, float)
    _, _, g0, _, lo, hi = nlp.evaluate(d0)
    if not np.all(np.isfinite(g0)):
        raise NoStrikeAtStart("codesign: a scenario does not strike from the starting "
                              "design")
    n0 = nlp.evaluations
    sp = ca.Sparsity.dense(g0.size, nlp.nd)
    cbs = [_Oracle("codesign_f", nlp, "f", sp), _Oracle("codesign_g", nlp, "g", sp),
           _Oracle("codesign_grad_f", nlp, "grad_f", sp), _Oracle("codesign_jac_g", nlp, "jac_g", sp)]
    x = ca.MX.sym("x", nlp.nd)
    opts = {"print_level": 0, "hessian_approximation": "limited-memory", "max_iter": 100,
            "tol": 1e-6, "acceptable_tol": 1e-4, "acceptable_iter": 5,
            "mu_strategy": "adaptive", "bound_push": 1e-8, "bound_frac": 1e-8,
            "linear_solver": "mumps", "sb": "yes"}
    opts.update(ipopt or {})
    # CasADi keeps only a weak reference to a Python callback: this name keeps it alive
    # (a budget of NLP evaluations that, unlike wall time, does not depend on the
    # machine's load; an iteration's line search may evaluate many trial points)
    budget = None if max_evaluations is None else iteration_stop(
        "codesign_budget", nlp.nd, g0.size,
        lambda g: nlp.evaluations - n0 >= max_evaluations)
    solver = ipopt_solver("codesign", {"x": x, "f": cbs[0](x), "g": cbs[1](x)},
                       {"ipopt": opts, "grad_f": cbs[2], "jac_g": cbs[3], "print_time": False,
                        "error_on_fail": False,
                        # a trial point where a scenario cannot strike is NaN by design
                        # (IPOPT steps back); CasADi's warning per such point is noise
                        "show_eval_warnings": False,
                        **({} if budget is None else {"iteration_callback": budget})})
    t0 = time.perf_counter()
    sol = solver(x0=d0, lbx=lb, ubx=ub, lbg=lo, ubg=hi)
    st = solver.stats()
    return NLPSolve(d=np.array(sol["x"]).ravel(), lam_g=np.array(sol["lam_g"]).ravel(),
                    status=str(st.get("return_status", "unknown")),
                    success=bool(st.get("success", False)),
                    iterations=int(st.get("iter_count", -1)),
                    time=time.perf_counter() - t0, evaluations=nlp.evaluations - n0)
