"""The main job, timed cold: ``biped reproduce`` and ``biped reproduce --quick``, each in a
fresh process with an empty ``BIPED_CACHE_DIR`` and a fresh output folder, then a warm
re-run of each (everything cached).

Prints every stage's time (from the run's own summary.json), the total wall time of the
process (imports and start-up included), the machine and its load before and after, and
which stages the warm re-run reused.  The README's time table and ``biped reproduce
--help`` quote its output.

    python benchmarks/bench_reproduce.py            # full and quick, cold then warm
    python benchmarks/bench_reproduce.py --quick    # the quick run only
    python benchmarks/bench_reproduce.py --json out.json
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))


def machine() -> str:
    """The processor, cores and Python, in one line (:func:`bench_sweep.machine_info`)."""
    from bench_sweep import machine_info
    m = machine_info()
    return f"{m['cpu']}, {m['nproc']} cores, Python {m['python']}"


def run(out: Path, cache: Path, quick: bool) -> dict:
    """One ``biped reproduce`` in a fresh process; its wall time and its summary."""
    env = dict(os.environ, BIPED_CACHE_DIR=str(cache), MPLBACKEND="Agg")
    cmd = [sys.executable, "-m", "analysis.cli", "reproduce", "--out", str(out),
           "--no-progress"] + (["--quick"] if quick else [])
    load0 = os.getloadavg()[0]
    t = time.perf_counter()
    p = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t
    folder = out / "quick" if quick else out
    summary = json.loads((folder / "summary.json").read_text()) \
        if (folder / "summary.json").is_file() else {}
    return dict(rc=p.returncode, wall=wall, load_before=load0, load_after=os.getloadavg()[0],
                stages=summary.get("stages", {}), total=summary.get("total_time"),
                reused=summary.get("reused", {}), helped=summary.get("helped", {}),
                codesign_help=summary.get("codesign_help"),
                stderr=p.stderr[-2000:])


def show(label: str, r: dict):
    print(f"\n{label}: wall {r['wall']:.1f} s (stages {r['total'] or float('nan'):.1f} s), "
          f"exit {r['rc']}, load {r['load_before']:.2f} -> {r['load_after']:.2f}")
    for name, s in r["stages"].items():
        t = s.get("time")
        reuse, helped = r["reused"].get(name), r["helped"].get(name)
        print(f"  {name:36s} {s['status']:8s} {t if t is not None else float('nan'):7.1f} s"
              + (f"   reused: {len(reuse)}" if reuse else "")
              + (f"   from the helper process: {len(helped)}" if helped else ""))
    h = r.get("codesign_help")
    if h and h.get("computed"):
        print(f"  (between the stages above: {h['computed']} of the co-design's units taken "
              f"from the helper, {h['time']:.1f} s in {h['calls']} looks)")
    if r["rc"] != 0:
        print("  stderr: " + r["stderr"].replace("\n", "\n    "))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the quick run only")
    ap.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    args = ap.parse_args(argv)
    print(f"machine: {machine()}; load {os.getloadavg()}")
    results = {}
    with tempfile.TemporaryDirectory(prefix="bench-reproduce-") as tmp:
        tmp = Path(tmp)
        for quick in ([True] if args.quick else [False, True]):
            name = "quick" if quick else "full"
            cache, out = tmp / f"cache-{name}", tmp / f"out-{name}"
            shutil.rmtree(cache, ignore_errors=True)
            cold = run(out, cache, quick)
            show(f"biped reproduce{' --quick' if quick else ''}, cold", cold)
            warm = run(out, cache, quick)
            show(f"biped reproduce{' --quick' if quick else ''}, warm re-run", warm)
            results[name] = dict(cold=cold, warm=warm)
    if args.json:
        Path(args.json).write_text(json.dumps(dict(machine=machine(), results=results),
                                              indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
