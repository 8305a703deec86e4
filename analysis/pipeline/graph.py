"""``biped reproduce``: the paper end to end as one graph of cached tasks on Dask.

Every stage is a flow of tasks (:mod:`.paper`, :mod:`.walking`, :mod:`.terrain`) whose
arguments are the results of the stages it needs: that is the graph.  Its figures are
tasks of their own (:mod:`.figures`).  Everything is submitted at once; the scheduler
runs what is ready, the co-design's units first (it is the critical path).  A stage
whose input failed is skipped, with the failure named; no stage falls back to another
input.  Results are kept by key, so a second run reads them and a killed run resumes.

Folders (:func:`~analysis.pipeline.options.run_folder`): a full run on RABBIT writes
into ``OUT``, a quick run into ``OUT/quick``, another robot into ``OUT/<name>`` (and
``.../quick``).  In a run's folder: ``report.md``, ``summary.json``, ``gait.json`` and
``figures/``.  A run writes them into a private staging folder first and moves them into
place at the end: a run that fails or is interrupted leaves the previous run's files as
they were, and a finished run replaces exactly the files of the previous run of the same
kind.
"""
from __future__ import annotations

import concurrent.futures as cf
import contextlib
import json
import os
import shutil
import sys
import time
import dataclasses
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path

from biped_casadi import RABBIT_DESCRIPTION, robot
from biped_casadi.files import write_bytes_atomic, write_text_atomic
from biped_casadi.results import Result, json_safe

from ..design.codesign import replay_args
from ..reporting.constants import PAPER
from ..reporting.report import write_report
from ..tasks import Engine, TaskError
from . import figures as F
from .options import ReproduceOptions, run_folder
from .paper import (stage_fig2, stage_fig3, stage_fig4, stage_gait, stage_grid, stage_m1,
                    stage_singular, stage_vc)
from .mujoco import mujoco_figure, stage_mujoco
from .speed import stage_family
from .terrain import stage_terrain
from .walking import (stage_basins, stage_basins_robust, stage_robust_design,
                      stage_robustness, stage_robustness_robust, stage_search, stage_sim,
                      stage_sim_robust, stage_tradeoff)

__all__ = ["reproduce", "ReproduceResult", "STAGES", "Stage", "Figures", "Need", "optional",
           "THIS", "Scope", "Outcome", "StageRecord"]


class Scope(StrEnum):
    """Where a stage applies."""

    PAPER = "paper"          # every robot
    ROBUST = "robust"        # RABBIT (the robust designs are calibrated on it)
    FULL = "full"            # RABBIT, full runs only


class Outcome(StrEnum):
    """How a stage ended."""

    OK = "ok"
    FAILED = "failed"
    SKIPPED = "skipped"      # a stage it needs failed


@dataclass(frozen=True, eq=False)
class Need:
    """A stage whose result another stage or a figure takes.

    Parameters
    ----------
    stage : Stage or None
        The stage (None: the stage the figure belongs to).
    optional : bool
        Passed as None when the stage is not in this run's graph (else it must be).
    """

    stage: object = None
    optional: bool = False


#: in a figure's needs: the result of the stage it belongs to
THIS = Need()


def optional(stage) -> Need:
    """A need passed as None when ``stage`` is not in the run's graph.

    Parameters
    ----------
    stage : Stage
        The stage.

    Returns
    -------
    Need
    """
    return Need(stage, optional=True)


@dataclass(frozen=True, eq=False)
class Figures:
    """Figures drawn from stage results by one task.

    Parameters
    ----------
    task : callable
        The figure task: it takes the results of ``needs`` in order, then the run's
        resolution if ``resolution``, and returns name -> format -> bytes.
    needs : tuple of Need or Stage
        Whose results it takes (default: its own stage's).
    resolution : bool
        Whether it takes the run's resolution last.
    """

    task: object
    needs: tuple = (THIS,)
    resolution: bool = False


@dataclass(frozen=True, eq=False)
class Stage:
    """One stage of the graph.

    Parameters
    ----------
    name : str
        Its name in the report.
    flow : callable
        Its flow (a task taking the engine first).
    needs : tuple of Stage or Need
        The stages whose results are its arguments (declared before it).
    model : bool
        Whether it takes the robot's model first.
    resolution : bool
        Whether it takes the run's resolution last.
    priority : int
        Dask's priority of its tasks.
    scope : Scope
        Where it applies.
    figures : tuple of Figures
        The figures it draws.
    """

    name: str
    flow: object
    needs: tuple = ()
    model: bool = False
    resolution: bool = True
    priority: int = 0
    scope: Scope = Scope.PAPER
    figures: tuple = ()

    def applies(self, rabbit: bool, quick: bool) -> bool:
        """Whether it is in the graph of a run.

        Parameters
        ----------
        rabbit : bool
            The robot is RABBIT.
        quick : bool
            A quick run.

        Returns
        -------
        bool
        """
        return self.scope is Scope.PAPER or (rabbit and not (self.scope is Scope.FULL
                                                             and quick))


