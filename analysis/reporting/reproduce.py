"""``biped reproduce``: the paper end to end on the embedded default (RABBIT, default
gait), or the same analysis on another robot (``robot='three_link'`` or a description
file), with figures (PNG and PDF), ``summary.json`` and ``report.md``.

Stages run in order; each shows its progress, a failed stage is reported (with its
error) and the stages that do not need its results still run.  What depends on the
number of torques nu: the M1 grid is the paper's 9^4 for nu = 4, the whole
(M1(1), M1(2)) plane for nu = 2 (the stable domain of M1 itself, with every solution of
a = b = 0 on it); Fig. 4 (the stable domains of the a = b = 0 groups over the free
components) exists for nu = 4 only; the paper's published numbers are RABBIT's and are
compared for RABBIT only.

Folders (:func:`run_folder`): a full run on RABBIT writes into ``OUT`` itself, a quick
run into ``OUT/quick``; another robot into ``OUT/<its name or file's stem>`` (and
``.../quick``), so no two kinds of run ever mix or overwrite each other's results,
whatever the order of the runs.  In a run's folder: ``report.md``, ``summary.json``, ``gait.json``,
``figures/`` and ``sweeps/`` (the resumable sweeps, one sub-folder per sweep and
settings, reused by the next run).  A run writes its report, summary, gait and figures
into a private staging folder first and moves them into place at the end: a run that
fails or is interrupted leaves the previous run's results as they were, and a finished
run replaces exactly the files of the previous run of the same kind (other files are
never touched).
"""
from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path


from biped_casadi import (RABBIT_DESCRIPTION, robot)
from biped_casadi.files import write_text_atomic
from biped_casadi.results import Result, json_safe

from .report import write_report

from .constants import PAPER
from .context import FORMATS, Context, is_rabbit
from .stages_paper import (stage_fig2, stage_fig3, stage_fig4, stage_gait, stage_grid, stage_m1,
                           stage_singular, stage_vc)
from .stages_walking import (help_codesign, stage_basins, stage_basins_robust,
                             stage_robust_design,
                             stage_robustness, stage_robustness_robust, stage_search_design,
                             stage_sim, stage_sim_robust, stage_terrain, stage_tradeoff,
                             warm_robust_runs)

__all__ = ["reproduce", "ReproduceOptions", "ReproduceResult", "PAPER", "run_folder", "STAGES",
           "FORMATS"]


@dataclass
class ReproduceOptions:
    """Resolution of every stage; ``quick`` gives the coarse variant (<= 3 min).
    ``robot``: a built-in name or a description file (default RABBIT)."""
    quick: bool = False
    robot: str = "rabbit"
    line_points: int = 401          # Fig. 2: points per component on [-10, 10]
    grid_n: int = 9                 # the paper's 9^4 grid
    plane_n: int = 161              # nu = 2: the (M1(1), M1(2)) grid, points per side
    domain_n: int = 81              # Fig. 4: (M1(2), M1(3)) grid per group
    domain_range: tuple = (-10.0, 10.0)
    nlp_starts: int = 10
    sim_steps: int = 10
    animation_steps: int = 4
    progress: bool = True
    helper: bool = True             # the robust half on the second core (see _Helper)

    @classmethod
    def make(cls, quick: bool = False, **kw):
        if quick:
            base = dict(quick=True, line_points=101, domain_n=41, plane_n=81, nlp_starts=4,
                        sim_steps=6, animation_steps=2)
            base.update(kw)
            return cls(**base)
        return cls(**kw)


@dataclass
class ReproduceResult(Result):
    """What a reproduction did.  ``status`` 'ok' (every stage ok) or 'failed' (some stage
    failed or was skipped; the others still ran); ``success`` means 'ok'.  ``folder`` is
    the run's folder (``OUT`` for a full run, ``OUT/quick`` for a quick one) with
    ``report`` and ``summary_file``; ``stages`` maps each stage to its status and time;
    ``summary`` (not in ``to_dict()``) is the content of summary.json."""

    status: str
    message: str
    mode: str
    folder: str
    report: str
    summary_file: str
    stages: dict
    total_time: float
    summary: dict = field(default_factory=dict, metadata={"dict": False})

    SUCCESS = ("ok",)


