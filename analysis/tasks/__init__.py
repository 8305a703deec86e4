"""Long work as a graph of pure, cached tasks: Dask schedules them, the toolkit names
them by content and keeps their results (:mod:`analysis.tasks.engine`; keys, code
digests and the store: :mod:`biped_casadi.caching`).  How to declare tasks, flows and
stages: the docs' how-to "Run on a Dask cluster", section "Declaring work"."""
from biped_casadi.caching import NotKeyable, ResultStore, argument_key, code_version, task_key

from .engine import (SCHEDULER_ENV, Engine, TaskError, TaskInfo, TaskRecord, TaskState,
                     resolve_scheduler, task)

__all__ = ["task", "TaskInfo", "Engine", "TaskError", "TaskRecord", "TaskState",
           "resolve_scheduler", "SCHEDULER_ENV", "code_version", "argument_key", "task_key",
           "NotKeyable", "ResultStore"]
