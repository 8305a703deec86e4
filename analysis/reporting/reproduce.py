"""``biped reproduce``: the paper end to end on the embedded default (RABBIT, default
gait), or the same analysis on another robot (``robot='three_link'`` or a description
file), with figures (PNG and PDF), ``summary.json`` and ``report.md``.

Stages run in order; each shows its progress, a failed stage is reported (with its
error) and the stages that do not need its results still run.  What depends on the
number of torques nu: the M1 grid is the paper's 9^4 for nu = 4, the whole
(M1(1), M1(2)) plane for nu = 2 (the stable domain of M1 itself, with every solution of
a = b = 0 on it); Fig. 4 (the stable domains of the a = b = 0 groups over the free
components) exists for nu = 4 only; the paper's published numbers are RABBIT's and are
compared for RABBIT only.

Folders (:func:`run_folder`): a full run on RABBIT writes into ``OUT`` itself, a quick
run into ``OUT/quick``; another robot into ``OUT/<its name or file's stem>`` (and
``.../quick``), so no two kinds of run ever mix or overwrite each other's results,
whatever the order of the runs.  In a run's folder: ``report.md``, ``summary.json``, ``gait.json``,
``figures/`` and ``sweeps/`` (the resumable sweeps, one sub-folder per sweep and
settings, reused by the next run).  A run writes its report, summary, gait and figures
into a private staging folder first and moves them into place at the end: a run that
fails or is interrupted leaves the previous run's results as they were, and a finished
run replaces exactly the files of the previous run of the same kind (other files are
never touched).
"""
from __future__ import annotations

import contextlib
import json
import os
import pickle
import re
import shutil
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from biped_casadi import (PAPER_SIZES, RABBIT_DESCRIPTION, SimulationOptions,
                          TimeVaryingController, VirtualConstraintController,
                          perturbed_initial_state, robot, simulate)
from biped_casadi.caching import DiskCache, source_digest
from biped_casadi.files import write_bytes_atomic, write_text_atomic
from biped_casadi.results import Result, json_safe
from gait_opt import GaitOptions, default_gait

from ..design.m1_nlp import coarse_map_points
from ..design import (RobustDesignSettings, ab_solution_set, coarse_grid_size,
                      conjecture_figures, domain_grid, optimize_m1, robust_design,
                      swing_height_at_Td, taylor_ab)
from ..robustness import Design, RobustnessSettings, basin, kept_directions, robustness
from ..stability import JacobianBatch, poincare_eigenvalues, singular_m1_values, vc_eigenvalue
from ..sweeps import grid_points, one_d_sweeps, run_sweep
from .plots import (basin_plot, conjecture_plot, gait_profiles_plot, gait_stick_plot,
                    m1_plane_plot, one_d_sweeps_plot, save_figure, stable_domains_plot,
                    swing_torques_plot, tradeoff_plot, unactuated_error_plot,
                    walking_animation)
from .report import write_report

__all__ = ["reproduce", "ReproduceOptions", "ReproduceResult", "PAPER", "run_folder"]

#: the paper's published figures (Wang & Chevallereau), for the side-by-side table
PAPER = dict(
    D11_T=24.2445,
    D12_T=[13.4347, 3.6283, 0.5375, 0.0410],
    singular_values=[1.8046, 6.6821, 45.1060, 592.7751],
    grid_counts=dict(stable=19, unstable=5363, singular_or_no_impact=6561 - 19 - 5363),
    example_M1=[1.9121, -4.0, -3.0, -1.4090],
    example_max_abs=0.2392,
    tv_convergence_steps=4,
)


@dataclass
class ReproduceOptions:
    """Resolution of every stage; ``quick`` gives the coarse variant (<= 3 min).
    ``robot``: a built-in name or a description file (default RABBIT)."""
    quick: bool = False
    robot: str = "rabbit"
    line_points: int = 401          # Fig. 2: points per component on [-10, 10]
    grid_n: int = 9                 # the paper's 9^4 grid
    plane_n: int = 161              # nu = 2: the (M1(1), M1(2)) grid, points per side
    domain_n: int = 81              # Fig. 4: (M1(2), M1(3)) grid per group
    domain_range: tuple = (-10.0, 10.0)
    nlp_starts: int = 10
    sim_steps: int = 10
    animation_steps: int = 4
    progress: bool = True

    @classmethod
    def make(cls, quick: bool = False, **kw):
        if quick:
            base = dict(quick=True, line_points=101, domain_n=41, plane_n=81, nlp_starts=4,
                        sim_steps=6, animation_steps=2)
            base.update(kw)
            return cls(**base)
        return cls(**kw)


