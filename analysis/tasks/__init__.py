"""Long work as a graph of pure, cached tasks: Dask schedules them, the toolkit names
them by content and keeps their results (:mod:`analysis.tasks.engine`; keys, code
digests and the store: :mod:`biped_casadi.caching`).

How to declare work (the same before and after the move to Dask's own scheduling):

- A **task** is a module-level pure function marked ``@task`` (``@task(code="figures")``
  for one that draws); it stays a plain function.  ``engine.submit(fn, *args)`` returns
  a future at once (``.result()`` waits; a :class:`TaskError` when it or an input
  failed); a future passed as an argument, anywhere in lists, tuples, dicts or
  dataclass fields, is an edge of the graph, so submit everything first and read later.
- A **flow** is a ``@task`` whose first argument is the engine: ``engine.spawn(flow,
  ...)`` runs it in a thread of its own; it submits tasks, waits for them with
  ``.result()``, may spawn other flows, reports with ``engine.say(line)``, and returns a
  typed result that is kept like a task's.
- A **stage** of ``biped reproduce`` is a flow plus a
  :class:`analysis.pipeline.graph.Stage` in ``STAGES``: ``Stage(name, flow, needs=(OTHER,
  optional(MAYBE)), model=..., resolution=..., priority=..., scope=Scope.ROBUST,
  figures=(Figures(task, needs=...),))``; the flow gets the model (``model=True``),
  then the futures of its ``needs`` in order, then the run's ``Resolution``; its result
  subclasses :class:`analysis.pipeline.paper.StageResult` (``summary`` goes into
  summary.json).  Quick/full differences belong in ``Resolution`` fields.
- ``engine.state(future)`` says whether a result was computed or reused;
  ``engine.records`` lists every task of the run.
"""
from biped_casadi.caching import NotKeyable, ResultStore, argument_key, code_version, task_key

from .engine import (SCHEDULER_ENV, Engine, TaskError, TaskInfo, TaskRecord, TaskState,
                     resolve_scheduler, task)

__all__ = ["task", "TaskInfo", "Engine", "TaskError", "TaskRecord", "TaskState",
           "resolve_scheduler", "SCHEDULER_ENV", "code_version", "argument_key", "task_key",
           "NotKeyable", "ResultStore"]