def _needed(need, own: Stage, done: dict):
    """The future a need stands for in a run (``done``: stage -> future)."""
    need = need if isinstance(need, Need) else Need(need)
    stage = need.stage or own
    if stage in done or not need.optional:
        return done[stage]
    return None


# the graph of a reproduction; the co-design and what hangs on it first in Dask's
# priority; STAGES lists it in the order of the report
GAIT = Stage("gait", stage_gait, model=True, resolution=False, priority=20,
             figures=(Figures(F.gait_figures),))
SINGULAR = Stage("singular outputs (eq. 24)", stage_singular, (GAIT,), resolution=False)
FIG2 = Stage("Fig. 2: 1-D sweeps", stage_fig2, (GAIT,), figures=(Figures(F.fig2),))
GRID = Stage("M1 grid", stage_grid, (GAIT,))
FIG3 = Stage("Fig. 3 and the conjecture", stage_fig3, (GAIT, GRID), resolution=False,
             figures=(Figures(F.fig3),))
FIG4 = Stage("a, b and Fig. 4", stage_fig4, (GAIT, GRID), figures=(Figures(F.fig4),))
M1 = Stage("M1 NLP", stage_m1, (GAIT, GRID, FIG4))
VC = Stage("virtual constraints", stage_vc, (GAIT, M1), resolution=False)
ROBUSTNESS = Stage("robustness (s*), default gait", stage_robustness, (GAIT, M1))
BASINS = Stage("basins of attraction, default gait", stage_basins, (GAIT, M1),
               figures=(Figures(F.basins_default),))
SEARCH = Stage("the sampling search's design", stage_search, model=True, scope=Scope.ROBUST)
ROBUST = Stage("robust design", stage_robust_design, model=True, priority=10,
               scope=Scope.ROBUST)
BASINS_R = Stage("basins of the robust designs", stage_basins_robust, (ROBUST, SEARCH),
                 priority=5, scope=Scope.ROBUST, figures=(Figures(F.basins_robust),))
TRADEOFF = Stage("the NLP's trade-off curve", stage_tradeoff, (ROBUST,), priority=5,
                 scope=Scope.FULL)
ROBUSTNESS_R = Stage("s* of the robust designs", stage_robustness_robust, (ROBUST, SEARCH),
                     priority=5, scope=Scope.ROBUST,
                     figures=(Figures(F.tradeoff, (ROBUST, optional(TRADEOFF), THIS)),))
SIM_R = Stage("Fig. 5, Fig. 6, animation", stage_sim_robust, (ROBUST, SEARCH), priority=5,
              scope=Scope.ROBUST)
SIM = Stage("Fig. 5 runs, default gait", stage_sim, (GAIT, M1),
            figures=(Figures(F.fig5_fig6, (THIS, optional(SIM_R))),
                     Figures(F.animation, (THIS, optional(SIM_R)), resolution=True)))
TERRAIN = Stage("uneven ground (MFPT, GSN)", stage_terrain, (GAIT, M1, ROBUST),
                scope=Scope.ROBUST, figures=(Figures(F.terrain_figures),))
FAMILY = Stage("gait family and speed", stage_family, (ROBUST,), model=True,
               scope=Scope.ROBUST, figures=(Figures(F.family_figure),))
MUJOCO = Stage("in MuJoCo", stage_mujoco, (GAIT, M1, ROBUST, SEARCH), scope=Scope.ROBUST,
               figures=(Figures(mujoco_figure),))
STAGES = (GAIT, SINGULAR, FIG2, GRID, FIG3, FIG4, M1, VC, ROBUSTNESS, SIM, BASINS, SEARCH,
          ROBUST, BASINS_R, TRADEOFF, ROBUSTNESS_R, SIM_R, TERRAIN, FAMILY, MUJOCO)


