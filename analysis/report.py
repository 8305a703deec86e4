"""report.md for ``biped reproduce``: our numbers beside the paper's, figures embedded."""
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
    rows = _comparison_rows(s)
    lines = ["# Reproduction of Wang & Chevallereau, time-varying control of RABBIT", ""]
    g = s.get("gait", {})
    if g:
        lines += [f"Reference gait: T = {_f(g.get('T'))} s, step length "
                  f"{_f(g.get('step_length'))} m, speed {_f(g.get('speed'))} m/s, cost "
                  f"{_f(g.get('cost'))} (∫u'u dt / step length), peak torque "
                  f"{_f(g.get('peak_torque'))} N m; periodicity residual "
                  f"{_f(g.get('periodicity_dq'), '.1e')}.", ""]
    lines += ["## Paper vs. ours", "", "| quantity | paper | ours | why they differ |",
              "|---|---|---|---|"]
    esc = lambda t: str(t).replace("|", "\\|")          # noqa: E731
    lines += [f"| {esc(a)} | {esc(b)} | {esc(c)} | {esc(d)} |" for a, b, c, d in rows]
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
