"""Small tasks for the engine's tests (importable by Dask workers)."""
from __future__ import annotations

import os
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
def echo(x):
    return x
