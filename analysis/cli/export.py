"""``biped export``: a controller as self-contained C99 code (header, law, README,
example), optionally compiled and compared with the Python law (``--verify``)."""
from __future__ import annotations

import hashlib
import os
import platform
import sys
import tempfile
from pathlib import Path

from biped_casadi import Gains, SimulationOptions, TimeVaryingController, VirtualConstraintController
from biped_casadi.control.compiled import CompilerError, find_c_compiler
from biped_casadi.control.export import EXPORT_ANGLES, HEADER, c_sources, exported_law
from biped_casadi.control.export_folder import check_destination, staged_export
from biped_casadi.model.description import torque_bound_text
from gait_opt.cache import cache_path
from analysis.verify_export import SIMULATION_TOL, TORQUE_RTOL, apart_reason, verify_export

from .common import (Progress, UserError, add_design_arguments, add_gait_arguments, add_robot,
                     check_m1_values, check_saturation, check_torque_limit, gait_friction,
                     load_gait, MU_HELP, output_dir, parse_m1, positive, print_json,
                     rejoin_fraction)
from .simulate import MAX_STEPS, _check_perturbation, _perturbation

#: random states the check compares by default
STATES = 10_000
#: the paper's perturbation (§V-C), rad and rad/s: --verify's default start
PAPER_PERTURBATION = (0.01, 0.1)


def _gains(args) -> Gains:
    """--gains KP KD EPS, or --eps (the output PD of eq. 13)."""
    if args.gains is not None and args.eps is not None:
        raise UserError("--gains excludes --eps (give the three gains with --gains)")
    if args.gains is not None:
        for name, v in zip(("KP", "KD", "EPS"), args.gains):
            positive(v, f"--gains {name}")
        return Gains(*args.gains)
    return Gains(eps=positive(args.eps, "--eps") if args.eps is not None else 0.02)


def _check_arguments(args):
    """Everything that can be checked before the gait is loaded; the C compiler of
    --verify (None without)."""
    check_m1_values(args.m1)
    if args.controller == "vc" and (args.m1 is not None or args.rejoin is not None):
        raise UserError("--m1 and --rejoin apply to the time-varying controller "
                        "(--controller tv)")
    if args.rejoin is not None:
        rejoin_fraction(args.rejoin)
    _gains(args)
    if not 1 <= args.steps <= MAX_STEPS:
        raise UserError(f"--steps must be between 1 and {MAX_STEPS}, got {args.steps}")
    if args.mu is not None:
        positive(args.mu, "--mu")
    check_torque_limit(args)
    if args.motor_side and args.angles != "urdf":
        raise UserError("--motor-side divides the URDF joints' torques by their reductions: "
                        "it needs --angles urdf")
    _check_perturbation(args)
    if args.perturb is None and args.perturb_q is None and args.perturb_dq is None:
        args.perturb = list(PAPER_PERTURBATION)
    return check_target(args)


def check_target(args):
    """``--out`` (a folder that can be written, or an earlier export to replace) and
    ``--states``; the C compiler of ``--verify`` (None without).

    Parameters
    ----------
    args : argparse.Namespace
        With ``out``, ``states`` and ``verify``.

    Returns
    -------
    list of str or None
        The compiler's command.

    Raises
    ------
    UserError
        A bad ``--out`` or ``--states``, or ``--verify`` without a compiler.
    """
    if not 1 <= args.states <= 1_000_000:
        raise UserError(f"--states must be between 1 and 1000000, got {args.states}")
    output_dir(args.out, "--out")
    try:
        check_destination(args.out)
    except ValueError as e:
        raise UserError(f"--{e}") from None
    if not args.verify:
        return None
    cc = find_c_compiler()
    if cc is None:
        env = os.environ.get("CC", "").strip()
        why = (f"CC={env} is not a program found on PATH" if env
               else "neither gcc nor cc is installed, and CC is not set")
        raise UserError(f"--verify: no C compiler ({why}); nothing written")
    return cc


def _controller(args, gait):
    model = gait.model
    gains = _gains(args)
    if args.controller == "vc":
        return VirtualConstraintController(gait, gains=gains)
    M1 = parse_m1(args.m1, model.nu, default_zero=True)
    return TimeVaryingController(gait, M1, gains,
                                 rejoin=0.5 if args.rejoin is None else args.rejoin)


