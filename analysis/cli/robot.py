"""``biped robot import``: a URDF file turned into the equivalent robot description
(TOML); ``biped robot mjcf``: a robot as a MuJoCo model (MJCF).  Reads top to bottom; the
import itself is :func:`biped_casadi.model.urdf.import_urdf`, the MJCF
:func:`biped_casadi.mujoco.mjcf`.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from biped_casadi.files import write_text_atomic
from biped_casadi.model.description import load_description, torque_bound_text
from biped_casadi.model.urdf import (MATCH_TOL, MAX_LEG, MAX_MATCH_TOL, description_toml,
                                     import_urdf, xacro_refusal)
from biped_casadi.model.urdf_legs import check_match_tol
from biped_casadi.model.urdf_tree import lock_table
from biped_casadi.mujoco import mjcf, mujoco_module

from .common import ROBOT_HELP, UserError, load_model, output_file, positive, print_json
from .mujoco_options import add_mujoco_settings, mujoco_settings, settings_error


def _locks(args) -> dict:
    """--lock NAME[=RAD] ... as name -> angle; --axis only with --lock-off-axis."""
    pairs = []
    for token in args.lock or []:
        name, eq, value = token.partition("=")
        try:
            angle = float(value) if eq else 0.0
        except ValueError:
            raise UserError(f"--lock {token}: the angle after '=' must be a number (rad)"
                            ) from None
        pairs.append((name.strip(), angle))
    if args.axis is not None and not args.lock_off_axis:
        raise UserError("--axis chooses the plane's normal for --lock-off-axis; give both "
                        "or neither")
    try:
        return lock_table(pairs, args.lock_off_axis, args.axis)
    except ValueError as e:
        raise UserError(f"--{e}") from None


def _beyond(args) -> float:
    """--foot-beyond checked (UserError)."""
    d = args.foot_beyond
    if d is None:
        return 0.0
    if not (math.isfinite(d) and 0 <= d <= MAX_LEG):
        raise UserError(f"--foot-beyond must be a distance in [0, {MAX_LEG:g}] m, got {d:g}")
    return d


def _match_tol(value) -> float:
    """--match-tol checked by the importer's own check (UserError naming the option)."""
    if value is None:
        return MATCH_TOL
    try:
        return check_match_tol(value)
    except ValueError as e:
        raise UserError("--" + str(e).replace("match_tol", "match-tol", 1)) from None


def cmd_import(args):
    src = Path(args.file)
    if src.suffix.lower() == ".xacro":
        raise UserError(f"FILE: {src.name} is a xacro file, not a URDF: "
                        f"{xacro_refusal(src.name)}")
    if src.suffix.lower() != ".urdf":
        raise UserError(f"FILE: a URDF file (.urdf) is expected, got {str(args.file)!r}")
    if not src.is_file():
        raise UserError(f"FILE: URDF file not found: {src}")
    out = output_file(args.out, "--out", (".toml",))
    foot = None
    if args.foot is not None:
        foot = np.array(args.foot, dtype=float)
        if not np.all(np.isfinite(foot)):
            raise UserError("--foot takes 3 finite numbers (x y z in m)")
    if args.torque_limit is not None and not (math.isfinite(args.torque_limit)
                                              and args.torque_limit > 0):
        raise UserError(f"--torque-limit must be a positive number (N m), got "
                        f"{args.torque_limit:g}")
    imp = import_urdf(src, foot, torque_limit=args.torque_limit, lock=_locks(args),
                      lock_off_axis=args.lock_off_axis, axis=args.axis,
                      match_tol=_match_tol(args.match_tol), foot_beyond=_beyond(args),
                      torso=args.torso)
    header = f"made by 'biped robot import' from {src.name}"
    if imp.locked:
        header += "\nits sagittal model, with these joints locked (rad): " + ", ".join(
            f"{k} = {v!r}" for k, v in imp.locked.items())
    text = description_toml(imp.description, header)
    write_text_atomic(out, text)
    back = load_description(out)                 # the file reads back to the same robot
    if back != imp.description or back.urdf != imp.description.urdf:
        raise RuntimeError(f"{out} does not read back to the imported robot")
    d = imp.description
    summary = dict(file=str(out), source=str(src), robot=d.to_dict(), torso=imp.torso,
                   legs=[list(leg) for leg in imp.legs], foot=imp.foot, notes=imp.notes,
                   locked=imp.locked,
                   total_mass=d.total_mass, torque_limit=d.torque_limit,
                   joint_map=d.urdf.describe())
    if args.json:
        print_json(summary)
        return 0
    print(f"{d}; written to {out}")
    print(f"  torso {imp.torso!r}; legs {', '.join(' -> '.join(leg) for leg in imp.legs)}; "
          f"foot from {imp.foot}")
    for link in (d.torso,) + d.leg:
        off = f" (off its line by {link.com_offset:g} m)" if link.com_offset else ""
        print(f"  {link.name:8s} mass {link.mass:g} kg, length {link.length:g} m, "
              f"com {link.com:g} m{off}, inertia {link.inertia:g} kg m^2")
    for joint, m in d.point_masses:
        print(f"  point mass {m:g} kg at the {joint}")
    print(f"  rotor inertia {d.rotor_inertia:g} kg m^2 (reflected), torque limit "
          f"{d.torque_limit_text}")
    print("  joint map, URDF angle theta -> the model's angle of the joint's child link "
          "relative to its parent (the swing leg's coordinates; the stance leg's are "
          "their negatives):")
    for line in d.urdf.describe():
        print(f"    {line}")
    for note in imp.notes:
        print(f"  note: {note}")
    return 0


