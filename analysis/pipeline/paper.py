"""The stages of ``biped reproduce`` that reproduce the paper's linear analysis, each a
flow of tasks with a typed result: the gait, the singular outputs (eq. 24), Fig. 2 and
the M1 grid, Fig. 3 and the swing-height conjecture, a = b = 0 and Fig. 4, the M1 NLP,
the virtual-constraint comparison."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from biped_casadi import RABBIT_DESCRIPTION
from gait_opt import GaitOptions, optimize_gait

from ..design import (ab_solution_set, coarse_grid_size, conjecture_figures, domain_grid,
                      optimize_m1, swing_height_at_Td, taylor_ab)
from ..design.m1_nlp import coarse_map_points
from ..reporting.constants import PAPER
from ..stability import JacobianBatch, poincare_eigenvalues, singular_m1_values, vc_eigenvalue
from ..sweeps import grid_points, one_d_sweeps, run_sweep
from ..tasks import task
from .options import Resolution

__all__ = ["StageResult", "GaitStage", "SweepStage", "GridStage", "ConjectureStage",
           "DomainStage", "M1Stage", "eigenvalues_of", "vc_eigen", "stage_gait",
           "stage_singular", "stage_fig2", "stage_grid", "stage_fig3", "stage_fig4",
           "stage_m1", "stage_vc"]


@dataclass
class StageResult:
    """What a stage adds to ``summary.json`` (``summary``: key -> value)."""

    summary: dict = field(default_factory=dict)


@dataclass
class GaitStage(StageResult):
    """The default gait of the robot."""

    gait: object = None


@dataclass
class SweepStage(StageResult):
    """Fig. 2's 1-D sweeps."""

    sweeps: object = None


@dataclass
class GridStage(StageResult):
    """The M1 grid (the paper's 9^4 for four torques)."""

    sweep: object = None


@dataclass
class ConjectureStage(StageResult):
    """Fig. 3: the swing height at T^d against max|lambda| on the grid."""

    zsw: np.ndarray = None
    max_abs: np.ndarray = None
    status: np.ndarray = None


@dataclass
class DomainStage(StageResult):
    """a = b = 0, Fig. 4's stable domains (four torques) or the M1 plane (two)."""

    kind: str = "none"
    maps: list = field(default_factory=list)
    figure: dict = field(default_factory=dict)
    ab_set: object = None


@dataclass
class M1Stage(StageResult):
    """The M1 NLP on every group, and the M1 chosen for the walking stages."""

    results: dict = field(default_factory=dict)
    chosen: np.ndarray = None


def _is_rabbit(model) -> bool:
    return model.description == RABBIT_DESCRIPTION


@task
def stage_gait(engine, model) -> GaitStage:
    """The robot's default gait (the default problem) and its figures' data."""
    g = engine.submit(optimize_gait, model, GaitOptions().for_model(model)).result()
    s = g.summary()
    engine.say(f"   T = {s['T']:.4f} s, step {s['step_length']:.4f} m, cost {s['cost']:.2f}")
    robot = dict(model.description.to_dict(), nq=model.nq, nu=model.nu,
                 joints=list(model.joint_names), total_mass=model.description.total_mass,
                 scuffing_ignored=model.scuffing_ignored)
    return GaitStage(summary=dict(robot=robot, gait=s), gait=g)


@task
def singular_outputs(gait) -> dict:
    """D11, D12 at the desired impact and the singular values of M1 of eq. (24) (a task)."""
    D = np.array(gait.model.D(gait.q(gait.T)))
    sv = singular_m1_values(gait)
    return dict(D11_T=float(D[0, 0]), D12_T=D[0, 1:].tolist(), singular_values=sv.tolist())


@task
def stage_singular(engine, gait_stage) -> StageResult:
    """The singular outputs of eq. (24) at the desired impact."""
    g = gait_stage.result().gait
    return StageResult(dict(singular=engine.submit(singular_outputs, g).result()))


