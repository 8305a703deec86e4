"""The co-design's front doors: :func:`codesign` (the method as a flow of tasks, kept by
its inputs) and :func:`codesign_tradeoff` (the (max|lambda|, s*) trade-off on its gait)."""
from __future__ import annotations

import time

import numpy as np

from biped_casadi.caching import cache_dir
from gait_opt import Gait

from ...robustness.s_star import kept_directions
from ...tasks import Engine, task
from .method import Method
from .problem import solve
from .settings import CodesignError, CodesignResult, CodesignSettings
from .units import fixed_problem, hardest, measure, vc_radius

__all__ = ["codesign", "codesign_flow", "codesign_tradeoff", "tradeoff_flow", "replay_args"]


@task
def codesign_flow(engine, model, settings: CodesignSettings, gait=None) -> CodesignResult:
    """The co-design as a flow of tasks, phase by phase.

    Starts -> scenario exchange -> rejoin choice -> gait steps -> verification
    (:class:`~analysis.design.codesign.method.Method`).

    Parameters
    ----------
    engine : Engine
        Where its units run.
    model : BipedModel
        The robot.
    settings : CodesignSettings
        The co-design.
    gait : Gait, optional
        Fix the gait to this one.

    Returns
    -------
    CodesignResult
        Without a gait file (:func:`codesign` saves the gait).

    Raises
    ------
    CodesignError
        When no start gives a verified design.
    """
    t0 = time.perf_counter()
    m = Method(engine, model, settings, gait)
    starts = m.setup()
    best = m.screen_starts(starts)
    if best is None:
        last = m.solves[-1] if m.solves else {}
        raise CodesignError(
            f"codesign: IPOPT ({last.get('status', 'not run')}) found no verified design "
            f"from {len(starts)} start(s); try other starts, more samples, a smaller "
            f"s_start or more iterations")
    best = m.exchange(best)
    if settings.rejoin_choices:
        best = m.choose_rejoin(best)
    if m.free:
        best = m.gait_steps(best)
    result = m.verify(best)
    result.elapsed = time.perf_counter() - t0
    return result


def replay_args(result: CodesignResult, gait_file) -> list:
    """``biped simulate`` arguments that replay a co-design from the paper's perturbation.

    Parameters
    ----------
    result : CodesignResult
        The co-design.
    gait_file : str or Path
        Where its gait is saved.

    Returns
    -------
    list of str
    """
    v = result.settings["verification"]
    d = result.design
    return (["--gait", str(gait_file), "--controller", "tv", "--m1"]
            + [repr(float(x)) for x in d.M1]
            + ["--rejoin", repr(d.rejoin), "--perturb", "0.01", "0.1", "--mu",
               repr(v["mu"]), "--steps", str(v["walk_steps"])]
            + ([] if v["torque_limit"] is None else ["--torque-limit", repr(v["torque_limit"])]))


def codesign(robot_or_gait, settings: CodesignSettings | None = None, *, gait_file=None,
             progress=None, cache=None, use_cache: bool = True, scheduler=None,
             workers: int | None = None, gait=None) -> CodesignResult:
    """Co-design the robust time-varying controller (and, by default, the gait).

    Parameters
    ----------
    robot_or_gait : BipedModel or Gait
        The robot (the gait is co-designed from ``settings.gait``), or a gait (fixed:
        only M1 moves).
    settings : CodesignSettings, optional
        The co-design (default: all defaults, the gait free).
    gait_file : str or Path, optional
        The file a given gait was read from (for the replay arguments).
    progress : callable, optional
        Called with one line of text per phase.
    cache : str or Path, optional
        Folder of kept results (default :func:`biped_casadi.cache_dir`).
    use_cache : bool
        Read kept results (every unit of the method is kept by its inputs).
    scheduler : str or Client, optional
        Where the units run (:func:`analysis.tasks.resolve_scheduler`; default a
        ``LocalCluster`` of this machine's cores).
    workers : int, optional
        Processes of that cluster (1: this process).
    gait : Gait, optional
        Older spelling of a fixed gait (``codesign(model, settings, gait=g)``).

    Returns
    -------
    CodesignResult
        ``result.design`` (a :class:`biped_casadi.Design` on its gait) and
        ``result.check`` (its verification).

    Raises
    ------
    CodesignError
        When IPOPT fails on every start or no design verifies (the message names the
        solver, its status and what to try).
    """
    st = settings or CodesignSettings()
    if isinstance(robot_or_gait, Gait):
        model, gait = robot_or_gait.model, robot_or_gait
    else:
        model = robot_or_gait
    if gait is not None and gait.model.params != model.params:
        raise ValueError("gait: made for other robot parameters than the model")
    with Engine(scheduler, workers, cache=cache, use_cache=use_cache, log=progress) as eng:
        ref = eng.spawn(codesign_flow, model, st, gait)
        result = ref.result()
        result.cached = eng.state(ref) == "reused"
    return _with_gait_file(result, gait, gait_file, cache, ref.key.rsplit("-", 1)[-1])


