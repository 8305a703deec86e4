"""The task engine: keys that ignore docstrings but not code, results kept and reused,
failures that mark their dependants, Dask's priorities, the same numbers in one process
and on a Dask cluster of worker processes, and a worker running other code refused."""
from __future__ import annotations

import ast
import collections

import numpy as np
import pytest

from analysis.tasks import Engine, NotKeyable, TaskError, argument_key, resolve_scheduler
from biped_casadi.caching import _strip_docstrings
from task_examples import (Pair, add, chain, default_of, echo, fails, pair_sum, pid, square,
                           started_at, total, unkept, unkept_flow)


def _tree(src):
    return ast.dump(_strip_docstrings(ast.parse(src)), include_attributes=False)


def test_code_version_ignores_docstrings_and_comments_not_code():
    a = 'def f(x):\n    """Square."""\n    return x * 2  # twice\n'
    b = 'def f(x):\n    """Twice x, the new words."""\n    # a comment\n    return x * 2\n'
    c = 'def f(x):\n    """Square."""\n    return x * 3\n'
    assert _tree(a) == _tree(b)
    assert _tree(a) != _tree(c)


def test_argument_keys_follow_content():
    assert argument_key(np.arange(3.0)) == argument_key(np.arange(3.0))
    assert argument_key(np.arange(3.0)) != argument_key(np.arange(3.0) + 1e-15)
    assert argument_key(Pair(1.0)) != argument_key(Pair(1.0, 2.0))
    assert argument_key([1.0, {"b": 2, "a": 1}]) == argument_key([1.0, {"a": 1, "b": 2}])
    with pytest.raises(NotKeyable):
        argument_key(lambda: 0)


def test_scheduler_spellings():
    assert resolve_scheduler("inline") == "synchronous"
    assert resolve_scheduler(None, workers=1) == "synchronous"
    assert resolve_scheduler("local", workers=1) == "synchronous"
    assert resolve_scheduler("tcp://h:1") == "tcp://h:1"
    with pytest.raises(ValueError, match="workers"):
        resolve_scheduler(None, workers=0)
    with pytest.raises(ValueError, match="scheduler"):
        resolve_scheduler(3.0)
    # the command line takes the same spellings (it tried to connect to 'Local')
    from analysis.cli.common import check_scheduler
    for s in ("Local", "sync", " inline"):
        check_scheduler(s)


def test_synchronous_results_are_kept_and_reused(tmp_path):
    with Engine("synchronous", cache=tmp_path) as eng:
        r = eng.submit(add, eng.submit(square, 3), eng.submit(square, 4))
        p = eng.submit(pair_sum, Pair(eng.submit(square, 2), 0.5))
        assert r.result() == 25.0 and p.result() == 4.5
        assert {rec.state for rec in eng.records} == {"computed"}
        assert len(eng.records) == 5
    with Engine("synchronous", cache=tmp_path) as eng:
        r = eng.submit(add, eng.submit(square, 3), eng.submit(square, 4))
        assert r.result() == 25.0 and eng.state(r) == "reused"
        # the top task is kept: its inputs are never computed, nor read
        assert [rec.state for rec in eng.records] == ["reused"] * 3


def test_a_failure_marks_its_dependants(tmp_path):
    with Engine("synchronous", cache=tmp_path) as eng:
        bad = eng.submit(fails, 1)
        dep = eng.submit(add, bad, 1.0)
        ok = eng.submit(square, 5)
        assert ok.result() == 25.0
        for r in (bad, dep):
            with pytest.raises(TaskError) as e:
                r.result()
            assert e.value.origin.endswith("fails") and "no good: 1" in e.value.message
        assert eng.state(dep) == "failed"
    # a failure is not kept: the next run tries again
    with Engine("synchronous", cache=tmp_path) as eng:
        assert eng.state(eng.submit(fails, 1)) == "failed"
        assert [r.state for r in eng.records] == ["failed"]


def test_a_result_that_cannot_be_kept_fails_its_task(tmp_path):
    """A task's or a flow's result that cannot be pickled fails it, with the reason (the
    flow's future had no outcome; the task's call raised and a second call waited)."""
    with Engine("synchronous", cache=tmp_path) as eng:
        for f in (eng.submit(unkept, 1), eng.submit(unkept, 1), eng.spawn(unkept_flow, 1)):
            with pytest.raises(TaskError, match="pickle"):
                f.result(timeout=10)
        assert [r.state for r in eng.records] == ["failed"] * 2


