"""The docs' benchmarks page, made from the results the benchmark scripts save
(``benchmarks/results/*.json``, written by ``benchmarks/_results.py``): per benchmark,
its date, commit, machine and load, and its figures beside the baseline run with it."""
from __future__ import annotations

import json
import math
from pathlib import Path

__all__ = ["benchmarks_page", "load_results"]

#: the order of the page (others follow by name)
ORDER = ("reproduce", "codesign", "codesign_gaits", "codesign_family", "gait", "family",
         "sweep", "simulate", "robust", "basin", "terrain", "export", "export_running", "mujoco",
         "model")


def load_results(folder: Path) -> list:
    """Every saved result, in :data:`ORDER`."""
    out = []
    for f in sorted(Path(folder).glob("*.json")):
        try:
            out.append(json.loads(f.read_text()))
        except (OSError, ValueError):
            continue
    out = [_adapted(r) for r in out]
    rank = {n: i for i, n in enumerate(ORDER)}
    return sorted(out, key=lambda r: (rank.get(str(r.get("name")).split(" ")[0], len(rank)),
                                      str(r.get("name", ""))))


def _fmt(v, unit=""):
    if v is None:
        return ""
    if isinstance(v, float):
        if not math.isfinite(v):
            return str(v)
        text = f"{v:.4g}"
    else:
        text = str(v)
    return f"{text} {unit}".strip()


def _median(xs):
    xs = sorted(float(x) for x in xs)
    n = len(xs)
    return math.nan if not n else (xs[n // 2] if n % 2 else 0.5 * (xs[n // 2 - 1] + xs[n // 2]))


def _adapted(r: dict) -> dict:
    """The standard form (``name``, ``title``, ``rows``) of results saved in the two
    other forms (bench_export.py and bench_family.py write their own)."""
    if r.get("rows") is not None:
        return r
    if r.get("benchmark") == "export":
        rows = [dict(what=f"one `biped_torque` call in C: {x['name']}", ours=x["c_us_median"],
                     baseline=x["python_us"], unit="us", ratio=x["ratio_python_to_c"],
                     target=f"<= {r.get('target_us', 5):g} us in C")
                for x in r.get("results", [])]
        return dict(r, name="export", title="the exported C controller against the "
                    "Python/CasADi law called one state at a time", rows=rows,
                    commit=r.get("commit", "?"))
    if r.get("benchmark") == "bench_family":
        rows = [dict(what=f"{r.get('robot')} family {r.get('speeds')} ({r.get('n_speeds')} "
                          "gaits): continuation against cold solves, wall (median of rounds)",
                     ours=round(_median(r.get("continuation_wall", [])), 2),
                     baseline=round(_median(r.get("cold_wall", [])), 2), unit="s",
                     ratio=r.get("ratio_median"), target=">= 3x"),
                dict(what="the same, CPU time", ours=round(_median(r.get("continuation_cpu", [])), 2),
                     baseline=round(_median(r.get("cold_cpu", [])), 2), unit="s",
                     ratio=r.get("cpu_ratio_median"), target="")]
        load = dict(before=r.get("loadavg_before"), after=r.get("loadavg_after"))
        return dict(r, name=f"family ({r.get('robot')})", title="a gait family by continuation "
                    "against a cold solve at every speed", rows=rows, load=load,
                    commit=r.get("commit", "?"))
    return r


def _section(r: dict) -> list:
    r = _adapted(r)
    m = r.get("machine", {})
    load = r.get("load", {})
    lines = [f"## {r.get('name')}: {r.get('title', '')}", "",
             f"Measured {r.get('date', '?')} at commit `{r.get('commit', '?')}` on "
             f"{m.get('cpu', m.get('machine', '?'))} ({m.get('affinity', m.get('nproc', m.get('cores', '?')))} "
             f"of {m.get('cores', m.get('nproc', '?'))} cores), "
             f"Python {m.get('python', '?')}, CasADi {m.get('casadi', '?')}; load average "
             f"{_fmt((load.get('before') or [None])[0])} before, "
             f"{_fmt((load.get('after') or [None])[0])} after.", ""]
    rows = r.get("rows") or []
    if rows:
        lines += ["| what | ours | baseline (same run) | ratio | target |",
                  "|---|---|---|---|---|"]
        for row in rows:
            ratio = row.get("ratio")
            lines.append(f"| {row.get('what', '')} | {_fmt(row.get('ours'), row.get('unit', ''))} "
                         f"| {_fmt(row.get('baseline'), row.get('unit', ''))} | "
                         f"{'' if ratio is None else _fmt(ratio) + 'x'} | "
                         f"{row.get('target', '')} |")
        lines.append("")
    for n in r.get("notes") or []:
        lines += [f"- {n}"]
    if r.get("notes"):
        lines.append("")
    return lines


def benchmarks_page(results: Path, page: Path) -> Path:
    """Write the benchmarks page from the saved results (only when it changes).

    Parameters
    ----------
    results : Path
        ``benchmarks/results``.
    page : Path
        The page to write (``docs/benchmarks.md``).

    Returns
    -------
    Path
    """
    lines = ["# Benchmarks", "",
             "Every figure on this page comes from a file the benchmark scripts of "
             "`benchmarks/` saved (`benchmarks/results/*.json`); a baseline is always run "
             "in the same run, side by side, and ratios are baseline / ours (above 1: "
             "ours is faster).  Run one with `python benchmarks/bench_<name>.py`; this page "
             "is made from the saved files when the documentation is built.", ""]
    found = load_results(results)
    if not found:
        lines += ["No saved results yet.", ""]
    for r in found:
        lines += _section(r)
    text = "\n".join(lines)
    if not page.exists() or page.read_text() != text:
        page.write_text(text)
    return page