@task
def one_d(gait, values) -> object:
    """Fig. 2's sweeps (a task)."""
    return one_d_sweeps(gait, np.asarray(values, float), progress=False)


@task
def stage_fig2(engine, gait_stage, res: Resolution) -> SweepStage:
    """Fig. 2: max|lambda| against each component of M1, the others zero."""
    g = gait_stage.result().gait
    vals = np.linspace(-10, 10, res.line_points)
    r = engine.submit(one_d, g, vals).result()
    best = []
    for part in r.results:
        b = part.best()
        best.append(None if b is None else dict(M1=b.M1.tolist(), max_abs=b.max_abs))
    return SweepStage(dict(fig2=dict(points_per_component=len(vals), best_per_component=best,
                                     stable_per_component=[int(p.counts["stable"])
                                                           for p in r.results])), r)


def grid_n(model, res: Resolution) -> int:
    """Points per component of the M1 grid: the paper's 9 for nu = 4, the plane's for
    nu = 2, a coarse grid of about 9^4 points otherwise."""
    nu = model.nu
    return res.grid_n if nu == 4 else res.plane_n if nu == 2 else coarse_grid_size(nu)


@task
def sweep(gait, points) -> object:
    """max|lambda| and status at every M1 of ``points`` (a task)."""
    return run_sweep(gait, np.asarray(points, float), progress=False)


@task
def stage_grid(engine, gait_stage, res: Resolution) -> GridStage:
    """The M1 grid on [-10, 10]^nu."""
    g = gait_stage.result().gait
    n = grid_n(g.model, res)
    P = grid_points(n, -10.0, 10.0, g.model.nu)
    r = engine.submit(sweep, g, P).result()
    stable = np.flatnonzero(r.point_status == "stable")
    best = None
    if stable.size:
        i = stable[np.argmin(r.max_abs[stable])]
        best = dict(M1=r.points[i].tolist(), max_abs=float(r.max_abs[i]))
    engine.say(f"   counts: {dict(r.counts)}")
    return GridStage(dict(grid=dict(n=n, dim=g.model.nu, n_points=len(P), counts=dict(r.counts),
                                    best_stable=best)), r)


@task
def conjecture(gait, grid) -> tuple:
    """The swing height at T^d of every grid point and the conjecture's figures."""
    zsw = swing_height_at_Td(gait, grid.points, 1e-2)
    return zsw, conjecture_figures(zsw, grid.max_abs, grid.point_status)


@task
def stage_fig3(engine, gait_stage, grid_stage) -> ConjectureStage:
    """Fig. 3 and the conjecture: max|lambda| against the swing height at T^d."""
    g, r = gait_stage.result().gait, grid_stage.result().sweep
    zsw, c = engine.submit(conjecture, g, r).result()
    return ConjectureStage(dict(conjecture=c), zsw, r.max_abs, r.point_status)


def _batch(r) -> JacobianBatch:
    """A sweep's points and values as the batch the M1 NLP starts from."""
    return JacobianBatch(r.points, r.point_status, r.A, r.eigenvalues, r.max_abs)


