"""What a run of :mod:`analysis.tasks` records: how each task ended, and the error of a
failed one."""
from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

__all__ = ["TaskState", "TaskRecord", "TaskError"]


class TaskState(StrEnum):
    """How a task of a run ended."""

    COMPUTED = "computed"
    REUSED = "reused"
    FAILED = "failed"


@dataclass
class TaskRecord:
    """One task of a run.

    Parameters
    ----------
    name, stage, key : str
        The task, its stage and its content key.
    state, seconds, error : TaskState, float, str
        How it ended (None while it runs), what it took (reused: when it was
        computed), its failure.
    flow : bool
        Whether it is a flow (its seconds are mostly waiting).
    deps : tuple of str
        The keys it came after: its inputs and, in a flow, the results finished then.
    """

    name: str
    stage: str
    key: str
    state: TaskState = None
    seconds: float = 0.0
    error: str = ""
    flow: bool = False
    deps: tuple = ()


class TaskError(RuntimeError):
    """A task failed (``str()``: its name and error, on one line).

    Parameters
    ----------
    origin, message, detail, key : str
        The task that raised first in a chain; its error (``Type: text``), traceback, key.
    """

    def __init__(self, origin: str, message: str, detail: str = "", key: str = ""):
        super().__init__(origin, message, detail, key)
        self.origin, self.message, self.detail, self.key = origin, message, detail, key

    def __str__(self):
        return " ".join(f"{self.origin.rsplit('.', 1)[-1]}: {self.message}".split())
