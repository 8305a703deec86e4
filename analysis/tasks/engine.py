"""The engine of :mod:`analysis.tasks`: a task goes to Dask under its content key with its
stage's priority, its inputs as Dask futures (a kept or flow result sent as a task of its
own under its key, so that a lost worker's copy is made again); Dask queues, places,
steals and fails dependants; a thread keeps each result."""
from __future__ import annotations

import concurrent.futures as cf
import contextlib
import dataclasses
import logging
import os
import queue
import sys
import threading
import time
import traceback

from biped_casadi.caching import (MISSING, ResultStore, TaskInfo, code_edited, code_files,
                                  code_version, files_differing, task, task_key)

from ..cluster import check_not_bootstrapping, close_cluster, connect, tune_allocator
from ..reporting.progress import progress_bar
from .records import TaskError, TaskRecord, TaskState

__all__ = ["task", "TaskInfo", "Engine", "TaskError", "TaskRecord", "TaskState",
           "resolve_scheduler", "SCHEDULER_ENV"]

#: the environment variable that sets the default scheduler ('synchronous', an address)
SCHEDULER_ENV = "BIPED_SCHEDULER"
#: the Dask event topic of a task's seconds on a worker, and the metadata key of the
#: client's code files (a stale worker's message names the module that differs)
_TOPIC = "biped-task"
#: per thread: its stage and priority, the futures its flow has seen, whether in a task
_LOCAL = threading.local()


def resolve_scheduler(scheduler=None, workers: int | None = None):
    """What ``scheduler`` means, the same for every function that takes it.

    Parameters
    ----------
    scheduler : None, str or dask.distributed.Client
        None: ``$BIPED_SCHEDULER`` if set; inside a task 'synchronous'; otherwise
        'local'.  'synchronous' (or 'inline'): this process, one task after another.
        'local': a Dask ``LocalCluster``.  Another string: a Dask scheduler's address.
    workers : int, optional
        Workers of the ``LocalCluster`` (default: the cores); 1: 'synchronous'.

    Returns
    -------
    str or Client
        'synchronous', 'local', an address or the client (ValueError naming 'workers'
        or 'scheduler' for anything else).
    """
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)
                                or workers < 1):
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    if scheduler is None:
        try:                # inside a task here or on a worker (which imported Dask)
            inside = getattr(_LOCAL, "task", False) or (
                "distributed" in sys.modules and bool(sys.modules["distributed"].get_worker()))
        except ValueError:
            inside = False
        scheduler = "synchronous" if inside else os.environ.get(SCHEDULER_ENV) or "local"
    if type(scheduler).__name__ == "Client":
        return scheduler
    if not isinstance(scheduler, str) or not scheduler.strip():
        raise ValueError(f"scheduler must be None, 'synchronous', 'local', an address or a "
                         f"dask.distributed.Client, got {scheduler!r}")
    s = scheduler.strip()
    if s.lower() in ("synchronous", "inline", "sync") or (s.lower() == "local" and workers == 1):
        return "synchronous"
    return "local" if s.lower() == "local" else s


def _info(fn) -> TaskInfo:
    info = getattr(fn, "task_info", None)
    if info is None:
        raise TypeError(f"{getattr(fn, '__qualname__', fn)!r} is not a task (decorate it "
                        "with analysis.tasks.task)")
    return info


def _is_future(obj) -> bool:
    return isinstance(obj, cf.Future) or (type(obj).__name__ == "Future" and
                                          type(obj).__module__.startswith("distributed"))


def _given(value):
    """A kept or flow result as a task's (Dask makes it again if its worker is lost)."""
    return value


def _key(future) -> str:
    """A future's content key (its Dask key is ``<name>-<content key>``)."""
    return str(future.key).rsplit("-", 1)[-1]


# Dask resolves futures inside lists, tuples and dicts only: a dataclass holding futures
# travels as a marked dict of its fields
_DATACLASS = "__task_dataclass__"


