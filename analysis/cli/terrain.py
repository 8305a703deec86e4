"""``biped terrain``: walking on stochastic terrain, with or without a model error.  The
mean first-passage time by Monte Carlo (on Dask) and the exact gait sensitivity norm."""
from __future__ import annotations

import math
from pathlib import Path

from analysis.reporting.plots import save_figures, survival_plot
from analysis.terrain import (MAX_RUNS, MAX_STEPS, MonteCarloSettings, WalkerSpec,
                              gait_sensitivity, monte_carlo)
from biped_casadi import SimulationOptions, robot
from biped_casadi.control import PAPER_REJOIN
from biped_casadi.model.biped import resolve_robot
from biped_casadi.simulation import Terrain, TerrainFileError
from biped_casadi.simulation.terrain import MAX_HEIGHT

from .common import (add_design_arguments, Progress, UserError, add_gait_arguments, add_robot, check_m1_values,
                     check_not_singular,
                     gait_friction, MU_HELP, output_dir, parse_m1, positive,
                     print_json, rejoin_fraction, scheduler_and_gait)

SCALES = ("mass", "inertia", "length", "torso_mass")


def _finite_nonnegative(v, name):
    if not (math.isfinite(v) and v >= 0):
        raise UserError(f"{name} must be a finite number >= 0, got {v!r}")
    return v


def _count(v, name, hi):
    if not 1 <= v <= hi:
        raise UserError(f"{name} must be between 1 and {hi}, got {v}")
    return v


def _plant(args, model):
    """The plant's description (None: the controller's model), or a UserError."""
    scales = {k: getattr(args, f"{k}_scale") for k in SCALES}
    given = {k: v for k, v in scales.items() if v is not None}
    if args.plant is not None and given:
        raise UserError("--plant excludes the scale options (--mass-scale, ...)")
    if args.plant is not None:
        try:
            d = resolve_robot(args.plant)
        except ValueError as e:
            raise UserError(f"--plant: {e}") from None
        except OSError as e:
            raise UserError(f"--plant: {args.plant}: {e.strerror or e}") from None
        if d.k != model.description.k:
            raise UserError(f"--plant: {args.plant} has {d.k} link(s) per leg, the controller's "
                            f"robot {model.description.k}: not a plant of this robot")
        return d
    if not given:
        return None
    try:
        return model.description.scaled(**{k: (1.0 if v is None else v)
                                           for k, v in scales.items()})
    except ValueError as e:               # the scaled robot's numbers out of range
        names = ", ".join(f"--{k.replace('_', '-')}-scale" for k in given)
        raise UserError(f"{names}: {e}") from None


def _check_scales(args):
    for k in SCALES:
        v = getattr(args, f"{k}_scale")
        if v is not None and not (math.isfinite(v) and v > 0):
            raise UserError(f"--{k.replace('_', '-')}-scale must be a positive number, got {v!r}")


def cmd_terrain(args):
    """``biped terrain``: check the arguments, build the walker, compute the gait
    sensitivity norm, run the Monte Carlo, then report (JSON or text) and draw."""
    gains, rejoin, profile = _check_arguments(args)
    say = Progress("terrain", quiet=args.json)
    gait, spec, st = _build(args, say, gains, rejoin, profile)

    # ---- the exact gait sensitivity norm, then the Monte Carlo
    gsn, gsn_error = _sensitivity(args, gait, spec, say)
    mc = _run_monte_carlo(args, gait, spec, st, say)

    out = _summary(mc, st, gsn, gsn_error)
    if args.plot is not None:
        name = dict(vc="virtual constraints", tv="time-varying").get(spec.controller,
                                                                     spec.controller)
        label = (f"{name}, sigma = {1000 * st.sigma:g} mm" if not profile
                 else f"{name} on {Path(args.terrain).name}")
        title = (f"{gait.model.description.name}: survival of {st.runs} runs on "
                 + ("random ground" if not profile else "a measured terrain"))
        out["figures"] = save_figures({"survival": survival_plot([mc], labels=[label],
                                                                 title=title)}, args.plot)
    if args.json:
        print_json(out)
        return 0
    _print_report(mc, st, gsn, out, args.friction)
    return 0


