"""report.md for ``biped reproduce``: our numbers beside the paper's (RABBIT), or the
same analysis's numbers for another robot, figures embedded."""
from __future__ import annotations

from pathlib import Path

from biped_casadi.files import write_text_atomic

from .plots import COLOUR_NAMES, STANCE, SWING, TORSO


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


GAIT_NOTE = ("Our reference gait is our own optimum (SPEC §2), not the paper's gait (its "
             "ref. [6]); every number marked ¹ depends on the gait and differs for that "
             "reason.")
NLP_NOTE = ("Deadbeat (max|λ| → 0) is the limit of the M1 NLP; ± is the change of max|λ| "
            "with a map of twice the RK4 steps.")
NOT_COMPUTED = "not computed"


def _comparison_rows(s: dict) -> list:
    """(quantity, paper, ours, why they differ) rows of the paper-vs-ours table; each
    explanation is given once (repeated reasons are the notes ¹ and ² under the table)."""
    P = s.get("paper", {})
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
    rows.append(("stable domains of the a = b = 0 groups (area in (M1(2), M1(3)))",
                 "large (Fig. 4)", area, f"¹ ({grid})" if grid else "¹"))
    rows.append(("best points of the two domain maps", "not given", best,
                 "the M1 NLP starts from the best points of such maps"))
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
    sim = s.get("simulation") or {}
    tv = _g(sim, "paper", "tv") or {}
    if tv:
        ours = str(tv.get("status")) + (f": {tv['message']}" if tv.get("message") else "")
        why = ("our gait already needs much of the friction cone at impact (¹)"
               if tv.get("status") != "ok" else "")
    else:
        ours, why = NOT_COMPUTED, ""
    rows.append(("paper's perturbation (0.01 rad, 0.1 rad/s on every joint), mu = 0.6: "
                 "time-varying run", "walks, converges in ~4 steps", ours, why))
    vcr = _g(sim, "paper", "vc") or {}
    if vcr:
        vsteps = vcr.get("steps") or []
        conv = vcr.get("steps_to_converge")
        ours = (f"{_f(vcr.get('status'))}, |dq_u error| < 1e-3 "
                + (f"from step {conv}" if conv else
                   f"not within {len(vsteps)} steps (last "
                   f"{_f(abs(vsteps[-1]['dqu_error']) if vsteps else None, '.2g')})"))
    else:
        ours = NOT_COMPUTED
    rows.append(("... virtual-constraint run", "walks, converges more slowly", ours,
                 f"its eigenvalue {_f(vc.get('eigenvalue'), '.3g')} sets the rate"
                 if vc else ""))
    fr = _g(sim, "figures_run") or {}
    pert = _f(fr.get("perturbation"))
    rows.append((f"Fig. 5 run (perturbation {pert}): steps until |dq_u error| < 1e-3, "
                 "time-varying", f"~{P.get('tv_convergence_steps')}",
                 _f(_g(fr, "tv", "steps_to_converge")) if fr else NOT_COMPUTED,
                 f"M1 = {_f(fr.get('M1'), '.4f')}" if fr else ""))
    rows.append((f"Fig. 5 run (perturbation {pert}): steps until |dq_u error| < 1e-3, "
                 "virtual constraints", "more than TV",
                 _f(_g(fr, "vc", "steps_to_converge")) if fr else NOT_COMPUTED, ""))
    return rows


def _figure_captions(s: dict) -> dict:
    """key -> (title, caption) of every figure a reproduction can make, in report order.
    Colours are named from :data:`analysis.plots.COLOUR_NAMES`, the plots' own."""
    st, sw, to = (COLOUR_NAMES[c] for c in (STANCE, SWING, TORSO))
    pts = _g(s, "fig2", "points_per_component")
    dom = s.get("domains") or {}
    fr = _g(s, "simulation", "figures_run") or {}
    scale = fr.get("scale")
    pert = ("" if not fr else f" from the perturbation {_f(fr.get('perturbation'))} "
            f"(rad, rad/s on every joint" + ("" if scale in (None, 1, 1.0) else
                                            f"; x{_f(scale)} of the paper's") + ")")
    anim = _g(s, "options", "animation_steps")
    grid = f"{_f(_g(s, 'grid', 'n', default=9))}^{_f(_g(s, 'grid', 'dim', default=4))}"
    return {
        "gait_stick": ("Reference gait: one step",
                       f"The optimised reference step (SPEC §2), poses evenly spaced from 0 "
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
        "fig5": ("Fig. 5: error of the unactuated variable",
                 f"q_u - q_u^d(T) and its velocity just before each impact{pert}: the "
                 f"time-varying controller (M1 = {_f(fr.get('M1'), '.4f')}) and virtual "
                 "constraints."),
        "fig6": ("Fig. 6: swing-leg torques",
                 "Swing hip and knee torques of the two runs of Fig. 5 against time; "
                 "dashed: the reference torques u^d."),
        "animation": ("Animation of the time-varying run",
                      f"The time-varying run of Fig. 5 (first {_f(anim)} steps): stance "
                      f"leg {st}, swing leg {sw}, torso {to}, footprints as triangles."),
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
    sim = s.get("simulation", {})
    fr = sim.get("figures_run") or {}
    for ctrl in ("tv", "vc"):
        rows.append((f"simulation (perturbation {_f(fr.get('perturbation'))}), "
                     f"{'time-varying' if ctrl == 'tv' else 'virtual constraints'}",
                     f"{_f(_g(fr, ctrl, 'status'))}, |dq_u error| < 1e-3 from step "
                     f"{_f(_g(fr, ctrl, 'steps_to_converge'))}",
                     _g(fr, ctrl, "message") or ""))
    return rows


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
    lines += ["", "## Stages", "", "| stage | status | time (s) |", "|---|---|---|"]
    for name, st in stages.items():
        extra = st.get("error") or st.get("reason") or ""
        extra = " ".join(str(extra).split())[:300]
        lines.append(f"| {esc(name)} | {esc(st.get('status'))}"
                     + (f": {esc(extra)}" if extra else "")
                     + f" | {_f(st.get('time'), '.1f')} |")
    lines += ["", "## Figures", ""]
    figures = s.get("figures", {})
    captions = _figure_captions(s)
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
