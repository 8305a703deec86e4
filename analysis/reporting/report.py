"""report.md for ``biped reproduce``: our numbers beside the paper's (RABBIT), or the
same analysis's numbers for another robot, figures embedded."""
from __future__ import annotations

from pathlib import Path

from biped_casadi.files import write_text_atomic
from biped_casadi.simulation import failure_text

from .in_mujoco import mujoco_caption, mujoco_lines
from .plots import COLOUR_NAMES, OUTCOME_COLOURS, STANCE, SWING, TORSO


def _g(d, *keys, default=None):
    for k in keys:
        if not isinstance(d, dict) or k not in d or d[k] is None:
            return default
        d = d[k]
    return d


def _f(x, fmt=".4g"):
    if x is None:
        return "n/a"
    if isinstance(x, (list, tuple)):
        return "[" + ", ".join(_f(v, fmt) for v in x) + "]"
    if isinstance(x, float):
        return format(x, fmt)
    return str(x)


def _rel(out: Path, p) -> str:
    """A link from the report in ``out`` to ``p`` (already relative: kept)."""
    p = Path(p)
    if not p.is_absolute():
        return p.as_posix()
    try:
        return p.resolve().relative_to(out.resolve()).as_posix()
    except ValueError:
        return str(p)


GAIT_NOTE = ("Our reference gait is our own optimum (docs: theory §2), not the paper's gait (its "
             "ref. [6]); every number marked ¹ depends on the gait and differs for that "
             "reason.")
NLP_NOTE = ("Deadbeat (max|λ| → 0) is the limit of the M1 NLP; ± is the change of max|λ| "
            "with a map of twice the RK4 steps.")
NOT_COMPUTED = "not computed"


def _comparison_rows(s: dict) -> list:
    """(quantity, paper, ours, why they differ) rows of the paper-vs-ours table; each
    explanation is given once (repeated reasons are the notes ¹ and ² under the table)."""
    P = s.get("paper", {})
    rows = _linear_analysis_rows(s, P)
    rows += _domain_rows(s)
    rows += _design_rows(s, P)
    rows += _run_rows(s)
    return rows


def _linear_analysis_rows(s: dict, P: dict) -> list:
    """Rows of D at T^d, the singular M1, the 9^4 grid's counts and the conjecture."""
    rows = []
    sing = s.get("singular") or {}
    rows.append(("D11 at T^d", _f(P.get("D11_T")), _f(sing.get("D11_T", NOT_COMPUTED)), "¹"))
    rows.append(("D12 at T^d", _f(P.get("D12_T")), _f(sing.get("D12_T", NOT_COMPUTED)), "¹"))
    rows.append(("singular M1(j) = D11/D12(j) (eq. 24)", _f(P.get("singular_values")),
                 _f(sing.get("singular_values", NOT_COMPUTED)), "¹ through D at T^d"))
    gc = _g(s, "grid", "counts") or {}
    pc = P.get("grid_counts", {})
    ours = NOT_COMPUTED if not gc else (
        f"{gc.get('stable')} / {gc.get('unstable')} / "
        f"{gc.get('singular', 0) + gc.get('no_impact', 0)} ({gc.get('singular')} singular, "
        f"{gc.get('no_impact')} no impact)")
    rows.append(("9^4 grid: stable / unstable / singular or no impact",
                 f"{pc.get('stable')} / {pc.get('unstable')} / "
                 f"{pc.get('singular_or_no_impact')}", ours,
                 "¹; the paper lumps singular and no impact; we test eq. 24 along the whole "
                 "step"))
    c = s.get("conjecture") or {}
    rows.append(("conjecture: max |Z_sw(T^d)| over stable cases", "~0 (Fig. 3)",
                 _f(c.get("max_abs_zsw_stable", NOT_COMPUTED)), "¹ (Δq_u = 1e-2 as in the paper)"))
    rows.append(("... fraction of unstable cases with |Z_sw| at most that", "not given",
                 _f(c.get("fraction_unstable_below", NOT_COMPUTED)),
                 "a necessary condition, not sufficient: a low fraction supports it"))
    return rows


def _domain_rows(s: dict) -> list:
    """Rows of the a = b = 0 groups' stable domains: their areas and best points."""
    dom = s.get("domains") or {}
    groups = dom.get("groups") or {}
    if groups:
        area = ", ".join(f"group {k}: {_f(_g(groups, k, 'stable_area'))}" for k in ("1", "2"))
        best = "; ".join(f"group {k}: {_f(_g(groups, k, 'best', 'max_abs'))} at "
                         f"{_f(_g(groups, k, 'best', 'M1'), '.4f')}" for k in ("1", "2"))
        grid = f"{_f(dom.get('grid'))}^2 grid on {_f(dom.get('range'))}"
    else:
        area = best = NOT_COMPUTED
        grid = ""
    return [("stable domains of the a = b = 0 groups (area in (M1(2), M1(3)))",
             "large (Fig. 4)", area, f"¹ ({grid})" if grid else "¹"),
            ("best points of the two domain maps", "not given", best,
             "the M1 NLP starts from the best points of such maps")]


