"""The stages of ``biped reproduce`` that ask which controllers walk: the robust design, s*
of every design, Fig. 5 and 6 at the paper's full perturbation, basins of attraction,
uneven ground and a wrong model."""
from __future__ import annotations


import numpy as np

from biped_casadi import (PAPER_SIZES, SimulationOptions,
                          TimeVaryingController, VirtualConstraintController,
                          perturbed_initial_state, simulate)
from gait_opt import GaitOptions, default_gait

from ..design import ROBUST_GAIT
from ..design.codesign import (FULL, QUICK, TODAY_DESIGN, codesign, codesign_prefetch,
                               codesign_tradeoff)
from ..robustness import Design, RobustnessSettings, basin, kept_directions, robustness
from .plots import (basin_plot, save_figure, swing_torques_plot, tradeoff_plot, unactuated_error_plot,
                    walking_animation)

from .context import FORMATS, Context, is_rabbit
from .constants import PAPER


def _brief(r) -> dict:
    """A run's status, steps to converge and validity margins (for summary.json)."""
    return dict(status=r.status, message=r.message, steps=len(r.steps),
                steps_to_converge=r.steps_to_converge(),
                qu_errors=r.qu_error[:len(r.steps)].tolist(),
                dqu_errors=r.dqu_error[:len(r.steps)].tolist(),
                peak_torque=r.peak_torque, min_normal_force=r.min_normal_force,
                max_friction_ratio=r.max_friction_ratio, max_impulse_ratio=r.max_impulse_ratio,
                failure_time=r.failure_time)


def stage_robust_design(ctx: Context):
    """The robust time-varying design by the co-design NLP (:mod:`analysis.design.codesign`;
    cached): in the full run the gait is co-designed (the settings of ``biped m1
    --robust``, one cache for both), in the quick run it is fixed.  Beside it, the
    sampling search's design (``biped m1 --robust --method search``), as it ships: its
    M1 on its gait, evaluated by the same stages, not searched again.  The full run also
    traces the (max|lambda|, s*) trade-off with the NLP."""
    if not is_rabbit(ctx):
        ctx.summary["robust_design"] = dict(
            skipped="the robust co-design starts from gait options calibrated on RABBIT; "
                    "run 'biped m1 --robust --robot ...' for another robot")
        return
    st = QUICK if ctx.opts.quick else FULL
    say = lambda m: ctx.log("   " + m)                 # noqa: E731
    # the two processes split its units, taking the independent ones from opposite ends
    # (this one took part in them already between its stages, help_codesign)
    r = codesign(ctx.model, st, progress=say,
                 share="forward" if ctx.data.get("helper") else "backward")
    ctx.data["robust"] = r
    ctx.data["robust_gait"] = r.gait
    _search(ctx)
    ctx.summary["robust_design"] = dict(r.to_dict(),
                                        method="co-design NLP (biped m1 --robust)")
    ctx.log(f"   {r.message}")


def help_codesign(ctx: Context, wait: bool = False):
    """Between two stages of the main process: the robust co-design's independent units
    that nobody has taken yet (its start screens and rejoin choices, from the last; the
    helper process takes them from the first), so that the helper reaches the sequential
    gait steps sooner (:func:`analysis.design.codesign.codesign_prefetch`).  ``wait``
    False: never wait for the helper (return at its first unit in progress); True: wait
    for its setup and its units in progress until every independent unit is done.  The
    time and the units go to ``summary['codesign_help']``.  Nothing without the helper,
    once every independent unit is done, or when the co-design is kept."""
    if not is_rabbit(ctx) or not ctx.data.get("helper_running") \
            or ctx.data.get("codesign_helped"):
        return
    st = QUICK if ctx.opts.quick else FULL
    p = codesign_prefetch(ctx.model, st, share="backward", wait=wait)
    h = ctx.summary.setdefault("codesign_help", dict(calls=0, time=0.0, computed=0))
    h["calls"] += 1
    h["time"] += p["time"]
    h["computed"] += p["computed"]
    if p["computed"]:
        ctx.log(f"   (took {p['computed']} of the co-design's units in {p['time']:.1f} s)")
    if p["finished"]:
        ctx.data["codesign_helped"] = True


