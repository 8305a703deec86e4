"""The main job, timed cold: ``biped reproduce`` and ``biped reproduce --quick``, each in a
fresh process with an empty ``BIPED_CACHE_DIR`` and a fresh output folder, against a
baseline checkout run in turn with it (pair by pair, the order alternating), then a
warm re-run of each; and how the wall time falls with the workers of the local cluster,
beside the graph's critical path (the bound for any number of workers).

    python benchmarks/bench_reproduce.py --baseline-commit 107a0d5 --rounds 2
    python benchmarks/bench_reproduce.py --baseline ../old/.venv/bin/python
    python benchmarks/bench_reproduce.py --quick --rounds 1      # the quick run only
    python benchmarks/bench_reproduce.py --workers 1 2            # the scaling only
    python benchmarks/bench_reproduce.py --baseline-commit 107a0d5 --rounds 2 \
        --cluster --name reproduce_cluster       # on a real `dask scheduler`, two workers

``--baseline-commit REV``: another version of the toolkit from this repository's history
(``git archive REV``, run by this interpreter with it first on ``PYTHONPATH``: its
dependencies must be this environment's); ``--baseline PYTHON``: the interpreter of an
installed baseline checkout.  Without either only this version runs.  ``--cluster``: each
run (cold or warm) against a ``dask scheduler`` with two single-threaded ``dask worker``
processes on loopback, started afresh for the run with its version's code and cache (the
scheduler too: it unpickles the tasks) and joined before the clock starts (a real cluster exists before the job), instead of the
local cluster that ``biped reproduce`` starts itself.  This version runs
from a snapshot of the working tree taken at the start, so editing the checkout during
the benchmark changes nothing.  Results are saved in benchmarks/results/reproduce.json
(the docs' benchmarks page is made from it).
"""
from __future__ import annotations

import argparse
import contextlib
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
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from _results import Run  # noqa: E402
from dask_cluster import dask_cluster  # noqa: E402
from summary_compare import differences  # noqa: E402

#: the workers of --cluster
CLUSTER_WORKERS = 2


def snapshot(rev, dest: Path) -> Path:
    """The packages of a commit (``rev``) or of the working tree (None) copied to ``dest``."""
    root = Path(__file__).resolve().parents[1]
    dest.mkdir(parents=True)
    if rev is None:
        for top in ("biped_casadi", "gait_opt", "analysis"):
            shutil.copytree(root / top, dest / top, ignore=shutil.ignore_patterns("__pycache__"))
    else:
        tar = subprocess.run(["git", "archive", rev, "biped_casadi", "gait_opt", "analysis"],
                             cwd=root, capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", str(dest)], input=tar, check=True)
    return dest


def run(python, out: Path, cache: Path, quick: bool, workers=None,
        cluster: bool = False) -> dict:
    """One ``biped reproduce`` in a fresh process; its wall time and its summary
    (``python``: an interpreter, or (interpreter, packages folder first on the path);
    ``cluster``: on a real Dask cluster started for it, see the module docstring)."""
    env = dict(os.environ, BIPED_CACHE_DIR=str(cache), MPLBACKEND="Agg")
    env.pop("BIPED_SCHEDULER", None)
    if isinstance(python, tuple):
        python, path = python
        env["PYTHONPATH"] = os.pathsep.join([str(path)] + ([env["PYTHONPATH"]]
                                                           if env.get("PYTHONPATH") else []))
    cmd = [python, "-m", "analysis.cli", "reproduce", "--out", str(out), "--no-progress"] \
        + (["--quick"] if quick else []) + ([] if workers is None else
                                            ["--workers", str(workers)])
    out.parent.mkdir(parents=True, exist_ok=True)   # the run's folder, outside any checkout
    with contextlib.ExitStack() as stack:
        if cluster:
            where = Path(tempfile.mkdtemp(prefix="cluster-", dir=out.parent))
            # the scheduler too unpickles the tasks: it runs the version's code as well
            address = stack.enter_context(dask_cluster(
                where, [dict(env, BIPED_THREADS="1")] * CLUSTER_WORKERS, scheduler_env=env,
                cwd=out.parent))
            _wait_for_workers(address, CLUSTER_WORKERS)
            cmd += ["--scheduler", address]
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
                stderr=p.stderr[-1500:], summary=summary)


def _wait_for_workers(address: str, n: int):
    """Block until ``n`` workers have joined the scheduler at ``address``."""
    from dask.distributed import Client
    with Client(address, timeout="30s") as client:
        client.wait_for_workers(n, timeout=120)


def _show(label, r):
    cp = f", critical path {r['critical_path']:.1f} s" if r.get("critical_path") else ""
    print(f"  {label:34s} wall {r['wall']:7.1f} s, exit {r['rc']}, stages ok {r['ok']}, "
          f"load {r['load_before']:.2f} -> {r['load_after']:.2f}{cp}", flush=True)
    if r["rc"] != 0:
        print("    " + r["stderr"].replace("\n", "\n    "))


