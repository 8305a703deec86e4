"""``biped reproduce``: the paper end to end (figures, summary.json, report.md)."""
from __future__ import annotations

from analysis.reproduce import reproduce

from .common import add_robot, load_model, print_json


def cmd_reproduce(args):
    load_model(args.robot)            # a bad --robot is a user error before any stage
    s = reproduce(args.out, quick=args.quick, progress=not args.no_progress,
                  robot=args.robot or "rabbit")
    failed = [k for k, v in s["stages"].items() if v["status"] != "ok"]
    if args.json:
        print_json(dict(out=args.out, stages=s["stages"], total_time=s["total_time"]))
    else:
        print(f"report: {args.out}/report.md   summary: {args.out}/summary.json")
        if failed:
            print("stages not ok: " + ", ".join(failed))
    return 1 if failed else 0


def register(sub):
    p = sub.add_parser(
        "reproduce", help="the paper end to end: figures, summary.json, report.md",
        description="Run the whole paper on RABBIT with the default gait (optimised once, "
                    "then cached): singular outputs (eq. 24), Fig. 2, the 9^4 grid, Fig. 3 "
                    "and the swing-height conjecture, a = b = 0 and Fig. 4, the M1 NLP, "
                    "the virtual-constraint comparison, Fig. 5 and 6, and an animation. "
                    "Figures are written as PNG and PDF; report.md sets our numbers beside "
                    "the paper's. With --robot, the same analysis for another robot (for "
                    "two torques the stable domain in the (M1(1), M1(2)) plane replaces "
                    "Fig. 4). Exit code 1 if a stage failed (the others still run).")
    p.add_argument("--out", default="reproduce_out", metavar="DIR",
                   help="output folder (default: reproduce_out)")
    add_robot(p, with_gait=False)
    p.add_argument("--quick", action="store_true", help="coarser grids (about 3 min)")
    p.add_argument("--no-progress", action="store_true", help="no progress output")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_reproduce)