def _search(ctx):
    """The sampling search's shipped design and its gait (``biped m1 --robust --method
    search``; not searched again)."""
    if "search_gait" not in ctx.data:
        ctx.data["search_gait"] = default_gait(ctx.model, GaitOptions(**ROBUST_GAIT))
        ctx.data["search_design"] = Design(tuple(TODAY_DESIGN), 0.75)
    return ctx.data["search_gait"], ctx.data["search_design"]


def stage_search_design(ctx: Context):
    """The sampling search's shipped design beside the co-design: its gait, s* of it and
    of virtual constraints on that gait, and its basin (computed while the co-design runs
    on the other core; the robust stages below read them back)."""
    if not is_rabbit(ctx):
        return
    g3, ds = _search(ctx)
    ctx.summary["search_design"] = dict(
        M1=list(ds.M1), rejoin=ds.rejoin, gait_options=dict(ROBUST_GAIT),
        note="the sampling search's shipped design (biped m1 --robust --method search), "
             "evaluated here by the same stages, not searched again")
    cands = [("virtual constraints", None), ("the sampling search's design", ds)]
    if ctx.data.get("helper"):      # the helper process takes them from the other end
        _basin(ctx, g3, ds, _basin_n(ctx))
        _s_star_rows(ctx, [("search", g3, cands[::-1])])
        return
    _s_star_rows(ctx, [("search", g3, cands)])
    _basin(ctx, g3, ds, _basin_n(ctx))


def stage_tradeoff(ctx: Context):
    """The (max|lambda|, s*) trade-off traced by the NLP on the co-design's gait (full
    run; :func:`analysis.design.codesign.codesign_tradeoff`)."""
    r = ctx.data.get("robust")
    if r is None or ctx.opts.quick:
        return
    # the helper process traces it too: the two split the points from opposite ends
    pts = ctx.memo("codesign_tradeoff", dict(design=r.design, gait=r.gait.cache_key,
                                             settings=r.settings),
                   lambda: codesign_tradeoff(
                       ctx.model, r, progress=lambda m: ctx.log("   " + m),
                       share="forward" if ctx.data.get("helper") else "backward"),
                   claim=False)
    ctx.data["tradeoff"] = pts
    ctx.summary["robust_design"]["tradeoff"] = pts


def _robustness_settings(ctx) -> RobustnessSettings:
    return (RobustnessSettings(directions=8, rounds=6) if ctx.opts.quick
            else RobustnessSettings())


def _s_star_rows(ctx, groups, reverse: bool = False) -> list:
    """s* of every (label, design) of every (gait name, gait, candidates) group, each
    kept between reproductions (:meth:`Context.memo`); ``reverse``: computed from the
    last (the reproduction's helper process takes them from the first)."""
    m, st = ctx.model, _robustness_settings(ctx)

    def kept_of(gait):
        return ctx.memo("kept_directions", dict(gait=gait.cache_key, settings=st.__dict__),
                        lambda: kept_directions(gait, st))

    def s_star(gait, design):
        kept = kept_of(gait)
        return ctx.memo("robustness", dict(gait=gait.cache_key, settings=st.__dict__,
                                           design=None if design is None
                                           else design.to_dict(),
                                           kept=kept.directions.tolist()),
                        lambda: robustness(gait, design, st, kept=kept))
    if reverse:                   # computed last first (another process takes them in order)
        for _, gait, cands in groups[::-1]:
            for _, design in cands[::-1]:
                s_star(gait, design)
    rows = []
    for gait_name, gait, cands in groups:
        for label, design in cands:
            r = s_star(gait, design)
            rows.append(dict(label=label, gait=gait_name, **r.to_dict()))
            ctx.log(f"   {gait_name} gait, {label}: s* = {r.s_star:.4g}")
    return rows


def stage_robustness(ctx: Context):
    """s* of virtual constraints, the deadbeat designs of both a = b = 0 groups and the
    paper's printed M1 on the default gait (the robust designs' rows follow in
    :func:`stage_robustness_robust`)."""
    cands = [("virtual constraints", None)]
    for name in ("group1", "group2"):
        if name in ctx.data.get("nlp_M1", {}):
            cands.append((f"deadbeat M1, {name.replace('group', 'group ')}",
                          Design(tuple(ctx.data["nlp_M1"][name]))))
    if is_rabbit(ctx):
        cands.append(("the paper's printed M1", Design(tuple(PAPER["example_M1"]))))
    ctx.summary["robustness"] = dict(settings=_robustness_settings(ctx).__dict__.copy(),
                                     rows=_s_star_rows(ctx, [("default", ctx.gait, cands)]))