def test_a_future_the_engine_cannot_pass_is_refused(tmp_path):
    """A future inside a namedtuple or an object array would reach the task as a future
    (its key counts it as an input): refused with what to pass instead."""
    P = collections.namedtuple("P", "a b")
    with Engine("synchronous", cache=tmp_path) as eng:
        x = eng.submit(square, 2.0)
        for arg in (P(x, 1.0), np.array([x, None], dtype=object)):
            with pytest.raises(TypeError, match="inside lists, tuples, dicts or dataclasses"):
                eng.submit(echo, arg)
        assert eng.submit(echo, [x, {"b": x}]).result() == [4.0, {"b": 4.0}]


def test_a_task_error_is_one_line():
    """str() of a TaskError is one line (a report's line, the command line's error)
    however many lines its task's error has; the message keeps them."""
    e = TaskError("pkg.mod.multi", "ValueError: first line\n  second line")
    assert str(e) == "multi: ValueError: first line second line"
    assert e.message.count("\n") == 1


def test_flows_wait_for_their_tasks(tmp_path):
    with Engine("synchronous", cache=tmp_path) as eng:
        v = eng.spawn(chain, 3).result()
    x = 1.0
    for _ in range(3):
        x = x + x * x
    assert v == x


@pytest.mark.slow
def test_local_cluster_gives_the_synchronous_numbers(tmp_path):
    """Two worker processes compute what one process computes, task for task."""
    values = np.linspace(0, 1, 7)
    with Engine("synchronous", cache=tmp_path / "a") as eng:
        want = eng.submit(total, [eng.submit(square, v) for v in values]).result()
        flow = eng.spawn(chain, 4).result()
    with Engine("local", workers=2, cache=tmp_path / "b") as eng:
        got = eng.submit(total, [eng.submit(square, v) for v in values])
        f = eng.spawn(chain, 4)
        pids = {eng.submit(pid, i).result() for i in range(8)}
        bad = eng.submit(add, eng.submit(fails, 2), 1.0)
        assert got.result() == want and f.result() == flow
        # a task's state is known as soon as its result has arrived
        assert all(eng.submit(square, x).result() >= 0 and
                   eng.state(eng.submit(square, x)) == "computed" for x in (0.5, 1.5))
        with pytest.raises(TaskError, match="no good: 2"):
            bad.result()
        # a fan-out whose calls share arguments (one task) yields every tag
        calls = {"a": (2.0,), "b": (2.0,), "c": (3.0,)}
        assert dict(eng.each(square, calls)) == {"a": 4.0, "b": 4.0, "c": 9.0}
    assert len(pids) >= 1


def _imported(name):
    import sys
    return name in sys.modules


@pytest.mark.slow
def test_the_cluster_starts_only_for_results_to_compute(tmp_path):
    """With nothing kept the cluster starts as the engine is made (its workers joining
    in the background, importing the preloaded modules); a run whose results are all
    kept starts none."""
    with Engine("local", workers=2, cache=tmp_path, preload=("task_examples",)) as eng:
        assert eng._client is not None
        v = eng.spawn(chain, 3).result()
        assert all(eng.client().run(_imported, "task_examples").values())
    with Engine("local", workers=2, cache=tmp_path) as eng:
        assert eng.spawn(chain, 3).result() == v
        assert eng._client is None


def test_dask_runs_the_highest_priority_first_and_close_fails_the_rest(tmp_path):
    """Two single-threaded workers, both busy: Dask keeps the other tasks queued (two at
    most on each worker), and a later one of higher priority starts before the earlier
    ones of lower priority still queued (at most three of the eight go first); closing the engine fails what never started instead
    of leaving it pending."""
    with Engine("local", workers=2, cache=tmp_path) as eng:
        [eng.submit(started_at, w).result() for w in ["warm 1", "warm 2"]]
        # busy for 2 s: the nine submissions below fit in that even on a loaded machine
        # (at 0.5 s a busy one could end before the high one was sent)
        busy = [eng.submit(started_at, f"busy {i}", 2.0) for i in range(2)]
        low = [eng.submit(started_at, f"low {i}") for i in range(8)]
        with eng.stage("urgent", priority=10):
            high = eng.submit(started_at, "high")
        # (when the busy ones start is not asserted: on a loaded machine a worker process
        # can be scheduled out long enough for the other to finish its busy one and start
        # the high one first, which is Dask's choice and correct)
        assert sum(r.result() < high.result() for r in low) <= 3
        assert all(r.result() > 0 for r in busy)
    eng = Engine("local", workers=2, cache=tmp_path / "closed")
    [eng.submit(started_at, w).result() for w in ["warm 1", "warm 2"]]
    [eng.submit(started_at, b, 2.0) for b in ["busy 1", "busy 2"]]
    never = eng.submit(started_at, "never")
    eng.close()
    assert never.done()
    with pytest.raises(Exception):
        never.result()
    assert any(r.error.endswith("not run: the engine was closed first") for r in eng.records)