def _check_arguments(args):
    """Everything that can be checked before any work: (gains, rejoin, terrain profile)."""
    check_m1_values(args.m1)
    if args.controller == "vc" and (args.m1 is not None or args.rejoin is not None):
        raise UserError("--m1 and --rejoin apply to the time-varying controller "
                        "(--controller tv)")
    if args.sigma is not None:
        _finite_nonnegative(args.sigma, "--sigma")
    if args.sigma is not None and args.sigma > MAX_HEIGHT:
        raise UserError(f"--sigma must be at most {MAX_HEIGHT} m, got {args.sigma}")
    _count(args.runs, "--runs", MAX_RUNS)
    _count(args.max_steps, "--max-steps", MAX_STEPS)
    if args.seed < 0:
        raise UserError(f"--seed must be >= 0, got {args.seed}")
    if args.mu is not None:
        positive(args.mu, "--mu")
    if args.torque_limit is not None:
        positive(args.torque_limit, "--torque-limit")
    gains = (1.0, 2.0, 0.02)
    if args.gains is not None:
        for name, v in zip(("KP", "KD", "EPS"), args.gains):
            positive(v, f"--gains {name}")
        gains = tuple(args.gains)
    rejoin = rejoin_fraction(PAPER_REJOIN if args.rejoin is None else args.rejoin)
    _check_scales(args)
    if args.scheduler is not None and not args.scheduler.strip():
        raise UserError("--scheduler: empty address")
    profile = ()
    if args.terrain is not None:
        if args.sigma_given:
            raise UserError("--terrain excludes --sigma (the file is the terrain)")
        try:
            profile = Terrain.load(args.terrain).heights
        except TerrainFileError as e:
            raise UserError(f"--terrain: {e}") from None
    if args.out is not None:
        output_dir(args.out, "--out")
    if args.plot is not None:
        output_dir(args.plot, "--plot")
    return gains, rejoin, profile


def _build(args, say, gains, rejoin, profile):
    """The gait, the walker's spec (controller, plant) and the Monte Carlo settings."""
    gait = scheduler_and_gait(args, say)
    model = gait.model
    args.friction = gait_friction(args, gait)
    M1 = parse_m1(args.m1, model.nu) if args.controller == "tv" else None
    plant = _plant(args, model)
    robot(plant) if plant is not None else None             # a plant that builds
    spec = WalkerSpec(args.controller, tuple(M1) if M1 is not None else (), rejoin, gains,
                      plant.to_dict() if plant is not None else None, args.saturate)
    if args.controller == "tv":
        check_not_singular(spec.controller_for(gait), M1)
    try:
        st = MonteCarloSettings(sigma=0.0 if profile else args.sigma, runs=args.runs,
                                max_steps=args.max_steps, seed=args.seed, chunk=args.chunk,
                                mu=args.mu, torque_limit=args.torque_limit,
                                profile=profile).for_model(model)
    except ValueError as e:
        raise UserError(str(e)) from None
    if spec.engine == "full_order":
        try:
            st.options(spec, gait.T)                 # gains the runs can integrate
        except ValueError as e:
            raise UserError(f"--{e}") from None
    return gait, spec, st


def _sensitivity(args, gait, spec, say):
    """The exact gait sensitivity norm, or (None, why there is none)."""
    say("gait sensitivity norm (exact, from the linearised step map; a few seconds)")
    opts = SimulationOptions(mu=args.mu, torque_limit=args.torque_limit,
                             saturate=args.saturate)
    controller = spec.controller_for(gait)
    try:
        return gait_sensitivity(controller, opts, spec.plant_model()), None
    except ValueError as e:
        return None, str(e)


def _run_monte_carlo(args, gait, spec, st, say):
    """The Monte Carlo on the scheduler the arguments name."""
    where = ("this process" if args.scheduler == "inline" else
             f"the Dask scheduler at {args.scheduler}" if args.scheduler else
             "a Dask LocalCluster of this machine's cores")
    say(f"Monte Carlo: {st.runs} runs of up to {st.max_steps} steps ({spec.engine}) on {where}")
    try:
        return monte_carlo(gait, spec, st, out_dir=args.out, scheduler=args.scheduler,
                           workers=args.workers, progress=not args.json)
    except ValueError as e:
        msg = str(e)
        raise UserError("--" + msg if msg.startswith(("out:", "scheduler:")) else msg) from None


def _summary(mc, st, gsn, gsn_error):
    """The JSON object: the estimate, the run's record and the gait sensitivity norm."""
    est = mc.estimate
    out = dict(status=mc.status, message=mc.message, mfpt=est.mfpt, mfpt_ci=est.mfpt_ci,
               mfpt_lower_bound=est.mfpt_ci[0],
               failure_probability=est.failure_probability,
               failure_probability_ci=est.failure_probability_ci,
               failures=est.failures, censored=est.censored,
               mean_steps_walked=est.mean_steps_walked, survival=est.survival,
               status_counts=mc.status_counts, step_time_rms=mc.step_time_rms,
               spec=mc.spec, settings=mc.settings, scenario_steps=mc.scenario_steps,
               elapsed=mc.elapsed, steps_per_second=mc.steps_per_second,
               chunks_computed=mc.chunks_computed, chunks_reused=mc.chunks_reused,
               folder=mc.folder)
    if gsn is not None:
        out["gsn"] = gsn.gsn
        out["gsn_ground_step_time"] = gsn.gsn["ground_height"]["step_time"]
        out["gsn_spectral_radius"] = gsn.spectral_radius
        out["gsn_predicted_step_time_rms"] = st.sigma * gsn.gsn["ground_height"]["step_time"]
        out["gsn_message"] = gsn.message
    else:
        out["gsn"] = None
        out["gsn_message"] = f"no gait sensitivity norm: {gsn_error}"
    return out