def stage_robustness_robust(ctx: Context):
    """s* of the robust designs and of virtual constraints on their gaits, and the
    trade-off figure (s* against max|lambda|)."""
    rows = _s_star_rows(ctx, _robust_groups(ctx), reverse=not ctx.data.get("helper"))
    summ = ctx.summary.setdefault("robustness", dict(
        settings=_robustness_settings(ctx).__dict__.copy(), rows=[]))
    summ["rows"] = summ["rows"] + rows
    rb = ctx.data.get("robust")
    if rb is None:
        return
    vc_s = next((r["s_star"] for r in rows if r["gait"] == "robust"
                 and r["controller"] == "vc"), None)
    ss = next((r for r in rows if r["label"] == "the sampling search's design"), None)
    mine = next((r for r in rows if r["label"] == "robust design (co-design NLP)"), None)
    # every marker's s* from the s* table (one protocol for all three)
    others = {"co-design NLP": (rb.max_abs, mine["s_star"] if mine else rb.s_star)}
    if ss is not None:
        others["sampling search's design"] = (ss["max_abs"], ss["s_star"])
    if vc_s is not None:
        others["virtual constraints"] = (rb.vc_eigenvalue, vc_s)
    pts = [(p["max_abs"], p["s_star"]) for p in ctx.data.get("tradeoff") or []
           if p.get("s_star") is not None]
    ctx.figures["tradeoff"] = save_figure(
        tradeoff_plot(pts, others, bound=rb.vc_eigenvalue, front_style="points",
                      front_label="the NLP, gait fixed, max|λ| <= 1/4, 1/2, 3/4, 1 x "
                                  "virtual constraints' (s* verified)",
                      title="s* against max|λ| on the co-design's gait"),
        ctx.out / "figures" / "tradeoff", FORMATS)


def _robust_groups(ctx):
    """(gait name, gait, [(label, design)]) of the robust designs: the co-design and
    virtual constraints on the co-design's gait ('robust'); the sampling search's design
    on its own gait ('search', with virtual constraints) or, when the gaits are one, on
    the same."""
    rb = ctx.data.get("robust")
    if rb is None:
        return []
    g2, g3 = ctx.data["robust_gait"], ctx.data["search_gait"]
    mine = ("robust design (co-design NLP)", Design(tuple(rb.design["M1"]), rb.design["rejoin"]))
    search = ("the sampling search's design", ctx.data["search_design"])
    if g3.cache_key == g2.cache_key:
        return [("robust", g2, [("virtual constraints", None), mine, search])]
    return [("robust", g2, [("virtual constraints", None), mine]),
            ("search", g3, [("virtual constraints", None), search])]


def _sim_options(ctx) -> SimulationOptions:
    return SimulationOptions(steps=ctx.opts.sim_steps, mu=0.6)


def stage_sim(ctx: Context):
    """Paper §V-C at the paper's full perturbation (0.01 rad, 0.1 rad/s on every joint,
    mu = 0.6, the robot's torque limit): virtual constraints and the deadbeat M1 of the
    NLP on the default gait (the robust designs' runs and the figures follow in
    :func:`stage_sim_robust`)."""
    m, g = ctx.model, ctx.gait
    M1 = np.asarray(ctx.data.get("chosen_M1", np.zeros(m.nu)), float)
    q0, dq0 = perturbed_initial_state(g, *PAPER_SIZES)
    out = dict(perturbation=list(PAPER_SIZES), mu=0.6, runs={})
    ctx.data["sim_runs"] = []
    for key, label, ctrl in (
            ("default_vc", "virtual constraints (default gait)",
             VirtualConstraintController(g)),
            ("default_deadbeat", f"deadbeat M1 = [{', '.join(f'{v:.3g}' for v in M1)}] "
                                 "(default gait)", TimeVaryingController(g, M1))):
        r = _simulated(ctx, g, ctrl, q0, dq0, _sim_options(ctx))
        ctx.data["sim_runs"].append((r, label))
        out["runs"][key] = dict(label=label, **_brief(r))
        ctx.log(f"   {label}: {r.status}")
    ctx.summary["simulation"] = out