@dataclass
class StageRecord:
    """How a stage of a run went (a row of summary.json's ``stages``).

    Parameters
    ----------
    status : Outcome
        Ok, failed or skipped.
    reason : str
        Why it was skipped.
    error : str
        Why it failed.
    traceback : str
        Where it failed.
    computed, reused : int
        Its tasks computed and reused.
    time : float
        Its tasks' seconds of work.
    """

    status: Outcome
    reason: str = ""
    error: str = ""
    traceback: str = ""
    computed: int = 0
    reused: int = 0
    time: float = 0.0

    def to_dict(self) -> dict:
        """The row (without empty texts).

        Returns
        -------
        dict
        """
        return {k: v for k, v in dataclasses.asdict(self).items() if v != ""}


@dataclass
class FigureJob:
    """A figure task submitted for a stage."""

    stage: Stage
    future: object


@dataclass
class ReproduceResult(Result):
    """What a reproduction did.

    Parameters
    ----------
    status : str
        'ok' (every stage ok) or 'failed' (some stage failed or was skipped; the others
        still ran); ``success`` means 'ok'.
    message : str
        Which stages were not ok.
    mode : str
        'full' or 'quick'.
    folder : str
        The run's folder.
    report : str
        Its report.md.
    summary_file : str
        Its summary.json.
    stages : dict
        Stage -> status, tasks computed and reused, work seconds.
    total_time : float
        Wall time, s.
    critical_path : dict
        The longest chain of computed tasks (``seconds``, ``tasks``): the wall time's
        bound on any number of workers.
    summary : dict
        The content of summary.json (not in ``to_dict()``).
    """

    status: str
    message: str
    mode: str
    folder: str
    report: str
    summary_file: str
    stages: dict
    total_time: float
    critical_path: dict = field(default_factory=dict)
    summary: dict = field(default_factory=dict, metadata={"dict": False})

    SUCCESS = ("ok",)


def build(eng, model, res, quick: bool) -> dict:
    """Spawn every stage of the run's graph: stage -> its future."""
    rabbit = model.description == RABBIT_DESCRIPTION
    S = {}
    for st in STAGES:
        if st.applies(rabbit, quick):
            args = ([model] if st.model else []) + [_needed(n, st, S) for n in st.needs] \
                + ([res] if st.resolution else [])
            with eng.stage(st.name, st.priority):
                S[st] = eng.spawn(st.flow, *args)
    return S


def reproduce(out_dir="reproduce_out", quick: bool = False, **kw) -> ReproduceResult:
    """Run the graph; the results go to :func:`run_folder` (module docstring).

    Parameters
    ----------
    out_dir : str or Path
        Created if needed; must not be a file.
    quick : bool
        Coarser grids and fewer starts, the co-design's gait fixed.
    **kw
        Fields of :class:`~analysis.pipeline.options.ReproduceOptions` (``robot``,
        ``scheduler``, ``workers``, ``progress``) or of
        :class:`~analysis.pipeline.options.Resolution`.

    Returns
    -------
    ReproduceResult
        Its ``summary`` is also in ``summary.json``.

    Raises
    ------
    ValueError
        ``out_dir`` (or the run's folder inside it) is a file; an unknown robot or
        option.
    """
    opts = ReproduceOptions.make(quick, **kw)
    model = robot(opts.robot)
    res = opts.resolution_of()
    folder = run_folder(out_dir, quick, opts.robot)
    for p in (Path(out_dir), folder, folder / "figures"):
        if p.exists() and not p.is_dir():
            raise ValueError(f"out_dir: {p} is a file, not a folder")
    made = _make_folder(folder)
    staging = folder / f".staging-{os.getpid()}"
    log = Log(opts.progress)
    t0 = time.perf_counter()
    try:
        shutil.rmtree(staging, ignore_errors=True)
        (staging / "figures").mkdir(parents=True)
        with Engine(opts.scheduler, opts.workers, progress=opts.progress, log=log,
                    preload=(__name__,)) as eng:
            S = build(eng, model, res, quick)
            log.expect(S)
            stages, summary, files = _collect(eng, S, res, staging, log)
            eng.check_started()
            total = time.perf_counter() - t0
            crit = eng.critical_path()
        summary = _finish(summary, stages, files, staging, opts, res, model, quick, total,
                          crit)
        write_text_atomic(staging / "summary.json",
                          json.dumps(summary, indent=1, allow_nan=False) + "\n")
        write_report(staging, summary)
        _publish(staging, folder)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
        _remove_empty(made)
    bad = [k for k, v in stages.items() if v.status is not Outcome.OK]
    log(f"done in {total:.0f} s (critical path {crit['seconds']:.0f} s)")
    return ReproduceResult(
        status="failed" if bad else "ok",
        message=f"stages not ok: {', '.join(bad)}" if bad else "every stage ok",
        mode="quick" if quick else "full", folder=str(folder), report=str(folder / "report.md"),
        summary_file=str(folder / "summary.json"), stages=summary["stages"], total_time=total,
        critical_path=crit, summary=summary)


