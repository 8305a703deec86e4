"""``biped reproduce``: the paper end to end (figures, summary.json, report.md), as one
graph of cached tasks on Dask (:mod:`analysis.pipeline`)."""
from __future__ import annotations

from analysis.pipeline import reproduce, run_folder

from .common import (UserError, add_robot, add_scheduler, check_scheduler, load_model,
                     output_dir, print_json)


def cmd_reproduce(args):
    load_model(args.robot)            # a bad --robot is a user error before any stage
    output_dir(args.out, "--out")                             # before any work
    output_dir(run_folder(args.out, args.quick, args.robot), "--out")
    if args.scheduler is not None and args.workers is not None:
        raise UserError("--workers sets the local cluster's processes; it excludes "
                        "--scheduler (an existing cluster has its own workers)")
    check_scheduler(args.scheduler)
    r = reproduce(args.out, quick=args.quick, progress=not (args.no_progress or args.json),
                  robot=args.robot or "rabbit", scheduler=args.scheduler,
                  workers=args.workers)
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
        description="Run the whole paper on RABBIT with the default gait: singular outputs "
                    "(eq. 24), Fig. 2, the 9^4 grid, Fig. 3 and the swing-height "
                    "conjecture, a = b = 0 and Fig. 4, the M1 NLP, the virtual-constraint "
                    "comparison; then which designs walk: the robust co-design NLP (the "
                    "gait fixed in --quick) beside the sampling search's design, s* of the "
                    "deadbeat outputs, virtual constraints and the robust designs, Fig. 5 "
                    "and 6 at the paper's full perturbation with validity margins, an "
                    "animation, basins of attraction, the s*-against-max|lambda| trade-off, "
                    "uneven ground, and a gait family at three speeds with a speed ramp "
                    "walked in full order. The run is one graph of tasks on Dask (a local "
                    "cluster of one worker process per core by default); every result is "
                    "kept in the cache folder ($BIPED_CACHE_DIR) by its inputs and the "
                    "numerical code, so a second run reads them and an interrupted run "
                    "resumes. Figures are PNG and PDF; report.md sets our numbers beside "
                    "the paper's. With --robot, the same analysis for another robot. A full "
                    "run writes into DIR, a quick run into DIR/quick, another robot into "
                    "DIR/<its name or file stem> (and .../quick). Times: the docs' "
                    "benchmarks page. Exit code 1 if a stage failed (the others still run).")
    p.add_argument("--out", default="reproduce_out", metavar="DIR",
                   help="output folder (default: reproduce_out; a quick run uses DIR/quick)")
    add_robot(p, with_gait=False)
    p.add_argument("--quick", action="store_true",
                   help="coarser grids, the co-design's gait fixed; into DIR/quick")
    add_scheduler(p)
    p.add_argument("--no-progress", action="store_true", help="no progress output")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_reproduce)