@task
def stage_fig4(engine, gait_stage, grid_stage, res: Resolution) -> DomainStage:
    """a = b = 0 and the stable domains of its groups (Fig. 4, four torques), or the
    stable domain in the (M1(1), M1(2)) plane with every solution of a = b = 0 (two)."""
    g = gait_stage.result().gait
    tay = taylor_ab(g)
    taylor = dict(taylor=dict(grad_zsw=tay.grad.tolist(), hess_zsw=tay.hess.tolist(),
                              zsw_T=tay.z0))
    nu = g.model.nu
    if nu == 2:
        return _plane_domain(engine, g, tay, grid_stage.result().sweep, taylor)
    if nu != 4:
        return DomainStage(dict(taylor, domains=dict(
            skipped=f"a = b = 0 leaves {nu - 2} components of M1 free: no 2-D domain map is "
                    "drawn")))
    lo, hi = res.domain_range
    n = res.domain_n
    s = domain_grid(tay, n, lo, hi)
    cell = ((hi - lo) / (n - 1)) ** 2
    groups = ((1, s.group1), (2, s.group2))
    refs = {}
    for k, M in groups:
        P = M.reshape(-1, 4)
        real = np.all(np.isfinite(P), axis=1)
        refs[k] = engine.submit(sweep, g, P[real]) if real.any() else None
    maps, out, batches = {}, {}, []
    for k, M in groups:
        P = M.reshape(-1, 4)
        real = np.all(np.isfinite(P), axis=1)
        mx, stable = np.full(len(P), np.nan), np.zeros(len(P), bool)
        if refs[k] is not None:
            r = refs[k].result()
            mx[real] = r.max_abs
            batches.append(_batch(r))
            stable[np.flatnonzero(real)] = r.point_status == "stable"
        maps[k] = mx.reshape(n, n)
        i = int(np.nanargmin(mx)) if np.isfinite(mx).any() else None
        out[k] = dict(stable_points=int(stable.sum()), real_points=int(real.sum()),
                      stable_area=float(stable.sum() * cell),
                      best=None if i is None else dict(M1=P[i].tolist(), max_abs=float(mx[i])))
    engine.say("   stable area: " + ", ".join(f"group {k}: {v['stable_area']:.2f}"
                                             for k, v in out.items()))
    best = {k: (np.array(v["best"]["M1"]) if v["best"] else None) for k, v in out.items()}
    return DomainStage(dict(taylor, domains=dict(grid=n, range=[lo, hi], groups=out)),
                       kind="groups", maps=batches,
                       figure=dict(m2=s.m2, m3=s.m3, map1=maps[1], map2=maps[2], best=best))


def _plane_domain(engine, g, tay, grid, taylor) -> DomainStage:
    """Two torques: the stable domain in the (M1(1), M1(2)) plane (the grid's map) with
    every solution of a = b = 0 on it."""
    ab = ab_solution_set(tay)
    n = int(round(np.sqrt(len(grid.points))))
    mx = np.where(np.isfinite(grid.max_abs), grid.max_abs, np.nan).reshape(n, n)
    stable = grid.point_status == "stable"
    cell = (20.0 / (n - 1)) ** 2
    on_set = ab.sample(401, -10, 10)
    keep = np.all((on_set >= -10) & (on_set <= 10), axis=1)
    ab_eval = None
    if len(on_set[keep]):
        r = engine.submit(sweep, g, on_set[keep]).result()
        b = r.best()
        ab_eval = dict(points=int(keep.sum()), stable=int(r.counts["stable"]),
                       best=None if b is None else dict(M1=b.M1.tolist(), max_abs=b.max_abs))
    best = grid.best()
    engine.say(f"   stable area {stable.sum() * cell:.2f}; a = b = 0: {ab.message}")
    fig = dict(m1=grid.points[:, 0].reshape(n, n), m2=grid.points[:, 1].reshape(n, n),
               max_abs=mx, ab_points=ab.points,
               ab_line=on_set[keep] if ab.kind == "line" else None,
               best=None if best is None else best.M1,
               title=f"{g.model.params.name}: stable domain of M1, contour max|λ| = 1 (red)")
    return DomainStage(dict(taylor, domains=dict(
        plane=True, grid=n, range=[-10.0, 10.0], stable_points=int(stable.sum()),
        stable_area=float(stable.sum() * cell), ab_set=ab.to_dict(), ab_set_on_map=ab_eval,
        best=None if best is None else dict(M1=best.M1.tolist(), max_abs=best.max_abs))),
        kind="plane", figure=fig, ab_set=ab)


def _groups(model, ab) -> list:
    """(name, group) of the M1 NLP runs for this robot."""
    if model.nu != 2:
        return [("group1", 1), ("group2", 2), ("free", None)]
    if ab.kind == "line":
        return [("ab_line", 1), ("free", None)]
    return [(f"group{k}", k) for k in range(1, len(ab.points) + 1)] + [("free", None)]