def cmd_mjcf(args):
    out = output_file(args.out, "--out", (".xml",))
    settings = mujoco_settings(args)
    if args.torque_limit is not None:
        positive(args.torque_limit, "--torque-limit")
    model = load_model(args.robot)
    try:
        text = mjcf(model, settings, args.torque_limit)
    except ValueError as e:
        raise settings_error(e) from None
    mujoco = mujoco_module()
    try:
        m = mujoco.MjModel.from_xml_string(text)
    except ValueError as e:
        raise UserError(f"MuJoCo rejects the model: {str(e).splitlines()[0]}") from None
    write_text_atomic(out, text)
    d = model.description
    summary = dict(file=str(out), robot=d.name, settings=settings.to_dict(),
                   torque_limit=float(min(m.actuator_ctrlrange[:, 1])),
                   motor_limits=[float(v) for v in m.actuator_ctrlrange[:, 1]], nq=int(m.nq),
                   actuators=int(m.nu), total_mass=float(sum(m.body_mass)),
                   joints=[mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, i)
                           for i in range(m.njnt)])
    if args.json:
        print_json(summary)
        return 0
    print(f"{d.name}: MuJoCo model written to {out}")
    print(f"  joints {', '.join(summary['joints'])} (planar floating base at the hip: x, z, "
          f"pitch); {summary['actuators']} motors limited to "
          f"{torque_bound_text(sorted(set(summary['motor_limits'])))} N m; total mass {summary['total_mass']:g} kg")
    s = settings
    print(f"  {s.contact} contact (solref {s.solref if s.solref is not None else 'MuJoCo default 0.02'}"
          f" s), time step {s.timestep:g} s, sphere feet of {s.foot_radius:g} m, mu {s.mu:g}")
    return 0


def register(sub):
    p = sub.add_parser("robot", help="robot files: import a URDF, write a MuJoCo model",
                       description="Robot files. 'biped robot import FILE.urdf --out "
                                   "robot.toml' reads a planar point-foot biped from a URDF "
                                   "and writes the equivalent description file; 'biped robot "
                                   "mjcf --out robot.xml' writes a robot as a MuJoCo model.")
    acts = p.add_subparsers(dest="action", metavar="ACTION")
    acts.required = True
    _register_import(acts)
    q = acts.add_parser(
        "mjcf", help="a robot as a MuJoCo model (MJCF)",
        description="Write the MuJoCo model (MJCF) of a robot the toolkit reads: a planar "
                    "floating base at the hip (slide x, slide z, hinge pitch), hinges with "
                    "the rotor inertia as armature, motors limited to the torque limit, "
                    "sphere feet (the only geometry that collides). Its mass matrix equals "
                    "the toolkit's (tested to 1e-12). MuJoCo's own URDF loader would weld the "
                    "torso to the world, drop the rotor inertia and make no motors.")
    q.add_argument("--robot", metavar="NAME|FILE", help=f"{ROBOT_HELP}; default: rabbit")
    q.add_argument("--out", metavar="FILE.xml", required=True, help="the MJCF file to write")
    add_mujoco_settings(q, gait=False)
    q.add_argument("--torque-limit", type=float, metavar="U",
                   help="the motors' limit, N m (default the robot's)")
    q.add_argument("--json", action="store_true", help="print one JSON object")
    q.set_defaults(func=cmd_mjcf)