def run_folder(out_dir, quick: bool, robot_name="rabbit") -> Path:
    """The folder a run writes into: ``out_dir`` for the full run on RABBIT,
    ``out_dir/quick`` for the quick one; for another robot ``out_dir/<name>`` and
    ``out_dir/<name>/quick``, the name being the built-in robot's or the description
    file's (``--robot my_biped.toml``: ``my_biped``).

    Parameters
    ----------
    out_dir : str or Path
    quick : bool
    robot_name : str or Path
        A built-in robot name or a description file (ValueError when unknown).

    Returns
    -------
    Path
    """
    folder = Path(out_dir)
    if robot(robot_name or "rabbit").description != RABBIT_DESCRIPTION:
        text = str(robot_name).strip()
        stem = Path(text).stem if Path(text).suffix.lower() in (".toml", ".json") else text
        slug = re.sub(r"[^A-Za-z0-9_.-]+", "_", stem).strip("._") or "robot"
        folder = folder / (f"robot_{slug}" if slug in ("quick", "figures", "sweeps")
                           else slug)
    return folder / "quick" if quick else folder


STAGES = [
    ("gait", stage_gait, ()),
    ("singular outputs (eq. 24)", stage_singular, ("gait",)),
    ("Fig. 2: 1-D sweeps", stage_fig2, ("gait",)),
    ("M1 grid", stage_grid, ("gait",)),
    ("Fig. 3 and the conjecture", stage_fig3, ("M1 grid",)),
    ("a, b and Fig. 4", stage_fig4, ("gait",)),
    ("M1 NLP", stage_m1, ("gait",)),
    ("virtual constraints", stage_vc, ("gait",)),
    ("robustness (s*), default gait", stage_robustness, ("M1 NLP",)),
    ("Fig. 5 runs, default gait", stage_sim, ("M1 NLP",)),
    ("basins of attraction, default gait", stage_basins, ("M1 NLP",)),
    ("the sampling search's design", stage_search_design, ("gait",)),
    ("robust design", stage_robust_design, ("gait",)),
    ("basins of the robust designs", stage_basins_robust, ("robust design",)),
    ("the NLP's trade-off curve", stage_tradeoff, ("robust design",)),
    ("s* of the robust designs", stage_robustness_robust, ("robust design",)),
    ("Fig. 5, Fig. 6, animation", stage_sim_robust, ("Fig. 5 runs, default gait",)),
    ("uneven ground (MFPT, GSN)", stage_terrain, ("gait",)),
]

#: the stages before which this process takes any of the co-design's independent units
#: that are free (its start screens and rejoin choices, from the last; never waiting), so
#: that the helper reaches the sequential gait steps sooner (:func:`help_codesign`)
PAPER_STAGES = (stage_fig2, stage_grid, stage_fig3, stage_fig4, stage_m1, stage_vc,
                stage_robustness, stage_sim, stage_basins, stage_search_design,
                stage_robust_design)

#: the stage before which the full run joins the co-design's independent units and waits
#: for the helper's share of them (measured, bench_reproduce.py: waiting here, while the
#: helper has both cores, beats taking units only when they are free, which leaves both
#: processes' threads on two cores; the quick run, whose co-design is short, never waits)
JOIN_STAGE = stage_m1

#: what the helper process computes ahead, in its order, while this process runs the
#: paper's stages: the co-design (the gait-fixed one of --quick split with this process,
#: unit by unit), the trade-off's points (split the same way), the sampling search's
#: design (from the other end of the stage, meeting this process in the middle), then the
#: robust designs' s*, full-order runs and basins (this process takes their basins first,
#: so the two meet in the middle), then the Monte Carlo runs of the terrain stage
HELPER_STAGES = (stage_robust_design, stage_tradeoff, stage_search_design,
                 stage_robustness_robust, warm_robust_runs, stage_basins_robust, stage_terrain)