@dataclass
class ReproduceResult(Result):
    """What a reproduction did.  ``status`` 'ok' (every stage ok) or 'failed' (some stage
    failed or was skipped; the others still ran); ``success`` means 'ok'.  ``folder`` is
    the run's folder (``OUT`` for a full run, ``OUT/quick`` for a quick one) with
    ``report`` and ``summary_file``; ``stages`` maps each stage to its status and time;
    ``summary`` (not in ``to_dict()``) is the content of summary.json."""

    status: str
    message: str
    mode: str
    folder: str
    report: str
    summary_file: str
    stages: dict
    total_time: float
    summary: dict = field(default_factory=dict, metadata={"dict": False})

    SUCCESS = ("ok",)


def run_folder(out_dir, quick: bool, robot_name="rabbit") -> Path:
    """The folder a run writes into: ``out_dir`` for the full run on RABBIT,
    ``out_dir/quick`` for the quick one; for another robot ``out_dir/<name>`` and
    ``out_dir/<name>/quick``, the name being the built-in robot's or the description
    file's (``--robot my_biped.toml``: ``my_biped``).

    Parameters
    ----------
    out_dir : str or Path
    quick : bool
    robot_name : str or Path
        A built-in robot name or a description file (ValueError when unknown).

    Returns
    -------
    Path
    """
    folder = Path(out_dir)
    if robot(robot_name or "rabbit").description != RABBIT_DESCRIPTION:
        text = str(robot_name).strip()
        stem = Path(text).stem if Path(text).suffix.lower() in (".toml", ".json") else text
        slug = re.sub(r"[^A-Za-z0-9_.-]+", "_", stem).strip("._") or "robot"
        folder = folder / (f"robot_{slug}" if slug in ("quick", "figures", "sweeps")
                           else slug)
    return folder / "quick" if quick else folder


#: the reproduction's long computations kept between runs (M1 NLP, s*, basins,
#: simulations): pickles in the cache folder, named by the digest of their inputs and of
#: the toolkit's source, so a run by other code recomputes them; any run of any mode
#: reuses what another computed with the same inputs
RESULTS = DiskCache("reproduce", version=1)


@dataclass
class _Context:
    out: Path                     # where this run's figures and files are staged
    opts: ReproduceOptions
    sweeps: Path = None           # persistent sweep folders of the run's mode
    summary: dict = field(default_factory=dict)
    figures: dict = field(default_factory=dict)
    data: dict = field(default_factory=dict)
    model: object = None
    gait: object = None
    stage: str = ""               # the stage running now
    reused: dict = field(default_factory=dict)

    def log(self, msg):
        if self.opts.progress:
            print(msg, file=sys.stderr, flush=True)

    def memo(self, name: str, inputs: dict, compute):
        """``compute()``, or its result kept by an earlier run with the same inputs and
        the same code (:data:`RESULTS`); what was reused is listed per stage in
        summary.json (``reused``)."""
        body = dict(name=name, inputs=inputs, code=source_digest(),
                    robot=self.model.params.to_dict() if self.model is not None else None)
        path = RESULTS.path(body, suffix=".pkl")
        if path.is_file():
            try:
                value = pickle.loads(path.read_bytes())
                self.reused.setdefault(self.stage, []).append(name)
                return value
            except Exception:            # noqa: BLE001 - a damaged entry is recomputed
                pass
        value = compute()
        with contextlib.suppress(OSError):
            path.parent.mkdir(parents=True, exist_ok=True)
            write_bytes_atomic(path, pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL))
        return value

    def sweep_dir(self, name: str, *settings) -> Path:
        """The sweep folder of ``name`` made with ``settings`` (part of the folder name,
        so a run with other settings never meets a folder it would refuse)."""
        return self.sweeps / "_".join([name, *(format(v, "g") if isinstance(v, float)
                                               else str(v) for v in settings)])


# ---------------------------------------------------------------- the stages
FORMATS = ("png", "pdf")


def _is_rabbit(ctx) -> bool:
    """Whether the paper's published (RABBIT) numbers apply."""
    return ctx.model.description == RABBIT_DESCRIPTION


def stage_gait(ctx: _Context):
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


