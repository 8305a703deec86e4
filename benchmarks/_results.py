"""Saved benchmark results: every script writes ``benchmarks/results/<name>.json`` with the
machine, its load before and after, the date, the commit and its figures; the docs'
benchmarks page is generated from these files (docs/_ext/benchmarks_page.py)."""
from __future__ import annotations

import json
import os
import platform
import subprocess
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
#: the checkout: figures under it are saved by their path in it (not this machine's)
ROOT = RESULTS.parents[1]


def machine() -> dict:
    """The processor, cores, Python and library versions."""
    cpu = "?"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import casadi
    import numpy
    return dict(cpu=cpu, cores=os.cpu_count(),
                affinity=len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                else os.cpu_count(), python=platform.python_version(),
                casadi=casadi.__version__, numpy=numpy.__version__)


def commit() -> str:
    """The checkout's commit (with '+changes' when the tree is not clean)."""
    root = Path(__file__).resolve().parents[1]
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root,
                              capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=root, capture_output=True, text=True).stdout.strip()
        return head + ("+changes" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "?"


def in_checkout(path) -> str:
    """``path`` relative to the checkout when it is in it, else as given."""
    p = Path(path)
    return p.relative_to(ROOT).as_posix() if p.is_absolute() and p.is_relative_to(ROOT) \
        else str(path)


class Run:
    """One benchmark run: ``with Run('name', title) as r: ...; r.row(...)``; saved on
    exit (unless ``save`` is False).

    Parameters
    ----------
    name : str
        The file name (``results/<name>.json``).
    title : str
        What the benchmark measures, one line.
    save : bool
        Write the file.
    """

    def __init__(self, name: str, title: str, save: bool = True):
        self.name, self.title, self.save = name, title, save
        self.rows, self.notes, self.data = [], [], {}

    def __enter__(self):
        self.load_before = os.getloadavg()
        self.started = time.strftime("%Y-%m-%d %H:%M")
        return self

    def row(self, what: str, ours, baseline=None, unit: str = "s", ratio=None,
            target: str = ""):
        """One line of the benchmarks page: what, our figure, the baseline's (run side by
        side), their ratio (baseline / ours when not given: above 1 is faster) and the
        target it answers."""
        if ratio is None and baseline is not None and ours:
            ratio = baseline / ours
        self.rows.append(dict(what=what, ours=ours, baseline=baseline, unit=unit,
                              ratio=ratio, target=target))

    def note(self, text: str):
        self.notes.append(text)

    def __exit__(self, exc_type, *exc):
        if exc_type is None and self.save:
            self.write()

    def write(self):
        """Write the file now (a long run saves what it has measured so far; the file is
        replaced in one step, so an interrupted write leaves the previous one)."""
        RESULTS.mkdir(exist_ok=True)
        if isinstance(self.data.get("figure"), list):
            self.data["figure"] = [in_checkout(f) for f in self.data["figure"]]
        body = dict(name=self.name, title=self.title, date=self.started,
                    commit=commit(), machine=machine(),
                    load=dict(before=list(self.load_before), after=list(os.getloadavg())),
                    rows=self.rows, notes=self.notes, data=self.data)
        path = RESULTS / f"{self.name}.json"
        part = path.with_suffix(".json.part")
        part.write_text(json.dumps(body, indent=1) + "\n")
        part.replace(path)
        print(f"saved {path.relative_to(Path.cwd()) if path.is_relative_to(Path.cwd()) else path}")