def _design_rows(s: dict, P: dict) -> list:
    """Rows of the paper's example M1, the M1 NLP's bests, the grid's best stable point
    and the virtual constraints' eigenvalue."""
    rows = []
    gc = _g(s, "grid", "counts") or {}
    m = s.get("m1_nlp") or {}
    rows.append(("paper's example M1 " + _f(P.get("example_M1")) + ": max|λ|",
                 _f(P.get("example_max_abs")),
                 _f(_g(m, "paper_example_M1", "max_abs", default=NOT_COMPUTED)),
                 "¹ (the same M1 on another gait)"))
    for name, label in (("group1", "group 1"), ("group2", "group 2"), ("free", "all free")):
        r = m.get(name)
        rows.append((f"best max|λ|, {label} (M1 NLP)", "not computed",
                     f"{_f(r.get('max_abs'), '.2e')} ± "
                     f"{_f(r.get('eigenvalue_uncertainty'), '.1e')} at M1 = "
                     f"{_f(r.get('M1'), '.4f')}" if r else NOT_COMPUTED, "²"))
    gb = _g(s, "grid", "best_stable")
    rows.append(("best stable point of the 9^4 grid", "not given",
                 f"{_f(gb.get('max_abs'))} at {_f(gb.get('M1'))}" if gb else
                 ("no stable point" if gc else NOT_COMPUTED), "¹"))
    vc = _g(s, "vc_comparison", "vc") or {}
    rows.append(("virtual constraints: eigenvalue of the 1-D map", "not given (slower, Fig. 5)",
                 _f(vc.get("eigenvalue", NOT_COMPUTED)), "¹"))
    return rows


def _run_rows(s: dict) -> list:
    """Rows of the runs from the paper's perturbation: deadbeat, robust and virtual
    constraints."""
    vc = _g(s, "vc_comparison", "vc") or {}
    runs = _g(s, "simulation", "runs") or {}
    rd = s.get("robust_design") or {}

    def run_text(r):
        if not r:
            return NOT_COMPUTED
        conv = r.get("steps_to_converge")
        return (f"{r.get('status')}" + (f", converged (1e-3) from step {conv}" if conv else "")
                + (f": {r['message']}" if r.get("message") else ""))

    rows = []
    db = runs.get("default_deadbeat")
    rows.append(("paper's perturbation (0.01 rad, 0.1 rad/s on every joint), mu = 0.6: "
                 "time-varying run, the NLP's deadbeat M1", "walks, converges in ~4 steps",
                 run_text(db), "deadbeat outputs are the least robust (s* in the robust-"
                 "walking section)" if db and db.get("status") != "ok" else ""))
    rr = runs.get("robust_design")
    rows.append(("... the robust time-varying design (on its gait)", "(the paper's claim: "
                 "converges in ~4 steps)", run_text(rr),
                 f"s* = {_f(rd.get('s_star'), '.4g')}, max|λ| {_f(rd.get('max_abs'), '.3g')}"
                 if rd and not rd.get("skipped") else ""))
    vr = runs.get("default_vc")
    rows.append(("... virtual-constraint run (default gait)", "walks, converges more slowly",
                 run_text(vr), f"its eigenvalue {_f(vc.get('eigenvalue'), '.3g')} sets the rate"
                 if vc else ""))
    return rows


