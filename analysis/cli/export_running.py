"""``biped export-running``: the running controller of ``biped running`` / ``biped
mujoco-running`` as self-contained C99 code, optionally compiled and compared with the
Python law (``--verify``: random states of both phases, and a MuJoCo run)."""
from __future__ import annotations

import hashlib
from pathlib import Path

from biped_casadi.control.compiled import CompilerError
from biped_casadi.control.export_folder import staged_export
from biped_casadi.model.description import torque_bound_text
from biped_casadi.control.export_running import (RUNNING_HEADER, RUNNING_LIBRARY,
                                                 exported_running_law, running_c_sources)
from analysis.verify_running_export import STRIDE_TOL, verify_running_export
from analysis.verify_export import TORQUE_RTOL

from .common import (Progress, UserError, add_robot, check_torque_limit, load_running_gait,
                     print_json)
from .export import check_target, keep_verified
from .running import add_tracking_arguments, check_tracking_arguments, running_controller

#: random states per phase --verify compares by default
STATES = 10_000
#: strides of --verify's MuJoCo comparison by default
STRIDES = 30
#: the copy of the gait file in the export
GAIT_COPY = "running.json"


def _check(args):
    """Everything that can be checked before the gait is loaded; the C compiler of
    --verify (None without)."""
    check_tracking_arguments(args)
    check_torque_limit(args, clip_only=True)
    if not str(args.gait).strip():
        raise UserError("--gait: empty name")
    if not 0 <= args.strides <= 5000:
        raise UserError(f"--strides must be between 0 and 5000, got {args.strides}")
    return check_target(args)


def cmd_export_running(args):
    cc = _check(args)
    say = Progress("export-running", quiet=args.json)
    gait, model = load_running_gait(args)
    ctrl = running_controller(args, gait, model, engine="MuJoCo" if args.verify else "")
    data = Path(args.gait).read_bytes()
    provenance = {"gait file": str(args.gait),
                  "gait file sha256": hashlib.sha256(data).hexdigest(),
                  "copy of the gait file": GAIT_COPY}
    say("generating C for the running controller ...")
    law = exported_running_law(ctrl)
    files = running_c_sources(law, provenance)
    result = dict(status="written", out=str(args.out), files=sorted(files) + [GAIT_COPY],
                  controller=law.controller, robot=law.robot, gait_file=str(args.gait),
                  gait_sha256=provenance["gait file sha256"], gait_digest=law.gait_digest,
                  nq=law.nq, nu=law.nu, nqe=law.nqe, saturate=ctrl.saturate,
                  clipped_at=ctrl.clipped_at)
    with staged_export(files, args.out, {GAIT_COPY: data}) as stage:
        if cc is not None:
            say(f"compiling with {' '.join(cc)} and comparing with the Python law "
                f"({args.states} states per phase, {args.strides} MuJoCo strides) ...")
            try:
                ver = verify_running_export(stage.path, ctrl, cc, args.states, args.strides)
            except CompilerError as e:
                raise UserError(f"--verify: {e}; nothing written") from None
            keep_verified(stage, result, ver, "biped export-running", "biped_running_torque",
                          lambda timing: running_c_sources(law, provenance,
                                                           timing)["README.md"])
    _report(args, result)
    return 0 if result["status"] in ("written", "verified") else 1


