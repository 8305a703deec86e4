"""Basins on windows that contain their boundary (``basin_to_boundary``) beside the fixed
window of ±0.05 rad x ±0.5 rad/s: the co-design of ``biped m1 --robust`` and virtual
constraints on its gait, the sampling search's design on the robust gait, and the
default gait's deadbeat design and virtual constraints.

Prints, per design, the fixed window's converged fraction and area, the windows the
boundary search walked, its final fraction, area (rad x rad/s) and status, and the time
of each; with ``--resolution`` the areas again on a twice finer grid (n = 2 (n - 1) + 1,
starting from the window reached), their difference being the grid's error on the area.  Saves
``benchmarks/results/basin_window.json``.

    python benchmarks/bench_basin_window.py              # n = 101, refine = 4
    python benchmarks/bench_basin_window.py --resolution --figures docs/_static
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import Run  # noqa: E402


def cases():
    """(label, design) of the five basins."""
    from analysis.design import ROBUST_GAIT, optimize_m1
    from analysis.design.codesign import FULL, TODAY_DESIGN, codesign
    from biped_casadi import Design, rabbit
    from gait_opt import GaitOptions, optimize_gait
    m = rabbit()
    r = codesign(m, FULL, workers=1)
    gr = optimize_gait(m, GaitOptions(**ROBUST_GAIT), cache=True)
    g = optimize_gait(m, cache=True)
    return [("co-design (biped m1 --robust)", r.design),
            ("virtual constraints (co-design's gait)", Design.vc(r.design.gait)),
            ("sampling search's design (robust gait)", Design.tv(gr, TODAY_DESIGN, 0.75)),
            ("deadbeat M1 (default gait)", Design.tv(g, optimize_m1(g, group=1).M1)),
            ("virtual constraints (default gait)", Design.vc(g))]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=101, help="cells per axis (101)")
    ap.add_argument("--refine", type=int, default=4, help="the adaptive grid's stride (4)")
    ap.add_argument("--resolution", action="store_true",
                    help="also the areas on a twice finer grid")
    ap.add_argument("--no-save", action="store_true", help="do not write the results file")
    ap.add_argument("--figures", metavar="DIR",
                    help="write the basins to their boundary as DIR/basin_boundary_robust.png "
                         "(the first three) and DIR/basin_boundary_default.png")
    a = ap.parse_args()
    from analysis.robustness import basin, basin_to_boundary
    with Run("basin_window", "basins on windows that contain their boundary, beside the "
             "fixed window", save=not a.no_save) as run:
        print(f"n = {a.n}, refine = {a.refine}; load {os.getloadavg()[0]:.2f}")
        autos = []
        for label, d in cases():
            basin(d, n=5)                       # build and compile the walker first
            t = time.perf_counter()
            fixed = basin(d, n=a.n, refine=a.refine)
            tf = time.perf_counter() - t
            t = time.perf_counter()
            auto = basin_to_boundary(d, n=a.n, refine=a.refine)
            ta = time.perf_counter() - t
            row = dict(design=label, controller=d.to_dict(), fixed=dict(
                converged_fraction=fixed.converged_fraction, area=fixed.area, seconds=tf),
                auto=dict(status=auto.status, q_span=auto.q_span, dq_span=auto.dq_span,
                          converged_fraction=auto.converged_fraction, area=auto.area,
                          seconds=ta, windows=auto.windows, cap=auto.cap))
            print(f"{label}\n  fixed ±0.05 x ±0.5: {100 * fixed.converged_fraction:5.1f} %, "
                  f"area {fixed.area:.4g} rad x rad/s, {tf:.1f} s\n  to its boundary "
                  f"({auto.status}): ±{auto.q_span:.3g} rad x ±{auto.dq_span:.3g} rad/s, "
                  f"{100 * auto.converged_fraction:5.1f} %, area {auto.area:.4g} rad x "
                  f"rad/s, {ta:.1f} s, {len(auto.windows)} windows")
            for w in auto.windows:
                what = ("edges only" if w.get("probe") else
                        f"{100 * w['converged_fraction']:5.1f} %, area {w['area']:.4g}")
                print(f"    ±{w['q_span']:.3g} x ±{w['dq_span']:.3g}: {what}, "
                      f"edges {w['edges']}, {w['elapsed']:.1f} s"
                      + (" (dropped)" if w.get("dropped") else ""))
            if a.resolution:
                fine = basin_to_boundary(d, n=2 * (a.n - 1) + 1, q_span=auto.q_span,
                                         dq_span=auto.dq_span, refine=a.refine, zoom=0)
                row["auto"]["area_fine"] = fine.area
                print(f"  from the same window at n = {2 * (a.n - 1) + 1}: ±{fine.q_span:.3g} x "
                      f"±{fine.dq_span:.3g}, area {fine.area:.4g} "
                      f"({100 * (auto.area - fine.area) / fine.area:+.1f} %)")
            run.row(f"{label}: time to the boundary (baseline: the fixed window)", ta, tf)
            run.note(f"{label}: fixed window {100 * fixed.converged_fraction:.1f} %, area "
                     f"{fixed.area:.4g} rad x rad/s; to the boundary ({auto.status}) "
                     f"±{auto.q_span:.3g} rad x ±{auto.dq_span:.3g} rad/s, "
                     f"{100 * auto.converged_fraction:.1f} %, area {auto.area:.4g} rad x "
                     f"rad/s, {len(auto.windows)} windows"
                     + (f"; n = {2 * (a.n - 1) + 1}: area {row['auto']['area_fine']:.4g}"
                        if a.resolution else ""))
            run.data.setdefault("basins", []).append(row)
            autos.append((label, auto))
        print(f"load {os.getloadavg()[0]:.2f}")
    if a.figures:
        from analysis.reporting.plots import basin_plot, save_figures
        figs = {"basin_boundary_robust": basin_plot(
                    [b for _, b in autos[:3]], labels=[lab for lab, _ in autos[:3]],
                    title="Basins of the robust designs on windows that contain their "
                          "boundary"),
                "basin_boundary_default": basin_plot(
                    [b for _, b in autos[3:]], labels=[lab for lab, _ in autos[3:]],
                    title="Basins on the default gait on windows that contain their "
                          "boundary")}
        print(save_figures(figs, a.figures, formats=("png",)))


if __name__ == "__main__":
    main()
