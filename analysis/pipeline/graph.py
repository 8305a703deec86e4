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
from dataclasses import dataclass, field
from pathlib import Path

from biped_casadi import RABBIT_DESCRIPTION, robot
from biped_casadi.files import write_bytes_atomic, write_text_atomic
from biped_casadi.results import Result, json_safe

from ..reporting.constants import PAPER
from ..reporting.report import write_report
from ..tasks import Engine, TaskError
from . import figures as F
from .options import ReproduceOptions, run_folder
from .paper import (stage_fig2, stage_fig3, stage_fig4, stage_gait, stage_grid, stage_m1,
                    stage_singular, stage_vc)
from .family import stage_family
from .terrain import stage_terrain
from .walking import (stage_basins, stage_basins_robust, stage_robust_design,
                      stage_robustness, stage_robustness_robust, stage_search, stage_sim,
                      stage_sim_robust, stage_tradeoff)

__all__ = ["reproduce", "ReproduceResult", "STAGES", "Stage"]


@dataclass(frozen=True)
class Figures:
    """Figures drawn from stage results.

    Parameters
    ----------
    task : callable
        The figure task.
    needs : tuple of str
        The stages whose results are its arguments (a name starting with '?' is passed
        as None when that stage is not in the graph).
    unless : str
        A stage whose presence makes these figures unnecessary (another declaration
        draws them).
    resolution : bool
        Whether it takes the run's resolution last.
    """

    task: object
    needs: tuple
    unless: str = ""
    resolution: bool = False


@dataclass(frozen=True)
class Stage:
    """One stage of the graph.

    Parameters
    ----------
    name : str
        Its name in the report.
    flow : callable
        Its flow (a task taking the engine first).
    needs : tuple of str
        The stages whose results are its arguments.
    model : bool
        Whether it takes the robot's model first.
    resolution : bool
        Whether it takes the run's resolution last.
    priority : int
        Dask's priority of its tasks.
    only : str
        Where it applies: 'paper' (every robot), 'robust' (RABBIT), 'full' (full runs).
    figures : tuple of Figures
        The figures it draws.
    """

    name: str
    flow: object
    needs: tuple = ()
    model: bool = False
    resolution: bool = True
    priority: int = 0
    only: str = "paper"
    figures: tuple = ()


_SIM, _SIM_R = "Fig. 5 runs, default gait", "Fig. 5, Fig. 6, animation"
_FIG56 = (Figures(F.fig5_fig6, (_SIM, _SIM_R)),
          Figures(F.animation, (_SIM, _SIM_R), resolution=True))

#: the graph of a reproduction, in the order of its report; the co-design and what hangs
#: on it first in Dask's priority
STAGES = (
    Stage("gait", stage_gait, (), model=True, resolution=False, priority=20,
          figures=(Figures(F.gait_figures, ("gait",)),)),
    Stage("singular outputs (eq. 24)", stage_singular, ("gait",), resolution=False),
    Stage("Fig. 2: 1-D sweeps", stage_fig2, ("gait",),
          figures=(Figures(F.fig2, ("Fig. 2: 1-D sweeps",)),)),
    Stage("M1 grid", stage_grid, ("gait",)),
    Stage("Fig. 3 and the conjecture", stage_fig3, ("gait", "M1 grid"), resolution=False,
          figures=(Figures(F.fig3, ("Fig. 3 and the conjecture",)),)),
    Stage("a, b and Fig. 4", stage_fig4, ("gait", "M1 grid"),
          figures=(Figures(F.fig4, ("a, b and Fig. 4",)),)),
    Stage("M1 NLP", stage_m1, ("gait", "M1 grid", "a, b and Fig. 4")),
    Stage("virtual constraints", stage_vc, ("gait", "M1 NLP"), resolution=False),
    Stage("robustness (s*), default gait", stage_robustness, ("gait", "M1 NLP")),
    Stage(_SIM, stage_sim, ("gait", "M1 NLP"),
          figures=tuple(Figures(f.task, (_SIM, "?" + _SIM_R), unless=_SIM_R,
                                resolution=f.resolution) for f in _FIG56)),
    Stage("basins of attraction, default gait", stage_basins, ("gait", "M1 NLP"),
          figures=(Figures(F.basins_default, ("basins of attraction, default gait",)),)),
    Stage("the sampling search's design", stage_search, (), model=True, only="robust"),
    Stage("robust design", stage_robust_design, (), model=True, priority=10, only="robust"),
    Stage("basins of the robust designs", stage_basins_robust,
          ("robust design", "the sampling search's design"), priority=5, only="robust",
          figures=(Figures(F.basins_robust, ("basins of the robust designs",)),)),
    Stage("the NLP's trade-off curve", stage_tradeoff, ("robust design",), priority=5,
          only="full"),
    Stage("s* of the robust designs", stage_robustness_robust,
          ("robust design", "the sampling search's design"), priority=5, only="robust",
          figures=(Figures(F.tradeoff, ("robust design", "?the NLP's trade-off curve",
                                        "s* of the robust designs")),)),
    Stage(_SIM_R, stage_sim_robust, ("robust design", "the sampling search's design"),
          priority=5, only="robust", figures=_FIG56),
    Stage("uneven ground (MFPT, GSN)", stage_terrain, ("gait", "M1 NLP", "robust design"),
          only="robust", figures=(Figures(F.terrain_figures, ("uneven ground (MFPT, GSN)",)),)),
    Stage("gait family and speed", stage_family, ("robust design",), model=True,
          only="robust", figures=(Figures(F.family_figure, ("gait family and speed",)),)),
)


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


