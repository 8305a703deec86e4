"""The stages of ``biped reproduce`` that reproduce the paper's linear analysis: the gait,
the singular outputs (eq. 24), Fig. 2 and the 9^4 grid, Fig. 3 and the swing-height
conjecture, a = b = 0 and Fig. 4, the M1 NLP, the virtual-constraint comparison."""
from __future__ import annotations

import time

import numpy as np

from biped_casadi import (robot)
from gait_opt import default_gait

from ..design.m1_nlp import coarse_map_points
from ..design import (ab_solution_set, coarse_grid_size,
                      conjecture_figures, domain_grid, optimize_m1, swing_height_at_Td, taylor_ab)
from ..stability import JacobianBatch, poincare_eigenvalues, singular_m1_values, vc_eigenvalue
from ..sweeps import grid_points, one_d_sweeps, run_sweep
from .plots import (conjecture_plot, gait_profiles_plot, gait_stick_plot,
                    m1_plane_plot, one_d_sweeps_plot, save_figure, stable_domains_plot)

from .context import FORMATS, Context, is_rabbit
from .constants import PAPER


def stage_gait(ctx: Context):
    ctx.model = robot(ctx.opts.robot)
    ctx.gait = g = default_gait(ctx.model, progress=ctx.log)
    s = g.summary()
    ctx.summary["robot"] = dict(ctx.model.description.to_dict(), nq=ctx.model.nq,
                                nu=ctx.model.nu, joints=list(ctx.model.joint_names),
                                total_mass=ctx.model.description.total_mass,
                                scuffing_ignored=ctx.model.scuffing_ignored)
    ctx.summary["gait"] = s
    g.save(ctx.out / "gait.json")
    figs = ctx.out / "figures"
    ctx.figures["gait_stick"] = save_figure(gait_stick_plot(g), figs / "gait_stick", FORMATS)
    ctx.figures["gait_profiles"] = save_figure(gait_profiles_plot(g), figs / "gait_profiles",
                                               FORMATS)
    ctx.log(f"   T = {s['T']:.4f} s, step {s['step_length']:.4f} m, cost {s['cost']:.2f}")


def stage_singular(ctx: Context):
    D = np.array(ctx.model.D(ctx.gait.q(ctx.gait.T)))
    sv = singular_m1_values(ctx.gait)
    ctx.summary["singular"] = dict(D11_T=float(D[0, 0]), D12_T=D[0, 1:].tolist(),
                                   singular_values=sv.tolist())
    ctx.data["singular_values"] = sv


def stage_fig2(ctx: Context):
    vals = np.linspace(-10, 10, ctx.opts.line_points)
    r = one_d_sweeps(ctx.gait, vals,
                     out_dir=ctx.sweep_dir("fig2", f"{len(vals)}pts", -10.0, 10.0),
                     progress=ctx.opts.progress)
    ctx.figures["fig2"] = save_figure(one_d_sweeps_plot(r), ctx.out / "figures" / "fig2",
                                      FORMATS)
    best = []
    for j, part in enumerate(r.results):
        b = part.best()
        best.append(None if b is None else dict(M1=b.M1.tolist(), max_abs=b.max_abs))
    ctx.summary["fig2"] = dict(points_per_component=len(vals), best_per_component=best,
                               stable_per_component=[int(p.counts["stable"]) for p in r.results])


def _grid_n(ctx) -> int:
    """Points per component of the M1 grid: the paper's 9 for nu = 4, the plane's for
    nu = 2, a coarse grid of about 9^4 points otherwise."""
    nu = ctx.model.nu
    return ctx.opts.grid_n if nu == 4 else ctx.opts.plane_n if nu == 2 else coarse_grid_size(nu)


def stage_grid(ctx: Context):
    n = _grid_n(ctx)
    P = grid_points(n, -10.0, 10.0, ctx.model.nu)
    r = run_sweep(ctx.gait, P, out_dir=ctx.sweep_dir(f"grid{n}", -10.0, 10.0),
                  progress=ctx.opts.progress)
    ctx.data["grid"] = r
    ctx.data.setdefault("maps", []).append(_as_batch(r))
    st = r.point_status
    stable = np.flatnonzero(st == "stable")
    best = None
    if stable.size:
        i = stable[np.argmin(r.max_abs[stable])]
        best = dict(M1=r.points[i].tolist(), max_abs=float(r.max_abs[i]))
    ctx.summary["grid"] = dict(n=n, dim=ctx.model.nu, n_points=len(P), counts=dict(r.counts),
                               best_stable=best, elapsed=r.elapsed)
    ctx.log(f"   counts: {dict(r.counts)}")