def _figure_captions(s: dict) -> dict:
    """key -> (title, caption) of every figure a reproduction can make, in report order.
    Colours are named from :data:`analysis.reporting.plots.COLOUR_NAMES`, the plots' own."""
    st, sw, to = (COLOUR_NAMES[c] for c in (STANCE, SWING, TORSO))
    pts = _g(s, "fig2", "points_per_component")
    dom = s.get("domains") or {}
    anim = _g(s, "options", "animation_steps")
    grid = f"{_f(_g(s, 'grid', 'n', default=9))}^{_f(_g(s, 'grid', 'dim', default=4))}"
    return {
        "gait_stick": ("Reference gait: one step",
                       f"The optimised reference step (docs: theory §2), poses evenly spaced from 0 "
                       f"to T, later poses darker: stance leg {st}, swing leg {sw}, torso "
                       f"{to}; dotted: the swing foot's path."),
        "gait_profiles": ("Reference gait: joint angles and torques",
                          "q^d(t) (top) and the torques u^d(t) that realise it (bottom) "
                          "over one step."),
        "fig2": ("Fig. 2: max|λ| against one component of M1",
                 f"max|λ| of A^z with one component of M1 varied ({_f(pts)} values on "
                 "[-10, 10]) and the others zero; red: stable; dashed: the singular value "
                 "of eq. (24), where the controller breaks down."),
        "fig3": ("Fig. 3: the swing-height conjecture",
                 "Swing-foot height Z_sw(T^d) after a perturbation Δq_u = 1e-2 rad against "
                 f"max|λ| over the {grid} grid of M1; red: stable cases, which should all "
                 "have Z_sw(T^d) near 0."),
        "fig4": ("Fig. 4: stable domains of the a = b = 0 groups",
                 f"For each solution group of a = b = 0, log10 max|λ| over (M1(2), M1(3)) "
                 f"({_f(dom.get('grid'))}^2 grid on {_f(dom.get('range'))}); red contour: "
                 "max|λ| = 1; star: the best point."),
        "m1_plane": ("The stable domain of M1 (two torques)",
                     f"log10 max|λ| over the (M1(1), M1(2)) plane ({_f(dom.get('grid'))}^2 "
                     f"grid on {_f(dom.get('range'))}); red contour: max|λ| = 1; orange: "
                     "the solutions of a = b = 0; star: the best point of the map."),
        "fig5_qu_error": ("Fig. 5 at the paper's full perturbation",
                 "q_u - q_u^d(T) and its velocity just before each impact, from the paper's "
                 "perturbation (0.01 rad on every joint, 0.1 rad/s on every velocity) with "
                 "mu = 0.6 and the robot's torque limit: virtual constraints and the deadbeat "
                 "M1 of the NLP on the default gait, virtual constraints and the robust "
                 "design on the robust design's gait; a run that fails ends at its failure "
                 "(legend: status and time). Errors are each run's own reference's."),
        "fig6_swing_torques": ("Fig. 6: swing-leg torques at the paper's full perturbation",
                 "The swing leg's torques of the robust design and of virtual constraints on "
                 "the robust design's gait; dashed: the reference torques u^d of each step."),
        "basin_default": ("Basins of attraction on the default gait",
                          "States on each controller's zero dynamics at the Poincaré section "
                          "(offsets from the fixed point), walked for 10 steps with every "
                          "validity condition checked; coloured by outcome: converged "
                          "(below 1e-3), walked but not converged, or the first failure's "
                          "cause; each on a window grown until it holds the basin's "
                          "boundary (dashed: the fixed window of earlier versions). Left: "
                          "the deadbeat M1; right: virtual constraints."),
        "basin_robust": ("Basins of attraction of the robust designs",
                         "As above, for the co-design NLP (left), the sampling search's "
                         "design (middle, on its gait) and virtual constraints (right, on "
                         "the co-design's gait)."),
        "tradeoff": ("Robustness against the linear convergence rate",
                     "s* (the largest scale of the paper's perturbation survived from every "
                     "kept direction, converging below 1e-3 in 10 steps) against max|λ| of "
                     "A^z: the NLP solved with max|λ| bounded at 1/4 to 1 times the "
                     "virtual constraints' eigenvalue (each design's s* verified by the "
                     "walker; full run), the co-design, the sampling search's design and "
                     "virtual constraints marked; dotted: the eigenvalue bound (the virtual constraints' "
                     "eigenvalue); dashed: the paper's perturbation."),
        "terrain_mfpt": ("Mean first-passage time on stochastic terrain",
                         "The mean number of steps walked before the first failure (every "
                         "step checked: contact, friction incl. the impact impulse, scuffing, "
                         "torque limit) against the standard deviation of the ground height "
                         "per step, with 95 % intervals from the censored per-step failure "
                         "probability; triangles: no run failed (the lower bound)."),
        "terrain_survival": ("Survival on stochastic terrain",
                             "The fraction of runs that walked at least k steps, at the "
                             "largest sigma of the figure above."),
        "walk_tv": ("Animation of the robust design's run",
                      f"The robust design's run of Fig. 5 (first {_f(anim)} steps): stance "
                      f"leg {st}, swing leg {sw}, torso {to}, footprints as triangles."),
    } | _SPEED_CAPTIONS


#: the captions of the study of speed
_SPEED_CAPTIONS = {
    "family": ("The co-design's M1 and virtual constraints over a gait family",
               "max|λ| of the restricted Poincaré map (virtual constraints: the eigenvalue's "
               "modulus) and s* against speed, on the family's members (the robust gait's "
               "options); one M1 at every speed."),
    "speed_ramp": ("A speed ramp in full order",
                   "Top: the speed of each step's gait (the reference switches gait at each "
                   "impact; gaits between the members are the family's interpolant polished "
                   "to an exact orbit).  Bottom: each step's error against its own gait "
                   "before impact; a cross marks a failed step."),
}