def stage_singular(ctx: _Context):
    D = np.array(ctx.model.D(ctx.gait.q(ctx.gait.T)))
    sv = singular_m1_values(ctx.model, ctx.gait)
    ctx.summary["singular"] = dict(D11_T=float(D[0, 0]), D12_T=D[0, 1:].tolist(),
                                   singular_values=sv.tolist())
    ctx.data["singular_values"] = sv


def stage_fig2(ctx: _Context):
    vals = np.linspace(-10, 10, ctx.opts.line_points)
    r = one_d_sweeps(ctx.model, ctx.gait, vals,
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


def stage_grid(ctx: _Context):
    n = _grid_n(ctx)
    P = grid_points(n, -10.0, 10.0, ctx.model.nu)
    r = run_sweep(ctx.model, ctx.gait, P, out_dir=ctx.sweep_dir(f"grid{n}", -10.0, 10.0),
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


def stage_fig3(ctx: _Context):
    r = ctx.data["grid"]
    zsw = swing_height_at_Td(ctx.model, ctx.gait, r.points, 1e-2)
    c = conjecture_figures(zsw, r.max_abs, r.point_status)
    ctx.summary["conjecture"] = c
    ctx.figures["fig3"] = save_figure(conjecture_plot(zsw, r.max_abs, r.point_status),
                                      ctx.out / "figures" / "fig3", FORMATS)


def stage_fig4(ctx: _Context):
    tay = taylor_ab(ctx.model, ctx.gait)
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
            r = run_sweep(ctx.model, ctx.gait, P[real],
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


def _plane_domain(ctx: _Context, tay):
    """nu = 2: the stable domain in the (M1(1), M1(2)) plane (the grid stage's map) with
    every solution of a = b = 0 on it."""
    ab = ab_solution_set(tay)
    ctx.data["ab_set"] = ab
    grid = ctx.data.get("grid")
    if grid is None:          # the grid stage failed: map the plane here
        n = _grid_n(ctx)
        grid = run_sweep(ctx.model, ctx.gait, grid_points(n, -10.0, 10.0, 2),
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
        from_map = run_sweep(ctx.model, ctx.gait, on_set[keep], progress=False)
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
    ab = ctx.data.get("ab_set") or ab_solution_set(taylor_ab(ctx.model, ctx.gait))
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
    P = coarse_map_points(taylor_ab(ctx.model, ctx.gait), group, ctx.model.nu)
    return next((b for b in ctx.data.get("maps", [])
                 if b.M1.shape == P.shape and np.array_equal(b.M1, P)), None)


def stage_m1(ctx: _Context):
    out = {}
    k = ctx.opts.nlp_starts
    groups = _m1_groups(ctx)
    for name, grp in groups:
        t = time.perf_counter()
        kw = dict(group=grp, n_best=k, n_ipopt=min(4, k), n_random=0 if ctx.opts.quick else 2)
        r = ctx.memo("optimize_m1", dict(gait=ctx.gait.cache_key, **kw),
                     lambda: optimize_m1(ctx.model, ctx.gait, coarse=_coarse_map(ctx, grp),
                                         **kw))
        out[name] = r.to_dict()
        ctx.log(f"   {name}: max|lambda| = {r.max_abs:.3g} (+- {r.eigenvalue_uncertainty:.1g}) "
                f"in {time.perf_counter() - t:.1f} s")
    if _is_rabbit(ctx):
        ex = poincare_eigenvalues(ctx.model, ctx.gait, PAPER["example_M1"])
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


def stage_vc(ctx: _Context):
    vc = vc_eigenvalue(ctx.model, ctx.gait)
    nu = ctx.model.nu
    M1 = ctx.data.get("chosen_M1", np.zeros(nu))
    tv = poincare_eigenvalues(ctx.model, ctx.gait, M1)
    tv0 = poincare_eigenvalues(ctx.model, ctx.gait, np.zeros(nu))
    ctx.summary["vc_comparison"] = dict(vc=vc.to_dict(), tv_chosen=dict(
        M1=M1.tolist(), max_abs=tv.max_abs, eigenvalues=[[e.real, e.imag] for e in tv.eigenvalues]),
        tv_M1_zero=dict(max_abs=tv0.max_abs, status=tv0.status))


def _brief(r) -> dict:
    """A run's status, steps to converge and validity margins (for summary.json)."""
    return dict(status=r.status, message=r.message, steps=len(r.steps),
                steps_to_converge=r.steps_to_converge(),
                qu_errors=r.qu_error[:len(r.steps)].tolist(),
                dqu_errors=r.dqu_error[:len(r.steps)].tolist(),
                peak_torque=r.peak_torque, min_normal_force=r.min_normal_force,
                max_friction_ratio=r.max_friction_ratio, max_impulse_ratio=r.max_impulse_ratio,
                failure_time=r.failure_time)


def _robust_settings(ctx) -> RobustDesignSettings:
    return (RobustDesignSettings(samples=20000, starts=1) if ctx.opts.quick
            else RobustDesignSettings())


def stage_robust_design(ctx: _Context):
    """The robust time-varying design (:mod:`analysis.design.robust_search`; cached)."""
    if not _is_rabbit(ctx):
        ctx.summary["robust_design"] = dict(
            skipped="the robust-design search is calibrated on RABBIT (its gait options); "
                    "run 'biped m1 --robust --robot ...' for another robot")
        return
    r = robust_design(ctx.model, _robust_settings(ctx), progress=lambda m: ctx.log("   " + m))
    ctx.data["robust"] = r
    ctx.data["robust_gait"] = default_gait(ctx.model, GaitOptions(**r.settings["gait"]))
    ctx.summary["robust_design"] = r.to_dict()
    ctx.log(f"   {r.message}")


def stage_robustness(ctx: _Context):
    """s* of virtual constraints, the deadbeat designs of both a = b = 0 groups and the
    paper's printed M1 on the default gait; of virtual constraints and the robust design
    on the robust design's gait."""
    m, g = ctx.model, ctx.gait
    st = (RobustnessSettings(directions=8, rounds=6) if ctx.opts.quick
          else RobustnessSettings())
    rows = []

    def kept_of(gait):
        return ctx.memo("kept_directions", dict(gait=gait.cache_key, settings=st.__dict__),
                        lambda: kept_directions(m, gait, st))

    def s_star(gait, design, kept):
        return ctx.memo("robustness", dict(gait=gait.cache_key, settings=st.__dict__,
                                           design=None if design is None else design.to_dict(),
                                           kept=kept.directions.tolist()),
                        lambda: robustness(m, gait, design, st, kept=kept))
    kept = kept_of(g)
    cands = [("virtual constraints", None)]
    for name in ("group1", "group2"):
        if name in ctx.data.get("nlp_M1", {}):
            cands.append((f"deadbeat M1, {name.replace('group', 'group ')}",
                          Design(tuple(ctx.data["nlp_M1"][name]))))
    if _is_rabbit(ctx):
        cands.append(("the paper's printed M1", Design(tuple(PAPER["example_M1"]))))
    for label, design in cands:
        r = s_star(g, design, kept)
        rows.append(dict(label=label, gait="default", **r.to_dict()))
        ctx.log(f"   default gait, {label}: s* = {r.s_star:.4g}")
    rb = ctx.data.get("robust")
    if rb is not None:
        g2 = ctx.data["robust_gait"]
        kept2 = kept_of(g2)
        for label, design in (("virtual constraints", None),
                              ("robust design", Design(tuple(rb.design["M1"]),
                                                       rb.design["rejoin"]))):
            r = s_star(g2, design, kept2)
            rows.append(dict(label=label, gait="robust", **r.to_dict()))
            ctx.log(f"   robust gait, {label}: s* = {r.s_star:.4g}")
    ctx.summary["robustness"] = dict(settings=st.__dict__.copy(), rows=rows)


def stage_sim(ctx: _Context):
    """Paper §V-C at the paper's full perturbation (0.01 rad, 0.1 rad/s on every joint,
    mu = 0.6, the robot's torque limit): virtual constraints and the deadbeat M1 of the
    NLP on the default gait; virtual constraints and the robust design on the robust
    design's gait.  Fig. 5, Fig. 6 and an animation of the robust design's run."""
    m, g = ctx.model, ctx.gait
    opts = SimulationOptions(steps=ctx.opts.sim_steps, mu=0.6)
    M1 = np.asarray(ctx.data.get("chosen_M1", np.zeros(m.nu)), float)
    runs, labels = [], []
    q0, dq0 = perturbed_initial_state(g, *PAPER_SIZES)
    out = dict(perturbation=list(PAPER_SIZES), mu=0.6, runs={})
    for key, label, ctrl in (
            ("default_vc", "virtual constraints (default gait)",
             VirtualConstraintController(m, g)),
            ("default_deadbeat", f"deadbeat M1 = [{', '.join(f'{v:.3g}' for v in M1)}] "
                                 "(default gait)", TimeVaryingController(m, g, M1))):
        r = _simulated(ctx, g, ctrl, q0, dq0, opts)
        runs.append(r)
        labels.append(label)
        out["runs"][key] = dict(label=label, **_brief(r))
        ctx.log(f"   {label}: {r.status}")
    rb = ctx.data.get("robust")
    robust_runs = []
    if rb is not None:
        g2 = ctx.data["robust_gait"]
        q0, dq0 = perturbed_initial_state(g2, *PAPER_SIZES)
        M1r = np.array(rb.design["M1"])
        for key, label, ctrl in (
                ("robust_vc", "virtual constraints (robust gait)",
                 VirtualConstraintController(m, g2)),
                ("robust_design", "robust design (robust gait)",
                 TimeVaryingController(m, g2, M1r, rejoin=rb.design["rejoin"]))):
            r = _simulated(ctx, g2, ctrl, q0, dq0, opts)
            runs.append(r)
            labels.append(label)
            robust_runs.append(r)
            out["runs"][key] = dict(label=label, **_brief(r))
            ctx.log(f"   {label}: {r.status}")
    figs = ctx.out / "figures"
    ctx.figures["fig5"] = save_figure(
        unactuated_error_plot(runs, labels=labels,
                              title="Fig. 5 at the paper's full perturbation: q_u error "
                                    "just before each impact"),
        figs / "fig5_qu_error", FORMATS)
    pair = (robust_runs, ctx.data["robust_gait"], labels[2:]) if robust_runs else \
        (runs, g, labels)
    ctx.figures["fig6"] = save_figure(
        swing_torques_plot(pair[0], pair[1], labels=pair[2],
                           title="Fig. 6 at the paper's full perturbation: swing-leg torques"),
        figs / "fig6_swing_torques", FORMATS)
    shown = robust_runs[-1] if robust_runs else runs[-1]
    if ctx.opts.animation_steps and shown.t.size:
        ctx.figures["animation"] = [walking_animation(shown, m, figs / "walk_tv.gif",
                                                      max_steps=ctx.opts.animation_steps)]
    ctx.summary["simulation"] = out


def _simulated(ctx, gait, ctrl, q0, dq0, opts):
    """A full-order run, kept between reproductions (:meth:`_Context.memo`)."""
    return ctx.memo("simulate", dict(gait=gait.cache_key, controller=ctrl.describe(),
                                     q0=np.asarray(q0).tolist(), dq0=np.asarray(dq0).tolist(),
                                     options=opts.to_dict()),
                    lambda: simulate(ctrl, q0, dq0, opts))


def _basin(ctx, gait, design, n):
    """A basin of attraction, kept between reproductions (:meth:`_Context.memo`)."""
    return ctx.memo("basin", dict(gait=gait.cache_key, n=n,
                                  design=None if design is None else design.to_dict()),
                    lambda: basin(ctx.model, gait, design, n=n))


def stage_basins(ctx: _Context):
    """Basins of attraction on the Poincaré section: the deadbeat M1 beside virtual
    constraints on the default gait, the robust design beside virtual constraints on its
    gait; and the trade-off between s* and max|lambda| found by the robust search."""
    m, g = ctx.model, ctx.gait
    n = 41 if ctx.opts.quick else 101
    M1 = np.asarray(ctx.data.get("chosen_M1", np.zeros(m.nu)), float)
    out = {}
    b1 = [_basin(ctx, g, Design(tuple(M1)), n), _basin(ctx, g, None, n)]
    out["default"] = [b.to_dict() for b in b1]
    figs = ctx.out / "figures"
    ctx.figures["basin_default"] = save_figure(
        basin_plot(b1, title="Basins on the default gait: deadbeat M1 and virtual "
                             "constraints"), figs / "basin_default", FORMATS)
    rb = ctx.data.get("robust")
    if rb is not None:
        g2 = ctx.data["robust_gait"]
        b2 = [_basin(ctx, g2, Design(tuple(rb.design["M1"]), rb.design["rejoin"]), n),
              _basin(ctx, g2, None, n)]
        out["robust"] = [b.to_dict() for b in b2]
        ctx.figures["basin_robust"] = save_figure(
            basin_plot(b2, title="Basins on the robust design's gait: the robust design "
                                 "and virtual constraints"), figs / "basin_robust", FORMATS)
        rows = (ctx.summary.get("robustness") or {}).get("rows", [])
        vc_s = next((r["s_star"] for r in rows if r["gait"] == "robust"
                     and r["controller"] == "vc"), None)
        others = {"robust design": (rb.max_abs, rb.s_star)}
        if vc_s is not None:
            others["virtual constraints"] = (rb.vc_eigenvalue, vc_s)
        ctx.figures["tradeoff"] = save_figure(
            tradeoff_plot(rb.tradeoff, others, bound=rb.vc_eigenvalue,
                          title="s* against max|λ| on the robust design's gait"),
            figs / "tradeoff", FORMATS)
    for k, v in out.items():
        ctx.log(f"   {k}: " + ", ".join(f"{b['controller']} {100 * b['converged_fraction']:.1f} %"
                                        for b in v))
    ctx.summary["basins"] = out


#: the two gain sets of the model-error table (Kp, Kd, eps of eq. 13)
TERRAIN_GAINS = ((1.0, 2.0, 0.02), (1.0, 2.0, 0.2))


def stage_terrain(ctx: _Context):
    """Beyond the initial push (issue 22), small: the mean first-passage time on
    stochastic terrain against sigma for virtual constraints and the robust design (on
    its gait) and the deadbeat M1 (default gait); the exact gait sensitivity norm and
    its check against the Monte Carlo's step-time RMS at small sigma; the MFPT with the
    torso 20 % heavier than the controller's model for two gain sets."""
    from ..terrain import MonteCarloSettings, WalkerSpec, gait_sensitivity, monte_carlo
    from ..terrain import predicted_rms
    from .plots import mfpt_sigma_plot, survival_plot
    m, g = ctx.model, ctx.gait
    quick = ctx.opts.quick
    rb, g2 = ctx.data.get("robust"), ctx.data.get("robust_gait")
    cands = []
    if rb is not None:
        cands += [("virtual constraints (robust gait)", g2, WalkerSpec("vc")),
                  ("robust design", g2, WalkerSpec("tv", tuple(rb.design["M1"]),
                                                   rb.design["rejoin"]))]
    else:
        cands.append(("virtual constraints (default gait)", g, WalkerSpec("vc")))
    if "group1" in ctx.data.get("nlp_M1", {}):
        cands.append(("deadbeat M1 (default gait)", g,
                      WalkerSpec("tv", tuple(ctx.data["nlp_M1"]["group1"]))))
    sigmas = (0.004, 0.008) if quick else (0.002, 0.004, 0.008, 0.012)
    runs, steps = (16, 12) if quick else (32, 20)
    curves, rows, survival = {}, [], []
    for label, gg, spec in cands:
        pts = []
        for sig in sigmas:
            st = MonteCarloSettings(sigma=sig, runs=runs, max_steps=steps, chunk=runs)
            r = monte_carlo(gg, spec, st, scheduler="inline")
            e = r.estimate
            pts.append((sig, e.mfpt, *e.mfpt_ci))
            rows.append(dict(label=label, sigma=sig, mfpt=e.mfpt, mfpt_ci=e.mfpt_ci,
                             failure_probability=e.failure_probability,
                             failures=e.failures, runs=runs, max_steps=steps,
                             status_counts=r.status_counts))
            if sig == sigmas[-1]:
                survival.append((r, label))
        curves[label] = pts
        ctx.log(f"   {label}: MFPT " + ", ".join(
            f"{p[1]:.3g}" if np.isfinite(p[1]) else f">{p[2]:.3g}" for p in pts)
            + f" steps at sigma = {', '.join(f'{1000 * v:g}' for v in sigmas)} mm")
    # the exact GSN, and the Monte Carlo's step-time RMS it predicts at sigma = 0.5 mm
    gsn = []
    tv = [c for c in cands if c[2].controller == "tv"]       # (the README has the VC's)
    for label, gg, spec in tv[-1:] if quick else tv:
        gs = gait_sensitivity(spec.controller_for(gg), SimulationOptions(rk4_steps=400))
        st = MonteCarloSettings(sigma=5e-4, runs=runs, max_steps=steps, chunk=runs)
        mc = monte_carlo(gg, spec, st, scheduler="inline")
        pred = predicted_rms(gs.linearisation, st.sigma, steps, st.transient)
        gsn.append(dict(label=label, gsn=gs.gsn, spectral_radius=gs.spectral_radius,
                        sigma=st.sigma, predicted_rms=pred, monte_carlo_rms=mc.step_time_rms,
                        relative_difference=abs(mc.step_time_rms - pred) / pred))
        ctx.log(f"   {label}: GSN (ground, step time) {gs.gsn['ground_height']['step_time']:.4g}"
                f" s/m; step-time RMS at 0.5 mm: predicted {pred:.3g} s, Monte Carlo "
                f"{mc.step_time_rms:.3g} s")
    # a 20 % torso-mass error, two gain sets (the full-order simulator)
    err = []
    label, gg, spec = cands[1] if rb is not None else cands[0]
    plant = m.description.scaled(torso_mass=1.2).to_dict()
    sig = sigmas[-1]
    st = MonteCarloSettings(sigma=sig, runs=6 if quick else 12, max_steps=steps, chunk=12)
    for gains in TERRAIN_GAINS:
        for pl in (None, plant):
            sp = WalkerSpec(spec.controller, spec.M1, spec.rejoin, gains, pl)
            r = monte_carlo(gg, sp, st, scheduler="inline")
            e = r.estimate
            err.append(dict(design=label, gains=list(gains), torso_mass_error=0.2 if pl else 0.0,
                            sigma=sig, mfpt=e.mfpt, mfpt_ci=e.mfpt_ci, failures=e.failures,
                            runs=st.runs, max_steps=steps, engine=sp.engine,
                            status_counts=r.status_counts))
    ctx.log("   torso +20 %: " + "; ".join(
        f"gains {r['gains']}: MFPT {r['mfpt']:.3g}" for r in err if r["torso_mass_error"]))
    figs = ctx.out / "figures"
    ctx.figures["terrain_mfpt"] = save_figure(mfpt_sigma_plot(curves), figs / "terrain_mfpt",
                                              FORMATS)
    ctx.figures["terrain_survival"] = save_figure(
        survival_plot([r for r, _ in survival], labels=[lab for _, lab in survival],
                      title=f"Survival at sigma = {1000 * sigmas[-1]:g} mm"),
        figs / "terrain_survival", FORMATS)
    ctx.summary["terrain"] = dict(sigmas=list(sigmas), runs=runs, max_steps=steps,
                                  mfpt=rows, gsn=gsn, model_error=err)


STAGES = [
    ("gait", stage_gait, ()),
    ("singular outputs (eq. 24)", stage_singular, ("gait",)),
    ("Fig. 2: 1-D sweeps", stage_fig2, ("gait",)),
    ("M1 grid", stage_grid, ("gait",)),
    ("Fig. 3 and the conjecture", stage_fig3, ("M1 grid",)),
    ("a, b and Fig. 4", stage_fig4, ("gait",)),
    ("M1 NLP", stage_m1, ("gait",)),
    ("virtual constraints", stage_vc, ("gait",)),
    ("robust design", stage_robust_design, ("gait",)),
    ("robustness (s*)", stage_robustness, ("M1 NLP",)),
    ("Fig. 5, Fig. 6, animation", stage_sim, ("M1 NLP",)),
    ("basins of attraction", stage_basins, ("M1 NLP",)),
    ("uneven ground (MFPT, GSN)", stage_terrain, ("gait",)),
]


def reproduce(out_dir="reproduce_out", quick: bool = False, **kw) -> ReproduceResult:
    """Run every stage; the results go to :func:`run_folder` (``out_dir`` for the full
    run on RABBIT, ``out_dir/quick`` for ``quick``, ``out_dir/<robot>`` for another
    robot), see the module docstring.

    Parameters
    ----------
    out_dir : str or Path
        Created if needed; must not be a file.
    quick : bool
        Coarser grids and fewer starts (:meth:`ReproduceOptions.make`).
    **kw
        Fields of :class:`ReproduceOptions` (``robot='three_link'``, ...).

    Returns
    -------
    ReproduceResult
        Its ``summary`` is also in ``summary.json``.

    Raises
    ------
    ValueError
        ``out_dir`` (or the run's folder inside it) is a file; an unknown robot.
    """
    opts = ReproduceOptions.make(quick, **kw)
    folder = run_folder(out_dir, quick, opts.robot)
    for p in (Path(out_dir), folder, folder / "figures", folder / "sweeps"):
        if p.exists() and not p.is_dir():
            raise ValueError(f"out_dir: {p} is a file, not a folder")
    folder.mkdir(parents=True, exist_ok=True)
    staging = folder / f".staging-{os.getpid()}"
    shutil.rmtree(staging, ignore_errors=True)
    (staging / "figures").mkdir(parents=True)
    ctx = _Context(staging, opts, sweeps=folder / "sweeps")
    try:
        status = _run_stages(ctx)
        mode = "quick" if opts.quick else "full"
        ctx.summary["mode"] = mode
        ctx.summary["stages"] = status
        ctx.summary["reused"] = ctx.reused
        ctx.summary["figures"] = {k: [_relative(f, staging) for f in
                                      ([v] if isinstance(v, str) else v)]
                                  for k, v in ctx.figures.items()}
        if ctx.model is not None and _is_rabbit(ctx):
            ctx.summary["paper"] = PAPER
        ctx.summary["options"] = dict(opts.__dict__)
        ctx.summary["finished"] = time.strftime("%Y-%m-%d %H:%M:%S %z")
        summary = json_safe(ctx.summary)
        write_text_atomic(staging / "summary.json",
                          json.dumps(summary, indent=1, allow_nan=False) + "\n")
        write_report(staging, summary)
        _publish(staging, folder)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    bad = [k for k, v in status.items() if v["status"] != "ok"]
    ctx.log(f"report: {folder / 'report.md'}  ({ctx.summary['total_time']:.0f} s)")
    return ReproduceResult(
        status="failed" if bad else "ok",
        message=(f"stages not ok: {', '.join(bad)}" if bad else "every stage ok"),
        mode=mode, folder=str(folder), report=str(folder / "report.md"),
        summary_file=str(folder / "summary.json"), stages=summary["stages"],
        total_time=ctx.summary["total_time"], summary=summary)


def _run_stages(ctx: _Context) -> dict:
    status = {}
    t_all = time.perf_counter()
    for k, (name, fn, needs) in enumerate(STAGES, start=1):
        missing = [n for n in needs if status.get(n, {}).get("status") != "ok"]
        if missing:
            status[name] = dict(status="skipped", reason=f"needs: {', '.join(missing)}")
            ctx.log(f"[{k}/{len(STAGES)}] {name}: skipped (needs {', '.join(missing)})")
            continue
        ctx.log(f"[{k}/{len(STAGES)}] {name} ...")
        ctx.stage = name
        t = time.perf_counter()
        try:
            fn(ctx)
            status[name] = dict(status="ok", time=time.perf_counter() - t)
            kept = ctx.reused.get(name)
            ctx.log(f"[{k}/{len(STAGES)}] {name}: done in {time.perf_counter() - t:.1f} s"
                    + (f" (reused {len(kept)} kept result(s))" if kept else ""))
        except Exception as e:          # a failed stage is reported, the others go on
            status[name] = dict(status="failed", error=f"{type(e).__name__}: {e}",
                                time=time.perf_counter() - t,
                                traceback=traceback.format_exc(limit=6))
            ctx.log(f"[{k}/{len(STAGES)}] {name}: FAILED ({type(e).__name__}: {e})")
    ctx.summary["total_time"] = time.perf_counter() - t_all
    return status


def _relative(path, root: Path) -> str:
    """``path`` relative to the run's folder (summary.json and report.md travel with it)."""
    try:
        return Path(path).resolve().relative_to(root.resolve()).as_posix()
    except ValueError:
        return str(path)


def _publish(staging: Path, folder: Path):
    """Move a finished run from ``staging`` into ``folder``: every file replaced
    atomically; the previous run's figures that this run did not make removed (they are
    listed in the previous summary.json); nothing else touched."""
    figures = folder / "figures"
    old = set()
    with contextlib.suppress(OSError, ValueError, TypeError, AttributeError):
        prev = json.loads((folder / "summary.json").read_text())
        for files in prev.get("figures", {}).values():
            for f in ([files] if isinstance(files, str) else files):
                # relative to the run's folder; older versions: to the working directory
                p = folder / f if Path(f).parts[:1] == ("figures",) else Path(f)
                old.add(p.resolve())
    figures.mkdir(exist_ok=True)
    new = set()
    for f in sorted((staging / "figures").iterdir()):
        os.replace(f, figures / f.name)
        new.add((figures / f.name).resolve())
    for p in sorted(old - new):
        if p.parent == figures.resolve() and p.is_file():     # only files in figures/
            p.unlink()
    for name in ("gait.json", "summary.json", "report.md"):
        if (staging / name).exists():
            os.replace(staging / name, folder / name)
