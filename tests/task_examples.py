"""Small tasks for the engine's tests (importable by Dask workers)."""
from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass

import numpy as np

from analysis.tasks import task


@dataclass(frozen=True)
class Pair:
    a: object
    b: float = 1.0


@task
def square(x):
    return float(x) ** 2


@task
def add(x, y):
    return x + y


@task
def total(values):
    return float(np.sum(values))


@task
def pair_sum(p: Pair):
    return p.a + p.b


@task
def fails(x):
    raise ValueError(f"no good: {x}")


@task
def pid(x):
    return os.getpid()


@task
def chain(engine, n):
    """A flow: each step depends on the result of the last."""
    v = 1.0
    for _ in range(n):
        v = engine.submit(add, v, engine.submit(square, v).result()).result()
    return v


@task
def unkept(x):
    """A result that cannot be kept: a lock cannot be pickled."""
    return threading.Lock()


@task
def unkept_flow(engine, x):
    return threading.Lock()


@task
def echo(x):
    return x


@task
def default_of(module: str, function: str, parameter: str):
    """The default of a parameter of a function, its module imported here if not yet."""
    import importlib
    import inspect
    fn = getattr(importlib.import_module(module), function)
    return inspect.signature(fn).parameters[parameter].default


@task
def default_of_flow(engine, module: str, function: str, parameter: str):
    """A flow returning :func:`default_of` (run in the client)."""
    return default_of(module, function, parameter)


@task
def started_at(x, wait: float = 0.0):
    """When it started (then it sleeps ``wait`` s)."""
    t = time.time()
    time.sleep(wait)
    return t


# ------------------------------------------------- stages for the reproduction's tests
from matplotlib.figure import Figure                    # noqa: E402

from analysis.pipeline.figures import figure_files      # noqa: E402
from analysis.pipeline.paper import StageResult         # noqa: E402


@task
def marker_stage(engine, res):
    """A cheap stage whose summary says which resolution made it."""
    return StageResult(dict(marker=dict(line_points=res.line_points)))


@task(code="figures")
def marker_figure(stage):
    fig = Figure()
    fig.add_subplot().set_title(f"line_points {stage.summary['marker']['line_points']}")
    return dict(marker=figure_files(fig))


@task(code="figures")
def slow_marker_figure(stage):
    """:func:`marker_figure`, a second late: still running when its stage has ended."""
    time.sleep(1.0)
    return marker_figure(stage)


@task
def failing_stage(engine, res):
    raise RuntimeError("this stage fails on purpose")


@task
def after_marker(engine, marker, res):
    return StageResult(dict(after=dict(seen=marker.result().summary["marker"])))


@task
def interrupted_stage(engine, res):
    raise KeyboardInterrupt
