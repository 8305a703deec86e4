"""The docs' benchmarks page, made from the results the benchmark scripts save
(``benchmarks/results/*.json``, written by ``benchmarks/_results.py``): per benchmark,
its date, commit, machine and load, and its figures beside the baseline run with it."""
from __future__ import annotations

import json
import math
from pathlib import Path

__all__ = ["benchmarks_page", "load_results"]

#: the order of the page (others follow by name)
ORDER = ("reproduce", "codesign", "gait", "family", "sweep", "simulate", "robust", "basin",
         "terrain", "export", "model")


def load_results(folder: Path) -> list:
    """Every saved result, in :data:`ORDER`."""
    out = []
    for f in sorted(Path(folder).glob("*.json")):
        try:
            out.append(json.loads(f.read_text()))
        except (OSError, ValueError):
            continue
    rank = {n: i for i, n in enumerate(ORDER)}
    return sorted(out, key=lambda r: (rank.get(r.get("name"), len(rank)), r.get("name", "")))


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


def _section(r: dict) -> list:
    m = r.get("machine", {})
    load = r.get("load", {})
    lines = [f"## {r.get('name')}: {r.get('title', '')}", "",
             f"Measured {r.get('date', '?')} at commit `{r.get('commit', '?')}` on "
             f"{m.get('cpu', '?')} ({m.get('affinity', '?')} of {m.get('cores', '?')} cores), "
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
