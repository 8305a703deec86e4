"""``biped robust``: how large a perturbation one design survives (s*), with every
contact condition checked, and its basin of attraction beside virtual constraints'."""
from __future__ import annotations

import dataclasses

import numpy as np

from analysis.reporting.plots import basin_plot, save_figures
from analysis.robustness import (Design, RobustnessSettings, basin_to_boundary, decay_steps,
                                 kept_directions, robustness)
from analysis.stability.vc_map import vc_eigenvalue
from biped_casadi.control import PAPER_REJOIN
from biped_casadi.simulation import failure_text

from .common import (add_design_arguments, Progress, UserError, add_gait_arguments, add_robot, check_m1_values,
                     check_not_singular, figure_or_na,
                     gait_friction, load_gait, MU_HELP, output_dir, parse_m1, positive,
                     print_json, rejoin_fraction)


def _steps(text: str):
    """``--steps``: a count, or None for 'auto'."""
    if text == "auto":
        return None
    try:
        steps = int(text)
    except ValueError:
        raise UserError(f"--steps must be a whole number of steps or 'auto', got "
                        f"{text!r}") from None
    if not 1 <= steps <= 1000:
        raise UserError(f"--steps must be between 1 and 1000, got {steps}")
    return steps


def _decay_steps(gait, st, say):
    """``--steps auto``: the settings with the steps of :func:`decay_steps`."""
    lam = vc_eigenvalue(gait).eigenvalue
    try:
        st = dataclasses.replace(st, steps=decay_steps(lam, st))
    except ValueError as e:
        raise UserError(f"--steps auto: {e}") from None
    say(f"{st.steps} steps: the largest perturbation decays below {st.tol:g} at the "
        f"virtual constraints' rate {abs(lam):.3g}")
    return st


def cmd_robust(args):
    check_m1_values(args.m1)
    if args.controller == "vc" and (args.m1 is not None or args.rejoin is not None):
        raise UserError("--m1 and --rejoin apply to the time-varying controller "
                        "(--controller tv)")
    if args.mu is not None:
        positive(args.mu, "--mu")
    if args.torque_limit is not None:
        positive(args.torque_limit, "--torque-limit")
    rejoin = rejoin_fraction(PAPER_REJOIN if args.rejoin is None else args.rejoin)
    if args.seed < 0:
        raise UserError(f"--seed must be >= 0, got {args.seed}")
    if not 1 <= args.directions <= 200:
        raise UserError(f"--directions must be between 1 and 200, got {args.directions}")
    steps = _steps(args.steps)
    if args.plot is not None:
        output_dir(args.plot, "--plot")
    say = Progress("robust", quiet=args.json)
    gait = load_gait(args, say)
    model = gait.model
    design = None
    if args.controller == "tv":
        design = Design(tuple(parse_m1(args.m1, model.nu)), rejoin)
        check_not_singular(Design.of(design, gait).controller_for(), design.M1)
    friction = gait_friction(args, gait)
    st = RobustnessSettings(directions=args.directions, mu=args.mu,
                            torque_limit=args.torque_limit, seed=args.seed,
                            steps=RobustnessSettings.steps if steps is None else steps)
    if steps is None:
        st = _decay_steps(gait, st, say)
    say(f"perturbation directions from which virtual constraints walk ({args.directions} "
        f"wanted; about 0.3 s each)")
    kept = kept_directions(gait, st)
    say("s* by bisection (up to a minute)")
    res = robustness(Design.of(design, gait), st, kept=kept)
    out = dict(res.to_dict(), mu=args.mu)
    if args.plot is not None:
        say("basins of attraction on windows grown until their boundary is inside, "
            "time-varying beside virtual constraints (about a minute)")
        runs = [basin_to_boundary(Design.of(design, gait))] if design is not None else []
        runs.append(basin_to_boundary(Design.vc(gait)))
        out["basins"] = [dict(controller=b.controller, converged_fraction=b.converged_fraction,
                              area=b.area, q_span=b.q_span, dq_span=b.dq_span,
                              status=b.status, counts=b.counts) for b in runs]
        out["figures"] = save_figures({"basin": basin_plot(runs)}, args.plot)
    if args.json:
        print_json(out)
        return 0
    print(res.message)
    print(f"  friction coefficient {friction}")
    print(f"  max|lambda| {res.max_abs:.4g}; directions kept {res.directions_kept} of "
          f"{res.directions_tried} tried (rejected: "
          + (", ".join(f"{k} {v}" for k, v in res.directions_rejected.items()) or "none") + ")")
    if res.paper:
        p = res.paper
        conv = p.get("steps_to_converge")
        status = p["status"]
        if status == "not_converged":
            err = p.get("error")
            status = (f"walks {p.get('step')} valid steps, not yet below {st.tol:g}"
                      + (f" (error {err:.2g} at the end)" if err is not None else ""))
        elif status == "ok":
            status = f"walks {p.get('step')} valid steps"
        else:
            status = failure_text(status, p.get('step'))
        print(f"  the paper's perturbation (s = 1): {status}"
              + (f", below {st.tol:g} from step {int(conv)}" if conv and np.isfinite(conv)
                 else "") + f"; peak |u| {figure_or_na(p['peak_torque'], '.1f')} N m, min F_z "
              f"{figure_or_na(p['min_normal_force'], '.1f')} N, max impulse ratio "
              f"{figure_or_na(p['max_impulse_ratio'], '.3f')}")
    for b in out.get("basins", []):
        print(f"  basin ({b['controller']}): area {b['area']:.3g} rad x rad/s, "
              f"{100 * b['converged_fraction']:.1f} % of the window +-{b['q_span']:.3g} rad x "
              f"+-{b['dq_span']:.3g} rad/s converges in 10 steps ({b['status']})")
    for f in out.get("figures", []):
        print(f"figure: {f}")
    return 0