def side_by_side(bench: Run, tmp: Path, quick: bool, rounds: int, ours, baseline,
                 cluster: bool = False):
    """Cold runs of both versions in turn, then warm re-runs."""
    name = "quick" if quick else "full"
    impls = [("this version", ours)] + ([("baseline", baseline)] if baseline else [])
    walls = {k: [] for k, _ in impls}
    for i in range(rounds):
        summaries = {}
        for label, py in (impls if i % 2 == 0 else impls[::-1]):
            d = tmp / f"{name}-{label.replace(' ', '_')}-{i}"
            r = run(py, d / "out", d / "cache", quick, cluster=cluster)
            _show(f"{name} cold, {label}", r)
            summaries[label] = r["summary"]
            if r["rc"] == 0:
                walls[label].append(r["wall"])
            if i == rounds - 1:
                w = run(py, d / "out", d / "cache", quick, cluster=cluster)
                _show(f"{name} warm, {label}", w)
                bench.row(f"`biped reproduce{' --quick' if quick else ''}` warm re-run, "
                          f"{label}", round(w["wall"], 1),
                          target="<= 2 s" if label == "this version" else "")
            shutil.rmtree(d, ignore_errors=True)
        if len(summaries) == 2 and all(summaries.values()):
            diff = differences(summaries["baseline"], summaries["this version"])
            print(f"  {name} round {i + 1}: summary.json leaves that differ: {len(diff)}")
            bench.note(f"{name} round {i + 1}: summary.json leaves that differ from the "
                       f"baseline's: {len(diff)}" + "".join(f"; {k}: {a!r} -> {b!r}"
                                                            for k, a, b in diff[:10]))
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
                  + ("; baseline / ours >= 0.95" if base else ""))
        if pairs:
            bench.note(f"{name}: wall ratio baseline / this version pair by pair "
                       + ", ".join(f"{p:.3f}" for p in pairs))


def scaling(bench: Run, tmp: Path, workers: list, quick: bool, ours):
    name = "quick" if quick else "full"
    for n in workers:
        d = tmp / f"scale-{n}"
        r = run(ours, d / "out", d / "cache", quick, workers=n)
        _show(f"{name} cold, --workers {n}", r)
        bench.row(f"`biped reproduce{' --quick' if quick else ''} --workers {n}` cold",
                  round(r["wall"], 1), target="falls with workers")
        if r.get("critical_path"):
            bench.row(f"its critical path (--workers {n})", round(r["critical_path"], 1),
                      target="the wall time's bound on any number of workers")
        shutil.rmtree(d, ignore_errors=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--baseline", metavar="PYTHON",
                    help="interpreter of an installed baseline version, run in turn")
    ap.add_argument("--baseline-commit", metavar="REV",
                    help="a commit of this repository as the baseline (run by this "
                         "interpreter), e.g. 107a0d5")
    ap.add_argument("--quick", action="store_true", help="the quick run only")
    ap.add_argument("--rounds", type=int, default=3, help="cold runs of each (default 3)")
    ap.add_argument("--workers", type=int, nargs="*", default=None,
                    help="also cold runs with these local-cluster sizes (e.g. 1 2)")
    ap.add_argument("--scaling-only", action="store_true",
                    help="only the --workers runs")
    ap.add_argument("--cluster", action="store_true",
                    help=f"run on a real `dask scheduler` with {CLUSTER_WORKERS} `dask worker` "
                         "processes on loopback (started for each run, joined before the "
                         "clock starts) instead of the local cluster")
    ap.add_argument("--no-save", action="store_true", help="do not write results/")
    ap.add_argument("--name", default="reproduce",
                    help="the results file's name (default reproduce: results/reproduce.json)")
    ap.add_argument("--note", action="append", default=[],
                    help="a note saved with the results (what is compared; repeatable)")
    args = ap.parse_args(argv)
    if args.cluster and (args.workers or args.scaling_only):
        ap.error("--cluster has its own two workers: it excludes --workers and --scaling-only")
    print(f"load {os.getloadavg()}")
    what = (f"on a real Dask scheduler with {CLUSTER_WORKERS} `dask worker` processes"
            if args.cluster else "wall time against local-cluster workers")
    with Run(args.name, "biped reproduce cold and warm, against a baseline version run "
             f"in turn; {what}", save=not args.no_save) \
            as bench, tempfile.TemporaryDirectory(prefix="bench-reproduce-") as tmp:
        tmp = Path(tmp)
        for n in args.note:
            bench.note(n)
        ours = (sys.executable, snapshot(None, tmp / "this-version"))
        baseline = args.baseline or (
            (sys.executable, snapshot(args.baseline_commit, tmp / "baseline"))
            if args.baseline_commit else None)
        if args.baseline_commit:
            rev = subprocess.run(["git", "rev-parse", "--short", args.baseline_commit],
                                 cwd=Path(__file__).resolve().parents[1], capture_output=True,
                                 text=True).stdout.strip()
            bench.note(f"baseline: commit {args.baseline_commit} ({rev})")
        if not args.scaling_only:
            for quick in ([True] if args.quick else [False, True]):
                side_by_side(bench, tmp, quick, args.rounds, ours, baseline, args.cluster)
        if args.workers:
            scaling(bench, tmp, args.workers, args.quick, ours)
    return 0


if __name__ == "__main__":
    sys.exit(main())