def test_a_script_without_a_main_guard_fails_fast_with_the_reason(tmp_path):
    """A script that starts a local cluster at module level, without
    ``if __name__ == "__main__":``: every worker process re-runs it as it starts.  The
    run stops within seconds, its tasks failed, saying what to change, instead of
    waiting forever for a cluster that cannot start."""
    import subprocess
    import sys
    from pathlib import Path
    tests = Path(__file__).resolve().parent
    script = tmp_path / "unguarded.py"
    script.write_text(
        "from analysis.tasks import Engine, TaskError\n"
        "from task_examples import square\n"
        f"eng = Engine('local', workers=2, cache={str(tmp_path / 'c')!r})\n"
        "ref = eng.submit(square, 3.0)\n"
        "try:\n"
        "    ref.result()\n"
        "except BaseException as e:\n"
        "    print('FAILED:', e)\n"
        "eng.check_started()\n")
    out = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True,
                         text=True, timeout=120,
                         env={**__import__("os").environ, "PYTHONPATH": str(tests)})
    assert out.returncode == 1
    assert "FAILED:" in out.stdout and "the Dask cluster did not start" in out.stdout
    assert 'if __name__ == "__main__":' in out.stderr
    assert "ValueError: scheduler: the Dask cluster did not start" in out.stderr


def _toolkit_copy(dest):
    """A copy of the three packages in ``dest``; returns ``dest``."""
    import shutil
    from pathlib import Path
    root = Path(__file__).resolve().parents[1]
    for top in ("biped_casadi", "gait_opt", "analysis"):
        shutil.copytree(root / top, dest / top, ignore=shutil.ignore_patterns("__pycache__"))
    return dest


def _code_version_of(tree, tmp_path, name):
    """code_version('numerical') of a copy of the packages (in a fresh process; the
    memo of file digests in ``tmp_path / 'cache'``, shared by the calls)."""
    import subprocess
    import sys
    dest = _toolkit_copy(tmp_path / name)
    tree(dest)
    out = subprocess.run([sys.executable, "-c", "from analysis.tasks import code_version; "
                          "print(code_version('numerical'), code_version('figures'))"],
                         cwd=dest, capture_output=True, text=True, check=True,
                         env={"PYTHONPATH": str(dest), "PATH": "/usr/bin:/bin",
                              "BIPED_CACHE_DIR": str(tmp_path / "cache")})
    return out.stdout.split()


def test_a_docstring_or_report_edit_keeps_every_result_a_code_edit_does_not(tmp_path):
    """The keys of every kept result: the same after an edit of a docstring in analysis/
    or of the report (so a re-run is warm), new after an edit of a number; the same with
    the on-disk memo of file digests read, absent or damaged."""
    import sys
    from pathlib import Path

    def nothing(root):
        pass

    def docstring(root):
        p = root / "analysis" / "robustness" / "basin.py"
        s = p.read_text()
        p.write_text(s.replace('"""The basin of attraction', '"""Edited: the basin of '
                                                            'attraction', 1))

    def report(root):
        p = Path(root) / "analysis" / "reporting" / "report.py"
        p.write_text(p.read_text() + "\n\ndef _extra():\n    return 1\n")

    def number(root):
        p = root / "analysis" / "robustness" / "basin.py"
        s = p.read_text()
        p.write_text(s.replace("q_span: float = 0.05", "q_span: float = 0.06", 1))

    base = _code_version_of(nothing, tmp_path, "a")
    memo = tmp_path / "cache" / f"code-digests-py{sys.version_info[0]}{sys.version_info[1]}.json"
    assert memo.is_file()                     # the file digests are kept on disk ...
    assert _code_version_of(nothing, tmp_path, "a2") == base      # ... and read back
    memo.write_text("{damaged")
    assert _code_version_of(nothing, tmp_path, "a3") == base      # a damaged memo: parsed
    assert _code_version_of(docstring, tmp_path, "b") == base
    num, fig = _code_version_of(report, tmp_path, "c")
    assert num == base[0] and fig == base[1]          # the report is neither
    changed = _code_version_of(number, tmp_path, "d")
    assert changed[0] != base[0] and changed[1] != base[1]