def register(sub):
    p = sub.add_parser(
        "robust", help="the largest perturbation a design survives (s*), and its basin",
        description="Robustness of one design: the largest scale s* of the paper's "
                    "perturbation (0.01 rad on every joint, 0.1 rad/s on every velocity) at "
                    "which every kept direction (the paper's, then seeded sign patterns and "
                    "random directions of the same size, kept only when virtual constraints "
                    "walk from them) walks --steps valid steps (10) (normal force, friction cone, "
                    "impact impulse, lift-off, scuffing, torque limit) and ends with "
                    "max(|q_u err|, |dq_u err|) < 1e-3; the first failure just above s* and "
                    "its cause. Both controllers run on their hybrid zero dynamics, batched "
                    "(time-varying designs: exact for every output gain; virtual "
                    "constraints: exact with their phase-based correction). With --plot: "
                    "basins of attraction on the Poincare section, each on a window grown "
                    "until the basin's boundary lies inside it, with their areas (rad x "
                    "rad/s), the design beside virtual constraints.")
    add_gait_arguments(p)
    add_robot(p)
    add_design_arguments(p)
    p.add_argument("--mu", type=float, help=f"friction coefficient ({MU_HELP})")
    p.add_argument("--torque-limit", type=float, metavar="U",
                   help="|u_i| bound, N m (default: the robot's, 150 for RABBIT)")
    p.add_argument("--directions", type=int, default=16, metavar="N",
                   help="perturbation directions kept (16)")
    p.add_argument("--seed", type=int, default=2024, help="seed of the directions (2024)")
    p.add_argument("--steps", default="10", metavar="N|auto",
                   help="steps every run walks, converging below 1e-3 at the last (10); "
                        "'auto': at least 10, and enough for the largest perturbation tried "
                        "to decay below 1e-3 at the virtual constraints' eigenvalue (a gait "
                        "whose eigenvalue is near 0.85 needs about 35: in 10 steps s* only "
                        "measures how fast it converges)")
    p.add_argument("--plot", metavar="DIR", help="write the basin picture into DIR")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_robust)