def stage_fig3(ctx: Context):
    r = ctx.data["grid"]
    zsw = swing_height_at_Td(ctx.gait, r.points, 1e-2)
    c = conjecture_figures(zsw, r.max_abs, r.point_status)
    ctx.summary["conjecture"] = c
    ctx.figures["fig3"] = save_figure(conjecture_plot(zsw, r.max_abs, r.point_status),
                                      ctx.out / "figures" / "fig3", FORMATS)


def stage_fig4(ctx: Context):
    tay = taylor_ab(ctx.gait)
    ctx.summary["taylor"] = dict(grad_zsw=tay.grad.tolist(), hess_zsw=tay.hess.tolist(),
                                 zsw_T=tay.z0)
    nu = ctx.model.nu
    if nu == 2:
        return _plane_domain(ctx, tay)
    if nu != 4:
        ctx.summary["domains"] = dict(skipped=f"a = b = 0 leaves {nu - 2} components of M1 "
                                              "free: no 2-D domain map is drawn")
        return
    lo, hi = ctx.opts.domain_range
    n = ctx.opts.domain_n
    s = domain_grid(tay, n, lo, hi)
    maps, res = {}, {}
    cell = ((hi - lo) / (n - 1)) ** 2
    for k, M in ((1, s.group1), (2, s.group2)):
        P = M.reshape(-1, 4)
        real = np.all(np.isfinite(P), axis=1)
        mx = np.full(len(P), np.nan)
        if real.any():
            r = run_sweep(ctx.gait, P[real],
                          out_dir=ctx.sweep_dir(f"group{k}", f"{n}x{n}", float(lo), float(hi)),
                          progress=ctx.opts.progress)
            mx[real] = r.max_abs
            ctx.data.setdefault("maps", []).append(_as_batch(r))
            stable = np.zeros(len(P), bool)
            stable[np.flatnonzero(real)] = r.point_status == "stable"
        else:
            stable = np.zeros(len(P), bool)
        maps[k] = mx.reshape(n, n)
        i = int(np.nanargmin(np.where(np.isfinite(mx), mx, np.nan))) if np.isfinite(mx).any() else None
        res[k] = dict(stable_points=int(stable.sum()), real_points=int(real.sum()),
                      stable_area=float(stable.sum() * cell),
                      best=None if i is None else dict(M1=P[i].tolist(), max_abs=float(mx[i])))
    ctx.data["domains"] = res
    best = {k: (np.array(v["best"]["M1"]) if v["best"] else None) for k, v in res.items()}
    ctx.figures["fig4"] = save_figure(stable_domains_plot(s.m2, s.m3, maps[1], maps[2], best),
                                      ctx.out / "figures" / "fig4", FORMATS)
    ctx.summary["domains"] = dict(grid=n, range=[lo, hi], groups=res)
    ctx.log("   stable area: " + ", ".join(f"group {k}: {v['stable_area']:.2f}"
                                          for k, v in res.items()))


def _plane_domain(ctx: Context, tay):
    """nu = 2: the stable domain in the (M1(1), M1(2)) plane (the grid stage's map) with
    every solution of a = b = 0 on it."""
    ab = ab_solution_set(tay)
    ctx.data["ab_set"] = ab
    grid = ctx.data.get("grid")
    if grid is None:          # the grid stage failed: map the plane here
        n = _grid_n(ctx)
        grid = run_sweep(ctx.gait, grid_points(n, -10.0, 10.0, 2),
                         progress=ctx.opts.progress)
    n = int(round(np.sqrt(len(grid.points))))
    m1 = grid.points[:, 0].reshape(n, n)
    m2 = grid.points[:, 1].reshape(n, n)
    mx = np.where(np.isfinite(grid.max_abs), grid.max_abs, np.nan).reshape(n, n)
    stable = grid.point_status == "stable"
    cell = (20.0 / (n - 1)) ** 2
    on_set = ab.sample(401, -10, 10)
    keep = np.all((on_set >= -10) & (on_set <= 10), axis=1)
    ab_eval = None
    if len(on_set[keep]):
        from_map = run_sweep(ctx.gait, on_set[keep], progress=False)
        ab_eval = dict(points=int(keep.sum()), stable=int(from_map.counts["stable"]),
                       best=None if from_map.best() is None else
                       dict(M1=from_map.best().M1.tolist(), max_abs=from_map.best().max_abs))
    best = grid.best()
    ctx.figures["m1_plane"] = save_figure(
        m1_plane_plot(m1, m2, mx, ab_points=ab.points,
                      ab_line=on_set[keep] if ab.kind == "line" else None,
                      best=None if best is None else best.M1,
                      title=f"{ctx.model.params.name}: stable domain of M1, contour "
                            "max|λ| = 1 (red)"),
        ctx.out / "figures" / "m1_plane", FORMATS)
    ctx.summary["domains"] = dict(plane=True, grid=n, range=[-10.0, 10.0],
                                  stable_points=int(stable.sum()),
                                  stable_area=float(stable.sum() * cell),
                                  ab_set=ab.to_dict(), ab_set_on_map=ab_eval,
                                  best=None if best is None else
                                  dict(M1=best.M1.tolist(), max_abs=best.max_abs))
    ctx.log(f"   stable area {stable.sum() * cell:.2f}; a = b = 0: {ab.message}")