def test_a_worker_running_other_code_is_refused(tmp_path):
    """A real ``dask worker`` started on a copy of the toolkit whose numerical code
    differs (one number in one module): the task fails with one line naming the module,
    and nothing is kept."""
    import os
    from pathlib import Path
    from dask_cluster import dask_cluster
    tests = Path(__file__).resolve().parent
    other = _toolkit_copy(tmp_path / "other")
    basin = other / "analysis" / "robustness" / "basin.py"
    basin.write_text(basin.read_text().replace("q_span: float = 0.05", "q_span: float = 0.06"))
    env = {k: v for k, v in os.environ.items() if k != "BIPED_SCHEDULER"}
    with dask_cluster(tmp_path, [dict(env, PYTHONPATH=f"{other}:{tests}")], cwd=tmp_path,
                      scheduler_env=dict(env, PYTHONPATH=str(tests))) as address, \
            Engine(address, cache=tmp_path / "cache") as eng:
        ref = eng.submit(square, 3.0)
        with pytest.raises(TaskError) as e:
            ref.result()
        assert eng.submit(add, ref, 1.0).exception() is not None      # its dependant too
        from analysis.cluster import check_workers            # before any work: one line
        with pytest.raises(ValueError, match=r"^scheduler: the Dask worker tcp://\S+ runs "
                                             r"other code: analysis/robustness/basin.py diff"):
            check_workers(eng.client())
    msg = str(e.value)
    assert "stale worker" in msg and "analysis/robustness/basin.py differs" in msg
    assert "\n" not in msg
    assert not list((tmp_path / "cache").rglob("*.pkl"))


#: a module the workers import with task_examples, and one imported by a task: the
#: function, its argument, the text before its default, this run's digit and another
_EDITS = {"imported, then checked out": ("analysis/robustness/basin.py", "basin", "q_span",
                                         "q_span: float = 0.0", "5", "6"),
          "digested, then edited": ("analysis/gait_metrics.py", "actuator_work", "n",
                                    "gait, n: int = 400", "1", "2")}


@pytest.mark.parametrize("case", list(_EDITS))
def test_a_worker_whose_files_change_after_it_imported_them_is_refused(case, tmp_path):
    """A real ``dask worker`` on a copy of the toolkit edited while it runs: it imported a
    module of other code (a checkout of another version), then the file was put back to
    this run's code before its first task (its digest, read from the files, equals this
    run's; the module it runs does not); or it computed its digest (the ``--scheduler``
    check), then a module it had not imported was edited, then imported by a task.  The
    task is refused (the old code returned 0.06 or 4002) with one line naming the file
    and saying to restart the worker, and so is the cluster; nothing is kept."""
    import os
    import re
    from pathlib import Path
    from dask_cluster import dask_cluster
    from analysis.cluster import check_workers
    tests = Path(__file__).resolve().parent
    env = {k: v for k, v in os.environ.items() if k != "BIPED_SCHEDULER"}
    rel, fn, arg, at, ours, theirs = _EDITS[case]
    tree = _toolkit_copy(tmp_path / "tree")
    f = tree / rel
    text = f.read_text()
    edited = text.replace(at + ours, at + theirs, 1)
    assert edited != text
    first = case.startswith("imported")
    if first:
        f.write_text(edited)                                 # the other version
    with dask_cluster(tree, [dict(env, PYTHONPATH=f"{tree}:{tests}")], cwd=tmp_path,
                      scheduler_env=dict(env, PYTHONPATH=str(tests))) as address, \
            Engine(address, cache=tmp_path / "cache") as eng:
        client = eng.client()
        if first:
            client.run(__import__, "task_examples")           # imports the basin module
            f.write_text(text)                                # checked out: this run's code
        else:
            check_workers(client)                             # the digest: this run's code
            f.write_text(edited)                              # then edited, not imported
        with pytest.raises(TaskError) as e:
            eng.submit(default_of, rel[:-3].replace("/", "."), fn, arg).result()
        with pytest.raises(ValueError, match=re.escape(
                f"runs other code: {rel} changed on disk after it imported the toolkit; "
                "restart the worker")):
            check_workers(client)
    assert re.fullmatch(rf"default_of: stale worker \(tcp://127.0.0.1:\d+, pid \d+\): {rel} "
                        r"changed on disk after it imported the toolkit; restart the worker "
                        r"\(or the command, on a local cluster\)", str(e.value)), str(e.value)
    assert not list((tmp_path / "cache").rglob("*.pkl"))