def stage_sim_robust(ctx: Context):
    """The same runs for virtual constraints and the robust design on the co-design's
    gait and for the sampling search's design on its gait; Fig. 5, Fig. 6 and an
    animation of the robust design's run."""
    g = ctx.gait
    runs = list(ctx.data.get("sim_runs", []))
    out = ctx.summary.setdefault("simulation", dict(perturbation=list(PAPER_SIZES), mu=0.6,
                                                    runs={}))
    robust_runs = _robust_runs(ctx, out["runs"])
    runs += robust_runs
    if not runs:
        return
    figs = ctx.out / "figures"
    ctx.figures["fig5"] = save_figure(
        unactuated_error_plot([r for r, _ in runs], labels=[lab for _, lab in runs],
                              title="Fig. 5 at the paper's full perturbation: q_u error "
                                    "just before each impact"),
        figs / "fig5_qu_error", FORMATS)
    pair, gg = (robust_runs, ctx.data["robust_gait"]) if robust_runs else (runs, g)
    ctx.figures["fig6"] = save_figure(
        swing_torques_plot([r for r, _ in pair], gg, labels=[lab for _, lab in pair],
                           title="Fig. 6 at the paper's full perturbation: swing-leg torques"),
        figs / "fig6_swing_torques", FORMATS)
    shown = pair[-1][0]
    if ctx.opts.animation_steps and shown.t.size:
        ctx.figures["animation"] = [_animation(ctx, shown, figs / "walk_tv.gif")]


def _animation(ctx, run, path) -> str:
    """The run's animation (:func:`walking_animation`), its GIF kept between reproductions
    by the content of the run (rendering it is most of a warm re-run's time)."""
    import hashlib

    from biped_casadi.files import write_bytes_atomic
    h = hashlib.sha256()
    for a in (run.t, run.q, run.step, run.stance_x):
        h.update(np.ascontiguousarray(a, dtype=float).tobytes())

    def render():
        walking_animation(run, ctx.model, path, max_steps=ctx.opts.animation_steps)
        return path.read_bytes()
    data = ctx.memo("animation", dict(run=h.hexdigest(), steps=ctx.opts.animation_steps),
                    render)
    if not path.is_file():
        write_bytes_atomic(path, data)
    return str(path)


def _robust_runs(ctx, runs: dict) -> list:
    """The full-order runs of virtual constraints and the co-design on the co-design's
    gait and of the sampling search's design on its gait, from the paper's perturbation
    (each kept between reproductions); their briefs go into ``runs``.  Returns the
    (result, label) of the first two (Fig. 6)."""
    rb = ctx.data.get("robust")
    if rb is None:
        return []
    m, opts = ctx.model, _sim_options(ctx)
    g2 = ctx.data["robust_gait"]
    g3, ds = _search(ctx)
    q0, dq0 = perturbed_initial_state(g2, *PAPER_SIZES)
    q3, dq3 = perturbed_initial_state(g3, *PAPER_SIZES)
    search = TimeVaryingController(g3, np.array(ds.M1), rejoin=ds.rejoin)
    if not ctx.data.get("helper"):    # last first: the helper process takes them in order
        _simulated(ctx, g3, search, q3, dq3, opts)
    out = []
    for key, label, ctrl in (
            ("robust_vc", "virtual constraints (the co-design's gait)",
             VirtualConstraintController(g2)),
            ("robust_design", "robust design, co-design NLP (its gait)",
             TimeVaryingController(g2, np.array(rb.design["M1"]),
                                   rejoin=rb.design["rejoin"]))):
        r = _simulated(ctx, g2, ctrl, q0, dq0, opts)
        out.append((r, label))
        runs[key] = dict(label=label, **_brief(r))
        ctx.log(f"   {label}: {r.status}")
    label = "the sampling search's design (its gait)"
    r = _simulated(ctx, g3, search, q3, dq3, opts)
    runs["search_design"] = dict(label=label, **_brief(r))
    ctx.log(f"   {label}: {r.status}")
    return out


def warm_robust_runs(ctx: Context):
    """The robust designs' full-order runs alone, into the cache (the reproduction's
    helper process computes them ahead of :func:`stage_sim_robust`)."""
    _robust_runs(ctx, {})