def reproduce(out_dir="reproduce_out", quick: bool = False, **kw) -> ReproduceResult:
    """Run every stage; the results go to :func:`run_folder` (``out_dir`` for the full
    run on RABBIT, ``out_dir/quick`` for ``quick``, ``out_dir/<robot>`` for another
    robot), see the module docstring.

    Parameters
    ----------
    out_dir : str or Path
        Created if needed; must not be a file.
    quick : bool
        Coarser grids and fewer starts (:meth:`ReproduceOptions.make`).
    **kw
        Fields of :class:`ReproduceOptions` (``robot='three_link'``, ...).

    Returns
    -------
    ReproduceResult
        Its ``summary`` is also in ``summary.json``.

    Raises
    ------
    ValueError
        ``out_dir`` (or the run's folder inside it) is a file; an unknown robot.
    """
    opts = ReproduceOptions.make(quick, **kw)
    folder = run_folder(out_dir, quick, opts.robot)
    for p in (Path(out_dir), folder, folder / "figures", folder / "sweeps"):
        if p.exists() and not p.is_dir():
            raise ValueError(f"out_dir: {p} is a file, not a folder")
    folder.mkdir(parents=True, exist_ok=True)
    staging = folder / f".staging-{os.getpid()}"
    shutil.rmtree(staging, ignore_errors=True)
    (staging / "figures").mkdir(parents=True)
    ctx = Context(staging, opts, sweeps=folder / "sweeps")
    try:
        status = _run_stages(ctx)
        mode = "quick" if opts.quick else "full"
        ctx.summary["mode"] = mode
        ctx.summary["stages"] = status
        ctx.summary["reused"] = ctx.reused
        ctx.summary["helped"] = ctx.helped
        ctx.summary["figures"] = {k: [_relative(f, staging) for f in
                                      ([v] if isinstance(v, str) else v)]
                                  for k, v in ctx.figures.items()}
        if ctx.model is not None and is_rabbit(ctx):
            ctx.summary["paper"] = PAPER
        ctx.summary["options"] = dict(opts.__dict__)
        ctx.summary["finished"] = time.strftime("%Y-%m-%d %H:%M:%S %z")
        summary = json_safe(ctx.summary)
        write_text_atomic(staging / "summary.json",
                          json.dumps(summary, indent=1, allow_nan=False) + "\n")
        write_report(staging, summary)
        _publish(staging, folder)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    bad = [k for k, v in status.items() if v["status"] != "ok"]
    ctx.log(f"report: {folder / 'report.md'}  ({ctx.summary['total_time']:.0f} s)")
    return ReproduceResult(
        status="failed" if bad else "ok",
        message=(f"stages not ok: {', '.join(bad)}" if bad else "every stage ok"),
        mode=mode, folder=str(folder), report=str(folder / "report.md"),
        summary_file=str(folder / "summary.json"), stages=summary["stages"],
        total_time=ctx.summary["total_time"], summary=summary)


def _helper_main(opts: dict, out: str):
    """The helper process: :data:`HELPER_STAGES` on a private staging folder, every
    long result kept in the cache (:meth:`Context.memo`, the co-design's own cache) for
    the main process to read; its figures and summary are thrown away."""
    import sys as _sys
    from gait_opt import default_gait
    _sys.stdout = _sys.stderr = open(os.devnull, "w")
    ctx = Context(Path(out), ReproduceOptions(**dict(opts, progress=False, helper=False)))
    (ctx.out / "figures").mkdir(parents=True, exist_ok=True)
    ctx.model = robot(ctx.opts.robot)
    ctx.data["helper"] = True
    for fn in HELPER_STAGES:
        ctx.stage = fn.__name__
        try:
            fn(ctx)
            if ctx.gait is None:       # after the robust design: the main process made it
                ctx.gait = default_gait(ctx.model)
        except Exception:              # noqa: BLE001 - the main process computes it again
            return


