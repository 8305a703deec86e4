"""Import of ``biped_casadi`` and model construction, each in a fresh process.

Baseline: a bare ``import casadi`` in the same kind of fresh process, so the ratio says
how much the toolkit adds on top of CasADi itself.  Target: import + build < 1 s.
The results go to ``benchmarks/results/model.json`` (the docs' benchmarks page).

    python benchmarks/bench_model.py [--repeats 5] [--no-save]
"""
import argparse
import statistics
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import Run  # noqa: E402

BASELINE = "import casadi (baseline)"
SNIPPETS = {
    BASELINE: "import time; t=time.perf_counter(); import casadi; print(time.perf_counter()-t)",
    "import biped_casadi": "import time; t=time.perf_counter(); import biped_casadi; print(time.perf_counter()-t)",
    "import + rabbit()": "import time; t=time.perf_counter(); import biped_casadi as b; b.rabbit(); print(time.perf_counter()-t)",
}


def main(repeats=5, save=True):
    with Run("model", "import of biped_casadi and the model's construction in a fresh "
             "process, against a bare import of CasADi", save=save) as bench:
        runs = {name: [] for name in SNIPPETS}
        for _ in range(repeats):             # interleaved: a drift of the load hits all
            for name, code in SNIPPETS.items():
                out = subprocess.check_output([sys.executable, "-c", code]).decode()
                runs[name].append(float(out.strip().splitlines()[-1]))
        res = {name: statistics.median(ts) for name, ts in runs.items()}
        base = res[BASELINE]
        for name, t in res.items():
            print(f"{name:28s} {t*1e3:8.1f} ms   x{t/base:5.2f} of bare casadi import")
        ok = res["import + rabbit()"] < 1.0
        print(f"target import + build < 1 s: {'met' if ok else 'MISSED'}")
        for name in ("import biped_casadi", "import + rabbit()"):
            bench.row(f"`{name}`, fresh process (median of {repeats})",
                      round(res[name] * 1e3, 1), round(base * 1e3, 1), unit="ms",
                      ratio=round(base / res[name], 3),
                      target="import + build < 1000 ms" if "rabbit" in name else "")
        bench.note("baseline: a bare `import casadi` in the same kind of fresh process; the "
                   "ratio (baseline / ours, below 1 as ours includes CasADi) says which "
                   "share of the time CasADi's own import is")
        bench.data.update(runs_s=runs, repeats=repeats, target_met=ok)
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5, help="fresh processes of each (5)")
    ap.add_argument("--no-save", action="store_true", help="do not write results/")
    a = ap.parse_args()
    main(a.repeats, not a.no_save)