def _robot_rows(s: dict) -> list:
    """(quantity, ours, note) rows for a robot other than RABBIT (the paper's numbers are
    RABBIT's, so there is nothing to set beside them)."""
    rows = []
    r = s.get("robot", {})
    rows.append(("robot", f"{r.get('name')}: {r.get('nq')} joints, {r.get('nu')} torques, "
                 f"{_f(r.get('total_mass'))} kg", ", ".join(r.get("joints", []))))
    sg = s.get("singular", {})
    rows.append(("D11, D12 at T^d", f"{_f(sg.get('D11_T'))}, {_f(sg.get('D12_T'))}", ""))
    rows.append(("singular M1(j) = D11/D12(j) (eq. 24)", _f(sg.get("singular_values")),
                 "one component non-zero"))
    f2 = s.get("fig2", {})
    rows.append(("1-D sweeps: stable points per component",
                 _f(f2.get("stable_per_component")),
                 f"{_f(f2.get('points_per_component'))} values of each M1(j) on [-10, 10]"))
    for j, b in enumerate(f2.get("best_per_component") or [], start=1):
        if b:
            rows.append((f"1-D sweep of M1({j}): best", f"{_f(b.get('max_abs'))} at "
                         f"{_f(b.get('M1'), '.4g')}", ""))
    gr = s.get("grid", {})
    gc = gr.get("counts") or {}
    rows.append((f"M1 grid {_f(gr.get('n'))}^{_f(gr.get('dim'))} on [-10, 10]: stable / "
                 "unstable / singular / no impact",
                 " / ".join(_f(gc.get(k)) for k in ("stable", "unstable", "singular", "no_impact")),
                 f"best stable {_f(_g(gr, 'best_stable', 'max_abs'))} at "
                 f"{_f(_g(gr, 'best_stable', 'M1'), '.4g')}"))
    dm = s.get("domains", {})
    if dm.get("plane"):
        rows.append(("stable domain in the (M1(1), M1(2)) plane: area", _f(dm.get("stable_area")),
                     f"{_f(dm.get('stable_points'))} stable points of {_f(dm.get('grid'))}^2"))
        ab = dm.get("ab_set") or {}
        rows.append(("solutions of a = b = 0 (eq. 28)", ab.get("kind", "n/a"),
                     ab.get("message", "")))
        on = dm.get("ab_set_on_map") or {}
        if on:
            rows.append(("... of them inside [-10, 10]^2: stable", f"{_f(on.get('stable'))} of "
                         f"{_f(on.get('points'))}",
                         f"best {_f(_g(on, 'best', 'max_abs'))} at {_f(_g(on, 'best', 'M1'), '.4g')}"))
    elif dm.get("skipped"):
        rows.append(("stable domains of the a = b = 0 groups", "not drawn", dm["skipped"]))
    c = s.get("conjecture", {})
    rows.append(("conjecture: max |Z_sw(T^d)| over stable grid cases",
                 _f(c.get("max_abs_zsw_stable")),
                 f"median over unstable {_f(c.get('median_abs_zsw_unstable'))}; fraction of "
                 f"unstable at most the stable max {_f(c.get('fraction_unstable_below'))}"))
    for name, r in (s.get("m1_nlp") or {}).items():
        if isinstance(r, dict) and "max_abs" in r:
            rows.append((f"M1 NLP, {name.replace('_', ' ')}",
                         f"{_f(r.get('max_abs'), '.3e')} ± {_f(r.get('eigenvalue_uncertainty'), '.1e')}",
                         f"M1 = {_f(r.get('M1'), '.5g')}, status {r.get('status')}"))
    vc = _g(s, "vc_comparison", "vc") or {}
    tvc = _g(s, "vc_comparison", "tv_chosen") or {}
    rows.append(("virtual constraints: eigenvalue of the 1-D map", _f(vc.get("eigenvalue")),
                 f"phase = the stance-foot-to-hip angle; time-varying with the chosen M1: "
                 f"max|λ| {_f(tvc.get('max_abs'), '.3e')}"))
    rows.append(("time-varying, M1 = 0", _f(_g(s, "vc_comparison", "tv_M1_zero", "max_abs")),
                 _g(s, "vc_comparison", "tv_M1_zero", "status") or ""))
    for r in (_g(s, "simulation", "runs") or {}).values():
        conv = r.get("steps_to_converge")
        rows.append((f"the paper's perturbation, {r.get('label')}",
                     f"{r.get('status')}" + (f", below 1e-3 from step {conv}" if conv else ""),
                     r.get("message") or ""))
    return rows


def _terrain_lines(s: dict) -> list:
    """The section on uneven ground and model error (issue 22)."""
    t = s.get("terrain") or {}
    if not t:
        return []
    esc = lambda v: str(v).replace("|", "\\|")                              # noqa: E731

    def mf(r):
        lo, hi = r.get("mfpt_ci") or (None, None)
        v = r.get("mfpt")
        head = _f(v, ".3g") if v is not None else f"> {_f(lo, '.3g')}"
        return f"{head} [{_f(lo, '.3g')}, {_f(hi, '.3g') if hi is not None else 'inf'}]"

    lines = ["## Uneven ground and model error", "",
             f"Mean first-passage time (MFPT, steps walked before the first failure, 95 % "
             f"interval; {t.get('runs')} runs of up to {t.get('max_steps')} steps each, ground "
             f"heights i.i.d. N(0, sigma^2) per step):", "",
             "| controller | " + " | ".join(f"sigma {1000 * v:g} mm" for v in t["sigmas"]) + " |",
             "|---|" + "---|" * len(t["sigmas"])]
    by = {}
    for r in t.get("mfpt", []):
        by.setdefault(r["label"], {})[r["sigma"]] = r
    for label, d in by.items():
        lines.append(f"| {esc(label)} | " + " | ".join(mf(d[v]) if v in d else "" for v in
                                                       t["sigmas"]) + " |")
    if t.get("gsn"):
        lines += ["", "Exact gait sensitivity norm (AD of the full-order step map) and the "
                      "step-time RMS it predicts against the Monte Carlo's:", "",
                  "| controller | GSN ground height: step time (s/m), step length (m/m) | "
                  "GSN torso push (per N s) | RMS at 0.5 mm: predicted, Monte Carlo |",
                  "|---|---|---|---|"]
        for r in t["gsn"]:
            gh, tp = r["gsn"]["ground_height"], r["gsn"]["torso_push"]
            lines.append(f"| {esc(r['label'])} | {_f(gh['step_time'], '.4g')}, "
                         f"{_f(gh['step_length'], '.4g')} | {_f(tp['total'], '.4g')} | "
                         f"{_f(r['predicted_rms'], '.3g')} s, {_f(r['monte_carlo_rms'], '.3g')} "
                         f"s ({_f(100 * r['relative_difference'], '.2g')} %) |")
    if t.get("model_error"):
        lines += _model_error_lines(t["model_error"], mf, esc)
    return lines + [""]