class _Helper:
    """The second core: once the gait is known, a process computes the robust design and
    what hangs on it (:data:`HELPER_STAGES`) while this one runs the paper's stages.
    Both go through the same cache: a result one of them is computing is claimed
    (:func:`analysis.reporting.context.claimed`), and the other waits for it instead of
    computing it twice.  The main process never depends on the helper: it computes
    whatever the helper has not, and stops the helper when it is done."""

    def __init__(self):
        self.proc = None

    def start(self, ctx: Context):
        import multiprocessing
        if self.proc is not None or not ctx.opts.helper or (os.cpu_count() or 1) < 2:
            return
        try:
            if robot(ctx.opts.robot).description != RABBIT_DESCRIPTION:
                return               # the robust design runs on RABBIT only
        except ValueError:           # an unknown robot: the gait stage says so
            return
        if not any(fn is stage_robust_design for _, fn, _ in STAGES):
            return                   # nothing for it to do in this run
        import tempfile
        self.out = out = tempfile.mkdtemp(prefix="biped-reproduce-helper-")
        self.proc = multiprocessing.get_context("spawn").Process(
            target=_helper_main, args=(dict(ctx.opts.__dict__), str(out)), daemon=True)
        self.proc.start()
        ctx.data["helper_running"] = True
        ctx.log("   (a helper process computes the robust design on the second core)")

    def stop(self):
        if self.proc is not None and self.proc.is_alive():
            self.proc.terminate()
            self.proc.join(5)
        if self.proc is not None:
            shutil.rmtree(self.out, ignore_errors=True)
        self.proc = None


def _run_stages(ctx: Context) -> dict:
    helper = _Helper()
    try:
        return _stages(ctx, helper)
    finally:
        helper.stop()


def _stages(ctx: Context, helper: _Helper) -> dict:
    status = {}
    t_all = time.perf_counter()
    for k, (name, fn, needs) in enumerate(STAGES, start=1):
        missing = [n for n in needs if status.get(n, {}).get("status") != "ok"]
        if missing:
            status[name] = dict(status="skipped", reason=f"needs: {', '.join(missing)}")
            ctx.log(f"[{k}/{len(STAGES)}] {name}: skipped (needs {', '.join(missing)})")
            continue
        if k == 1:
            helper.start(ctx)          # the robust design needs no stage of this process
        elif fn in PAPER_STAGES:
            # the co-design's free independent units, if any (the full run waits once)
            help_codesign(ctx, wait=fn is JOIN_STAGE and not ctx.opts.quick)
        ctx.log(f"[{k}/{len(STAGES)}] {name} ...")
        ctx.stage = name
        t = time.perf_counter()
        try:
            fn(ctx)
            status[name] = dict(status="ok", time=time.perf_counter() - t)
            kept, helped = ctx.reused.get(name), ctx.helped.get(name)
            ctx.log(f"[{k}/{len(STAGES)}] {name}: done in {time.perf_counter() - t:.1f} s"
                    + (f" (reused {len(kept)} kept result(s))" if kept else "")
                    + (f" ({len(helped)} result(s) from the helper process)" if helped
                       else ""))
        except Exception as e:          # a failed stage is reported, the others go on
            status[name] = dict(status="failed", error=f"{type(e).__name__}: {e}",
                                time=time.perf_counter() - t,
                                traceback=traceback.format_exc(limit=6))
            ctx.log(f"[{k}/{len(STAGES)}] {name}: FAILED ({type(e).__name__}: {e})")
    ctx.summary["total_time"] = time.perf_counter() - t_all
    return status


def _relative(path, root: Path) -> str:
    """``path`` relative to the run's folder (summary.json and report.md travel with it)."""
    try:
        return Path(path).resolve().relative_to(root.resolve()).as_posix()
    except ValueError:
        return str(path)


def _publish(staging: Path, folder: Path):
    """Move a finished run from ``staging`` into ``folder``: every file replaced
    atomically; the previous run's figures that this run did not make removed (they are
    listed in the previous summary.json); nothing else touched."""
    figures = folder / "figures"
    old = set()
    with contextlib.suppress(OSError, ValueError, TypeError, AttributeError):
        prev = json.loads((folder / "summary.json").read_text())
        for files in prev.get("figures", {}).values():
            for f in ([files] if isinstance(files, str) else files):
                # relative to the run's folder; older versions: to the working directory
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