def _report(args, r):
    if args.json:
        print_json(r)
        return
    c = r["controller"]
    if r["status"] in ("written", "verified"):
        print(f"wrote {r['out']}: " + ", ".join(r["files"]))
    clip = f", torques clipped at {torque_bound_text(c['torque_limit'])} N m" \
        if c["saturate"] else ""
    print(f"  running controller ({c['law']}), Kp {c['Kp']}, Kd {c['Kd']}, M1 {c['M1']}"
          f"{clip}; robot {r['robot']} (nq {r['nq']}, nu {r['nu']}, flight nqe {r['nqe']})")
    print(f"  gait {r['gait_file']}, sha256 {r['gait_sha256']}")
    print(f"  build: gcc -O2 -shared -fPIC -o {RUNNING_LIBRARY} {r['out']}/*.c -lm")
    v = r.get("verification")
    if v is None:
        return
    s, m = v["states"], v["mujoco"]
    print(f"verification: {v['status']}" + ("" if v["status"] == "verified" else
                                             " (nothing written: the export is not in place)"))
    rel, same = s["max_torque_rel"], s["bitwise_equal"]
    print(f"  {s['n']} random states per phase: torques differ by at most "
          f"{rel['stance']:.3g} (stance), {rel['flight']:.3g} (flight) relative (limit "
          f"{TORQUE_RTOL:g}); equal bit for bit at {same['stance'] + same['flight']} of "
          f"{2 * s['n']}; return codes {s['return_codes']}")
    if m is not None and m["status"] == "nothing_compared":
        print(f"  {m['message']}, nothing verified: the design does not run in MuJoCo "
              "('biped mujoco-running' shows how it stops; --strides 0 compares the states "
              "only)")
    elif m is not None:
        worst = m["max_difference"]         # None: inf (a number in one record only)
        print(f"  MuJoCo, {m['strides']} strides with the library ({m['compiled_status']}) and "
              f"with the Python law ({m['python_status']}): records differ by at most "
              f"{'inf' if worst is None else format(worst, '.3g')} (limit {STRIDE_TOL:g}), "
              f"{m['identical_strides']} "
              f"strides identical; {m['compiled_seconds']:.2f} s against "
              f"{m['python_seconds']:.2f} s")
    print(f"  time per call: {v['c_us']:.3f} us in C (the example's loop, {v['c_calls']} "
          f"calls), {s['ctypes_us']:.2f} us through ctypes, {s['python_us']:.1f} us for the "
          f"Python law's Function (C {s['python_us'] / v['c_us']:.0f} times faster)")


def register(sub):
    p = sub.add_parser(
        "export-running",
        help="write the running controller as self-contained C99 code (and check it)",
        description="Write the tracking controller of a running step saved by 'biped "
                    "running' (the --kp, --kd, --m1, --law of 'biped mujoco-running') as "
                    "C99 code that needs only the C library and libm: "
                    f"DIR/{RUNNING_HEADER} declares biped_running_sizes and "
                    "biped_running_torque(phase, t, q, dq, u), phase 0 stance (q, dq) or 1 "
                    "flight (the extended qe, dqe), t the time since the phase began; the "
                    "gains are part of the code. DIR/*.c build with 'gcc -O2 -shared -fPIC "
                    f"-o {RUNNING_LIBRARY} DIR/*.c -lm', DIR/README.md says how to call it "
                    "and DIR/example/main.c times it. --verify compiles it, compares its "
                    "torques with the Python law's at random states of both phases (to 1e-12 "
                    "relative) and a MuJoCo run driven by the library with the same run "
                    "driven by the Python law (stride records to 1e-9), and prints the "
                    "time per call; a difference beyond the limits, or runs that both stop "
                    "in their first stride (nothing compared), exits with 1 and writes "
                    "nothing. 'biped mujoco-running --compiled DIR' runs the export in "
                    "MuJoCo. The folder appears complete or not at all.")
    p.add_argument("--gait", required=True, metavar="FILE",
                   help="a running step saved by 'biped running --out FILE'")
    add_robot(p)
    add_tracking_arguments(p)
    p.add_argument("--saturate", action="store_true",
                   help="clip the law's torques at the robot's limit (or --torque-limit), as "
                        "'biped running --saturate' does (the clipping is part of the C "
                        "code; --verify compares it with the Python law clipped the same "
                        "way and runs MuJoCo with motors of that limit)")
    p.add_argument("--torque-limit", type=float, metavar="U",
                   help="with --saturate: the limit the law clips at, N m (default the "
                        "robot's)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="the folder to write (new, empty, or an earlier export, replaced)")
    p.add_argument("--verify", action="store_true",
                   help="compile with $CC (or gcc, cc), compare with the Python law, time it")
    p.add_argument("--states", type=int, default=STATES, metavar="N",
                   help=f"random states per phase --verify compares ({STATES})")
    p.add_argument("--strides", type=int, default=STRIDES, metavar="N",
                   help=f"strides of --verify's MuJoCo comparison, 0 to 5000 ({STRIDES}; "
                        "0: none)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_export_running)