def _family_lines(s: dict) -> list:
    """The small study of speed: the gait family and the designs on it."""
    f = s.get("family") or {}
    recs = f.get("records") or []
    if not recs:
        return []
    labels = list(dict.fromkeys(k for r in recs for k in r["designs"]))
    lines = ["## Walking at other speeds", "",
             f"A gait family with the robust gait's options ({f.get('message', '')}); at each "
             f"speed, s* and max|λ| of the co-design's M1 (one M1 for all speeds, v_c "
             f"rejoining at {_f(f.get('rejoin'))} T) and of virtual constraints fitted to "
             "that speed's gait.  The co-design at each speed, an M1 scheduled over "
             "speed, and speed changes: `biped m1 --robust --gait FAMILY.json` and `biped "
             "simulate --gait FAMILY.json --speeds ...`.", "",
             "| speed (m/s) | " + " | ".join(f"{k}: s*, max\\|λ\\|" for k in labels) + " |",
             "|---|" + "---|" * len(labels)]
    for r in recs:
        lines.append(f"| {_f(r['speed'], '.3g')} | " + " | ".join(
            f"{_f(r['designs'][k]['s_star'], '.3g')}, {_f(r['designs'][k]['max_abs'], '.3g')}"
            if k in r["designs"] else "" for k in labels) + " |")
    rp = f.get("ramp") or {}
    if rp.get("runs"):
        lines += ["", f"A ramp {_f(rp['v1'], 'g')} -> {_f(rp['v2'], 'g')} -> "
                      f"{_f(rp['v1'], 'g')} m/s by {_f(rp['dv'], 'g')} m/s per step, then "
                      f"{_f(rp['hold'], 'd')} steps at {_f(rp['v1'], 'g')} m/s, in full order "
                      f"(mu = {_f(rp['mu'], 'g')}, |u| <= {_f(rp['torque_limit'], 'g')} N m):",
                  "", "| controller | status | steps walked | largest error | error at the end "
                      "| peak torque (N m) | friction margin |", "|---|---|---|---|---|---|---|"]
        for k, r in rp["runs"].items():
            lines.append(f"| {k} | {r['status']} | {r['steps']} of {r['planned']} | "
                         f"{_f(r['largest_error'], '.3g')} | {_f(r['last_error'], '.2g')} | "
                         f"{_f(r['peak_torque'], '.1f')} | {_f(r['friction_margin'], '.3f')} |")
    return lines + [""]


def _model_error_lines(rows: list, mf, esc) -> list:
    """The model-error table, and whether its gain sets separate."""
    lines = ["", "MFPT with the torso heavier than the controller's model (the full-order "
                 "simulator; without an error the closed loop is its zero dynamics and the "
                 "gains change nothing), and the RMS of the step time about its mean, which "
                 "the gains move even where the failures do not:", "",
             "| design | gains (Kp, Kd, eps) | torso error | sigma (mm) | MFPT | failures / "
             "runs | step-time RMS (s) |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {esc(r['design'])} | {r['gains']} | "
                     f"{100 * r['torso_mass_error']:g} % | {1000 * r['sigma']:g} | {mf(r)} | "
                     f"{r['failures']} / {r['runs']} | {_f(r.get('step_time_rms'), '.3g')} |")
    by = {}
    for r in rows:
        by.setdefault((r["torso_mass_error"], r["sigma"]), []).append(r)
    for (err, sig), rs in sorted(by.items()):
        if err == 0 or len(rs) < 2:
            continue
        same = len({(tuple(r.get("failed_runs") or []), tuple(r.get("steps_walked") or []))
                    for r in rs}) == 1
        if not same:
            continue
        what = (f"With the torso {100 * err:g} % heavier at sigma = {1000 * sig:g} mm ")
        rms = ("their step times (RMS column) do differ." if len(
            {round(r.get("step_time_rms") or 0.0, 6) for r in rs}) > 1
            else "nor do their step times.")
        if any(r.get("failures") for r in rs):
            lines += ["", what + "both gain sets lose the same runs at the same steps: "
                      "those failures come from the ground (large steps down), not from the "
                      "model error, so their MFPT cannot separate the gains; " + rms]
        else:
            lines += ["", what + "neither gain set loses a run, so their MFPT is a lower "
                      "bound for both and cannot separate them; " + rms]
    return lines