def _make_folder(folder: Path) -> list:
    """Create ``folder`` and its missing parents; those it created, deepest first."""
    made, p = [], folder
    while not p.exists():
        made.append(p)
        p = p.parent
    folder.mkdir(parents=True, exist_ok=True)
    return made


def _remove_empty(folders: list):
    """Remove those of ``folders`` (deepest first) that are still empty: a run stopped
    before its results (Ctrl-C, an error) leaves no folder it made; a folder with files,
    or one that was there before, is kept."""
    for p in folders:
        with contextlib.suppress(OSError):
            p.rmdir()


class Log:
    """Progress on stderr: one line per stage as it finishes, and the flows' lines."""

    def __init__(self, enabled: bool):
        self.enabled = bool(enabled)
        self.total, self.done = 0, 0

    def expect(self, stages: dict):
        self.total = len(stages)

    def __call__(self, msg: str):
        """A line of a flow, after the name of its stage."""
        if self.enabled:
            stage = Engine.current_stage()[0]
            print(f"   {stage}: {msg.strip()}" if stage else msg, file=sys.stderr, flush=True)

    def stage(self, name: str, st: StageRecord):
        self.done += 1
        what = st.status + (f" ({st.reason or st.error})" if st.status is not Outcome.OK
                            else "")
        self(f"[{self.done}/{self.total}] {name}: {what}; tasks computed {st.computed}, "
             f"reused {st.reused}, {st.time:.1f} s of work")


def _status(eng, name: str, future) -> StageRecord:
    """A finished stage's record."""
    try:
        future.result()
        return StageRecord(Outcome.OK)
    except TaskError as e:
        origin = next((r.stage for r in eng.records if r.key == e.key), "")
        if origin and origin != name:
            return StageRecord(Outcome.SKIPPED, reason=f"needs {origin!r}, which failed: {e}")
        return StageRecord(Outcome.FAILED, error=str(e), traceback=e.detail[-2000:])


def _merge(into: dict, part: dict):
    """Deep-merge a stage's summary: dicts merged, lists appended, values set."""
    for k, v in part.items():
        if isinstance(v, dict) and isinstance(into.get(k), dict):
            _merge(into[k], v)
        elif isinstance(v, list) and isinstance(into.get(k), list):
            into[k] = into[k] + v
        else:
            into[k] = v


def _collect(eng, S: dict, res, staging: Path, log: Log) -> tuple:
    """Wait for the stages as they finish, submitting each figure once the stages it
    draws from are done, then for the figures; write the figures and the gaits."""
    stages, jobs = {}, []
    figures = [(st, f) for st in S for f in st.figures]
    pending = {fut: st for st, fut in S.items()}
    while pending:
        for fut in cf.wait(pending, return_when=cf.FIRST_COMPLETED).done:
            st = pending.pop(fut)
            stages[st] = _status(eng, st.name, fut)
        for st, f in list(figures):
            needs = [n if isinstance(n, Need) else Need(n) for n in f.needs]
            if all((n.stage or st) in stages or (n.optional and (n.stage or st) not in S)
                   for n in needs):
                figures.remove((st, f))
                if all(stages.get(n.stage or st, StageRecord(Outcome.OK)).status is Outcome.OK
                       for n in needs):
                    args = [_needed(n, st, S) for n in needs] + ([res] if f.resolution else [])
                    with eng.stage(st.name, st.priority):
                        jobs.append(FigureJob(st, eng.submit(f.task, *args)))
    files = {}
    for job in jobs:
        try:
            for fname, by_fmt in job.future.result().items():
                files[fname] = _write_figure(staging / "figures", fname, by_fmt)
        except TaskError as e:
            if stages[job.stage].status is Outcome.OK:
                stages[job.stage] = dataclasses.replace(stages[job.stage], status=Outcome.FAILED,
                                                        error=f"figure: {e}")
    for st, rec in stages.items():          # after the figures: their tasks count too
        rec.computed, rec.reused, rec.time = _counts(eng, st.name)
        log.stage(st.name, rec)
    summary = {}
    for st, fut in S.items():
        if stages[st].status is Outcome.OK:
            _merge(summary, json_safe(fut.result().summary))
    summary["replay"] = _replay(S, stages, staging, res)
    return {st.name: stages[st] for st in STAGES if st in stages}, summary, files