@task
def m1_nlp(gait, groups: tuple, kw: dict, maps: list) -> list:
    """The M1 NLP on each group, one after the other (a task: the groups share the
    symbolic A^z(M1), built once), each started from the map among ``maps`` that has
    exactly its coarse points, if any."""
    out = []
    for group in groups:
        coarse = None
        if not (gait.model.nu < 3 and group is not None):
            P = coarse_map_points(taylor_ab(gait), group, gait.model.nu)
            coarse = next((b for b in maps if b.M1.shape == P.shape
                           and np.array_equal(b.M1, P)), None)
        out.append(optimize_m1(gait, group=group, coarse=coarse, **kw))
    return out


@task
def eigenvalues_of(gait, M1s: tuple, rejoin: float = 0.5) -> list:
    """:func:`analysis.stability.poincare_eigenvalues` of each M1 on a gait (a task).

    Parameters
    ----------
    gait : Gait
        The reference.
    M1s : tuple of tuple of float
        The gains.
    rejoin : float
        The correction's rejoin time, fraction of T.

    Returns
    -------
    list of PoincareResult
    """
    return [poincare_eigenvalues(gait, list(M1), rejoin=rejoin) for M1 in M1s]


@task
def vc_eigen(gait):
    """:func:`analysis.stability.vc_eigenvalue` of a gait (a task)."""
    return vc_eigenvalue(gait)


@task
def stage_m1(engine, gait_stage, grid_stage, domain_stage, res: Resolution) -> M1Stage:
    """The M1 NLP on every a = b = 0 group and with all components free; the best group
    (RABBIT: of the a = b = 0 groups, as in the paper) is the M1 the walking stages use."""
    g = gait_stage.result().gait
    dom = domain_stage.result()
    maps = [_batch(grid_stage.result().sweep)] + list(dom.maps)
    groups = _groups(g.model, dom.ab_set)
    k = res.nlp_starts
    example = engine.submit(eigenvalues_of, g, (tuple(PAPER["example_M1"]),)) \
        if _is_rabbit(g.model) else None
    kw = dict(n_best=k, n_ipopt=min(4, k), n_random=res.nlp_random)
    results = engine.submit(m1_nlp, g, tuple(grp for _, grp in groups), kw, maps)
    out = {}
    for (name, _), r in zip(groups, results.result()):
        out[name] = r.to_dict()
        engine.say(f"   {name}: max|lambda| = {r.max_abs:.3g} "
                   f"(+- {r.eigenvalue_uncertainty:.1g})")
    if example is not None:
        ex = example.result()[0]
        out["paper_example_M1"] = dict(M1=PAPER["example_M1"], max_abs=ex.max_abs,
                                       status=ex.status)
    names = [n for n, _ in groups]
    constrained = [n for n, grp in groups if grp is not None]
    pool = constrained if g.model.nu != 2 else names
    best = min((out[n] for n in pool), key=lambda v: v["max_abs"])
    out["chosen_for_simulation"] = best["M1"]
    return M1Stage(dict(m1_nlp=out), {n: np.array(out[n]["M1"]) for n in names},
                   np.array(best["M1"]))


@task
def stage_vc(engine, gait_stage, m1_stage) -> StageResult:
    """Virtual constraints' eigenvalue beside the time-varying outputs' (the chosen M1
    and M1 = 0)."""
    g = gait_stage.result().gait
    M1 = m1_stage.result().chosen
    vc_ref = engine.submit(vc_eigen, g)
    tv, tv0 = engine.submit(eigenvalues_of, g, (tuple(float(x) for x in M1),
                                                (0.0,) * g.model.nu)).result()
    vc = vc_ref.result()
    return StageResult(dict(vc_comparison=dict(
        vc=vc.to_dict(), tv_chosen=dict(M1=M1.tolist(), max_abs=tv.max_abs,
                                        eigenvalues=[[e.real, e.imag] for e in tv.eigenvalues]),
        tv_M1_zero=dict(max_abs=tv0.max_abs, status=tv0.status))))