@pytest.mark.parametrize("case", ["touched", "added"])
def test_a_worker_whose_files_are_touched_works_one_with_a_file_added_says_so(case, tmp_path):
    """A real ``dask worker`` on a copy of the toolkit that, after it imported the
    toolkit and computed its code's digest, has a module it imported touched and one it
    had not imported saved again with the same code (a new file): its tasks run and are
    kept, and the cluster passes the check (they were refused until the worker was
    restarted).  Or one whose copy lacked a file when it imported the toolkit, added
    since: its tasks and the cluster are refused, naming the file as added."""
    import os
    import re
    from pathlib import Path
    from dask_cluster import dask_cluster
    from analysis.cluster import check_workers
    tests, tree = Path(__file__).resolve().parent, _toolkit_copy(tmp_path / "tree")
    env = {k: v for k, v in os.environ.items() if k != "BIPED_SCHEDULER"}
    basin, metrics = tree / "analysis/robustness/basin.py", tree / "analysis/gait_metrics.py"
    text = metrics.read_text()
    if case == "added":
        metrics.unlink()
    with dask_cluster(tree, [dict(env, PYTHONPATH=f"{tree}:{tests}")], cwd=tmp_path,
                      scheduler_env=dict(env, PYTHONPATH=str(tests))) as address, \
            Engine(address, cache=tmp_path / "cache") as eng:
        client = eng.client()
        client.run(__import__, "task_examples")           # imports the basin module
        if case == "added":
            assert "analysis/gait_metrics.py" not in client.run(
                lambda: __import__("biped_casadi.caching").caching.code_files()).popitem()[1]
            metrics.write_text(text)
            with pytest.raises(ValueError, match=re.escape(
                    "runs other code: analysis/gait_metrics.py was added in this checkout; ")):
                check_workers(client)
            with pytest.raises(TaskError, match=r"^square: stale worker \(tcp://\S+, pid \d+\): "
                               r"analysis/gait_metrics.py was added in this run's code; run the "
                               "same version of the toolkit on every worker$"):
                eng.submit(square, 3.0).result()
            return
        check_workers(client)                             # the digest: this run's code
        os.utime(basin, ns=(basin.stat().st_atime_ns, basin.stat().st_mtime_ns + 10**9))
        metrics.unlink()
        metrics.write_text(text)                          # the same code, a new file
        assert eng.submit(default_of, "analysis.robustness.basin", "basin", "q_span"
                          ).result() == 0.05
        assert eng.submit(default_of, "analysis.gait_metrics", "actuator_work", "n"
                          ).result() == 4001
        check_workers(client)
    assert len(list((tmp_path / "cache").rglob("*.pkl"))) == 2


def test_a_touched_file_is_read_once_and_kept_an_edited_one_is_not(tmp_path, monkeypatch):
    """A file of the code whose stat changed (a ``touch``, a save of the same code, a
    comment) is read once and kept, and so is one touched before it was first read;
    one whose code changed, whose bytes changed before it was first read, or removed is
    the file named; files added or removed between two processes' code are said so."""
    import hashlib
    import os
    import biped_casadi.caching as caching
    monkeypatch.setenv("BIPED_CACHE_DIR", str(tmp_path / "cache"))
    files = {rel: tmp_path / rel.replace("/", "_") for rel in ("analysis/a.py", "analysis/b.py")}
    reads = []

    def imported():
        for f in files.values():
            f.write_text("x = 1\n")
        monkeypatch.setattr(caching, "_IMPORTED", {
            r: (f, caching._stat(f), hashlib.sha256(f.read_bytes()).hexdigest())
            for r, f in files.items()})
        monkeypatch.setattr(caching, "_READ", {}, raising=False)
        monkeypatch.setattr(caching, "_FILES", {})

    def later(f, text=None):
        os.utime(f, ns=(f.stat().st_atime_ns, f.stat().st_mtime_ns + 10**9))
        if text is not None:
            f.write_text(text)

    digest = caching._file_digest
    monkeypatch.setattr(caching, "_file_digest",
                        lambda f, sha="": reads.append(f) or digest(f, sha))
    imported()
    assert caching.code_edited() == "" and len(reads) == 2           # the code read once
    a, b = files["analysis/a.py"], files["analysis/b.py"]
    later(a)
    assert caching.code_edited() == "" and len(reads) == 3           # touched: read once
    assert caching.code_edited() == "" and len(reads) == 3           # then a stat only
    later(b, "x = 1  # the same code\n")
    assert caching.code_edited() == "" == caching.code_edited() and len(reads) == 4
    later(b, "x = 2\n")
    assert caching.code_edited() == "analysis/b.py"
    imported()
    later(a)                                              # before this process read it
    assert caching.code_edited() == "" == caching.code_edited()
    imported()
    later(a, "x = 1  # the same code\n")                  # other bytes: not known the same
    assert caching.code_edited() == "analysis/a.py"
    imported()
    caching.code_files()
    b.unlink()
    assert caching.code_edited() == "analysis/b.py"
    ours = {"a.py": "1", "b.py": "2", "c.py": "3"}
    assert caching.files_differing(ours, ours) == ""
    assert caching.files_differing({"a.py": "1"}, {"a.py": "1", "b.py": "2"}) == \
        "b.py was removed"
    assert caching.files_differing(ours, {"a.py": "1", "c.py": "3"}) == "b.py was added"
    assert caching.files_differing(ours, {"a.py": "0", "c.py": "3"}) == \
        "a.py differs (and 1 more)"