def _gait_file(args, gait) -> tuple:
    """(the gait file's name for the header, its bytes): the file given, or the default
    gait's cache file (saved afresh when the cache holds none)."""
    if args.gait:
        return str(args.gait), Path(args.gait).read_bytes()
    path = cache_path(gait.model, gait.options)
    if path.is_file():
        return f"{path} (the default gait of {gait.model.params.name})", path.read_bytes()
    with tempfile.TemporaryDirectory() as tmp:
        gait.save(Path(tmp) / "gait.json")
        return (f"the default gait of {gait.model.params.name}",
                (Path(tmp) / "gait.json").read_bytes())


def _machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return cpu


def cmd_export(args):
    # ---- arguments (the output folder and the compiler before any work)
    cc = _check_arguments(args)
    say = Progress("export", quiet=args.json)
    gait = load_gait(args, say)
    if args.angles == "urdf" and gait.model.description.urdf is None:
        raise UserError(f"--angles urdf: the robot {gait.model.params.name} has no URDF joint "
                        f"map (give --robot FILE.urdf, a description written by 'biped robot "
                        f"import', or a gait made for one); nothing written")
    if args.motor_side and all(j.reduction == 1.0 for j in gait.model.description.urdf.joints):
        print("biped export: warning: --motor-side: the robot's URDF has no <transmission> "
              "with a mechanicalReduction: every reduction is 1, so the motors' torques are "
              "the joints'", file=sys.stderr, flush=True)
    _perturbation(args, gait.model.nq)       # its shape, also when only --verify uses it
    check_saturation(args, gait.model)
    ctrl = _controller(args, gait)
    try:
        law = exported_law(ctrl, angles=args.angles, motor_side=args.motor_side,
                           saturate=args.saturate, torque_limit=args.torque_limit)
    except ValueError as e:
        what = "--m1" if args.controller == "tv" else "--controller vc"
        raise UserError(f"{what}: {str(e).split(': ', 1)[1]}; nothing written") from None
    name, data = _gait_file(args, gait)
    provenance = {"gait file": name, "gait file sha256": hashlib.sha256(data).hexdigest(),
                  "copy of the gait file": "gait.json"}

    # ---- write (staged), verify, move into place
    say(f"generating C for the {'time-varying' if law.kind == 'tv' else 'virtual-constraint'}"
        " controller ...")
    files = c_sources(law, provenance)
    result = dict(status="written", out=str(args.out), files=sorted(files) + ["gait.json"],
                  controller=ctrl.describe(), robot=law.robot, gait_file=name,
                  gait_sha256=provenance["gait file sha256"], nq=law.nq, nu=law.nu,
                  nstate=law.nstate, angles=law.angles, saturate=args.saturate,
                  clipped_at=law.torque_limit)
    if law.angles == "urdf":
        result.update(inputs=["pitch"] + list(law.urdf.names), torques=list(law.urdf.names),
                      motor_side=law.motor_side, stance_legs=list(law.urdf.hips))
    with staged_export(files, args.out, {"gait.json": data}) as stage:
        if cc is not None:
            say(f"compiling with {' '.join(cc)} and comparing with the Python law "
                f"({args.states} states, a {args.steps}-step simulation) ...")
            model = gait.model
            q0, dq0 = _perturbation(args, model.nq).initial_state(gait)
            result["friction"] = gait_friction(args, gait)
            opts = SimulationOptions(steps=args.steps, mu=args.mu, saturate=args.saturate,
                                     torque_limit=args.torque_limit)
            try:
                ver = verify_export(stage.path, ctrl, q0, dq0, opts, cc, args.states,
                                    law=law)
            except CompilerError as e:
                raise UserError(f"--verify: {e}; nothing written") from None
            keep_verified(stage, result, ver, "biped export", "biped_torque",
                          lambda timing: c_sources(law, provenance, timing)["README.md"])
    _report(args, result)
    return 0 if result["status"] in ("written", "verified") else 1