def _replay(S: dict, stages: dict, staging: Path, res) -> dict:
    """The gaits of the run's designs saved beside the report, and the ``biped simulate``
    arguments that replay each design from the paper's perturbation."""
    done = {st.flow: fut.result() for st, fut in S.items() if stages[st].status is Outcome.OK}
    out, tail = {}, ["--perturb", "0.01", "0.1", "--mu", "0.6", "--steps", str(res.sim_steps)]
    designs = []
    if stage_gait in done:
        done[stage_gait].gait.save(staging / "gait.json")
        designs.append(("virtual constraints, default gait", "gait.json", ["--controller", "vc"]))
        if stage_m1 in done:
            designs.append(("the chosen deadbeat M1, default gait", "gait.json",
                            ["--controller", "tv", "--m1", *_numbers(done[stage_m1].chosen)]))
    if stage_search in done:
        d = done[stage_search].design
        d.gait.save(staging / "gait_search.json")
        designs.append(("the sampling search's design, its gait", "gait_search.json",
                        ["--controller", "tv", "--m1", *_numbers(d.M1), "--rejoin",
                         *_numbers([d.rejoin])]))
    for label, file, args in designs:
        out[label] = dict(gait_file=file, simulate_args=["--gait", file, *args, *tail])
    if stage_robust_design in done:     # with the co-design's own verification settings
        r = done[stage_robust_design].result
        r.gait.save(staging / "gait_robust.json")
        out["the robust co-design, its gait"] = dict(
            gait_file="gait_robust.json", simulate_args=replay_args(r, "gait_robust.json"))
    return out


def _numbers(x) -> list:
    return [repr(float(v)) for v in x]


def _counts(eng, name: str) -> tuple:
    recs = [r for r in eng.records if r.stage == name]
    return (sum(r.state == "computed" for r in recs), sum(r.state == "reused" for r in recs),
            round(sum(r.seconds for r in recs if r.state == "computed" and not r.flow), 2))


def _write_figure(folder: Path, name: str, by_fmt: dict) -> list:
    out = []
    for ext, data in by_fmt.items():
        p = folder / f"{name}.{ext}"
        write_bytes_atomic(p, data)
        out.append(f"figures/{p.name}")
    return out


def _finish(summary, stages, files, staging, opts, res, model, quick, total, crit) -> dict:
    rabbit = model.description == RABBIT_DESCRIPTION
    if not rabbit:
        summary.setdefault("robust_design", dict(
            skipped="the robust co-design starts from gait options calibrated on RABBIT; "
                    "run 'biped m1 --robust --gait gait.json' (the gait beside this report) "
                    "for another robot"))
    # the settings as run on this robot (its scaled defaults filled in)
    used = dataclasses.replace(res, codesign=res.codesign.for_model(model))
    summary.update(mode="quick" if quick else "full", stages=stages, figures=files,
                   options=dict(used.to_dict(), robot=opts.robot), total_time=total,
                   critical_path=crit, finished=time.strftime("%Y-%m-%d %H:%M:%S %z"))
    if rabbit:
        summary["paper"] = PAPER
    return json_safe(summary)


def _publish(staging: Path, folder: Path):
    """Move a finished run from ``staging`` into ``folder``: every file replaced
    atomically; the previous run's figures that this run did not make removed (they are
    listed in the previous summary.json); nothing else touched."""
    figures = folder / "figures"
    old = set()
    with contextlib.suppress(OSError, ValueError, TypeError, AttributeError):
        prev = json.loads((folder / "summary.json").read_text())
        for fs in prev.get("figures", {}).values():
            for f in ([fs] if isinstance(fs, str) else fs):
                p = folder / f if Path(f).parts[:1] == ("figures",) else Path(f)
                old.add(p.resolve())
    figures.mkdir(exist_ok=True)
    new = set()
    for f in sorted((staging / "figures").iterdir()):
        os.replace(f, figures / f.name)
        new.add((figures / f.name).resolve())
    for p in sorted(old - new):
        if p.parent == figures.resolve() and p.is_file():     # only files in figures/
            p.unlink()
    for name in ("gait.json", "gait_robust.json", "gait_search.json", "summary.json",
                 "report.md"):
        if (staging / name).exists():
            os.replace(staging / name, folder / name)
