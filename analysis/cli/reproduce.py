"""``biped reproduce``: the paper end to end (figures, summary.json, report.md)."""
from __future__ import annotations

from analysis.reporting.reproduce import reproduce, run_folder

from .common import add_robot, load_model, output_dir, print_json

#: measured by benchmarks/bench_reproduce.py (fresh processes, empty caches) on the 2-core AMD
#: EPYC VM (Python 3.11), nothing cached, on four days, the VM's speed changing by up to 2.5
#: times: full 140 to 160 s and quick 47 to 62 s on the first; 298 s and 104 to 110 s on the
#: second; 245.6 s and 69.7 to 76.9 s on the third (the previous version); on the fourth,
#: this version: full 123.3 to 134.6 s, quick 42.0 to 47.1 s; warm re-runs 7 to 23 s; the
#: README quotes the same figures (tests/test_reproduce.py checks it)
TIME_FULL = "2 to 5 min"
TIME_QUICK = "40 s to 2 min"


def cmd_reproduce(args):
    load_model(args.robot)            # a bad --robot is a user error before any stage
    output_dir(args.out, "--out")                             # before any work
    output_dir(run_folder(args.out, args.quick, args.robot), "--out")
    r = reproduce(args.out, quick=args.quick, progress=not (args.no_progress or args.json),
                  robot=args.robot or "rabbit", helper=not args.one_core)
    if args.json:
        print_json(r)
    else:
        print(f"report: {r.report}   summary: {r.summary_file}")
        if not r.success:
            print(r.message)
    return 0 if r.success else 1


def register(sub):
    p = sub.add_parser(
        "reproduce", help="the paper end to end: figures, summary.json, report.md",
        description="Run the whole paper on RABBIT with the default gait (optimised once, "
                    "then cached): singular outputs (eq. 24), Fig. 2, the 9^4 grid, Fig. 3 "
                    "and the swing-height conjecture, a = b = 0 and Fig. 4, the M1 NLP, "
                    "the virtual-constraint comparison; then which designs walk: the robust "
                    "co-design NLP (the gait fixed in --quick; cached once found) beside "
                    "the sampling search's design, s* of the deadbeat outputs, virtual "
                    "constraints and the robust designs, Fig. 5 and 6 at the paper's full "
                    "perturbation with validity margins, an animation, basins of "
                    "attraction, the s*-against-max|lambda| trade-off, and uneven ground. "
                    "On two or more cores a helper process computes the robust design and "
                    "what depends on it while the paper's stages run (--one-core: not). "
                    "Figures are written as PNG and PDF; report.md sets our numbers beside "
                    f"the paper's. With --robot, the same analysis for another robot (for "
                    "two torques the stable domain in the (M1(1), M1(2)) plane replaces "
                    f"Fig. 4). A full run ({TIME_FULL} on a loaded 2-core VM) writes into "
                    f"DIR, a quick run ({TIME_QUICK}) into DIR/quick, another robot into "
                    "DIR/<its name or file stem> (and .../quick), so re-runs of any kind into "
                    "the same DIR never mix; sweeps already computed are reused. Exit code 1 "
                    "if a stage failed (the others still run).")
    p.add_argument("--out", default="reproduce_out", metavar="DIR",
                   help="output folder (default: reproduce_out; a quick run uses DIR/quick)")
    add_robot(p, with_gait=False)
    p.add_argument("--quick", action="store_true",
                   help=f"coarser grids ({TIME_QUICK} on 2 cores), into DIR/quick")
    p.add_argument("--one-core", action="store_true",
                   help="every stage in this process (no helper process on a second core)")
    p.add_argument("--no-progress", action="store_true", help="no progress output")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_reproduce)