def _comparison_lines(s: dict) -> list:
    """The co-design NLP, the sampling search's design and virtual constraints side by
    side: s*, steps to converge, max|λ|, basin fraction and peak torque."""
    rob = (s.get("robustness") or {}).get("rows", [])
    runs = (s.get("simulation") or {}).get("runs", {})
    bas = s.get("basins") or {}
    fr = dict(zip(bas.get("robust_labels", []), bas.get("robust", [])))
    rows = [("robust design (co-design NLP)", "robust", "robust_design"),
            ("the sampling search's design", None, "search_design"),
            ("virtual constraints", "robust", "robust_vc")]
    out = ["| design | gait | s* | paper's perturbation: below 1e-3 from step | "
           "max\\|λ\\| | basin area (rad x rad/s) | peak \\|u\\| (N m) |",
           "|---|---|---|---|---|---|---|"]
    for label, gait, run in rows:
        r = next((x for x in rob if x.get("label") == label
                  and (gait is None or x.get("gait") == gait)), None)
        if r is None:
            continue
        sim = runs.get(run) or {}
        b = fr.get(label) or {}
        area = "" if b.get("area") is None else _f(b.get("area"), ".3g")
        out.append(f"| {label} | {r.get('gait')} | {_f(r.get('s_star'), '.4g')} | "
                   f"{_f(sim.get('steps_to_converge'))} | {_f(r.get('max_abs'), '.3g')} | "
                   f"{area} | {_f(sim.get('peak_torque'), '.1f')} |")
    if len(out) == 2:
        return []
    st = (s.get("robustness") or {}).get("settings") or {}
    return ["The designs compared (s* as in the s* table below: the walker's bisection "
            f"over its {st.get('directions', '')} kept directions, {st.get('rounds', '')} "
            "rounds; the paper's perturbation in full order; the basin's converged area on "
            "the Poincaré section, on a window grown until it holds the basin's "
            "boundary):", ""] \
        + out + [""]


def _robust_lines(s: dict) -> list:
    """The section on robust walking: the finding, the s* table, the runs' margins."""
    rd = s.get("robust_design") or {}
    rob = (s.get("robustness") or {}).get("rows", [])
    runs = (s.get("simulation") or {}).get("runs", {})
    if not (rd or rob or runs):
        return []
    lines = ["## Robust walking: which time-varying designs walk", ""]
    if rd.get("skipped"):
        lines += [f"Robust design: not run ({rd['skipped']}).", ""]
    elif rd:
        lines += _robust_design_lines(rd, (s.get("replay") or {}).get(
            "the robust co-design, its gait", {}).get("simulate_args") or [])
        lines += _comparison_lines(s)
    if rob:
        lines += _robustness_table(s, rob)
    if runs:
        lines += _runs_table(runs)
    return lines


def _esc(t) -> str:
    """A table cell: its pipes escaped, on one line."""
    return str(t).replace("|", "\\|").replace("\n", " ")


def _replay_lines(s: dict) -> list:
    """How to replay each design of the run in full order (the gait files beside the
    report)."""
    replay = s.get("replay") or {}
    if not replay:
        return []
    return ["## Replay a design", "",
            "Each design from the paper's perturbation in the full-order simulator (the gait "
            "files are beside this report; run from this folder):", ""] + [
        f"- {label}: `biped simulate {' '.join(r.get('simulate_args', []))}`"
        for label, r in replay.items()] + [""]


