"""report.md for ``biped reproduce``: our numbers beside the paper's (RABBIT), or the
same analysis's numbers for another robot, figures embedded."""
from __future__ import annotations

from pathlib import Path


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
    try:
        return str(Path(p).resolve().relative_to(out.resolve()))
    except ValueError:
        return str(p)


def _comparison_rows(s: dict) -> list:
    """(quantity, paper, ours, why they differ) rows of the paper-vs-ours table."""
    P = s.get("paper", {})
    rows = []
    ns = "our reference gait is our own optimum (SPEC §2), not the paper's gait from its ref. [6]"
    rows.append(("D11 at T^d", _f(P.get("D11_T")), _f(_g(s, "singular", "D11_T")), ns))
    rows.append(("D12 at T^d", _f(P.get("D12_T")), _f(_g(s, "singular", "D12_T")), ns))
    rows.append(("singular M1(j) = D11/D12(j) (eq. 24)", _f(P.get("singular_values")),
                 _f(_g(s, "singular", "singular_values")), "follows from D at T^d"))
    gc = _g(s, "grid", "counts") or {}
    pc = P.get("grid_counts", {})
    rows.append(("9^4 grid: stable", _f(pc.get("stable")), _f(gc.get("stable")), ns))
    rows.append(("9^4 grid: unstable", _f(pc.get("unstable")), _f(gc.get("unstable")), ns))
    ours_other = None if not gc else gc.get("singular", 0) + gc.get("no_impact", 0)
    rows.append(("9^4 grid: singular / no impact", _f(pc.get("singular_or_no_impact")),
                 f"{_f(ours_other)} ({_f(gc.get('singular'))} singular, "
                 f"{_f(gc.get('no_impact'))} no impact)",
                 "the paper lumps both; we test eq. 24 along the whole step"))
    c = s.get("conjecture", {})
    rows.append(("conjecture: max |Z_sw(T^d)| over stable cases", "~0 (Fig. 3)",
                 _f(c.get("max_abs_zsw_stable")), "Δq_u = 1e-2 as in the paper"))
    rows.append(("... fraction of unstable cases with |Z_sw| at most that", "not given",
                 _f(c.get("fraction_unstable_below")),
                 "a necessary condition, not sufficient: a low fraction supports it"))
    for k in ("1", "2"):
        d = _g(s, "domains", "groups", k) or _g(s, "domains", "groups", int(k)) or {}
        rows.append((f"stable domain, group {k} (area in (M1(2), M1(3)))", "large (Fig. 4)",
                     _f(d.get("stable_area")),
                     f"grid {_f(_g(s, 'domains', 'grid'))}^2 on {_f(_g(s, 'domains', 'range'))}"))
    m = s.get("m1_nlp", {})
    rows.append(("paper's example M1 " + _f(P.get("example_M1")) + ": max|λ|",
                 _f(P.get("example_max_abs")), _f(_g(m, "paper_example_M1", "max_abs")),
                 "the same M1 on another gait"))
    for name, label in (("group1", "group 1"), ("group2", "group 2"), ("free", "all free")):
        r = m.get(name)
        if r:
            rows.append((f"best max|λ|, {label} (M1 NLP)", "not computed",
                         f"{_f(r.get('max_abs'), '.2e')} ± {_f(r.get('eigenvalue_uncertainty'), '.1e')}"
                         f" at M1 = {_f(r.get('M1'), '.4f')}",
                         "deadbeat (max|λ| -> 0) is the limit; ± from a 2x finer map"))
    for k in ("1", "2"):
        d = _g(s, "domains", "groups", k, "best") or {}
        rows.append((f"best point of the group-{k} domain map", "not given",
                     f"{_f(d.get('max_abs'))} at {_f(d.get('M1'), '.4f')}",
                     "the NLP starts from the best points of such maps"))
    rows.append(("best stable point of the 9^4 grid", "not given",
                 f"{_f(_g(s, 'grid', 'best_stable', 'max_abs'))} at "
                 f"{_f(_g(s, 'grid', 'best_stable', 'M1'))}", ""))
    vc = _g(s, "vc_comparison", "vc") or {}
    rows.append(("virtual constraints: eigenvalue of the 1-D map", "not given (slower, Fig. 5)",
                 _f(vc.get("eigenvalue")), "same gait, same model"))
    sim = s.get("simulation", {})
    rows.append(("paper's perturbation (0.01 rad, 0.1 rad/s on every joint), mu = 0.6: "
                 "time-varying run", "walks, converges in ~4 steps",
                 f"{_f(_g(sim, 'paper', 'tv', 'status'))}: {_f(_g(sim, 'paper', 'tv', 'message'))}",
                 "our gait needs much of the friction cone at impact already; see the message"))
    vsteps = _g(sim, "paper", "vc", "steps") or []
    conv = _g(sim, "paper", "vc", "steps_to_converge")
    rows.append(("... virtual-constraint run", "walks, converges more slowly",
                 f"{_f(_g(sim, 'paper', 'vc', 'status'))}, |dq_u error| < 1e-3 "
                 + (f"from step {conv}" if conv else
                    f"not within {len(vsteps)} steps (last {_f(abs(vsteps[-1]['dqu_error']) if vsteps else None, '.2g')})"),
                 f"its eigenvalue {_f(_g(s, 'vc_comparison', 'vc', 'eigenvalue'), '.3g')} sets the rate"))
    fr = _g(sim, "figures_run") or {}
    pert = _f(fr.get("perturbation"))
    rows.append((f"Fig. 5 run (perturbation {pert}): steps until |dq_u error| < 1e-3, "
                 "time-varying", f"~{P.get('tv_convergence_steps')}",
                 _f(_g(fr, "tv", "steps_to_converge")), f"M1 = {_f(fr.get('M1'), '.4f')}"))
    rows.append((f"Fig. 5 run (perturbation {pert}): steps until |dq_u error| < 1e-3, "
                 "virtual constraints", "more than TV", _f(_g(fr, "vc", "steps_to_converge")), ""))
    return rows


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
        The reproduction folder (figures are linked relative to it).
    s : dict
        The summary (JSON types).

    Returns
    -------
    Path
        The report.
    """
    rabbit = "paper" in s
    name = _g(s, "robot", "name", default="RABBIT")
    title = ("# Reproduction of Wang & Chevallereau, time-varying control of RABBIT" if rabbit
             else f"# Wang & Chevallereau's output analysis on {name}")
    lines = [title, ""]
    g = s.get("gait", {})
    if g:
        lines += [f"Reference gait: T = {_f(g.get('T'))} s, step length "
                  f"{_f(g.get('step_length'))} m, speed {_f(g.get('speed'))} m/s, cost "
                  f"{_f(g.get('cost'))} (∫u'u dt / step length), peak torque "
                  f"{_f(g.get('peak_torque'))} N m; periodicity residual "
                  f"{_f(g.get('periodicity_dq'), '.1e')}.", ""]
    esc = lambda t: str(t).replace("|", "\\|")          # noqa: E731
    if rabbit:
        lines += ["## Paper vs. ours", "", "| quantity | paper | ours | why they differ |",
                  "|---|---|---|---|"]
        lines += [f"| {esc(a)} | {esc(b)} | {esc(c)} | {esc(d)} |"
                  for a, b, c, d in _comparison_rows(s)]
    else:
        lines += ["The paper's numbers are RABBIT's; for this robot the same stages give:", "",
                  "## Results", "", "| quantity | ours | note |", "|---|---|---|"]
        lines += [f"| {esc(a)} | {esc(b)} | {esc(c)} |" for a, b, c in _robot_rows(s)]
    lines += ["", "## Stages", "", "| stage | status | time (s) |", "|---|---|---|"]
    for name, st in s.get("stages", {}).items():
        extra = st.get("error") or st.get("reason") or ""
        lines.append(f"| {name} | {st.get('status')} {extra} | {_f(st.get('time'), '.1f')} |")
    lines += ["", "## Figures", ""]
    for key, files in s.get("figures", {}).items():
        files = [files] if isinstance(files, str) else files
        png = [f for f in files if str(f).endswith((".png", ".gif"))]
        for f in png:
            lines.append(f"### {key}\n\n![{key}]({_rel(out, f)})\n")
    lines += ["", f"Total time: {_f(s.get('total_time'), '.0f')} s. Every number above is in "
              "summary.json."]
    path = out / "report.md"
    path.write_text("\n".join(lines) + "\n")
    return path