@pytest.mark.parametrize("change", ["touched", "edited"])
def test_a_file_touched_before_it_is_first_read_is_the_code_imported(change, tmp_path):
    """A fresh process on a copy of the toolkit imports it; a module of its code is then
    touched (or edited) before the process reads any file's code: the touch was the
    file named as changed on disk (its tasks refused until the process restarted); the
    edit still is."""
    import os
    import subprocess
    import sys
    tree = _toolkit_copy(tmp_path / "tree")
    f = tree / "analysis" / "gait_metrics.py"
    script = f"""
import os, pathlib
import biped_casadi.caching as caching
f = pathlib.Path({str(f)!r})
if {change!r} == "touched":
    os.utime(f, ns=(f.stat().st_atime_ns, f.stat().st_mtime_ns + 10**9))
else:
    f.write_text(f.read_text().replace("gait, n: int = 4001", "gait, n: int = 4002", 1))
print(repr(caching.code_edited()), repr(caching.code_edited("figures")))
"""
    out = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True,
                         text=True, timeout=300, env=dict(
                             os.environ, PYTHONPATH=str(tree),
                             BIPED_CACHE_DIR=str(tmp_path / "cache")))
    assert out.returncode == 0, out.stderr
    named = "''" if change == "touched" else "'analysis/gait_metrics.py'"
    assert out.stdout == f"{named} {named}\n"


@pytest.mark.parametrize("change", ["touched", "edited"])
def test_the_command_refuses_its_own_stale_code_before_any_work(change, tmp_path,
                                                                monkeypatch):
    """A command that runs tasks checks its own files with the scheduler, before any
    work: a module edited after it imported the toolkit failed only the tasks it ran
    itself and its flows, stage by stage; one touched passes."""
    import hashlib
    import os
    import biped_casadi.caching as caching
    from analysis.cli.common import UserError, check_scheduler
    monkeypatch.setenv("BIPED_CACHE_DIR", str(tmp_path / "cache"))
    f = tmp_path / "a.py"
    f.write_text("x = 1\n")
    monkeypatch.setattr(caching, "_IMPORTED", {
        "analysis/a.py": (f, caching._stat(f), hashlib.sha256(f.read_bytes()).hexdigest())})
    monkeypatch.setattr(caching, "_READ", {})
    monkeypatch.setattr(caching, "_FILES", {})
    os.utime(f, ns=(f.stat().st_atime_ns, f.stat().st_mtime_ns + 10**9))
    if change == "touched":
        check_scheduler(None)
        return
    f.write_text("x = 2\n")
    with pytest.raises(UserError, match=r"^stale code: analysis/a.py changed on disk after "
                                        r"this command started \(it imported the toolkit\); "
                                        r"restart the command$"):
        check_scheduler(None)


@pytest.mark.parametrize("argv", [["sweep", "--grid", "2"], ["terrain", "--runs", "2"],
                                  ["m1", "--robust"]])
def test_a_command_refuses_a_bad_gait_file_before_its_code_check(argv, gait, tmp_path,
                                                                 monkeypatch, capsys):
    """A missing --gait (or --robot) file is one line before the stale-code check (the code's digest,
    0.7 s and more with an empty cache, was read first); with a good file the stale code
    is still refused, before any task."""
    import analysis.cli.common as common
    from analysis.cli import main
    checked = []
    monkeypatch.setattr(common, "code_edited", lambda: checked.append(1) or "analysis/a.py")
    assert main([*argv, "--gait", str(tmp_path / "missing.json")]) == 2
    assert "gait file not found" in capsys.readouterr().err and checked == []
    if argv[0] != "sweep":                              # (sweep needs --gait)
        assert main([*argv, "--robot", str(tmp_path / "missing.toml")]) == 2
        assert "file not found" in capsys.readouterr().err and checked == []
    assert main([*argv, "--gait", str(gait.save(tmp_path / "gait.json"))]) == 2
    assert "error: stale code: analysis/a.py changed" in capsys.readouterr().err
    assert checked == [1]
    if argv[0] == "m1":                                 # the search: no --gait
        assert main([*argv, "--method", "search"]) == 2 and checked == [1, 1]


