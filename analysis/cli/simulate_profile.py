"""``biped simulate --gait FAMILY.json --speeds V1 V2 ...`` (or ``--ramp V1 V2 DV``): a
speed profile walked in full order, step k on the family's gait at Vk.  Reads top to
bottom; the computation is in :mod:`analysis.design.schedule` (speeds, gaits, designs)
and :func:`biped_casadi.simulation.simulate_profile`, the figure in
:mod:`analysis.reporting.plots`."""
from __future__ import annotations


import numpy as np

from biped_casadi import Gains, SimulationOptions
from biped_casadi.simulation import simulate_profile
from analysis.design.schedule import (M1Schedule, check_profile, profile_designs,
                                      profile_gaits, ramp_speeds)
from analysis.reporting.plots import save_figures, speed_profile_plot
from gait_opt import GaitFamily

from .common import (UserError, check_not_singular, figure_or_na, friction_source, load_model,
                     output_dir, parse_m1, print_json, require_members)

__all__ = ["add_profile_arguments", "profile_requested", "check_profile_arguments",
           "cmd_profile"]

#: a profile longer than this fills the memory with the logged states
MAX_PROFILE = 1000


def add_profile_arguments(p):
    """The speed-profile options of ``biped simulate``."""
    p.add_argument("--speeds", nargs="+", type=float, metavar="V",
                   help="a speed profile: step k walks the gait of --gait FAMILY.json at "
                        "speed Vk (m/s; a member, or between members the family's "
                        "interpolant polished to an exact orbit); the reference switches "
                        "gait at each impact")
    p.add_argument("--ramp", nargs=3, type=float, metavar=("V1", "V2", "DV"),
                   help="a speed profile: up from V1 to V2 and back down to V1 by DV per "
                        "step (m/s; V1 < V2, V2 - V1 a whole number of DV)")
    p.add_argument("--hold", type=int, default=0, metavar="N",
                   help="with --speeds or --ramp: N more steps at the profile's last speed "
                        "(0)")
    p.add_argument("--schedule", metavar="FILE",
                   help="with --controller tv and a profile: M1 (and the rejoin time) per "
                        "speed from a JSON schedule file, interpolated linearly in speed "
                        "(format: docs/howto/speed-changes.md); instead of one --m1")


def profile_requested(args) -> bool:
    """Whether the command walks a speed profile."""
    return args.speeds is not None or args.ramp is not None


def check_profile_arguments(args):
    """Conflicts of the profile options, before any file is read (UserError)."""
    if not profile_requested(args):
        for name in ("schedule",):
            if getattr(args, name) is not None:
                raise UserError(f"--{name} applies with --speeds or --ramp only")
        if args.hold:
            raise UserError("--hold applies with --speeds or --ramp only")
        return
    if args.speeds is not None and args.ramp is not None:
        raise UserError("--speeds and --ramp exclude each other")
    if not args.gait:
        raise UserError("--speeds/--ramp need --gait FAMILY.json (a gait family from "
                        "'biped gait --speeds A:B:STEP')")
    for flag, given in (("--steps", args.steps is not None), ("--terrain", args.terrain),
                        ("--animate", args.animate), ("--allow-open-orbit",
                                                      args.allow_open_orbit)):
        if given:
            raise UserError(f"{flag} does not apply with a speed profile (one step per "
                            "speed; --hold adds steps at the last one)")
    if args.schedule is not None and args.controller == "vc" and not args.compare:
        raise UserError("--schedule applies to the time-varying controller (--controller "
                        "tv, or --compare)")
    if args.schedule is not None and args.m1 is not None:
        raise UserError("--schedule and --m1 exclude each other (the schedule gives M1)")
    if args.hold < 0 or args.hold > MAX_PROFILE:
        raise UserError(f"--hold must be between 0 and {MAX_PROFILE}, got {args.hold}")


def _speeds(args) -> np.ndarray:
    """The profile's speeds (UserError naming --speeds or --ramp)."""
    try:
        if args.ramp is not None:
            v = ramp_speeds(*args.ramp, hold=args.hold)
        else:
            v = check_profile(args.speeds, hold=args.hold)
    except ValueError as e:
        opt = "--ramp" if args.ramp is not None else "--speeds"
        raise UserError(f"{opt}: {str(e).removeprefix('speeds: ')}") from None
    if v.size > MAX_PROFILE:
        raise UserError(f"the profile has {v.size} steps, more than {MAX_PROFILE}")
    return v


def _schedule(args, nu: int) -> M1Schedule:
    if args.schedule is not None:
        try:
            s = M1Schedule.load(args.schedule)
        except ValueError as e:
            raise UserError(f"--schedule: {e}") from None
        if len(s.M1[0]) != nu:
            raise UserError(f"--schedule: M1 has {len(s.M1[0])} components, this robot "
                            f"{nu} (one per torque)")
        return s
    return M1Schedule.constant(parse_m1(args.m1, nu, default_zero=True), args.rejoin)


def _designs(kind, gaits, speeds, schedule, gains):
    """The profile's designs; a time-varying one singular on its gait is refused."""
    try:
        designs = profile_designs(gaits, kind, schedule if kind == "tv" else None, gains,
                                  speeds=speeds)
    except ValueError as e:
        raise UserError(f"--schedule: {e}" if str(e).startswith("speed") else str(e)) \
            from None
    if kind == "tv":
        for d, v in {id(d): (d, v) for d, v in zip(designs, speeds)}.values():
            check_not_singular(d.controller_for(), d.M1, f"the gait at {v:g} m/s")
    return designs