def _print_report(mc, st, gsn, out, friction):
    """The text report."""
    print(mc.message)
    print(f"  friction coefficient {friction}")
    print("  how the runs ended: " + ", ".join(f"{k} {v}" for k, v in mc.status_counts.items()))
    if math.isfinite(mc.step_time_rms):
        print(f"  step time RMS deviation {mc.step_time_rms:.3g} s (from step "
              f"{st.transient + 1})")
    print("  " + out["gsn_message"])
    if gsn is not None and st.sigma > 0:
        print(f"  predicted step time RMS at sigma = {st.sigma:g} m: "
              f"{out['gsn_predicted_step_time_rms']:.3g} s")
    print(f"  {mc.scenario_steps} steps in {mc.elapsed:.1f} s ({mc.steps_per_second:.0f} steps/s)")
    for f in out.get("figures", []):
        print(f"figure: {f}")


def register(sub):
    p = sub.add_parser(
        "terrain", help="mean first-passage time on stochastic terrain, and the gait "
                        "sensitivity norm",
        description="Walk N runs of up to K steps on ground whose height changes at every "
                    "step (i.i.d. N(0, sigma^2), or a profile file), every step checked "
                    "(contact, friction incl. the impact impulse, scuffing, torque limit); "
                    "report the survival curve, the per-step failure probability and the "
                    "mean first-passage time (MFPT, steps, with a 95 percent interval that stays "
                    "right when few runs fail), and the exact gait sensitivity norm (GSN) "
                    "of the step-to-step map with respect to the ground height and a torso "
                    "push. With a model error (--plant FILE or the scale options) or "
                    "--saturate the runs go through the full-order simulator, where the "
                    "output gains (--gains) matter; otherwise through the exact batched "
                    "walkers. Runs go through Dask: a LocalCluster of this machine's cores "
                    "by default, a cluster with --scheduler ADDRESS, or this process with "
                    "--scheduler inline; with --out the chunks are written as they arrive "
                    "and a rerun resumes, with the same numbers for the same seed.")
    add_gait_arguments(p)
    add_robot(p)
    add_design_arguments(p)
    p.add_argument("--sigma", type=float, default=None, metavar="S",
                   help="standard deviation of the ground height per step, m (default "
                        "scaled with leg length: 0.00625 x leg, 0.005 for RABBIT)")
    p.add_argument("--terrain", metavar="FILE",
                   help="a terrain profile (JSON list or numbers in text, m) instead of "
                        "random heights: run i walks it from its i-th height on, wrapping "
                        "round (the runs are then windows of one profile, not independent "
                        "draws: the MFPT's interval is indicative)")
    p.add_argument("--runs", type=int, default=200, metavar="N", help="runs (200)")
    p.add_argument("--max-steps", type=int, default=50, metavar="K",
                   help="steps per run at most (50)")
    p.add_argument("--seed", type=int, default=0, help="seed of the terrain (0)")
    p.add_argument("--chunk", type=int, default=50, metavar="C",
                   help="runs per chunk (a Dask task, a Parquet file) (50)")
    p.add_argument("--plant", metavar="FILE",
                   help="the robot that walks, a description file (model error: the "
                        "controller keeps its own model)")
    for k in SCALES:
        p.add_argument(f"--{k.replace('_', '-')}-scale", type=float, metavar="F",
                       help=f"plant = the controller's robot with its {k.replace('_', ' ')}"
                            f"{'es' if k.endswith('mass') else 's'} times F")
    p.add_argument("--saturate", action="store_true",
                   help="clip torques at the limit and keep walking (full-order simulator)")
    p.add_argument("--gains", nargs=3, type=float, metavar=("KP", "KD", "EPS"),
                   help="output PD of eq. (13) (1 2 0.02); they matter with a model error")
    p.add_argument("--mu", type=float, help=f"friction coefficient ({MU_HELP})")
    p.add_argument("--torque-limit", type=float, metavar="U",
                   help="|u_i| bound, N m (default: the robot's, 150 for RABBIT)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="a Dask scheduler (tcp://HOST:PORT), or 'inline' (this process); "
                        "default a LocalCluster")
    p.add_argument("--workers", type=int, metavar="K",
                   help="processes of the LocalCluster (default: the cores)")
    p.add_argument("--out", metavar="DIR", help="write the runs' chunks (Parquet) into DIR "
                                                "and resume from them")
    p.add_argument("--plot", metavar="DIR", help="write the survival curve into DIR")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_with_sigma_default)


def _with_sigma_default(args):
    args.sigma_given = args.sigma is not None        # None: the robot's (MonteCarloSettings)
    if args.workers is not None and not 1 <= args.workers <= 64:
        raise UserError(f"--workers must be between 1 and 64, got {args.workers}")
    if not 1 <= args.chunk <= MAX_RUNS:
        raise UserError(f"--chunk must be between 1 and {MAX_RUNS}, got {args.chunk}")
    return cmd_terrain(args)


__all__ = ["cmd_terrain", "register"]