def _simulated(ctx, gait, ctrl, q0, dq0, opts):
    """A full-order run, kept between reproductions (:meth:`Context.memo`)."""
    return ctx.memo("simulate", dict(gait=gait.cache_key, controller=ctrl.describe(),
                                     q0=np.asarray(q0).tolist(), dq0=np.asarray(dq0).tolist(),
                                     options=opts.to_dict()),
                    lambda: simulate(ctrl, q0, dq0, opts))


#: basins on the adaptive grid (:func:`analysis.robustness.basin`, ``refine``): every
#: 4th row and column first, the boundary cell by cell (benchmarks/bench_basin.py
#: measures the cells that differ from the full grid)
BASIN_REFINE = 4


def _basin(ctx, gait, design, n):
    """A basin of attraction, kept between reproductions (:meth:`Context.memo`)."""
    return ctx.memo("basin", dict(gait=gait.cache_key, n=n, refine=BASIN_REFINE,
                                  design=None if design is None else design.to_dict()),
                    lambda: basin(gait, design, n=n, refine=BASIN_REFINE))


def _basin_n(ctx) -> int:
    return 41 if ctx.opts.quick else 101


def _log_basins(ctx, name, bs):
    ctx.log(f"   {name}: " + ", ".join(f"{b['controller']} {100 * b['converged_fraction']:.1f} %"
                                       for b in bs))


def stage_basins(ctx: Context):
    """Basins of attraction on the Poincaré section: the deadbeat M1 beside virtual
    constraints on the default gait (the robust designs' follow in
    :func:`stage_basins_robust`)."""
    m, g, n = ctx.model, ctx.gait, _basin_n(ctx)
    M1 = np.asarray(ctx.data.get("chosen_M1", np.zeros(m.nu)), float)
    b1 = [_basin(ctx, g, Design(tuple(M1)), n), _basin(ctx, g, None, n)]
    out = ctx.summary.setdefault("basins", {})
    out["default"] = [b.to_dict() for b in b1]
    ctx.figures["basin_default"] = save_figure(
        basin_plot(b1, title="Basins on the default gait: deadbeat M1 and virtual "
                             "constraints"), ctx.out / "figures" / "basin_default", FORMATS)
    _log_basins(ctx, "default", out["default"])


def stage_basins_robust(ctx: Context):
    """The basins of the co-design, the sampling search's design and virtual
    constraints."""
    rb = ctx.data.get("robust")
    if rb is None:
        return
    n = _basin_n(ctx)
    g2, g3 = ctx.data["robust_gait"], ctx.data["search_gait"]
    todo = [(g2, Design(tuple(rb.design["M1"]), rb.design["rejoin"])),
            (g3, ctx.data["search_design"]), (g2, None)]
    # the reproduction's helper process takes them from the other end (the two meet)
    order = range(len(todo))[::-1] if ctx.data.get("helper") else range(len(todo))
    done = {i: _basin(ctx, todo[i][0], todo[i][1], n) for i in order}
    b2 = [done[i] for i in range(len(todo))]
    out = ctx.summary.setdefault("basins", {})
    out["robust"] = [b.to_dict() for b in b2]
    out["robust_labels"] = ["robust design (co-design NLP)",
                            "the sampling search's design", "virtual constraints"]
    same = g3.cache_key == g2.cache_key
    ctx.figures["basin_robust"] = save_figure(
        basin_plot(b2, title="Basins: the co-design, the sampling search's design"
                             + (" and virtual constraints on one gait" if same else
                                " (on its gait) and virtual constraints (the "
                                "co-design's gait)")),
        ctx.out / "figures" / "basin_robust", FORMATS)
    _log_basins(ctx, "robust", out["robust"])


def _mc(ctx, gait, spec, st):
    """A Monte Carlo run of the terrain stage (in this process), kept between
    reproductions (:meth:`Context.memo`)."""
    from ..terrain import monte_carlo
    return ctx.memo("monte_carlo", dict(gait=gait.cache_key, spec=repr(spec),
                                        settings=repr(st)),
                    lambda: monte_carlo(gait, spec, st, scheduler="inline"))