def _pack(obj, leaf):
    """``obj`` with every future replaced by ``leaf(future)``."""
    if _is_future(obj):
        return leaf(obj)
    if type(obj) in (list, tuple):
        return type(obj)(_pack(v, leaf) for v in obj)
    if type(obj) is dict:
        return {k: _pack(v, leaf) for k, v in obj.items()}
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        fields = {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj) if f.init}
        packed = {k: _pack(v, leaf) for k, v in fields.items()}
        if any(packed[k] is not v for k, v in fields.items()):
            return {_DATACLASS: type(obj), "fields": packed}
    return obj


def _unpack(obj):
    if type(obj) is dict:
        if _DATACLASS in obj and len(obj) == 2:
            return obj[_DATACLASS](**{k: _unpack(v) for k, v in obj["fields"].items()})
        return {k: _unpack(v) for k, v in obj.items()}
    if type(obj) in (list, tuple):
        return type(obj)(_unpack(v) for v in obj)
    return obj


def _error(name: str, e: BaseException, key: str) -> TaskError:
    """``e`` as the :class:`TaskError` of task ``name`` (in its ``except`` block)."""
    return e if isinstance(e, TaskError) else TaskError(
        name, f"{type(e).__name__}: {e}", traceback.format_exc(limit=8), key)


def _one(e: BaseException) -> str:
    text = str(e).strip().splitlines()
    return f"{type(e).__name__}: {text[-1] if text else ''}".rstrip(": ")


def _run(fn, key: str, code: str | None, args, kwargs):
    """Run a task here or on a worker (refused, before and after, when its code changed
    on disk or is not ``code``, the digest in the key); an error becomes a
    :class:`TaskError` naming the task."""
    info = _info(fn)
    tune_allocator()
    was, _LOCAL.task = getattr(_LOCAL, "task", False), True
    t = time.perf_counter()
    try:
        value = _checked(info, key, code, lambda: fn(*_unpack(args), **_unpack(kwargs)))
    except Exception as e:          # noqa: BLE001 - reported with the task's name
        raise _error(info.name, e, key) from None
    finally:
        _LOCAL.task = was
    if code is not None:            # on a worker: its seconds go to the client
        with contextlib.suppress(Exception):
            from dask.distributed import get_worker
            get_worker().log_event(_TOPIC, [key, time.perf_counter() - t])
    return value


def _checked(info: TaskInfo, key: str, code: str | None, call):
    """``call()``, refused before and after it (:func:`_check_code`)."""
    _check_code(info, key, code)
    value = call()
    _check_code(info, key, code)            # (a module it imported, edited meanwhile)
    return value


def _check_code(info: TaskInfo, key: str, code: str | None):
    """Refuse a task when a file of its code changed since this process imported the
    toolkit (its modules and the digest in the key may then differ), or on a worker
    (``code`` given) when its code is not ``code``: naming the first file that differs
    from the client's (the engine leaves the client's files in the scheduler's metadata)."""
    if (edited := code_edited(info.code)) and code is None:    # synchronous, or a flow
        raise TaskError(info.name, f"stale code (pid {os.getpid()}): {edited} changed on disk "
                        "after this process imported the toolkit; restart the command", key=key)
    if code is None or not (edited or code_version(info.code) != code):
        return
    theirs, at = {}, ""
    with contextlib.suppress(Exception):
        from dask.distributed import get_client, get_worker
        at = f"{get_worker().address}, "
        theirs = get_client().get_metadata([_TOPIC, info.code, code], None) or {}
    why = (f"{edited} changed on disk after it imported the toolkit; restart the worker (or "
           "the command, on a local cluster)") if edited else (
        f"{files_differing(theirs, code_files(info.code)) if theirs else 'a file differs'} "
        "in this run's code; run the same version of the toolkit on every worker")
    raise TaskError(info.name, f"stale worker ({at}pid {os.getpid()}): {why}", key=key)