def _robust_design_lines(rd: dict, replay: list = ()) -> list:
    """The robust design's finding, the design and its full-order check, what binds
    (``replay``: the simulate arguments when the design has none of its own)."""
    args = rd.get("simulate_args") or list(replay)
    solves = _g(rd, "ipopt", "solves") or []
    seconds = _g(rd, "ipopt", "time")
    if seconds is None and solves and all(x.get("time") is not None for x in solves):
        seconds = sum(x["time"] for x in solves)
    met = rd.get("status") == "target_met"
    lines = [
        "The paper's linear analysis recommends deadbeat outputs (max|λ| -> 0). From the "
        "paper's own perturbation (0.01 rad on every joint, 0.1 rad/s on every velocity, "
        "mu = 0.6, |u| <= the torque limit) they do not walk on our gait: the table below "
        "gives s*, the largest scale of that perturbation every kept direction survives "
        "(10 valid steps, error below 1e-3 at the end). The robust design comes from "
        "one NLP (CasADi + IPOPT, exact first derivatives): perturbation scenarios of "
        "the paper's per-joint sizes walk several steps of the closed-loop hybrid zero "
        "dynamics by the walker's own RK4 rule, every contact, friction, impulse, torque "
        "and clearance condition a smooth inequality, with their common scale s "
        "maximised and max|λ| <= the virtual constraints' eigenvalue; "
        + ("the gait's own Bezier coefficients and T move with M1 (trust-region steps, "
           "each gait made exactly periodic). " if rd.get("gait_free") else
           "the gait is fixed (quick run; the full run co-designs it). ")
        + ("It meets the target." if met else
           f"It does not reach the paper's claim: best s* = {_f(rd.get('s_star'), '.4g')} "
           f"(the paper's perturbation is s = 1); just above s* the binding failure is "
           f"'{rd.get('failure')}'; from the paper's perturbation it walks and converges "
           f"below 1e-3 from step {_f(rd.get('steps_to_converge'))} (the paper: step 4)."),
        "",
        f"Robust design: M1 = {_f(_g(rd, 'design', 'M1'), '.5g')}, v_c rejoining at "
        f"{_f(_g(rd, 'design', 'rejoin'))} T; its gait (T = "
        f"{_f(_g(rd, 'gait_change', 'T'), '.4g')} s, from "
        f"{_f(_g(rd, 'gait_change', 'T_start'), '.4g')} s) bounds the impact impulse ratio "
        f"|F_x|/F_z by {rd.get('gait_options', {}).get('impact_mu')} and continues the "
        f"reference past T ({rd.get('gait_options', {}).get('continuation')}); "
        f"max|λ| {_f(rd.get('max_abs'), '.3g')} against the virtual constraints' "
        f"{_f(rd.get('vc_eigenvalue'), '.3g')} on that gait. Full-order check: "
        + "; ".join(f"{k.replace('_', ' ')} (s = {_f(v.get('scale'), '.4g')}) {v.get('passed')} "
                    f"of {len(v.get('outcomes', []))} directions walk and converge"
                    for k, v in (rd.get("verified") or {}).items())
        + (f". Replay: `biped simulate {' '.join(args)}`." if args else "."), ""]
    act = rd.get("active_constraints") or []
    if act:
        lines += ["What binds at the optimum (the inequalities with the largest "
                  "multipliers): " + "; ".join(
                      f"{a['constraint']} ({_f(a['multiplier'], '.3g')})"
                      for a in act[:4]) + ". IPOPT: "
                  f"{len(solves)} solves, {_g(rd, 'ipopt', 'iterations')} iterations"
                  + (f", {_f(seconds, '.1f')} s." if seconds is not None else "."), ""]
    return lines


def _robustness_table(s: dict, rob: list) -> list:
    """The s* table of the designs, and how its directions were chosen."""
    st = (s.get("robustness") or {}).get("settings") or {}
    res_note = (f" s* by bisection to {_f(st['s_max'] / 2 ** (st['rounds'] - 1), '.3g')} "
                "(the co-design's own verification above: 16 directions, 10 rounds)."
                if "s_max" in st and "rounds" in st else "")
    lines = ["| design | gait | max\\|λ\\| | s* | first failure just above s* | "
             "directions kept |", "|---|---|---|---|---|---|"]
    for r in rob:
        f = r.get("failure") or {}
        fail = (f"{failure_text(f.get('status'), f.get('step'))} (direction "
                f"{f.get('direction')}) at s = {_f(r.get('s_fail'), '.4g')}" if f else
                "none up to the largest scale tried")
        lines.append(f"| {_esc(r.get('label'))} | {r.get('gait')} | "
                     f"{_f(r.get('max_abs'), '.3g')} | {_f(r.get('s_star'), '.4g')} | "
                     f"{_esc(fail)} | {r.get('directions_kept')} of "
                     f"{r.get('directions_tried')} |")
    lines += ["", "Directions: the paper's (all positive) and seeded sign patterns / "
              "random directions of the same per-joint size, kept only when virtual "
              "constraints walk from them at full scale (the others start with the "
              "swing foot in the ground). Both controllers run on their exact hybrid zero "
              "dynamics, batched (time-varying designs: the zero-dynamics walker; virtual "
              "constraints: the phase walker, whose pass/fail verdicts equal the "
              "full-order simulator's on the tested directions)." + res_note, ""]
    return lines


def _runs_table(runs: dict) -> list:
    """The runs from the paper's full perturbation with their validity margins, and what
    their statuses mean."""
    lines = ["Runs from the paper's full perturbation (Fig. 5), with their validity "
             "margins:", "", "| run | status | steps | converged (1e-3) from step | "
             "peak \\|u\\| (N m) | min F_z (N) | max \\|F_x\\|/F_z | max impulse ratio |",
             "|---|---|---|---|---|---|---|---|"]
    for r in runs.values():
        lines.append(f"| {_esc(r.get('label'))} | {_esc(r.get('status'))} | {r.get('steps')} "
                     f"| {_f(r.get('steps_to_converge'))} | {_f(r.get('peak_torque'), '.1f')} "
                     f"| {_f(r.get('min_normal_force'), '.1f')} | "
                     f"{_f(r.get('max_friction_ratio'), '.3f')} | "
                     f"{_f(r.get('max_impulse_ratio'), '.3f')} |")
    seen = sorted({r.get("status") for r in runs.values()} & set(OUTCOME_COLOURS))
    if seen:
        meaning = {k: OUTCOME_COLOURS[k][1] for k in seen}
        if "slipped" in meaning:
            meaning["slipped"] = ("the stance force or the impact impulse left the "
                                  "friction cone |F_x| <= mu F_z")
        lines += ["", "Statuses: " + "; ".join(f"{k}: {v}" for k, v in meaning.items())
                  + "; every run stops at its first invalid state."]
    lines.append("")
    return lines