def _m1_groups(ctx) -> list:
    """(name, group) of the M1 NLP runs for this robot."""
    if ctx.model.nu != 2:
        return [("group1", 1), ("group2", 2), ("free", None)]
    ab = ctx.data.get("ab_set") or ab_solution_set(taylor_ab(ctx.gait))
    if ab.kind == "line":
        return [("ab_line", 1), ("free", None)]
    return [(f"group{k}", k) for k in range(1, len(ab.points) + 1)] + [("free", None)]


def _as_batch(r) -> JacobianBatch:
    """A sweep's points and values as the batch the M1 NLP starts from."""
    return JacobianBatch(r.points, r.point_status, r.A, r.eigenvalues, r.max_abs)


def _coarse_map(ctx, group):
    """The coarse map of the M1 NLP when an earlier stage evaluated exactly its points."""
    if ctx.model.nu < 3 and group is not None:
        return None
    P = coarse_map_points(taylor_ab(ctx.gait), group, ctx.model.nu)
    return next((b for b in ctx.data.get("maps", [])
                 if b.M1.shape == P.shape and np.array_equal(b.M1, P)), None)


def stage_m1(ctx: Context):
    out = {}
    k = ctx.opts.nlp_starts
    groups = _m1_groups(ctx)
    for name, grp in groups:
        t = time.perf_counter()
        kw = dict(group=grp, n_best=k, n_ipopt=min(4, k), n_random=0 if ctx.opts.quick else 2)
        r = ctx.memo("optimize_m1", dict(gait=ctx.gait.cache_key, **kw),
                     lambda: optimize_m1(ctx.gait, coarse=_coarse_map(ctx, grp),
                                         **kw))
        out[name] = r.to_dict()
        ctx.log(f"   {name}: max|lambda| = {r.max_abs:.3g} (+- {r.eigenvalue_uncertainty:.1g}) "
                f"in {time.perf_counter() - t:.1f} s")
    if is_rabbit(ctx):
        ex = poincare_eigenvalues(ctx.gait, PAPER["example_M1"])
        out["paper_example_M1"] = dict(M1=PAPER["example_M1"], max_abs=ex.max_abs,
                                       status=ex.status)
    names = [n for n, _ in groups]
    constrained = [n for n, g in groups if g is not None]
    # RABBIT: the best a = b = 0 group, as in the paper; otherwise the best of all runs
    pool = constrained if ctx.model.nu != 2 else names
    best = min((out[n] for n in pool), key=lambda v: v["max_abs"])
    ctx.data["chosen_M1"] = np.array(best["M1"])
    ctx.data["nlp_M1"] = {n: np.array(out[n]["M1"]) for n in names}
    out["chosen_for_simulation"] = best["M1"]
    ctx.summary["m1_nlp"] = out


def stage_vc(ctx: Context):
    vc = vc_eigenvalue(ctx.gait)
    nu = ctx.model.nu
    M1 = ctx.data.get("chosen_M1", np.zeros(nu))
    tv = poincare_eigenvalues(ctx.gait, M1)
    tv0 = poincare_eigenvalues(ctx.gait, np.zeros(nu))
    ctx.summary["vc_comparison"] = dict(vc=vc.to_dict(), tv_chosen=dict(
        M1=M1.tolist(), max_abs=tv.max_abs, eigenvalues=[[e.real, e.imag] for e in tv.eigenvalues]),
        tv_M1_zero=dict(max_abs=tv0.max_abs, status=tv0.status))