#: the two gain sets of the model-error table (Kp, Kd, eps of eq. 13)
TERRAIN_GAINS = ((1.0, 2.0, 0.02), (1.0, 2.0, 0.2))


def stage_terrain(ctx: Context):
    """Beyond the initial push (issue 22), small: the mean first-passage time on
    stochastic terrain against sigma for virtual constraints and the robust design (on
    its gait) and the deadbeat M1 (default gait); the exact gait sensitivity norm and
    its check against the Monte Carlo's step-time RMS at small sigma; the MFPT with the
    torso 20 % heavier than the controller's model for two gain sets."""
    from ..terrain import MonteCarloSettings, WalkerSpec, gait_sensitivity
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
    mfpt_st = {sig: MonteCarloSettings(sigma=sig, runs=runs, max_steps=steps, chunk=runs)
               for sig in sigmas}
    tv = [c for c in cands if c[2].controller == "tv"]       # (the README has the VC's)
    gsn_cands = tv[-1:] if quick else tv
    gsn_st = MonteCarloSettings(sigma=5e-4, runs=runs, max_steps=steps, chunk=runs)

    def sensitivity(gg, spec):
        return ctx.memo("gait_sensitivity", dict(gait=gg.cache_key, spec=repr(spec)),
                        lambda: gait_sensitivity(spec.controller_for(gg),
                                                 SimulationOptions(rk4_steps=400)))
    # a 20 % torso-mass error, two gain sets (the full-order simulator); a few short runs:
    # CasADi's virtual machine is faster than compiling the simulator
    err_label, err_gait, err_spec = cands[1] if rb is not None else cands[0]
    plant = m.description.scaled(torso_mass=1.2).to_dict()
    err_st = MonteCarloSettings(sigma=sigmas[-1], runs=6 if quick else 12, max_steps=steps,
                                chunk=12, compiled=False)
    err_specs = [(gains, pl, WalkerSpec(err_spec.controller, err_spec.M1, err_spec.rejoin,
                                        gains, pl))
                 for gains in TERRAIN_GAINS for pl in (None, plant)]
    # every Monte Carlo first, the helper process from the first and this one from the
    # last (each is kept, and one being computed is waited for): the two meet in between
    jobs = [lambda gg=gg, spec=spec, st=st: _mc(ctx, gg, spec, st)
            for _, gg, spec in cands for st in mfpt_st.values()]
    for _, gg, spec in gsn_cands:
        jobs += [lambda gg=gg, spec=spec: sensitivity(gg, spec),
                 lambda gg=gg, spec=spec: _mc(ctx, gg, spec, gsn_st)]
    jobs += [lambda sp=sp: _mc(ctx, err_gait, sp, err_st) for _, _, sp in err_specs]
    for job in (jobs if ctx.data.get("helper") else jobs[::-1]):
        job()
    curves, rows, survival = {}, [], []
    for label, gg, spec in cands:
        pts = []
        for sig, st in mfpt_st.items():
            r = _mc(ctx, gg, spec, st)
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
    for label, gg, spec in gsn_cands:
        gs = sensitivity(gg, spec)
        st = gsn_st
        mc = _mc(ctx, gg, spec, st)
        pred = predicted_rms(gs.linearisation, st.sigma, steps, st.transient)
        gsn.append(dict(label=label, gsn=gs.gsn, spectral_radius=gs.spectral_radius,
                        sigma=st.sigma, predicted_rms=pred, monte_carlo_rms=mc.step_time_rms,
                        relative_difference=abs(mc.step_time_rms - pred) / pred))
        ctx.log(f"   {label}: GSN (ground, step time) {gs.gsn['ground_height']['step_time']:.4g}"
                f" s/m; step-time RMS at 0.5 mm: predicted {pred:.3g} s, Monte Carlo "
                f"{mc.step_time_rms:.3g} s")
    err = []
    for gains, pl, sp in err_specs:
        r = _mc(ctx, err_gait, sp, err_st)
        e = r.estimate
        err.append(dict(design=err_label, gains=list(gains),
                        torso_mass_error=0.2 if pl else 0.0,
                        sigma=err_st.sigma, mfpt=e.mfpt, mfpt_ci=e.mfpt_ci, failures=e.failures,
                        runs=err_st.runs, max_steps=steps, engine=sp.engine,
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