def keep_verified(stage, result: dict, ver, command: str, function: str, readme):
    """Record a verification in ``result``: a verified export's README gets the measured
    time per call, a failed one is discarded (nothing is put in place).

    Parameters
    ----------
    stage : export_folder.Stage
        The staged export.
    result : dict
        The command's result; gets ``verification`` and ``status``.
    ver : Result
        The verification (``success``, ``status``, ``c_us``, ``c_calls``, ``to_dict()``).
    command, function : str
        The command that measured, the C function timed.
    readme : callable
        The README's text for a timing line.
    """
    result["verification"] = ver.to_dict()
    result["status"] = ver.status
    if not ver.success:
        stage.discard()
        return
    timing = (f"\nMeasured by `{command} --verify` ({_machine()}): {ver.c_us:.3f} us per "
              f"`{function}` call in the example's loop ({ver.c_calls} calls).\n")
    (stage.path / "README.md").write_text(readme(timing), encoding="utf-8")


def _report(args, r):
    if args.json:
        print_json(r)
        return
    c = r["controller"]
    if r["status"] in ("written", "verified"):
        print(f"wrote {r['out']}: " + ", ".join(r["files"]))
    desc = (f"time-varying controller, M1 = {c['M1']}, rejoin {c['rejoin']:g} T"
            if c["controller"] == "tv" else "virtual-constraint controller fitted to the gait")
    g = c["gains"]
    if r["saturate"]:
        desc += f", torques clipped at {torque_bound_text(r['clipped_at'])} N m"
    print(f"  {desc}, gains Kp {g['Kp']:g} Kd {g['Kd']:g} eps {g['eps']:g} s; robot "
          f"{r['robot']} (nq {r['nq']}, nu {r['nu']}, nstate {r['nstate']})")
    print(f"  gait {r['gait_file']}, sha256 {r['gait_sha256']}")
    if r["angles"] == "urdf":
        print(f"  inputs: {', '.join(r['inputs'])} (and rates); torques on "
              f"{', '.join(r['torques'])} ({'motor' if r['motor_side'] else 'joint'} side); "
              f"state[0] the stance leg: 0 {r['stance_legs'][0]}, 1 {r['stance_legs'][1]}")
    print(f"  build: gcc -O2 -shared -fPIC -o libbiped_controller.so {r['out']}/*.c -lm")
    v = r.get("verification")
    if v is None:
        return
    s, m = v["states"], v["simulation"]
    print(f"verification: {v['status']}" + ("" if v["success"] else
                                             " (nothing written: the export is not in place)"))
    where = " (URDF angles, random stance legs)" if r["angles"] == "urdf" else ""
    print(f"  {s['n']} random states near the orbit{where}: torques differ by at most "
          f"{s['max_torque_rel']:.3g} relative ({s['max_torque_abs']:.3g} N m; limit "
          f"{TORQUE_RTOL:g}); outputs by {s['max_output_abs']:.3g}, denominator by "
          f"{s['max_den_rel']:.3g} relative; return codes {s['return_codes']}")
    if s.get("starts_refused") or s.get("starts_disagree"):
        print(f"  step starts: {s['starts_refused']} of the {s['n']} refused by both laws "
              f"(the phase moving backwards), {s['starts_disagree']} by one law only")
    if s.get("stance_found") is not None:
        started = s["n"] - s.get("starts_refused", 0) - s.get("starts_disagree", 0)
        print(f"  biped_step_start found the stance leg at {s['stance_found']} of {started} "
              f"step starts")
    if m.get("start") == "orbit":
        print(f"  {m['message'].split('; from the orbit')[0]}: compared from the orbit's start "
              "instead")
    if m["status"] == "nothing_compared":
        print(f"  from the orbit's start too the runs ended before an impact "
              f"({m['compiled_status']}): no impact to compare, nothing verified (the "
              "design does not walk there: 'biped simulate' shows how it stops)")
    else:
        _report_simulation(m, r["friction"], c["controller"])
    print(f"  time per call: {v['c_us']:.3f} us in C (the example's loop, {v['c_calls']} "
          f"calls), {s['ctypes_us']:.2f} us through ctypes, {s['python_us']:.1f} us for the "
          f"Python law one state at a time (C {s['python_us'] / v['c_us']:.0f} times faster)")


def _report_simulation(m: dict, friction: str, controller: str):
    print(f"  {m['steps']}-impact simulation ({friction}) driven by the library "
          f"({m['compiled_status']}) "
          f"against biped simulate's ({m['python_status']}): impact times differ by at most "
          f"{m['max_impact_time']:.3g} s, states by {m['max_state']:.3g} (limit "
          f"{SIMULATION_TOL:g})")
    print(f"  against the Python law driven the same way ({m['twin_status']}): "
          f"{m['twin_max_impact_time']:.3g} s, {m['twin_max_state']:.3g}"
          + ("" if m["status"] != "discretisation" else
             "; the larger difference from biped simulate is "
             + apart_reason(int(controller == "tv"))))