def cmd_profile(args, say, perturbation_of) -> int:
    """``biped simulate`` with ``--speeds``/``--ramp``: walk the profile, report."""
    check_profile_arguments(args)
    speeds = _speeds(args)
    if args.plot is not None:
        output_dir(args.plot, "--plot")
    try:
        family = GaitFamily.load(args.gait, model=load_model(args.robot) if args.robot
                                 else None)
    except ValueError as e:
        raise UserError(f"--gait: {e} (--speeds/--ramp need a gait family from 'biped gait "
                        "--speeds A:B:STEP')") from None
    require_members(family, args.gait, "--gait")
    model = family.model
    schedule = _schedule(args, model.nu) if args.controller == "tv" or args.compare else None
    perturbation = perturbation_of(args, model.nq)
    try:
        gaits, sources = profile_gaits(family, speeds)
    except ValueError as e:
        raise UserError(f"{'--ramp' if args.ramp is not None else '--speeds'}: "
                        f"{str(e).removeprefix('speeds: ')}") from None
    kinds = [args.controller] + (["vc" if args.controller == "tv" else "tv"]
                                 if args.compare else [])
    gains = Gains(eps=args.eps)
    profiles = {k: _designs(k, gaits, speeds, schedule, gains) for k in kinds}
    opts = SimulationOptions(mu=args.mu, jit=args.jit, torque_limit=args.torque_limit)
    q0, dq0 = perturbation.initial_state(gaits[0])
    say(f"walking a profile of {speeds.size} step(s) ({len(sources)} gait(s))"
        + (" with each controller" if args.compare else "") + " ...")
    runs = {k: simulate_profile(d, q0, dq0, opts) for k, d in profiles.items()}
    figures = {}
    if args.plot:
        names = {"tv": "time-varying" + (" (scheduled M1)" if args.schedule else ""),
                 "vc": "virtual constraints"}
        (figures["speed_profile"],) = save_figures(
            {"speed_profile": speed_profile_plot(
                {names[k]: r for k, r in runs.items()},
                title=f"{model.params.name}: speed profile of {speeds.size} steps in full "
                      f"order, speed and error per step")},
            args.plot)
    res = runs[args.controller]
    if args.json:
        d = res.to_dict()
        d["controller"] = args.controller
        d["gaits"] = [s.to_dict() for s in sources]
        d["perturbation"] = perturbation.to_dict()
        if schedule is not None and args.controller == "tv":
            d["schedule"] = schedule.to_dict()
        if args.compare:
            d["compare"] = runs[kinds[1]].to_dict()
        if figures:
            d["figures"] = figures
        print_json(d)
        return walked(res)
    for k, r in runs.items():
        _print_run(k, r, [friction_source(g, args.mu) for g in gaits])
    for s in sources:
        if s.source == "interpolated":
            print(f"gait at {s.speed:g} m/s: interpolated ({s.status}; interpolant "
                  f"residual {s.interpolant_residual:.1e}, polished to {s.orbit_residual:.1e})")
    for k, v in figures.items():
        print(f"{k}: {v}")
    return walked(res)


def walked(run) -> int:
    """The exit code of ``biped simulate``: 0 when every step of the walk of
    ``--controller`` was valid, 1 when it stopped at an invalid state (reported; the other
    controller's walk of ``--compare`` is reported only; bad input is 2).

    Parameters
    ----------
    run : WalkOutcome
    """
    return 0 if run.ok else 1


def _print_run(kind, r, sources):
    """One run's table; its last column names the friction coefficient of each gait the
    profile switches to (``sources``: where each step's came from), once per switch."""
    print(f"{kind}: status {r.status}" + (f" - {r.message}" if r.message else ""))
    print("  step  speed [m/s]  status      q_u - q_u^d(T)   dq_u - dq_u^d(T)   peak |u| [N m]"
          "  friction margin  mu (at a gait switch)")
    for s, before in zip(r.steps, [None] + r.steps):
        switch = before is None or s.controller.get("gait") != before.controller.get("gait")
        print((f"  {s.index + 1:4d}  {s.speed:10.4f}  {s.status:10s}  {s.qu_error:+.6e}   "
               f"{s.dqu_error:+.6e}   {figure_or_na(s.peak_torque, '12.1f')}  "
               f"{figure_or_na(s.friction_margin, '.3f'):15s}"
               + (f"  {s.mu:g}, {sources[s.index]}" if switch else "")).rstrip())
    conv = [f"{g.speed:.3g} m/s: {figure_or_na(g.steps_to_converge, '.0f')}" for g in r.segments
            if g.n_steps > 1]
    if conv:
        print("  steps to converge (error < 1e-3) on each held speed: " + ", ".join(conv))
    print(f"  peak |u| {figure_or_na(r.peak_torque, '.1f')} N m, min F_z {figure_or_na(r.min_normal_force, '.1f')}"
          f" N, friction margin {figure_or_na(r.friction_margin, '.3f')} (mu - max |F_x|/F_z, "
          "impulses included)")
