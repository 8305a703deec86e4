"""``biped view``: seconds from the command to its ready line (``view: http://...``), warm
(the gait and the sliders' reach in the cache), beside ``biped eig`` for the same design
run side by side (the fixed cost of any command that loads the cached gait), and the
readout of one M1 in the server (:meth:`analysis.view.Explorer.readout`) beside
:func:`analysis.poincare_eigenvalues` alone.  The issue's target: ready within 3 s warm.
Saves ``benchmarks/results/view.json``.

    python benchmarks/bench_view.py [--repeats R] [--no-save]

Needs the extra ``view`` (viser).  Every server it starts is stopped with SIGINT (its
exit code is checked).
"""
from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import Run  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
M1 = ["-10", "7.5", "10", "-5"]
TARGET = 3.0


def ready_seconds(args) -> float:
    """Start ``biped view ARGS``, time its ready line, stop it with SIGINT."""
    t = time.perf_counter()
    p = subprocess.Popen([sys.executable, "-m", "analysis.cli", "view", *args],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
                         env=dict(os.environ, MPLBACKEND="Agg"))
    try:
        line = p.stdout.readline()
        seconds = time.perf_counter() - t
        if not line.startswith("view: http://"):
            raise SystemExit(f"biped view: no ready line ({line!r}): {p.stderr.read()}")
    finally:
        p.send_signal(signal.SIGINT)
        rc = p.wait(timeout=60)
    if rc != 0:
        raise SystemExit(f"biped view exited with {rc} after SIGINT")
    return seconds


def command_seconds(args) -> float:
    t = time.perf_counter()
    subprocess.run([sys.executable, "-m", "analysis.cli", *args], check=True, cwd=ROOT,
                   capture_output=True, env=dict(os.environ, MPLBACKEND="Agg"))
    return time.perf_counter() - t


def readout_seconds(repeats: int) -> tuple:
    """(readout, poincare_eigenvalues) per call in this process, s (median)."""
    from analysis import poincare_eigenvalues
    from analysis.view import Explorer, ViewSettings
    from biped_casadi import rabbit
    from gait_opt import optimize_gait
    g = optimize_gait(rabbit(), cache=True)
    ex = Explorer(ViewSettings(g, M1=tuple(map(float, M1))))
    designs = [[-10 + 0.01 * k, 7.5, 10, -5] for k in range(repeats)]
    ex.readout("tv", designs[0])

    def per_call(fn):
        t = time.perf_counter()
        for d in designs:
            fn(d)
        return (time.perf_counter() - t) / len(designs)
    return per_call(lambda d: ex.readout("tv", d)), per_call(lambda d: poincare_eigenvalues(g, d))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5, help="starts of each command (5)")
    ap.add_argument("--no-save", action="store_true", help="do not write the results file")
    a = ap.parse_args()
    with Run("view", "biped view: ready line warm, beside biped eig", save=not a.no_save) as run:
        print(f"load {os.getloadavg()[0]:.2f}")
        ready_seconds(["--m1", *M1])                           # fill the cache: warm from here
        ready_seconds([])
        view, default, eig = [], [], []
        for _ in range(a.repeats):                             # side by side, interleaved
            view.append(ready_seconds(["--m1", *M1]))
            default.append(ready_seconds([]))
            eig.append(command_seconds(["eig", "--m1", *M1]))
        med = {k: statistics.median(v) for k, v in
               (("view", view), ("default", default), ("eig", eig))}
        for k, v in (("view --m1", view), ("view (default M1)", default), ("eig", eig)):
            print(f"{k:18s} median {statistics.median(v):.2f} s, best {min(v):.2f} s")
        run.row("biped view --m1 -10 7.5 10 -5: start to the ready line, warm", med["view"],
                med["eig"], target=f"< {TARGET:g} s warm")
        run.row("biped view (default M1): start to the ready line, warm", med["default"],
                med["eig"], target=f"< {TARGET:g} s warm")
        r, p = readout_seconds(200)
        print(f"readout {1e3 * r:.2f} ms a design, poincare_eigenvalues {1e3 * p:.2f} ms")
        run.row("the eigenvalue readout of one M1 in the server", r, p, target="live")
        run.note("baseline of the ready lines: 'biped eig --m1 -10 7.5 10 -5' start to exit, "
                 "run interleaved with them; of the readout: poincare_eigenvalues alone")
        run.data.update(view=view, default=default, eig=eig, repeats=a.repeats)


if __name__ == "__main__":
    main()