def register(sub):
    p = sub.add_parser(
        "export", help="write a controller as self-contained C99 code (and check it)",
        description="Write the controller that 'biped simulate' runs (the same options; "
                    "'biped m1 --robust' prints them as simulate_args) as C99 code that "
                    f"needs only the C library and libm: DIR/{HEADER} declares "
                    "biped_sizes, biped_step_start and biped_torque (and biped_outputs), "
                    "DIR/*.c build with 'gcc -O2 -shared -fPIC -o libbiped_controller.so "
                    "DIR/*.c -lm', DIR/README.md says how to call it and "
                    "DIR/example/main.c times it. --verify compiles it, compares it with "
                    "the Python law on random states near the orbit (torques to 1e-12 "
                    "relative) and on a full-order simulation driven by the compiled law "
                    "(impact times and states to 1e-9 against the Python law driven the "
                    "same way; biped simulate's run, which integrates the time-varying "
                    "law's reference state with the robot, is compared too and differs by "
                    "that discretisation), and prints the largest differences and the time "
                    "per call; a difference beyond the limits, or runs that all end "
                    "before an impact (nothing compared), exits with 1 and writes "
                    "nothing. The folder appears complete or not at all.")
    add_gait_arguments(p)
    add_robot(p)
    add_design_arguments(p, m1_zero=True)
    p.add_argument("--gains", nargs=3, type=float, metavar=("KP", "KD", "EPS"),
                   help="output PD of eq. (13) (default 1 2 0.02)")
    p.add_argument("--eps", type=float, help="epsilon of eq. (13) with Kp = 1, Kd = 2 "
                                             "(as 'biped simulate'; excludes --gains)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="the folder to write (new, empty, or an earlier export, replaced)")
    p.add_argument("--angles", choices=EXPORT_ANGLES, default="relative",
                   help="the law's coordinates: the toolkit's relative angles q (default), or "
                        "'urdf': the robot's own URDF joint angles and its root link's pitch "
                        "in, one torque per URDF joint out (file order and sign), the stance "
                        "leg in the state (needs the robot's URDF map: --robot FILE.urdf, a "
                        "description from 'biped robot import', or a gait made for one)")
    p.add_argument("--motor-side", action="store_true",
                   help="with --angles urdf: torques divided by each joint's transmission "
                        "reduction (the motors' torques)")
    p.add_argument("--verify", action="store_true",
                   help="compile with $CC (or gcc, cc), compare with the Python law, time it")
    p.add_argument("--states", type=int, default=STATES, metavar="N",
                   help=f"random states --verify compares ({STATES})")
    p.add_argument("--steps", type=int, default=10, metavar="N",
                   help="steps of --verify's simulation (10)")
    p.add_argument("--perturb", nargs=2, type=float, default=None, metavar=("Q_ERR", "DQ_ERR"),
                   help="initial error of --verify's simulation on every joint (rad) and "
                        "velocity (rad/s) (default the paper's: 0.01 0.1)")
    p.add_argument("--perturb-q", nargs="+", type=float, metavar="Q",
                   help="initial error of each joint angle, rad (instead of --perturb)")
    p.add_argument("--perturb-dq", nargs="+", type=float, metavar="DQ",
                   help="initial error of each joint velocity, rad/s (instead of --perturb)")
    p.add_argument("--mu", type=float,
                   help=f"friction coefficient of --verify's simulation ({MU_HELP})")
    p.add_argument("--torque-limit", type=float, metavar="U",
                   help="torque limit of --verify's simulation, N m (default the robot's); "
                        "with --saturate also the limit the law clips at; without either "
                        "unused (accepted: 'biped m1 --robust''s simulate_args replay here "
                        "unchanged)")
    p.add_argument("--saturate", action="store_true",
                   help="clip the law's torques at the robot's limit (or --torque-limit), as "
                        "'biped simulate' does with saturation and 'biped export-running "
                        "--saturate' for running (the clipping is part of the C code; "
                        "--verify compares it with the Python law clipped the same way and "
                        "simulates with the torques saturated instead of stopping at the "
                        "limit)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_export)
