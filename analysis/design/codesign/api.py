"""The co-design's front doors: :func:`codesign` (the method as a flow of tasks, kept by
its inputs) and :func:`codesign_tradeoff` (the (max|lambda|, s*) trade-off on its gait)."""
from __future__ import annotations

import re
import time
from dataclasses import dataclass

import numpy as np

from biped_casadi.caching import cache_dir
from gait_opt import Gait

from ...robustness.s_star import kept_directions
from biped_casadi.results import Result

from ...tasks import Engine, TaskError, task
from .method import Method
from .problem import solve
from .settings import CodesignError, CodesignResult, CodesignSettings, NoDesign
from .units import fixed_problem, hardest, measure, vc_radius

__all__ = ["codesign", "codesign_flow", "given_gait_flow", "NoDesignFound", "codesign_tradeoff",
           "tradeoff_flow", "replay_args"]

#: an error carried as text by a failed task: ``Type: text``
_TYPED = re.compile(r"^(\w+): ")


def _no_start_line(sampled: dict, nu: int) -> str:
    """Why drawn starts gave none: none stable within the bound, or none walking."""
    n, box, ok = sampled["samples"], sampled["box"], sampled["stable"]
    why = (f"none is stable with max|lambda| <= {sampled['bound']:.3g} (the virtual "
           f"constraints' eigenvalue times the margin)" if ok == 0 else
           f"{ok} are stable with max|lambda| <= {sampled['bound']:.3g}, none walks the "
           f"paper's perturbation")
    return (f"codesign: no start for the NLP: of {n} M1 drawn in [-{box:g}, {box:g}]^{nu} "
            f"(a box for RABBIT's default gait), {why}; start from a gait of this robot "
            f"instead (biped m1 --robust --gait FILE: starts that fit the gait)")


def _designed(m: Method, settings: CodesignSettings) -> CodesignResult:
    """One co-design by a :class:`Method`: starts -> scenario exchange -> rejoin choice
    -> gait steps -> verification."""
    starts = m.setup()
    best = m.screen_starts(starts)
    if best is None:
        if m.screen is not None:
            raise NoDesign(m.no_design_line(), m.no_design_details())
        if not starts and m.sampled:
            raise CodesignError(_no_start_line(m.sampled, m.model.nu))
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
    return m.verify(best)


def _summary(r) -> dict:
    """A design (or a NoDesign) in a few figures, for the record of 'auto'."""
    if isinstance(r, NoDesign):
        return dict(status="no_design", message=str(r))
    return dict(status=r.status, message=r.message, s_star=float(r.s_star),
                max_abs=float(r.max_abs), vc_s_star=float(r.vc_s_star),
                steps_to_converge=r.steps_to_converge, M1=list(map(float, r.design.M1)))


def _better(a: CodesignResult, b: CodesignResult) -> bool:
    """Whether design a is better than b: the target met, then s* (max|lambda| within
    virtual constraints' is part of the target)."""
    def key(r):
        return (r.status == "target_met", bool(r.max_abs <= r.vc_eigenvalue), float(r.s_star))
    return key(a) > key(b)


@task
def codesign_flow(engine, model, settings: CodesignSettings, gait=None) -> CodesignResult:
    """The co-design as a flow of tasks, phase by phase.

    Starts -> scenario exchange -> rejoin choice -> gait steps -> verification
    (:class:`~analysis.design.codesign.method.Method`).  With a gait given,
    ``settings.given_gait`` says what happens to it: 'fixed' (only M1 moves), 'free'
    (moved to the robust gait constraints near it, then co-designed from there), 'auto'
    (fixed; free when the fixed gait's design misses the target, or its start screen
    already shows it will; the better design is the result).

    Parameters
    ----------
    engine : Engine
        Where its units run.
    model : BipedModel
        The robot.
    settings : CodesignSettings
        The co-design.
    gait : Gait, optional
        The given gait.

    Returns
    -------
    CodesignResult
        Without a gait file (:func:`codesign` saves the gait).

    Raises
    ------
    NoDesign
        (a CodesignError) With starts that fit the gait, when nothing walks: one line
        naming the start screen's best scale and what stops it.
    CodesignError
        When no start gives a verified design.
    """
    return _codesign(engine, model, settings, gait)