class Engine:
    """Submits tasks and flows to Dask, keeps their results, records the run.

    A context manager that closes the cluster it started.  The cluster starts (workers
    joining in the background) with the engine when nothing is kept, else with the first
    result to compute: a run of kept results starts none.

    Parameters
    ----------
    scheduler, workers : None, str or Client; int, optional
        Where tasks run (:func:`resolve_scheduler`); a local cluster's workers.
    cache : str, Path or False, optional
        The cache folder (default :func:`biped_casadi.cache_dir`); False: keep nothing.
    use_cache : bool
        Read kept results (False: compute every task again, still writing results).
    progress : bool
        A bar of finished tasks on stderr (when it is a terminal).
    log : callable, optional
        Called with the lines of :meth:`say`.
    preload, processes : tuple of str; bool
        A local cluster's: modules its workers import as they start; single-threaded
        processes (else threads of this process).
    """

    def __init__(self, scheduler=None, workers: int | None = None, cache=None,
                 use_cache: bool = True, progress: bool = False, log=None,
                 preload: tuple = (), processes: bool = True):
        self.scheduler = resolve_scheduler(scheduler, workers)
        if self.scheduler == "local":
            check_not_bootstrapping()
        self.workers, self.preload, self.processes = workers, tuple(preload), processes
        self.store, self.use_cache = ResultStore(cache), bool(use_cache)
        self._log, self._progress = log, bool(progress) and sys.stderr.isatty()
        self.closed, self._records, self._published = False, [], set()
        self._futures, self._tasks, self._sent, self._seconds = {}, {}, {}, {}
        self._cond = threading.Condition(threading.RLock())
        self._client = self._cluster = self._start_error = self._bar = self._keeper = None
        self._client_level = None
        self._kept = queue.Queue()
        if self.scheduler != "synchronous" and (not self.use_cache or self.store.empty()):
            with contextlib.suppress(Exception):       # raised again by the first submit
                self.client()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    @property
    def records(self) -> list:
        """The :class:`TaskRecord` of every task that has ended, in that order."""
        self._settle()
        return list(self._records)

    def _settle(self):     # what has arrived and the keeper has not kept yet (on the
        for f in list(self._futures.values()):      # caller's thread: its Ctrl-C passes)
            if not isinstance(f, cf.Future) and f.done():
                self._keep_one(f, Exception)

    def client(self):
        """The Dask client (None when synchronous), connected on first use.

        Returns
        -------
        dask.distributed.Client or None
        """
        if self.scheduler == "synchronous":
            return None
        with self._cond:
            if self._start_error is not None:
                raise self._start_error
            if self._client is None:
                try:
                    self._client, self._cluster = connect(self.scheduler, self.workers,
                                                          self.preload, self.processes)
                except Exception as e:
                    self._start_error = e
                    raise
                self._client.subscribe_topic(_TOPIC, self._on_seconds)
                if self._cluster is None:    # a lost scheduler: one line, not Dask's log
                    log = logging.getLogger("distributed.client")
                    self._client_level, _ = log.level, log.setLevel(logging.CRITICAL)
                self._keeper = threading.Thread(target=self._keep, daemon=True)
                self._keeper.start()
                if self._cluster is not None:
                    threading.Thread(target=self._watch, daemon=True).start()
            return self._client

    def _watch(self):
        """Wait for the local cluster's workers (off the run's path); if none can start,
        fail every task with the reason instead of waiting forever."""
        with contextlib.suppress(Exception):
            self._cluster.sync(self._cluster._correct_state)
        nannies = list(self._cluster.workers.values())
        if nannies and all(getattr(w.status, "name", "") == "failed" for w in nannies):
            e = RuntimeError("its worker processes failed to start (their error above)")
            with self._cond:
                if self.closed:
                    return
                self._start_error = e
                pending = [f for f in self._futures.values()
                           if not isinstance(f, cf.Future) and not f.done()]
            with contextlib.suppress(Exception):
                self._client.cancel(pending, reason=f"the Dask cluster did not start "
                                                    f"({_one(e)})")

    def check_started(self):
        """Raise ``ValueError('scheduler: ...')`` if the cluster did not start or was lost.

        Lost: the client is reconnecting or closed (Dask cancelled every task then).
        """
        e, c = self._start_error, self._client
        if e is not None:
            raise ValueError(e.args[0] if isinstance(e, ValueError) and e.args
                             else f"scheduler: the Dask cluster did not start ({_one(e)})") \
                from e
        if c is not None and self._cluster is None and c.status != "running":
            at = f" at {self.scheduler}" if isinstance(self.scheduler, str) else ""
            raise ValueError(f"scheduler: lost the Dask scheduler{at} during the run: start it "
                             "and its workers again and run the same command (it resumes "
                             "from the results kept so far)")

    def close(self):
        """Keep what has arrived, fail what has not, close the cluster it started."""
        if self.closed:
            return
        self.closed = True
        if self._keeper is not None:
            self._kept.put(None)
            self._keeper.join()
        self._settle()
        lost = {k: f for k, f in list(self._futures.items()) if not f.done()}
        for key, f in lost.items():
            err = TaskError(self._tasks[key].name, "not run: the engine was closed first", key=key)
            self._finish(key, TaskState.FAILED, error=err, fut=f)
        quiet = logging.getLogger("distributed")         # the cluster's shutdown chatter
        level, _ = quiet.level, quiet.setLevel(logging.CRITICAL + 1)   # its own too
        try:
            with contextlib.suppress(Exception):
                if self._client is not None and isinstance(self.scheduler, str):
                    self._client.close()            # its own (closing cancels its tasks)
                elif self._client is not None:      # the caller's: its tasks cancelled
                    self._client.cancel([f for f in lost.values() if not isinstance(f, cf.Future)])
            with contextlib.suppress(Exception):
                if self._cluster is not None:
                    close_cluster(self._cluster)
        finally:
            quiet.setLevel(level)
            if self._client_level is not None:
                logging.getLogger("distributed.client").setLevel(self._client_level)
        if self._bar is not None:
            self._bar.close()

    def say(self, message: str):
        """Report a line of a flow's progress (to ``log``).

        Parameters
        ----------
        message : str
        """
        if self._log is not None:
            with contextlib.suppress(Exception):
                self._log(message)

    @contextlib.contextmanager
    def stage(self, name: str, priority: int = 0):
        """Put what this block submits (and the flows it spawns) into a stage.

        Parameters
        ----------
        name, priority : str, int
            The stage; Dask's priority of its tasks (higher first).
        """
        old, _LOCAL.stage = self.current_stage(), (name, int(priority))
        try:
            yield
        finally:
            _LOCAL.stage = old

    @staticmethod
    def current_stage() -> tuple:
        """The stage of this thread.

        Returns
        -------
        tuple
            (name, priority).
        """
        return getattr(_LOCAL, "stage", ("", 0))

    def submit(self, fn, *args, **kwargs):
        """Run task ``fn(*args, **kwargs)``, or read its kept result.

        Parameters
        ----------
        fn : callable
            A :func:`task`.
        *args, **kwargs
            Its arguments; futures in them (also in lists, tuples, dicts, dataclass
            fields) stand for their results.

        Returns
        -------
        dask.distributed.Future or concurrent.futures.Future
            Keyed ``<name>-<content key>``; ``result()`` raises :class:`TaskError` when
            the task, or one it depends on, failed.
        """
        return self._start(fn, args, kwargs, flow=False)

    def spawn(self, flow, *args, **kwargs):
        """Run a flow, ``flow(self, *args, **kwargs)``, in a thread of its own.

        Here when synchronous; its result is kept like a task's.

        Parameters
        ----------
        flow : callable
            A :func:`task` taking the engine first (it submits tasks and waits for them).
        *args, **kwargs
            Its other arguments, futures passed as they are.

        Returns
        -------
        concurrent.futures.Future
        """
        return self._start(flow, args, kwargs, flow=True)

    def each(self, fn, calls: dict):
        """Fan out a task: (tag, result) of each call as it finishes.

        Synchronous, or kept, a call's result comes as it is submitted.

        Parameters
        ----------
        fn : callable
            A task.
        calls : dict
            Tag -> the call's arguments (a tuple).

        Yields
        ------
        tuple
            (tag, result); a failed call raises its :class:`TaskError`.
        """
        on_dask = {}
        for tag, args in calls.items():
            f = self.submit(fn, *args)
            if isinstance(f, cf.Future):
                yield tag, f.result()
            else:                      # calls with equal arguments share one future
                on_dask.setdefault(f, []).append(tag)
        if on_dask:
            from dask.distributed import as_completed
            for f in as_completed(list(on_dask)):
                for tag in on_dask[f]:
                    yield tag, f.result()

    def state(self, future):
        """How a future's task ended (None while it runs).

        Parameters
        ----------
        future : future

        Returns
        -------
        TaskState or None
        """
        self._settle()
        rec = self._tasks.get(_key(future))
        return rec.state if rec is not None else None

    def critical_path(self) -> dict:
        """The longest chain of computed tasks: the wall time's bound on any workers.

        Flows weigh nothing (their work is in their tasks).

        Returns
        -------
        dict
            ``seconds`` and ``tasks`` (the chain's names, first to last).
        """
        tasks, memo = {r.key: r for r in self.records}, {}

        def longest(key):
            if key not in memo:
                memo[key], r = (0.0, []), tasks[key]         # (a cycle cannot happen)
                w = r.seconds if (r.state is TaskState.COMPUTED and not r.flow) else 0.0
                best = max((longest(d) for d in r.deps if d in tasks), key=lambda x: x[0],
                           default=(0.0, []))
                memo[key] = (w + best[0], best[1] + ([r.name.rsplit(".", 1)[-1]] if w else []))
            return memo[key]
        top = max((longest(k) for k in tasks), key=lambda x: x[0], default=(0.0, []))
        return dict(seconds=round(top[0], 2), tasks=top[1])

    # ------------------------------------------------------------- internals
    def _start(self, fn, args, kwargs, flow: bool):
        info = _info(fn)
        if self.closed:
            raise TaskError(info.name, "not run: the engine was closed")
        seen, inputs, ctx = [], [], getattr(_LOCAL, "flow", None)
        key = task_key(info.name, info.version, info.code, args, kwargs,
                       ref_key=lambda o: seen.append(o) or _key(o) if _is_future(o) else None)
        _pack((args, kwargs), lambda f: inputs.append(f) or f)
        if len(inputs) != len(seen):            # (a namedtuple, an object array, ...)
            raise TypeError(f"{info.name}: a future inside an argument the engine cannot "
                            "unpack; pass futures as arguments or inside lists, tuples, dicts "
                            "or dataclasses")
        kept = self.store.read(key) if self.use_cache and key not in self._tasks else MISSING
        with self._cond:
            new = key not in self._tasks             # else submitted before, or right now
            if new:
                deps = inputs + [f for f in (ctx or ()) if f.done()]
                self._tasks[key] = TaskRecord(info.name, self.current_stage()[0], key, flow=flow,
                                              deps=tuple(dict.fromkeys(map(_key, deps))))
                if kept is MISSING:
                    self._count_new()
            while not new and key not in self._futures:
                self._cond.wait()
        if not new:
            fut = self._futures[key]
        else:                          # its outcome here (sent to Dask: if not sent)
            fut = cf.Future()
            fut.key = f"{info.name.rsplit('.', 1)[-1]}-{key}"
            if kept is not MISSING:
                self._set(key, self._finish(key, TaskState.REUSED, kept["value"],
                                            seconds=kept.get("seconds", 0.0), fut=fut))
            elif not (flow or self.scheduler == "synchronous"):
                fut = self._on_cluster(fn, key, fut, args, kwargs)
            elif flow:
                self._flow(fn, key, self._set(key, fut), args, kwargs, inputs)
            else:
                self._complete(key, self._set(key, fut), lambda: _run(fn, key, None, *(
                    _pack(x, lambda f: f.result()) for x in (args, kwargs))))
        if ctx is not None:
            ctx.append(fut)
        return fut

    def _set(self, key, future):
        with self._cond:
            self._futures[key] = future
            self._cond.notify_all()
        return future

    def _complete(self, key, fut, call, catch=Exception):
        """Run ``call`` here: its value or its error (also one keeping the value: it
        cannot be pickled) is the task's outcome."""
        t = time.perf_counter()
        try:
            self._finish(key, TaskState.COMPUTED, call(), seconds=time.perf_counter() - t,
                         fut=fut)
        except catch as e:                              # noqa: BLE001 - the task's error
            self._finish(key, TaskState.FAILED, error=_error(self._tasks[key].name, e, key),
                         fut=fut)

    def _on_cluster(self, fn, key, holder, args, kwargs):
        """Submit a task to Dask (``holder``: its future if it cannot be sent)."""
        info = _info(fn)
        try:
            client = self.client()
            a, k = (_pack(x, lambda f: self._on_dask(client, f)) for x in (args, kwargs))
            code = code_version(info.code)
            if info.code not in self._published:       # for a stale worker's message
                self._published.add(info.code)
                client.set_metadata([_TOPIC, info.code, code], code_files(info.code))
            with self._cond:                 # not while the cluster is found dead
                if self._start_error is not None:
                    raise self._start_error
                fut = self._set(key, client.submit(_run, fn, key, code, a, k, key=holder.key,
                                                   pure=False, priority=self.current_stage()[1]))
        except Exception as e:                         # noqa: BLE001 - this task fails
            err = e if isinstance(e, TaskError) else TaskError(info.name, (
                f"not run: the Dask cluster did not start ({_one(e)})"
                if self._start_error is not None else f"not sent to the cluster ({_one(e)})"),
                key=key)
            return self._set(key, self._finish(key, TaskState.FAILED, error=err, fut=holder))
        fut.add_done_callback(self._kept.put)
        return fut

    def _on_dask(self, client, f):
        """A future as a Dask future: itself, or its value (waited for: a flow's) as a
        task under its key: scattered, it would be lost with the worker that holds it."""
        if not isinstance(f, cf.Future):
            return f
        value = f.result()                     # a failed input fails the task
        if _key(f) not in self._sent:
            self._sent[_key(f)] = client.submit(_given, value, key=f.key, pure=False,
                                                     priority=self.current_stage()[1])
        return self._sent[_key(f)]

    def _flow(self, flow, key, fut, args, kwargs, inputs):
        """Run a flow: in a thread of its own, or here when synchronous."""
        stage, sync = self.current_stage(), self.scheduler == "synchronous"

        def run():
            saved = self.current_stage(), getattr(_LOCAL, "flow", None)
            _LOCAL.stage, _LOCAL.flow = stage, list(inputs)
            try:
                self._complete(key, fut, lambda: _checked(_info(flow), key, None, lambda: flow(
                    self, *args, **kwargs)), Exception if sync else BaseException)
            finally:
                _LOCAL.stage, _LOCAL.flow = saved

        if sync:
            return run()
        with contextlib.suppress(Exception):
            self.client()                      # its workers join while the flow works
        threading.Thread(target=run, name=f"flow {_info(flow).name}", daemon=True).start()

    def _on_seconds(self, event):
        with contextlib.suppress(Exception):
            self._seconds[event[1][0]] = float(event[1][1])

    def _keep(self):
        """The keeper thread: each task's result kept as it arrives."""
        while (f := self._kept.get()) is not None:
            self._keep_one(f, BaseException)

    def _keep_one(self, f, catch):
        key = _key(f)
        if self._tasks[key].state is not None:
            return
        try:                                   # (a result may fail to be kept too)
            self._finish(key, TaskState.COMPUTED, f.result(), seconds=self._seconds.pop(key, 0.0))
        except catch as e:                     # noqa: BLE001 - failed, cancelled, lost
            self._finish(key, TaskState.FAILED, error=e if isinstance(e, TaskError) else
                         TaskError(self._tasks[key].name, _one(e), key=key))

    def _finish(self, key: str, state: TaskState, value=None, error=None, seconds=0.0,
                fut=None):
        """Record how a task ended and give ``fut``, when it is one of the engine's own
        futures (not Dask's), that outcome; the first outcome stands."""
        rec = self._tasks[key]
        if state is TaskState.COMPUTED and rec.state is None:
            self.store.write(key, rec.name, value, seconds)
        with self._cond:
            if rec.state is None:
                rec.state, rec.seconds, rec.error = state, float(seconds), str(error or "")
                self._records.append(rec)
                if self._bar is not None and state is not TaskState.REUSED:
                    self._bar.update(1)
        if isinstance(fut, cf.Future):
            with contextlib.suppress(cf.InvalidStateError):
                fut.set_result(value) if error is None else fut.set_exception(error)
        return fut

    def _count_new(self):
        if not self._progress:
            return
        with self._cond:
            if self._bar is None:                    # tqdm's import: 0.1 s
                self._bar = progress_bar(True, 0, 0, "task", "tasks")
            self._bar.total += 1
            self._bar.refresh()
