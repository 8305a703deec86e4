"""The main job, timed cold: ``biped reproduce`` and ``biped reproduce --quick``, each in a
fresh process with an empty ``BIPED_CACHE_DIR`` and a fresh output folder, against a
baseline checkout run in turn with it (pair by pair, the order alternating), then a
warm re-run of each; and how the wall time falls with the workers of the local cluster,
beside the graph's critical path (the bound for any number of workers).

    python benchmarks/bench_reproduce.py --baseline ../old/.venv/bin/python
    python benchmarks/bench_reproduce.py --quick --rounds 1      # the quick run only
    python benchmarks/bench_reproduce.py --workers 1 2            # the scaling only

``--baseline PYTHON``: the interpreter of an installed baseline checkout (another
version of the toolkit); without it only this version runs.  Results are saved in
benchmarks/results/reproduce.json (the docs' benchmarks page is made from it).
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import Run  # noqa: E402


def run(python: str, out: Path, cache: Path, quick: bool, workers=None) -> dict:
    """One ``biped reproduce`` in a fresh process; its wall time and its summary."""
    env = dict(os.environ, BIPED_CACHE_DIR=str(cache), MPLBACKEND="Agg")
    env.pop("BIPED_SCHEDULER", None)
    cmd = [python, "-m", "analysis.cli", "reproduce", "--out", str(out), "--no-progress"] \
        + (["--quick"] if quick else []) + ([] if workers is None else
                                            ["--workers", str(workers)])
    out.parent.mkdir(parents=True, exist_ok=True)   # the run's folder, outside any checkout
    load0 = os.getloadavg()[0]
    t = time.perf_counter()
    p = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=out.parent)
    wall = time.perf_counter() - t
    folder = out / "quick" if quick else out
    summary = json.loads((folder / "summary.json").read_text()) \
        if (folder / "summary.json").is_file() else {}
    stages = summary.get("stages", {})
    return dict(rc=p.returncode, wall=wall, load_before=load0, load_after=os.getloadavg()[0],
                ok=all(v.get("status") == "ok" for v in stages.values()) and bool(stages),
                critical_path=(summary.get("critical_path") or {}).get("seconds"),
                computed=sum(v.get("computed", 0) for v in stages.values()),
                stderr=p.stderr[-1500:])


def _show(label, r):
    cp = f", critical path {r['critical_path']:.1f} s" if r.get("critical_path") else ""
    print(f"  {label:34s} wall {r['wall']:7.1f} s, exit {r['rc']}, stages ok {r['ok']}, "
          f"load {r['load_before']:.2f} -> {r['load_after']:.2f}{cp}", flush=True)
    if r["rc"] != 0:
        print("    " + r["stderr"].replace("\n", "\n    "))


def side_by_side(bench: Run, tmp: Path, quick: bool, rounds: int, baseline):
    """Cold runs of both versions in turn, then warm re-runs."""
    name = "quick" if quick else "full"
    impls = [("this version", sys.executable)] + ([("baseline", baseline)] if baseline else [])
    walls = {k: [] for k, _ in impls}
    for i in range(rounds):
        for label, py in (impls if i % 2 == 0 else impls[::-1]):
            d = tmp / f"{name}-{label.replace(' ', '_')}-{i}"
            r = run(py, d / "out", d / "cache", quick)
            _show(f"{name} cold, {label}", r)
            if r["rc"] == 0:
                walls[label].append(r["wall"])
            if i == rounds - 1:
                w = run(py, d / "out", d / "cache", quick)
                _show(f"{name} warm, {label}", w)
                bench.row(f"`biped reproduce{' --quick' if quick else ''}` warm re-run, "
                          f"{label}", round(w["wall"], 1),
                          target="<= 10 s" if label == "this version" else "")
            shutil.rmtree(d, ignore_errors=True)
    ours = walls["this version"]
    base = walls.get("baseline", [])
    bench.data[name] = walls
    if ours:
        pairs = [b / o for o, b in zip(ours, base)]
        bench.row(f"`biped reproduce{' --quick' if quick else ''}` cold (median of "
                  f"{len(ours)})", round(statistics.median(ours), 1),
                  round(statistics.median(base), 1) if base else None,
                  ratio=round(statistics.median(pairs), 3) if pairs else None,
                  target=("<= 60 s" if quick else "<= 180 s")
                  + ("; baseline / ours >= 1" if base else ""))
        if pairs:
            bench.note(f"{name}: wall ratio baseline / this version pair by pair "
                       + ", ".join(f"{p:.3f}" for p in pairs))


def scaling(bench: Run, tmp: Path, workers: list, quick: bool):
    name = "quick" if quick else "full"
    for n in workers:
        d = tmp / f"scale-{n}"
        r = run(sys.executable, d / "out", d / "cache", quick, workers=n)
        _show(f"{name} cold, --workers {n}", r)
        bench.row(f"`biped reproduce{' --quick' if quick else ''} --workers {n}` cold",
                  round(r["wall"], 1), target="falls with workers")
        if r.get("critical_path"):
            bench.row(f"its critical path (--workers {n})", round(r["critical_path"], 1),
                      target="the wall time's bound on any number of workers")
        shutil.rmtree(d, ignore_errors=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", metavar="PYTHON",
                    help="interpreter of an installed baseline version, run in turn")
    ap.add_argument("--quick", action="store_true", help="the quick run only")
    ap.add_argument("--rounds", type=int, default=3, help="cold runs of each (default 3)")
    ap.add_argument("--workers", type=int, nargs="*", default=None,
                    help="also cold runs with these local-cluster sizes (e.g. 1 2)")
    ap.add_argument("--scaling-only", action="store_true",
                    help="only the --workers runs")
    ap.add_argument("--no-save", action="store_true", help="do not write results/")
    args = ap.parse_args(argv)
    print(f"load {os.getloadavg()}")
    with Run("reproduce", "biped reproduce cold and warm, against a baseline version run "
             "in turn; wall time against local-cluster workers", save=not args.no_save) \
            as bench, tempfile.TemporaryDirectory(prefix="bench-reproduce-") as tmp:
        tmp = Path(tmp)
        if not args.scaling_only:
            for quick in ([True] if args.quick else [False, True]):
                side_by_side(bench, tmp, quick, args.rounds, args.baseline)
        if args.workers:
            scaling(bench, tmp, args.workers, args.quick)
    return 0


if __name__ == "__main__":
    sys.exit(main())