def _applies(stage: Stage, rabbit: bool, quick: bool) -> bool:
    return (stage.only == "paper" or rabbit) and not (stage.only == "full" and quick)


def _figure_jobs(eng, stages, S: dict, res) -> list:
    """(stage, figure task ref) of every figure of the stages in the graph."""
    jobs = []
    for st in stages:
        if st.name not in S:
            continue
        for f in st.figures:
            if f.unless and f.unless in S:
                continue
            args = [S.get(n[1:]) if n.startswith("?") else S[n] for n in f.needs]
            with eng.stage(st.name, st.priority):
                jobs.append((st.name, eng.submit(f.task, *args, *([res] if f.resolution
                                                                 else []))))
    return jobs


def build(eng, model, res, quick: bool) -> tuple:
    """Submit the whole graph: (stage refs by name, figure jobs)."""
    rabbit = model.description == RABBIT_DESCRIPTION
    S = {}
    for st in STAGES:
        if not _applies(st, rabbit, quick):
            continue
        args = ([model] if st.model else []) + [S[n] for n in st.needs] \
            + ([res] if st.resolution else [])
        with eng.stage(st.name, st.priority):
            S[st.name] = eng.spawn(st.flow, *args)
    return S, _figure_jobs(eng, STAGES, S, res)


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
    folder.mkdir(parents=True, exist_ok=True)
    staging = folder / f".staging-{os.getpid()}"
    shutil.rmtree(staging, ignore_errors=True)
    (staging / "figures").mkdir(parents=True)
    log = Log(opts.progress)
    t0 = time.perf_counter()
    try:
        with Engine(opts.scheduler, opts.workers, progress=opts.progress, log=log,
                    preload=(__name__,)) as eng:
            S, jobs = build(eng, model, res, quick)
            log.expect(S)
            stages, summary, files = _collect(eng, S, jobs, staging, log)
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
    bad = [k for k, v in stages.items() if v["status"] != "ok"]
    log(f"report: {folder / 'report.md'}  ({total:.0f} s; critical path "
        f"{crit['seconds']:.0f} s)")
    return ReproduceResult(
        status="failed" if bad else "ok",
        message=f"stages not ok: {', '.join(bad)}" if bad else "every stage ok",
        mode="quick" if quick else "full", folder=str(folder), report=str(folder / "report.md"),
        summary_file=str(folder / "summary.json"), stages=summary["stages"], total_time=total,
        critical_path=crit, summary=summary)


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

    def stage(self, name: str, st: dict):
        self.done += 1
        what = st["status"] + (f" ({st.get('reason') or st.get('error')})"
                               if st["status"] != "ok" else "")
        self(f"[{self.done}/{self.total}] {name}: {what}; tasks computed {st['computed']}, "
             f"reused {st['reused']}, {st['time']:.1f} s of work")


def _status(eng, name: str, ref) -> dict:
    """A stage's status from its ref (waited for)."""
    try:
        ref.result()
        return dict(status="ok")
    except TaskError as e:
        origin = eng.origin_stage(e)
        if origin and origin != name:
            return dict(status="skipped", reason=f"needs {origin!r}, which failed: {e}")
        return dict(status="failed", error=str(e), traceback=e.detail[-2000:])


def _merge(into: dict, part: dict):
    """Deep-merge a stage's summary: dicts merged, lists appended, values set."""
    for k, v in part.items():
        if isinstance(v, dict) and isinstance(into.get(k), dict):
            _merge(into[k], v)
        elif isinstance(v, list) and isinstance(into.get(k), list):
            into[k] = into[k] + v
        else:
            into[k] = v


def _collect(eng, S: dict, jobs: list, staging: Path, log: Log) -> tuple:
    """Wait for every stage (as they finish) and figure; write the figures."""
    stages, files = {}, {}
    pending = {r: n for n, r in S.items()}
    while pending:
        for r in cf.wait(pending, return_when=cf.FIRST_COMPLETED).done:
            name = pending.pop(r)
            stages[name] = _status(eng, name, r)
            stages[name].update(_counts(eng, name))
            log.stage(name, stages[name])
    for stage, ref in jobs:
        try:
            for fname, by_fmt in ref.result().items():
                files[fname] = _write_figure(staging / "figures", fname, by_fmt)
        except TaskError as e:
            if stages.get(stage, {}).get("status") == "ok":
                stages[stage] = dict(stages[stage], status="failed",
                                     error=f"figure: {e}")
    summary = {}
    for name, ref in S.items():
        if stages[name]["status"] == "ok":
            _merge(summary, json_safe(ref.result().summary))
    if stages.get("gait", {}).get("status") == "ok":
        S["gait"].result().gait.save(staging / "gait.json")
    order = [s.name for s in STAGES if s.name in stages]
    return {n: stages[n] for n in order}, summary, files


def _counts(eng, name: str) -> dict:
    recs = [r for r in eng.records if r.stage == name]
    return dict(computed=sum(r.state == "computed" for r in recs),
                reused=sum(r.state == "reused" for r in recs),
                time=round(sum(r.seconds for r in recs if r.state == "computed"
                               and not r.flow), 2))


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
                    "run 'biped m1 --robust --robot ...' for another robot"))
    summary.update(mode="quick" if quick else "full", stages=stages, figures=files,
                   options=dict(res.__dict__, robot=opts.robot), total_time=total,
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
    for name in ("gait.json", "summary.json", "report.md"):
        if (staging / name).exists():
            os.replace(staging / name, folder / name)
