"""Long work as a graph of pure, cached tasks on Dask (:mod:`analysis.tasks.engine`),
keyed by their inputs and the version of the numerical code (:mod:`analysis.tasks.keys`),
kept on disk (:mod:`analysis.tasks.store`)."""
from .engine import (SCHEDULER_ENV, Engine, Ref, TaskError, TaskInfo, TaskRecord, in_task,
                     resolve_scheduler, task)
from .keys import CODE_SETS, NotKeyable, argument_key, code_version, task_key
from .store import ResultStore

__all__ = ["task", "TaskInfo", "Engine", "Ref", "TaskError", "TaskRecord", "in_task",
           "resolve_scheduler", "SCHEDULER_ENV", "code_version", "argument_key", "task_key",
           "CODE_SETS", "NotKeyable", "ResultStore"]
