"""The robust design, NLP against sampling search, side by side in one run: ``biped m1
--robust`` (the co-design NLP, gait free), ``biped m1 --robust --gait FILE`` (the NLP with
the gait fixed) and ``biped m1 --robust --method search`` (the sampling search), each in
a fresh process with an empty ``BIPED_CACHE_DIR``.

Prints each one's wall time (start-up, the gait and the compiled functions included),
what it reaches by the same verification protocol (s*, the step from which the paper's
perturbation stays below 1e-3, max|lambda| against virtual constraints, peak torque) and
the time ratio of each NLP run to the search.  The README quotes its output.

    python benchmarks/bench_codesign.py                 # all three
    python benchmarks/bench_codesign.py --skip-search   # the NLP runs only
    python benchmarks/bench_codesign.py --json out.json
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_reproduce import machine  # noqa: E402


def _f(v, spec=".4g"):
    return "n/a" if v is None else format(v, spec)


def run(args: list[str], cache: Path) -> dict:
    """One ``biped m1 --robust ...`` in a fresh process with its own cache."""
    env = dict(os.environ, BIPED_CACHE_DIR=str(cache), MPLBACKEND="Agg")
    cmd = [sys.executable, "-m", "analysis.cli", "m1", "--robust", "--json", *args]
    load0 = os.getloadavg()[0]
    t = time.perf_counter()
    p = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t
    out = dict(cmd="biped m1 --robust " + " ".join(args), rc=p.returncode, wall=wall,
               load_before=load0, load_after=os.getloadavg()[0])
    if p.returncode != 0:
        out["stderr"] = p.stderr[-1500:]
        return out
    r = json.loads(p.stdout)
    paper = r.get("paper") or {}
    out.update(status=r.get("status"), s_star=r.get("s_star"), max_abs=r.get("max_abs"),
               vc_eigenvalue=r.get("vc_eigenvalue"),
               steps_to_converge=r.get("steps_to_converge", paper.get("steps_to_converge")),
               peak_torque=r.get("peak_torque", paper.get("peak_torque")),
               M1=r.get("design", {}).get("M1"), ipopt=(r.get("ipopt") or {}).get("time"),
               stages=r.get("stages"))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--skip-search", action="store_true", help="the NLP runs only")
    ap.add_argument("--search-only", action="store_true", help="the sampling search only")
    ap.add_argument("--json", metavar="FILE", help="write the results here")
    a = ap.parse_args()
    print(f"machine: {machine()}; load {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        # the robust gait as a file for the fixed-gait run (made in its own cache)
        gait_file = tmp / "robust_gait.json"
        subprocess.run([sys.executable, "-c",
                        "import sys; from analysis.design import ROBUST_GAIT; "
                        "from biped_casadi import RABBIT, BipedModel; "
                        "from gait_opt import GaitOptions, optimize_gait; "
                        "optimize_gait(BipedModel(RABBIT), GaitOptions(**ROBUST_GAIT), cache=True)"
                        ".save(sys.argv[1])", str(gait_file)],
                       env=dict(os.environ, BIPED_CACHE_DIR=str(tmp / "gait_cache")),
                       check=True)
        runs = [] if a.search_only else [("nlp, gait free", []),
                                          ("nlp, gait fixed", ["--gait", str(gait_file)])]
        if not a.skip_search:
            runs.append(("search", ["--method", "search"]))
        results = {}
        for i, (label, args) in enumerate(runs):
            print(f"\n{label}: {' '.join(['biped m1 --robust', *args])} (fresh cache)",
                  flush=True)
            r = run(args, tmp / f"cache{i}")
            results[label] = r
            if r["rc"]:
                print(f"  exit {r['rc']}: {r.get('stderr', '')}")
                continue
            print(f"  {r['wall']:.1f} s wall (load {r['load_before']:.2f} -> "
                  f"{r['load_after']:.2f}); {r['status']}: s* {_f(r['s_star'])}, below 1e-3 "
                  f"from step {r['steps_to_converge']}, max|lambda| {_f(r['max_abs'])} "
                  f"(virtual constraints {_f(r['vc_eigenvalue'])}), peak torque "
                  f"{_f(r['peak_torque'])} N m", flush=True)
        s = results.get("search")
        if s and not s["rc"]:
            print()
            for label in ("nlp, gait free", "nlp, gait fixed"):
                r = results.get(label)
                if r and not r["rc"]:
                    print(f"{label}: {s['wall'] / r['wall']:.2f}x faster than the search "
                          f"({r['wall']:.0f} s vs {s['wall']:.0f} s)")
    if a.json:
        Path(a.json).write_text(json.dumps(dict(machine=machine(), runs=results), indent=1))


if __name__ == "__main__":
    main()
