"""Import of ``biped_casadi`` and model construction, each in a fresh process.

Baseline: a bare ``import casadi`` in the same kind of fresh process, so the ratio says
how much the toolkit adds on top of CasADi itself.  Target: import + build < 1 s.
"""
import statistics
import subprocess
import sys

SNIPPETS = {
    "import casadi (baseline)": "import time; t=time.perf_counter(); import casadi; print(time.perf_counter()-t)",
    "import biped_casadi": "import time; t=time.perf_counter(); import biped_casadi; print(time.perf_counter()-t)",
    "import + rabbit()": "import time; t=time.perf_counter(); import biped_casadi as b; b.rabbit(); print(time.perf_counter()-t)",
}


def main(repeats=5):
    res = {}
    for name, code in SNIPPETS.items():
        ts = [float(subprocess.check_output([sys.executable, "-c", code]).decode().strip().splitlines()[-1])
              for _ in range(repeats)]
        res[name] = statistics.median(ts)
    base = res["import casadi (baseline)"]
    for name, t in res.items():
        print(f"{name:28s} {t*1e3:8.1f} ms   x{t/base:5.2f} of bare casadi import")
    ok = res["import + rabbit()"] < 1.0
    print(f"target import + build < 1 s: {'met' if ok else 'MISSED'}")
    return res


if __name__ == "__main__":
    main()
