"""Long work as a graph of pure, cached tasks run by Dask.

A *task* is a pure, deterministic function of typed arguments (numbers, arrays,
dataclasses, models, gaits) marked with :func:`task`.  ``engine.submit(fn, *args)``
returns a :class:`Ref` to its result at once; passing a ``Ref`` as an argument of
another task makes the edge of the graph.  Every result is kept on disk under the key
of its task, version, code version and arguments (:mod:`analysis.tasks.keys`), so a
re-run reads what it computed before and a run that was killed resumes where it
stopped, with the same numbers: nothing depends on which process computed a result or
when.

Where it runs is one choice, the ``scheduler`` (:func:`resolve_scheduler`):
'synchronous' (this process, one task after the other, in the order submitted), a Dask
``LocalCluster`` of one single-threaded worker process per core (the default), a
scheduler's address ('tcp://host:8786') or a ``dask.distributed.Client``.

Decisions that need a result (an exchange round that depends on the last solve) are
*flows*: plain functions ``flow(engine, ...)`` started with :meth:`Engine.spawn`, which
run in a thread of this process, submit tasks and wait for them; their own result is
kept like a task's.
"""
from __future__ import annotations

import contextlib
import functools
import heapq
import itertools
import logging
import os
import sys
import threading
import time
import traceback
from concurrent.futures import ThreadPoolExecutor

from biped_casadi.caching import TaskInfo, task

from ..cluster import check_not_bootstrapping, connect as _connect
from .keys import task_key
from .placement import Placement
from .refs import (_LOCAL, Ref, TaskError, TaskRecord, _execute, _info, _pack, _refs_in,
                   _RESULT, in_task)
from .store import MISSING, ResultStore

__all__ = ["task", "TaskInfo", "Engine", "Ref", "TaskError", "resolve_scheduler",
           "SCHEDULER_ENV", "in_task", "TaskRecord"]

#: the environment variable that sets the default scheduler ('synchronous', an address)
SCHEDULER_ENV = "BIPED_SCHEDULER"

#: tasks sent to the cluster beyond its threads, so that a worker finishing a task
#: starts the next one at once instead of waiting for the round trip through this process
AHEAD = 1


# ---------------------------------------------------------------------- engine
def resolve_scheduler(scheduler=None, workers: int | None = None):
    """What ``scheduler`` means, the same for every function that takes it.

    Parameters
    ----------
    scheduler : None, str or dask.distributed.Client
        None: ``$BIPED_SCHEDULER`` if set; inside a task 'synchronous'; otherwise
        'local'.  'synchronous' (or 'inline'): this process, one task after another.
        'local': a Dask ``LocalCluster`` of ``workers`` single-threaded processes.  Any
        other string: a Dask scheduler's address.  A ``Client``: used as it is.
    workers : int, optional
        Processes of the ``LocalCluster`` (default: this machine's cores); 1 means
        'synchronous' unless a scheduler is named.

    Returns
    -------
    str or Client
        'synchronous', 'local', an address or the client.

    Raises
    ------
    ValueError
        Naming 'workers' (not a positive integer) or 'scheduler' (not a string or
        client).
    """
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)
                                or workers < 1):
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    if scheduler is None:
        if in_task():
            return "synchronous"
        scheduler = os.environ.get(SCHEDULER_ENV) or None
    if scheduler is None:
        return "synchronous" if workers == 1 else "local"
    if isinstance(scheduler, str):
        s = scheduler.strip()
        if not s:
            raise ValueError("scheduler must not be empty")
        if s.lower() in ("synchronous", "inline", "sync"):
            return "synchronous"
        if s.lower() == "local":
            return "synchronous" if workers == 1 else "local"
        return s
    if type(scheduler).__name__ == "Client":
        return scheduler
    raise ValueError(f"scheduler must be None, 'synchronous', 'local', an address or a "
                     f"dask.distributed.Client, got {type(scheduler).__name__}")