@task
def given_gait_flow(engine, model, settings: CodesignSettings, gait):
    """:func:`codesign_flow` on a given gait, with "no design" as a value.

    Parameters
    ----------
    engine : Engine
        Where its units run.
    model : BipedModel
        The robot.
    settings : CodesignSettings
        The co-design (``given_gait`` says what happens to the gait).
    gait : Gait
        The given gait.

    Returns
    -------
    CodesignResult or NoDesignFound
        The design, or why there is none (kept like a design: asking again is instant).
    """
    try:
        return _codesign(engine, model, settings, gait)
    except NoDesign as e:
        return NoDesignFound(message=str(e), details=e.details)


@dataclass
class NoDesignFound(Result):
    """No design on a given gait (:func:`given_gait_flow`): :class:`NoDesign` as a value.

    Parameters
    ----------
    message : str
        Why, in one line.
    details : dict
        What the line says, as values.
    status : str
        'no_design'.
    """

    message: str
    details: dict
    status: str = "no_design"

    SUCCESS = ("no_design",)


def _codesign(engine, model, settings: CodesignSettings, gait=None) -> CodesignResult:
    """The body of :func:`codesign_flow`."""
    t0 = time.perf_counter()
    mode = settings.given_gait if gait is not None else "fixed"
    if mode == "fixed":
        result = _designed(Method(engine, model, settings, gait), settings)
    elif mode == "free":
        result = _designed(Method(engine, model, settings, start_gait=gait), settings)
    else:
        result = _auto(engine, model, settings, gait)
    result.elapsed = time.perf_counter() - t0
    return result


def _reason(e: NoDesign) -> str:
    """A NoDesign's line without its 'codesign: ' lead."""
    s = str(e)
    return s[len("codesign: "):] if s.startswith("codesign: ") else s


def _auto(engine, model, settings: CodesignSettings, gait) -> CodesignResult:
    """'auto': the gait fixed first (given up after the start screen when its best s*
    is below 1: the target is out of reach), then free from it when the target is
    missed; the better design, with the other's summary in ``result.alternative``."""
    try:
        fixed = _designed(Method(engine, model, settings, gait, stop_below=1.0), settings)
    except NoDesign as e:
        fixed = e
    if isinstance(fixed, CodesignResult) and fixed.status == "target_met":
        return fixed
    engine.say("the fixed gait misses the target: the gait moves from it")
    try:
        free = _designed(Method(engine, model, settings, start_gait=gait), settings)
    except NoDesign as e:
        if isinstance(fixed, CodesignResult):
            return fixed
        # the fixed gait's screen gave up early: its design after all, if it has one
        try:
            return _designed(Method(engine, model, settings, gait), settings)
        except NoDesign as e_fixed:
            raise NoDesign(f"codesign: on the gait as given: {_reason(e_fixed)}; on the gait "
                           f"moved from it: {_reason(e)}",
                           dict(e_fixed.details, free=e.details)) from None
    if isinstance(fixed, CodesignResult) and not _better(free, fixed):
        fixed.alternative = _summary(free)
        return fixed
    free.alternative = _summary(fixed)
    return free


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
    NoDesign
        (a CodesignError) With a gait given and starts that fit it, when there is no
        design: one line naming the start screen's best scale and what stops it.
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
    # a gait given: its own flow, where "no design" is a value (the default co-design keeps
    # the flow it shares with `biped reproduce`)
    flow = codesign_flow if gait is None else given_gait_flow
    with Engine(scheduler, workers, cache=cache, use_cache=use_cache, log=progress) as eng:
        ref = eng.spawn(flow, model, st, gait)
        try:
            result = ref.result()
        except TaskError as e:          # the method's own errors reach the caller as such
            m = _TYPED.match(str(e.message))
            if m and m.group(1) in ("CodesignError", "NoDesign"):
                raise CodesignError(str(e.message)[m.end():]) from None
            raise
        if isinstance(result, NoDesignFound):
            raise NoDesign(result.message, result.details)
        result.cached = eng.state(ref) == "reused"
    return _with_gait_file(result, gait, gait_file, cache, ref.key.rsplit("-", 1)[-1])


def _with_gait_file(result: CodesignResult, gait, gait_file, cache, key: str):
    """The result with its gait saved (beside the cache) and the replay arguments: the
    given file only when the design runs on the gait as given (not on one moved from it)."""
    if (gait is not None and gait_file is not None
            and result.gait.cache_key == gait.cache_key):
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