def _register_import(acts):
    q = acts.add_parser("import", help="a URDF file as a robot description (TOML)",
                        description="Read a planar biped from a URDF (a torso and two "
                                    "identical legs of revolute or continuous joints about "
                                    "one axis n, +n or -n per joint (n across the torso "
                                    "frame's z: its y, its x, ...), in any zero pose; "
                                    "inertials anywhere in the plane, joint origins, "
                                    "transmissions, effort limits) and write the equivalent "
                                    "description file, with the map from the URDF's joint "
                                    "angles to the model's (printed; the [urdf] table). A "
                                    "3-D biped's sagittal model: lock its other joints "
                                    "(--lock NAME[=RAD], --lock-off-axis). A CAD export: "
                                    "axes within 1e-3 rad (rounded angles) turn about their "
                                    "mean; mirrored legs that differ in their last digits "
                                    "import as their mean with --match-tol.")
    q.add_argument("file", metavar="FILE.urdf",
                   help="the URDF file (a xacro file: expand it first, 'xacro FILE.xacro "
                        "> robot.urdf')")
    q.add_argument("--foot", nargs=3, type=float, metavar=("X", "Y", "Z"),
                   help="the foot point in the last leg link's frame, m (when the file has "
                        "no foot link or frame)")
    q.add_argument("--torque-limit", type=float, metavar="N",
                   help="the robot's torque limit, N m (default: the smallest <limit "
                        "effort> of the leg joints; none when they give none, e.g. "
                        "continuous joints without <limit>)")
    q.add_argument("--lock", nargs="+", action="extend", metavar="NAME[=RAD]",
                   help="hold these revolute/continuous joints fixed at RAD (default 0; "
                        "repeatable): a 3-D robot's sagittal model (hip yaw and roll, ankle "
                        "joints, arms); each becomes a fixed joint and its child links merge "
                        "into its parent")
    q.add_argument("--lock-off-axis", action="store_true",
                   help="also lock at 0 every revolute/continuous joint below the torso "
                        "whose axis (at the file's zero angles) is not parallel to the "
                        "plane's normal n: --axis, else the direction across the torso "
                        "frame's z that most of those joints turn about (a tie: the one "
                        "nearer the torso's y, then the first in the file); a joint given "
                        "with --lock keeps its angle")
    q.add_argument("--foot-beyond", type=float, metavar="D",
                   help="the foot D m beyond the foot point found (or --foot), along the "
                        "last link's line: the sole below a locked ankle, for legs whose "
                        "shins' frames differ (a mirrored export), where one --foot point "
                        "cannot serve both")
    q.add_argument("--torso", metavar="LINK",
                   help="the torso link, when the file hangs the robot from a test rig or "
                        "a boom (joints of any type above it): those joints and the links "
                        "above and beside it are left out (default: the root, or the first "
                        "link with mass below a massless world link)")
    q.add_argument("--match-tol", type=float, metavar="REL",
                   help="how closely the two legs (masses, lengths, centres of mass, "
                        "inertias, relative to the leg's mass and length) and the hips in "
                        "the plane must agree; within it the model's leg is their mean, "
                        f"the notes give the largest difference (default {MATCH_TOL:g}: "
                        "identical legs; a CAD export's mirrored legs differ by about 1e-4; "
                        f"at most {MAX_MATCH_TOL:g})")
    q.add_argument("--axis", choices=("x", "y"),
                   help="with --lock-off-axis: the plane's normal n is this axis of the "
                        "torso's frame (z, vertical at pitch 0, lies in the plane)")
    q.add_argument("--out", metavar="FILE.toml", required=True,
                   help="the description file to write")
    q.add_argument("--json", action="store_true", help="print one JSON object")
    q.set_defaults(func=cmd_import)