class Engine:
    """Runs tasks and flows, keeps their results, counts what was computed or reused.

    Use it as a context manager (``with Engine(...) as eng:``); the cluster it started,
    if any, is closed at the end.  The cluster starts only when something must be
    computed: a run whose results are all kept starts none.  It starts in the background
    as soon as a flow is spawned whose result is not kept (at once when the cache holds
    nothing), so that its processes start (and import ``preload``) while the flows
    compute their tasks' keys.

    Parameters
    ----------
    scheduler : None, str or dask.distributed.Client
        Where tasks run (:func:`resolve_scheduler`).
    workers : int, optional
        Processes of a local cluster.
    cache : str, Path or False, optional
        The cache folder (default :func:`biped_casadi.cache_dir`); False: keep nothing.
    use_cache : bool
        Read kept results (False: compute every task again; results are still written).
    progress : bool
        One bar of finished tasks on stderr (when it is a terminal).
    on_record : callable, optional
        Called with each :class:`TaskRecord` as a task finishes.
    log : callable, optional
        Called with the lines flows report (:meth:`say`).
    preload : tuple of str
        Modules the processes of a local cluster import as they start (those of the
        tasks to come).
    """

    def __init__(self, scheduler=None, workers: int | None = None, cache=None,
                 use_cache: bool = True, progress: bool = False, on_record=None, log=None,
                 preload: tuple = ()):
        self.scheduler = resolve_scheduler(scheduler, workers)
        if self.scheduler == "local":
            check_not_bootstrapping()
        self.workers = workers
        self.store = ResultStore(cache)
        self.use_cache = bool(use_cache)
        self.records: list[TaskRecord] = []
        self.on_record = on_record
        self._log = log
        self.closed = False
        self._refs: dict[str, Ref] = {}
        self._lock = threading.RLock()
        self._client = None
        self._cluster = None
        self.preload = tuple(preload)
        self._starting = None          # the thread connecting in the background
        self._start_error = None
        self._pool = None
        self._bar = None
        self._progress = bool(progress)
        self._known = 0
        # tasks whose inputs are known, waiting for a free worker thread, highest
        # priority first (then in submission order); each worker is given its threads'
        # tasks and AHEAD more, chosen by Placement (kinds it has run first)
        self._queue: list = []
        self._order = itertools.count()
        self._place = Placement(AHEAD)
        if not self.use_cache or self.store.empty():     # every task will run
            self._start_early()

    @property
    def synchronous(self) -> bool:
        """Whether tasks run in this process, one after another."""
        return self.scheduler == "synchronous"

    # ---------------------------------------------------------------- lifetime
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        """Stop: pending flows are told, the cluster this engine started is closed."""
        self.closed = True
        with self._lock:
            queued, self._queue = self._queue, []
        for *_, job in queued:                  # never sent: their waiters are told
            self._done(job[0], "failed", error=_not_run(job[0]))
        if self._starting is not None:          # a cluster starting is closed once up
            self._starting.join()
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
        # the cluster's processes report its shutdown (lost heartbeats, closed streams):
        # nothing for the user
        quiet = logging.getLogger("distributed")
        level = quiet.level
        quiet.setLevel(logging.CRITICAL)
        try:
            if self._client is not None and (self._cluster is not None
                                             or isinstance(self.scheduler, str)):
                with contextlib.suppress(Exception):
                    self._client.close()
            if self._cluster is not None:
                with contextlib.suppress(Exception):
                    self._cluster.close()
        finally:
            quiet.setLevel(level)
        with self._lock:                        # sent, and lost with the cluster
            lost = [r for r in self._refs.values() if r._future is not None and not r.done()]
        for r in lost:
            self._done(r, "failed", error=_not_run(r))
        if self._bar is not None:
            self._bar.close()

    def client(self):
        """The Dask client, started on first use.

        Returns
        -------
        dask.distributed.Client or None
            None when synchronous.
        """
        if self.synchronous:
            return None
        starting = self._starting
        if starting is not None:
            starting.join()
        with self._lock:
            if self._start_error is not None:
                raise self._start_error
            if self._client is None:
                self._client, self._cluster = _connect(self.scheduler, self.workers,
                                                       self.preload)
            return self._client

    def _start_early(self):
        """Start connecting in a background thread (once), unless synchronous or
        connected; :meth:`client` waits for it."""
        with self._lock:
            if self.synchronous or self.closed or self._client is not None \
                    or self._starting is not None:
                return

            def connect():
                try:
                    client, cluster = _connect(self.scheduler, self.workers, self.preload)
                except Exception as e:          # noqa: BLE001 - raised by client()
                    self._start_error = e
                    return
                with self._lock:
                    self._client, self._cluster = client, cluster
            self._starting = threading.Thread(target=connect, name="biped-connect",
                                              daemon=True)
            self._starting.start()

    def check_started(self):
        """Raise the reason the cluster could not start, if it could not.

        Raises
        ------
        ValueError
            ``scheduler: the Dask cluster did not start (...)``.
        """
        e = self._start_error
        if e is not None:
            raise ValueError(e.args[0] if isinstance(e, ValueError) and e.args
                             else f"scheduler: the Dask cluster did not start ({_one(e)})") \
                from e

    def say(self, message: str):
        """Report one line of a flow's progress (to the ``log`` callable, if any).

        Parameters
        ----------
        message : str
            The line.
        """
        if self._log is not None:
            with contextlib.suppress(Exception):
                self._log(message)

    # ---------------------------------------------------------------- stages
    @contextlib.contextmanager
    def stage(self, name: str, priority: int = 0):
        """Put what this block submits into a stage, with a Dask priority.

        Tasks submitted in the block (by this thread and the flows it spawns) belong to
        stage ``name`` and run with priority ``priority`` (higher first).

        Parameters
        ----------
        name : str
            The stage.
        priority : int
            Dask's priority of its tasks.
        """
        old = getattr(_LOCAL, "stage", ("", 0))
        _LOCAL.stage = (name, int(priority))
        try:
            yield
        finally:
            _LOCAL.stage = old

    @staticmethod
    def current_stage():
        """The stage of this thread.

        Returns
        -------
        tuple
            (stage name, priority).
        """
        return getattr(_LOCAL, "stage", ("", 0))

    # ---------------------------------------------------------------- submit
    def key(self, fn, *args, **kwargs) -> str:
        """The key a call of a task has (nothing is run).

        Parameters
        ----------
        fn : callable
            A task.
        *args, **kwargs
            Its arguments.

        Returns
        -------
        str
        """
        info = _info(fn)
        return task_key(info.name, info.version, info.code, args, kwargs,
                        ref_key=lambda o: o.key if isinstance(o, Ref) else None)

    def submit(self, fn, *args, **kwargs) -> Ref:
        """Run task ``fn(*args, **kwargs)`` (or read its kept result).

        Parameters
        ----------
        fn : callable
            A :func:`task`.
        *args, **kwargs
            Its arguments; :class:`Ref` s anywhere in them (lists, tuples, dicts,
            dataclass fields) are replaced by their results.

        Returns
        -------
        Ref
        """
        info = _info(fn)
        key = self.key(fn, *args, **kwargs)
        stage, priority = self.current_stage()
        with self._lock:
            if key in self._refs:
                return self._refs[key]
            ref = Ref(self, key, info.name, stage)
            ref.deps = self._deps((args, kwargs))
            self._refs[key] = ref
        if self._reuse(ref):
            return ref
        self._count_new()
        failed = next((r for r in _refs_in((args, kwargs)) if r.done() and r.state == "failed"),
                      None)
        if failed is not None:
            self._done(ref, "failed", error=failed._error)
            return ref
        if self.synchronous:
            self._run_here(ref, fn, args, kwargs)
            return ref
        # inputs still being computed: queued once they are known, without waiting here
        waiting = [r for r in _refs_in((args, kwargs)) if not r.done()]
        if not waiting:
            self._enqueue(ref, fn, args, kwargs, priority)
            return ref
        left = [len(waiting)]
        lock = threading.Lock()

        def ready(_):
            with lock:
                left[0] -= 1
                go = left[0] == 0
            if go:
                self._enqueue(ref, fn, args, kwargs, priority)
        for r in waiting:
            r._when_done(ready)
        return ref

    def map(self, fn, items, *args, **kwargs) -> list:
        """Submit a task once per item: ``[submit(fn, item, *args, **kwargs) ...]``.

        Parameters
        ----------
        fn : callable
            A task.
        items : iterable
            Its first arguments.
        *args, **kwargs
            Its other arguments.

        Returns
        -------
        list of Ref
        """
        return [self.submit(fn, item, *args, **kwargs) for item in items]

    def spawn(self, flow, *args, **kwargs) -> Ref:
        """Run a flow, ``flow(self, *args, **kwargs)``, in a thread of this process.

        At once when synchronous; ``flow`` is a :func:`task` whose result is kept like a
        task's.

        Parameters
        ----------
        flow : callable
            A task taking the engine first: it submits tasks and waits for them.
        *args, **kwargs
            Its other arguments (``Ref`` s are passed as they are: the flow waits for
            them with ``.result()``).

        Returns
        -------
        Ref
        """
        info = _info(flow)
        key = self.key(flow, *args, **kwargs)
        stage, priority = self.current_stage()
        with self._lock:
            if key in self._refs:
                return self._refs[key]
            ref = Ref(self, key, info.name, stage)
            ref.deps, ref.flow = self._deps((args, kwargs)), True
            self._refs[key] = ref
        if self._reuse(ref):
            return ref
        self._start_early()

        def run():
            _LOCAL.stage = (stage, priority)
            _LOCAL.awaited, _LOCAL.flow_deps = [], ref.deps
            t = time.perf_counter()
            try:
                value = flow(self, *args, **kwargs)
            except TaskError as e:
                self._done(ref, "failed", error=e)
                return
            except Exception as e:          # noqa: BLE001 - reported with the flow's name
                self._done(ref, "failed", error=TaskError(
                    info.name, f"{type(e).__name__}: {e}", traceback.format_exc(limit=8),
                    ref.key))
                return
            self._done(ref, "computed", value=value, seconds=time.perf_counter() - t,
                       keep=True)

        def run_flow():
            try:
                run()
            finally:
                _LOCAL.awaited, _LOCAL.flow_deps = None, ()

        if self.synchronous:
            saved = getattr(_LOCAL, "awaited", None), getattr(_LOCAL, "flow_deps", ())
            try:
                run()
            finally:
                _LOCAL.awaited, _LOCAL.flow_deps = saved
        else:
            with self._lock:
                if self._pool is None:
                    self._pool = ThreadPoolExecutor(32, thread_name_prefix="biped-flow")
            self._pool.submit(run_flow)
        return ref

    @staticmethod
    def _deps(args) -> tuple:
        """The refs a new task or flow comes after: those in its arguments, and, inside a
        flow, everything the flow has waited for so far (and the flow's own)."""
        deps = list(_refs_in(args)) + list(getattr(_LOCAL, "awaited", None) or ()) \
            + list(getattr(_LOCAL, "flow_deps", ()) or ())
        return tuple({id(r): r for r in deps}.values())

    def critical_path(self) -> dict:
        """The longest chain of computed tasks of this run: the wall time's bound.

        Flows weigh nothing (their work is in their tasks); on any number of workers the
        run takes at least this long.

        Returns
        -------
        dict
            ``seconds`` and ``tasks`` (the chain's names, first to last).
        """
        memo: dict = {}

        def longest(r):
            if id(r) in memo:
                return memo[id(r)]
            memo[id(r)] = (0.0, [])                      # (a cycle cannot happen)
            w = r.seconds if (r.state == "computed" and not r.flow) else 0.0
            best = max((longest(d) for d in r.deps), key=lambda x: x[0], default=(0.0, []))
            memo[id(r)] = (w + best[0], best[1] + ([r.name.rsplit(".", 1)[-1]] if w else []))
            return memo[id(r)]
        with self._lock:
            refs = list(self._refs.values())
        top = max((longest(r) for r in refs), key=lambda x: x[0], default=(0.0, []))
        return dict(seconds=round(top[0], 2), tasks=top[1])

    def origin_stage(self, error: TaskError) -> str:
        """The stage of the task where a failure began.

        Parameters
        ----------
        error : TaskError
            The failure (its own task's, or of one it depends on).

        Returns
        -------
        str
        """
        r = self._refs.get(getattr(error, "key", ""))
        return r.stage if r is not None else ""

    # ---------------------------------------------------------------- internals
    def _reuse(self, ref: Ref) -> bool:
        if not self.use_cache:
            return False
        rec = self.store.read(ref.key)
        if rec is MISSING:
            return False
        self._done(ref, "reused", value=rec["value"], seconds=rec.get("seconds", 0.0))
        return True

    def _count_new(self):
        with self._lock:
            self._known += 1
            if self._progress and self._bar is None and sys.stderr.isatty():
                from tqdm.auto import tqdm
                self._bar = tqdm(total=0, unit="task", desc="tasks", file=sys.stderr,
                                 dynamic_ncols=True)
            if self._bar is not None:
                self._bar.total = self._known
                self._bar.refresh()

    def _done(self, ref: Ref, state: str, value=None, error=None, seconds=0.0,
              keep: bool = False):
        if keep and state == "computed":
            self.store.write(ref.key, ref.name, value, seconds)
        ref._finish(state, value, error, seconds)
        rec = TaskRecord(ref.name, ref.stage, ref.key, state, float(seconds),
                         "" if error is None else str(error), ref.flow)
        with self._lock:
            self.records.append(rec)
            if self._bar is not None and state != "reused":
                self._bar.update(1)
        if self.on_record is not None:
            with contextlib.suppress(Exception):
                self.on_record(rec)

    def _run_here(self, ref, fn, args, kwargs):
        try:
            a = _pack(args, lambda r: r.result())
            k = _pack(kwargs, lambda r: r.result())
            value, seconds = _execute(fn, ref.key, a, k)
        except TaskError as e:
            self._done(ref, "failed", error=e)
            return
        self._done(ref, "computed", value=value, seconds=seconds, keep=True)

    def _leaf(self, client, r: Ref):
        """What a Ref becomes in a Dask call: its future, or its value scattered once."""
        if r._future is not None and r.state != "failed":
            return {_RESULT: r._future}
        if r.state == "pending":              # a flow's result: wait for it here
            r.result()
        if r.state == "failed":
            raise r._error
        with self._lock:
            if r._scattered is None:
                r._scattered = client.scatter((r._value, 0.0), hash=False)
            return {_RESULT: r._scattered}

    def _enqueue(self, ref, fn, args, kwargs, priority):
        if self.closed:
            self._done(ref, "failed", error=_not_run(ref))
            return
        with self._lock:
            heapq.heappush(self._queue, (-int(priority), next(self._order),
                                         (ref, fn, args, kwargs, priority)))
        self._pump()

    def _workers(self, client):
        if not self._place.threads or self._cluster is None:  # an outside cluster can grow
            try:
                self._place.update(client.nthreads() or {None: 1})
            except Exception:                                   # noqa: BLE001
                if not self._place.threads:
                    self._place.update({None: 1})

    def _pump(self):
        """Send queued tasks to the cluster while it has free threads (or, when the
        cluster could not start, fail them with the reason: nothing waits forever)."""
        try:
            client = self.client()
        except Exception as e:                 # noqa: BLE001 - kept in start_error
            with self._lock:
                if self._start_error is None:
                    self._start_error = e
                jobs = [j[2] for j in self._queue]
                self._queue.clear()
            for ref, *_ in jobs:
                self._done(ref, "failed", error=TaskError(
                    ref.name, f"not run: the Dask cluster did not start ({_one(e)})",
                    key=ref.key))
            return
        while True:
            with self._lock:
                if not self._queue:
                    return
                self._workers(client)
                worker = self._place.free_worker()
                if worker is None:
                    return
                job = self._place.take(self._queue, worker)
                self._place.sent(worker, job[0].name)
            try:
                self._run_on_cluster(*job, worker=worker)
            except Exception as e:            # noqa: BLE001 - the task fails, the run goes on
                self._release(worker)
                self._done(job[0], "failed", error=TaskError(
                    job[0].name, f"not sent to the cluster ({_one(e)})", key=job[0].key))

    def _release(self, worker):
        with self._lock:
            self._place.finished(worker)
        if not self.closed:
            self._pump()

    def _run_on_cluster(self, ref, fn, args, kwargs, priority, worker=None):
        client = self.client()
        try:
            a = _pack(args, lambda r: self._leaf(client, r))
            k = _pack(kwargs, lambda r: self._leaf(client, r))
        except TaskError as e:
            with self._lock:                  # the slot goes back to the pump's loop
                self._place.finished(worker)
            self._done(ref, "failed", error=e)
            return
        short = ref.name.rsplit(".", 1)[-1]
        where = {} if worker is None else dict(workers=[worker], allow_other_workers=True)
        fut = client.submit(_execute, fn, ref.key, a, k, key=f"{short}-{ref.key}", pure=False,
                            priority=priority, **where)
        ref._future = fut
        fut.add_done_callback(functools.partial(self._collect, ref, worker))

    def _collect(self, ref: Ref, worker, fut):
        try:
            value, seconds = fut.result()
        except TaskError as e:
            self._release(worker)
            self._done(ref, "failed", error=e)
            return
        except BaseException as e:             # noqa: BLE001 - cancelled, lost worker
            self._release(worker)
            self._done(ref, "failed", error=TaskError(ref.name, f"{type(e).__name__}: {e}",
                                                      key=ref.key))
            return
        self._release(worker)
        self._done(ref, "computed", value=value, seconds=seconds, keep=True)


def _one(e: BaseException) -> str:
    """An exception as one line."""
    text = str(e).strip().splitlines()
    return f"{type(e).__name__}: {text[-1] if text else ''}".rstrip(": ")


def _not_run(ref: Ref) -> TaskError:
    return TaskError(ref.name, "not run: the engine was closed first", key=ref.key)