def _edited_in_this_process(tmp_path, edit: str, scheduler: str = "synchronous"):
    """A fresh process on a copy of the toolkit: it imports basin.py's module, computes
    the code's digest, then ``edit`` ('imported': basin.py, 'not imported':
    gait_metrics.py) is edited on disk and a task and a flow reading that module's
    default run in it.  Returns its lines: the results, or the errors."""
    import os
    import subprocess
    import sys
    from pathlib import Path
    tree, tests = _toolkit_copy(tmp_path / "tree"), Path(__file__).resolve().parent
    rel, fn, arg, at = {"imported": ("analysis/robustness/basin.py", "basin", "q_span",
                                     "q_span: float = 0.05"),
                        "not imported": ("analysis/gait_metrics.py", "actuator_work", "n",
                                         "gait, n: int = 4001")}[edit]
    script = f"""
import pathlib
from analysis.tasks import Engine, TaskError
from task_examples import default_of, default_of_flow, square
import analysis.robustness.basin
f, args = pathlib.Path({str(tree / rel)!r}), ({rel[:-3].replace("/", ".")!r}, {fn!r}, {arg!r})
with Engine({scheduler!r}, cache={str(tmp_path / "cache")!r}) as eng:
    print(eng.submit(square, 2.0).result())
    f.write_text(f.read_text().replace({at!r}, {at + "1"!r}, 1))
    for call in (eng.submit, eng.spawn):
        try:
            print(call(default_of if call == eng.submit else default_of_flow, *args).result())
        except TaskError as e:
            print(e)
"""
    env = {k: v for k, v in os.environ.items() if k != "BIPED_SCHEDULER"}
    out = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True,
                         text=True, env=dict(env, PYTHONPATH=f"{tree}:{tests}"), timeout=300)
    assert out.returncode == 0, out.stderr
    return rel, out.stdout.splitlines()


@pytest.mark.parametrize("edit", ["imported", "not imported"])
def test_a_process_whose_files_change_after_it_imported_them_refuses_its_tasks(edit, tmp_path):
    """The process running the tasks (synchronous) and the flows: a module of its code
    edited on disk after it imported the toolkit and computed the code's digest.  It
    ran the module it imported (basin's q_span 0.05, not 0.051) or the one imported
    after the edit (actuator_work's n 40011, not 4001), either under the key of the code
    before the edit: now the task and the flow are refused, one line naming the file
    and saying to restart the command, and nothing is kept but the first task's."""
    import re
    rel, lines = _edited_in_this_process(tmp_path, edit)
    assert lines[0] == "4.0" and len(lines) == 3, lines
    for name, line in zip(("default_of", "default_of_flow"), lines[1:]):
        assert re.fullmatch(rf"{name}: stale code \(pid \d+\): {rel} changed on disk after "
                            "this process imported the toolkit; restart the command", line), line
    assert len(list((tmp_path / "cache").rglob("*.pkl"))) == 1


def test_check_workers_compares_each_worker_once(monkeypatch):
    """A worker that differs is compared with this process once (the message reuses the
    file found); one that runs the same code passes; a second differing worker is not
    reached (the first one refuses the cluster)."""
    from analysis import cluster
    import biped_casadi.caching as caching
    calls = []

    def counted(mine, theirs):
        calls.append(1)
        return files_differing(mine, theirs)

    files_differing = caching.files_differing
    mine = caching.code_files()
    other = dict(mine, **{"analysis/cli/main.py": "another digest"})

    class Client:
        def __init__(self, workers):
            self.workers = workers

        def run(self, fn, kind):
            return self.workers if fn is caching.code_files else dict.fromkeys(self.workers, "")

    monkeypatch.setattr(caching, "files_differing", counted)
    cluster.check_workers(Client({"tcp://a:1": mine}))
    assert len(calls) == 1
    calls.clear()
    with pytest.raises(ValueError, match=r"^scheduler: the Dask worker tcp://b:1 runs other "
                                         r"code: analysis/cli/main.py was removed in this"):
        cluster.check_workers(Client({"tcp://a:1": mine, "tcp://b:1": other,
                                      "tcp://c:1": other}))
    assert len(calls) == 2


def test_a_malformed_address_is_refused_before_any_client(monkeypatch):
    """An address without host and port ('--scheduler nonsense') was refused by the
    Dask client made for it, whose IO-loop thread must start within 10 s: on a loaded
    machine the refusal was Dask's bare AssertionError ('internal error')."""
    import dask.distributed
    from analysis import cluster

    def client(*args, **kwargs):
        raise AssertionError("a client was made for a malformed address")

    monkeypatch.setattr(dask.distributed, "Client", client)
    for address in ("nonsense", "tcp://host", "tcp://host:port"):
        with pytest.raises(ValueError, match=f"^scheduler: cannot connect to the Dask "
                                             f"scheduler at {address} \\(ValueError: "):
            cluster.connect(address)


