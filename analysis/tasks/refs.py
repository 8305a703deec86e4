"""What the engine hands out and passes around: task failures, the records of a run,
the handles of results (:class:`Ref`), the thread-local state of flows, and the packing
of arguments that hold results of other tasks (Dask resolves futures inside lists,
tuples and dicts only)."""
from __future__ import annotations

import dataclasses
import threading
import time
import traceback
from dataclasses import dataclass

from biped_casadi.caching import TaskInfo

from ..cluster import tune_allocator

__all__ = ["TaskError", "TaskRecord", "Ref", "in_task"]

#: per thread: the stage and priority of what it submits, whether it runs a task, and,
#: in a flow, the refs it waited for (the edges of the graph)
_LOCAL = threading.local()


# ------------------------------------------------------------------------ tasks
def _info(fn) -> TaskInfo:
    info = getattr(fn, "task_info", None)
    if info is None:
        raise TypeError(f"{getattr(fn, '__qualname__', fn)!r} is not a task (decorate it "
                        "with analysis.tasks.task)")
    return info


class TaskError(RuntimeError):
    """A task failed.

    Parameters
    ----------
    origin : str
        The task that raised (the first failure of a chain).
    message : str
        Its error, ``Type: text``.
    detail : str
        Its traceback.
    key : str
        The key of the task that raised.
    """

    def __init__(self, origin: str, message: str, detail: str = "", key: str = ""):
        super().__init__(origin, message, detail, key)
        self.origin, self.message, self.detail, self.key = origin, message, detail, key

    def __str__(self):
        return f"{self.origin.rsplit('.', 1)[-1]}: {self.message}"


def in_task() -> bool:
    """Whether this thread is running a task (library calls inside run synchronously).

    Returns
    -------
    bool
    """
    if getattr(_LOCAL, "task", False):
        return True
    try:
        from dask.distributed import get_worker
        get_worker()
        return True
    except (ImportError, ValueError):
        return False


def _execute(fn, key, args, kwargs):
    """Run a task (in this process or on a worker): (value, seconds); any error becomes a
    :class:`TaskError` naming the task."""
    tune_allocator()
    was = getattr(_LOCAL, "task", False)
    _LOCAL.task = True
    t = time.perf_counter()
    try:
        value = fn(*_unpack(args), **_unpack(kwargs))
    except TaskError:
        raise
    except Exception as e:          # noqa: BLE001 - reported with the task's name
        raise TaskError(_info(fn).name, f"{type(e).__name__}: {e}",
                        traceback.format_exc(limit=8), key) from None
    finally:
        _LOCAL.task = was
    return value, time.perf_counter() - t


# ------------------------------------------------------------ packed arguments
# Dask resolves futures inside lists, tuples and dicts only: a dataclass holding results
# of other tasks travels as a marked dict of its fields, and a result as a marked dict
# around the (value, seconds) pair its task returns.
_DATACLASS, _RESULT = "__task_dataclass__", "__task_result__"


def _unpack(obj):
    if isinstance(obj, dict):
        if _RESULT in obj and len(obj) == 1:
            return obj[_RESULT][0]
        if _DATACLASS in obj and len(obj) == 2:
            return obj[_DATACLASS](**{k: _unpack(v) for k, v in obj["fields"].items()})
        return {k: _unpack(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_unpack(v) for v in obj]
    if isinstance(obj, tuple):
        return tuple(_unpack(v) for v in obj)
    return obj


def _has_ref(obj) -> bool:
    if isinstance(obj, Ref):
        return True
    if isinstance(obj, (list, tuple)):
        return any(_has_ref(v) for v in obj)
    if isinstance(obj, dict):
        return any(_has_ref(v) for v in obj.values())
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return any(_has_ref(getattr(obj, f.name)) for f in dataclasses.fields(obj))
    return False


def _pack(obj, leaf):
    """``obj`` with every Ref replaced by ``leaf(ref)`` (dataclasses holding one become
    marked dicts of their fields)."""
    if isinstance(obj, Ref):
        return leaf(obj)
    if isinstance(obj, list):
        return [_pack(v, leaf) for v in obj]
    if isinstance(obj, tuple):
        return tuple(_pack(v, leaf) for v in obj)
    if isinstance(obj, dict):
        return {k: _pack(v, leaf) for k, v in obj.items()}
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type) and _has_ref(obj):
        return {_DATACLASS: type(obj), "fields": {f.name: _pack(getattr(obj, f.name), leaf)
                                                 for f in dataclasses.fields(obj) if f.init}}
    return obj


def _refs_in(obj) -> list:
    out = []
    _pack(obj, lambda r: out.append(r) or r)
    return out


# ------------------------------------------------------------------------- refs
@dataclass
class TaskRecord:
    """One task of a run.

    Parameters
    ----------
    name, stage, key : str
        The task, its stage and its key.
    state : str
        'computed', 'reused' or 'failed'.
    seconds : float
        What it took (computed: in this run; reused: when it was computed).
    error : str
        The failure, if any.
    flow : bool
        Whether it is a flow (whose seconds are mostly waiting).
    """

    name: str
    stage: str
    key: str
    state: str
    seconds: float
    error: str = ""
    flow: bool = False


class Ref:
    """The result of a submitted task or flow, available later.

    Parameters
    ----------
    engine : Engine
        The engine that runs it.
    key : str
        The task's key.
    name : str
        The task's name.
    stage : str
        The stage it was submitted in.

    Attributes
    ----------
    key : str
        The task's key.
    name : str
        The task's name.
    stage : str
        The stage it was submitted in.
    state : str
        'pending', 'computed', 'reused' or 'failed'.
    """

    def __init__(self, engine, key: str, name: str, stage: str):
        self.engine, self.key, self.name, self.stage = engine, key, name, stage
        self.state = "pending"
        self.seconds = 0.0
        self._value = None
        self._error = None
        self._event = threading.Event()
        self._future = None            # a Dask future while on the cluster
        self._scattered = None
        self._callbacks = []
        self._lock = threading.Lock()
        self.deps = ()                 # the refs it waited for (the graph's edges)
        self.flow = False

    def _finish(self, state, value=None, error=None, seconds=0.0):
        with self._lock:
            if self._event.is_set():            # the first outcome stands
                return
            self.state, self._value, self._error, self.seconds = state, value, error, seconds
            self._event.set()
            callbacks, self._callbacks = self._callbacks, []
        for cb in callbacks:
            cb(self)

    def _when_done(self, callback):
        """Call ``callback(self)`` once the result is known (at once if it is)."""
        with self._lock:
            if not self._event.is_set():
                self._callbacks.append(callback)
                return
        callback(self)

    def done(self) -> bool:
        """Whether the result (or the failure) is known.

        Returns
        -------
        bool
        """
        return self._event.is_set()

    def result(self):
        """The task's value; waits for it.

        Returns
        -------
        object

        Raises
        ------
        TaskError
            The task, or one it depends on, failed.
        """
        awaited = getattr(_LOCAL, "awaited", None)
        if awaited is not None:
            awaited.append(self)
        while not self._event.wait(0.5):
            if self.engine.closed:
                raise TaskError(self.name, "interrupted: the engine was closed", key=self.key)
        if self._error is not None:
            raise self._error
        return self._value

    def __repr__(self):
        return f"Ref({self.name.rsplit('.', 1)[-1]}, {self.state}, {self.key[:8]})"


