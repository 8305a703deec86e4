"""Which worker of the cluster runs a task.

A worker process builds what a kind of task needs (CasADi Functions, walkers, maps,
compiled kernels) the first time it runs one, and keeps it; the second worker that runs
that kind builds it again.  :class:`Placement` sends a task to a worker with a free
thread (plus ``ahead`` more, so that it starts its next task without waiting for the
round trip through the scheduling process) and, among the first few tasks of the queue,
prefers one of a kind that worker has already run, then a kind no worker has run, then
the first.  A task that only another worker has run waits for it while other work is
there; the work is never held back when nothing else is queued.
"""
from __future__ import annotations

import heapq

__all__ = ["Placement"]


class Placement:
    """The load and the kinds of task of every worker.

    Parameters
    ----------
    ahead : int
        Tasks sent to a worker beyond its threads.
    window : int
        How many of the first queued tasks a free worker chooses from.
    """

    def __init__(self, ahead: int = 1, window: int = 6):
        self.ahead, self.window = int(ahead), int(window)
        self.threads: dict = {}
        self.load: dict = {}
        self.seen: dict = {}

    def update(self, nthreads: dict):
        """The cluster's workers now (address -> threads); new ones start idle."""
        self.threads = {a: max(1, int(n)) for a, n in nthreads.items()}
        self.seen = {a: k for a, k in self.seen.items() if a in self.threads}
        for a in self.threads:
            self.load.setdefault(a, 0)
            self.seen.setdefault(a, set())

    def free_worker(self):
        """The least loaded worker with room for one more task, or None."""
        room = [(self.load[a], a) for a in self.threads
                if self.load[a] < self.threads[a] + self.ahead]
        return min(room)[1] if room else None

    def take(self, queue: list, worker: str):
        """Pop the queued job that ``worker`` runs next (``queue``: a heap of
        (-priority, order, job), ``job[0]`` the task's Ref).

        Returns
        -------
        job
        """
        top = [heapq.heappop(queue) for _ in range(min(self.window, len(queue)))]
        mine = self.seen.get(worker, set())
        others = set().union(*(s for a, s in self.seen.items() if a != worker))
        kinds = [e[2][0].name for e in top]
        pick = next((i for i, k in enumerate(kinds) if k in mine), None)
        if pick is None:
            pick = next((i for i, k in enumerate(kinds) if k not in others), 0)
        for i, e in enumerate(top):
            if i != pick:
                heapq.heappush(queue, e)
        return top[pick][2]

    def sent(self, worker: str, kind: str):
        """A task of ``kind`` went to ``worker``."""
        self.load[worker] = self.load.get(worker, 0) + 1
        self.seen.setdefault(worker, set()).add(kind)

    def finished(self, worker: str):
        """A task of ``worker`` finished (or failed)."""
        if worker in self.load:
            self.load[worker] = max(0, self.load[worker] - 1)