def _with_gait_file(result: CodesignResult, gait, gait_file, cache, key: str):
    """The result with its gait saved (beside the cache) and the replay arguments."""
    if gait is not None and gait_file is not None:
        path = gait_file
    else:
        path = cache_dir(cache) / "codesign" / f"codesign-{key[:20]}.gait.json"
        if not path.is_file():
            path.parent.mkdir(parents=True, exist_ok=True)
            result.gait.save(path)
    result.gait_file = str(path)
    result.simulate_args = replay_args(result, path)
    return result


@task
def tradeoff_flow(engine, design, s_star: float, settings: CodesignSettings,
                  fractions: tuple) -> list:
    """:func:`codesign_tradeoff` as a flow (its points side by side).

    Parameters
    ----------
    engine : Engine
        Where the units run.
    design : Design
        The co-design's design (on its gait).
    s_star : float
        Its verified s*.
    settings : CodesignSettings
        Its settings.
    fractions : tuple of float
        The bounds, fractions of the virtual constraints' eigenvalue.

    Returns
    -------
    list of dict
    """
    gait = design.gait
    m = Method(engine, gait.model, settings, gait)
    M1, rejoin = np.asarray(design.M1, float), design.rejoin
    kept = m.run(kept_directions, gait, m.rs)
    lvc = m.run(vc_radius, gait)
    active = m.run(hardest, gait, kept, M1, rejoin, max(s_star, 0.1),
                   settings.initial_active, m.rs)
    ps = m.problem_settings(rejoin, gait)
    solves = []
    for f in fractions:
        p = fixed_problem(gait, kept, M1, active, max(s_star - 0.1, 0.1),
                          **dict(ps, jury_bound=float(f) * lvc))
        solves.append(engine.submit(solve, p, settings.solve))
    meas = [engine.submit(measure, gait, kept, s.result().M1, rejoin, m.rs)
            if s.result().finite else None for s in solves]
    out = []
    for f, s, mr in zip(fractions, solves, meas):
        res = s.result()
        if mr is None:
            out.append(dict(bound=float(f * lvc), nlp_status=res.status, s_star=None,
                            max_abs=None))
            continue
        r = mr.result()
        engine.say(f"trade-off: bound {f * lvc:.3g}: IPOPT {res.status}, verified s* "
                   f"{r.robustness.s_star:.4g} at max|lambda| {r.max_abs:.3g}")
        out.append(dict(bound=float(f * lvc), nlp_status=res.status, nlp_s=res.s,
                        s_star=float(r.robustness.s_star), max_abs=float(r.max_abs),
                        M1=res.M1.tolist()))
    return out


def codesign_tradeoff(result: CodesignResult, settings: CodesignSettings | None = None,
                      fractions=(0.25, 0.5, 0.75, 1.0), progress=None, cache=None,
                      scheduler=None, workers: int | None = None) -> list:
    """The (max|lambda|, s*) trade-off traced by the NLP on the co-design's gait.

    For each bound rho = fraction x the virtual constraints' eigenvalue, the fixed-gait
    NLP (the Jury conditions at rho) is solved from the co-design's M1 with the
    directions that fail first at its s*, and its design is verified by the walker's
    bisection over the kept directions: each point is a verified s* and its exact
    max|lambda|.

    Parameters
    ----------
    result : CodesignResult
        A co-design (its gait, M1).
    settings : CodesignSettings, optional
        Its settings (default: all defaults).
    fractions : tuple of float
        The bounds, as fractions of the virtual constraints' eigenvalue.
    progress : callable, optional
        One line per point.
    cache : str or Path, optional
        Folder of kept results.
    scheduler : str or Client, optional
        Where the units run.
    workers : int, optional
        Processes of a local cluster.

    Returns
    -------
    list of dict
        Per bound: ``bound``, the NLP's status and s, the verified ``s_star`` and
        ``max_abs``, and ``M1``.
    """
    st = settings or CodesignSettings()
    with Engine(scheduler, workers, cache=cache, log=progress) as eng:
        return eng.spawn(tradeoff_flow, result.design, float(result.s_star), st,
                         tuple(float(f) for f in fractions)).result()