def test_an_address_without_a_scheduler_is_refused_within_the_connect_timeout(monkeypatch):
    """Nothing listening; a web server (a scheduler's dashboard port: Dask's client waited
    for its handshake for ever); a server that answers something else and hangs up (the
    client read its bytes as a length: "internal error: MemoryError: Unable to allocate
    3.07 EiB"): one line naming the address, within the connect timeout."""
    import queue
    import re
    import socket
    import threading
    import time
    from http.server import BaseHTTPRequestHandler, HTTPServer
    from analysis import cluster
    monkeypatch.setattr(cluster, "DASK_CONNECT_TIMEOUT", "2s")
    web = HTTPServer(("127.0.0.1", 0), BaseHTTPRequestHandler)
    other = socket.create_server(("127.0.0.1", 0))

    def serve():
        while True:
            c, _ = other.accept()
            c.recv(64)
            c.sendall(b"HTTP/1.1 400 Bad Request\r\ncontent-length: 0\r\n\r\n")
            c.close()

    free = socket.create_server(("127.0.0.1", 0))
    port = free.getsockname()[1]
    free.close()
    for target in (web.serve_forever, serve):
        threading.Thread(target=target, daemon=True).start()
    for p, why in ((other.getsockname()[1], r"ValueError: what answers there is not a Dask "
                                            r"scheduler \(MemoryError"),
                   (web.server_port, "TimeoutError: "), (port, "(OSError|TimeoutError): ")):
        address, out = f"tcp://127.0.0.1:{p}", queue.Queue()
        t = time.monotonic()
        threading.Thread(target=lambda: out.put(_raised(cluster.connect, address)),
                         daemon=True).start()
        e = out.get(timeout=60)                      # (the old code: for ever)
        assert time.monotonic() - t < 20
        assert isinstance(e, ValueError) and re.match(
            rf"scheduler: cannot connect to the Dask scheduler at {address} \({why}", str(e)), e
        assert "\n" not in str(e)
    web.shutdown()
    other.close()


def _raised(fn, *args):
    try:
        fn(*args)
    except BaseException as e:                   # noqa: BLE001 - what it raised
        return e


def test_a_lost_worker_or_scheduler_on_a_real_cluster(tmp_path, monkeypatch):
    """``kill -9`` of the worker that holds a kept result another task needs: Dask makes
    it again on the other worker (a scattered copy was lost with it and failed every
    later dependant).  Then the scheduler killed: a waiting task's ``result()`` raises
    Dask's cancellation, which the command line says in one line (also inside a flow's
    TaskError), and the engine says the scheduler was lost."""
    import os
    import signal
    import time
    from concurrent.futures import CancelledError
    from pathlib import Path

    from dask_cluster import dask_cluster

    import dask.distributed
    from analysis.cli.failures import failure_line
    env = {k: v for k, v in os.environ.items() if k != "BIPED_SCHEDULER"}
    env["PYTHONPATH"] = str(Path(__file__).resolve().parent)
    with Engine("synchronous", cache=tmp_path / "cache") as eng:
        eng.submit(square, 3.0).result()                      # kept
    with dask_cluster(tmp_path, [env, env], scheduler_env=env) as address, \
            Engine(address, cache=tmp_path / "cache") as eng:
        client = eng.client()
        client.wait_for_workers(2, timeout=60)
        kept = eng.submit(square, 3.0)
        assert eng.submit(add, kept, 1.0).result() == 10.0
        holder = client.who_has()[kept.key][0]
        os.kill(client.run(os.getpid, workers=[holder])[holder], signal.SIGKILL)
        t0 = time.time()
        while holder in client.scheduler_info()["workers"] and time.time() - t0 < 30:
            time.sleep(0.2)
        assert eng.submit(add, kept, 2.0).result(timeout=60) == 11.0
        from analysis.cluster import connect         # a worker's address, not the scheduler's
        with pytest.raises(ValueError, match=r"\(ValueError: what answers there is not a "
                                             r"Dask scheduler \("):
            connect(next(iter(client.scheduler_info()["workers"])))
        with monkeypatch.context() as m:    # Dask's client thread not started within 10 s
            m.setattr(dask.distributed, "Client", _assertion)
            with pytest.raises(ValueError, match=r"^scheduler: cannot connect to the Dask "
                                                 r"scheduler at tcp://\S+ \(Dask's client "
                                                 r"thread did not start within 10 s\); is"):
                connect(address)
        waiting = eng.submit(started_at, 0.0, 60.0)
        os.kill(client.run_on_scheduler(os.getpid), signal.SIGKILL)
        with pytest.raises(CancelledError) as e:
            waiting.result(timeout=60)
        line = failure_line(e.value)
        assert line.startswith("the Dask cluster dropped the run's tasks (scheduler-conn")
        assert "\n" not in line and "run the same command" in line
        inside = TaskError("m.flow", f"{type(e.value).__name__}: {e.value}")  # in a flow
        assert failure_line(inside) == line
        with pytest.raises(ValueError, match="^scheduler: lost the Dask scheduler at tcp://"):
            eng.check_started()


def _assertion(*args, **kwargs):
    """Dask's client when its IO loop's thread did not start within 10 s."""
    raise AssertionError