def write_report(out: Path, s: dict) -> Path:
    """Write ``report.md`` into ``out`` from the summary ``s`` of :func:`reproduce`.

    Parameters
    ----------
    out : Path
        The folder the report goes into; figure paths in ``s`` are relative to it.
    s : dict
        The summary (JSON types).

    Returns
    -------
    Path
        The report (written through a temporary file).
    """
    esc = lambda t: str(t).replace("|", "\\|").replace("\n", " ")          # noqa: E731
    stages = s.get("stages", {})
    bad = [k for k, v in stages.items() if v.get("status") != "ok"]
    o = s.get("options") or {}
    mode = s.get("mode", "full")
    rabbit = "paper" in s
    name = _g(s, "robot", "name", default="RABBIT")
    title = ("# Reproduction of Wang & Chevallereau, time-varying control of RABBIT" if rabbit
             else f"# Wang & Chevallereau's output analysis on {name}")
    lines = [title, ""]
    head = (f"**{'Quick' if mode == 'quick' else 'Full'} run**"
            + (" (coarser grids than the paper's; a full run goes to the parent folder)"
               if mode == "quick" else "")
            + f": {_f(o.get('line_points'))} points per component for Fig. 2, "
            + (f"{_f(o.get('domain_n'))}^2 domain grids for Fig. 4, " if rabbit else "")
            + f"{_f(o.get('nlp_starts'))} starts for the M1 NLP, {_f(o.get('sim_steps'))} "
            f"simulated steps; finished {s.get('finished', '')} in "
            f"{_f(s.get('total_time'), '.0f')} s; "
            + ("every stage ok." if not bad else
               f"{len(bad)} of {len(stages)} stages not ok (see Stages)."))
    lines += [head, ""]
    g = s.get("gait", {})
    if g:
        lines += [f"Reference gait: T = {_f(g.get('T'))} s, step length "
                  f"{_f(g.get('step_length'))} m, speed {_f(g.get('speed'))} m/s, cost "
                  f"{_f(g.get('cost'))} (∫u'u dt / step length), peak torque "
                  f"{_f(g.get('peak_torque'))} N m; periodicity residual "
                  f"{_f(g.get('periodicity_dq'), '.1e')} (gait.json).", ""]
    if rabbit:
        lines += ["## Paper vs. ours", "", "| quantity | paper | ours | why they differ |",
                  "|---|---|---|---|"]
        lines += [f"| {esc(a)} | {esc(b)} | {esc(c)} | {esc(d)} |"
                  for a, b, c, d in _comparison_rows(s)]
        lines += ["", f"¹ {GAIT_NOTE}", "", f"² {NLP_NOTE}"]
    else:
        lines += ["The paper's numbers are RABBIT's; for this robot the same stages give:", "",
                  "## Results", "", "| quantity | ours | note |", "|---|---|---|"]
        lines += [f"| {esc(a)} | {esc(b)} | {esc(c)} |" for a, b, c in _robot_rows(s)]
    lines += [""] + _robust_lines(s) + _terrain_lines(s) + _family_lines(s) + mujoco_lines(s) \
        + _replay_lines(s)
    cp = s.get("critical_path") or {}
    lines += ["## Stages", "", "Each stage is a flow of tasks; every result is kept in the "
              "cache folder by its inputs and the version of the numerical code.  Computed: "
              "tasks run by this run; reused: read from the cache; work: the computed "
              "tasks' seconds (several run at once)."
              + (f"  The longest chain of computed tasks took {_f(cp.get('seconds'), '.1f')} "
                 "s: the run's bound on any number of workers." if cp.get("tasks") else ""),
              "", "| stage | status | computed | reused | work (s) |", "|---|---|---|---|---|"]
    for name, st in stages.items():
        extra = st.get("error") or st.get("reason") or ""
        extra = " ".join(str(extra).split())[:300]
        lines.append(f"| {esc(name)} | {esc(st.get('status'))}"
                     + (f": {esc(extra)}" if extra else "")
                     + f" | {_f(st.get('computed'), 'd')} | {_f(st.get('reused'), 'd')} | "
                     f"{_f(st.get('time'), '.1f')} |")
    lines += ["", "## Figures", ""]
    figures = s.get("figures", {})
    captions = _figure_captions(s) | mujoco_caption(s)
    for key in [k for k in captions if k in figures] + [k for k in figures if k not in captions]:
        files = figures[key]
        files = [files] if isinstance(files, str) else files
        title, caption = captions.get(key, (key, ""))
        shown = [f for f in files if str(f).endswith((".png", ".gif"))]
        other = [f for f in files if f not in shown]
        lines.append(f"### {title}\n")
        lines += [f"![{title}]({_rel(out, f)})\n" for f in shown]
        lines.append(caption + ("" if not other else " Also as " + ", ".join(
            f"[{Path(f).suffix[1:].upper()}]({_rel(out, f)})" for f in other) + ".") + "\n")
    lines += ["", "Every number above is in summary.json."]
    path = out / "report.md"
    write_text_atomic(path, "\n".join(lines) + "\n")
    return path
