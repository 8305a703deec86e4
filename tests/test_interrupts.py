"""Ctrl-C ends a command with one line and exit code 130 whenever it comes: while the
command line loads, and when a terminal sends it to the whole process group (the local
Dask cluster's workers too)."""
from __future__ import annotations

import multiprocessing
import os
import re
import select
import signal
import subprocess
import sys
import time

import pytest

import biped_cli


def test_ctrl_c_while_the_command_line_loads_is_one_line(monkeypatch, capsys):
    """A Ctrl-C in the second or two ``biped`` takes to import its command line printed
    a traceback of the imports."""
    class Interrupted:                    # a Ctrl-C while analysis.cli is imported
        def find_spec(self, name, path=None, target=None):
            if name == "analysis.cli":
                raise KeyboardInterrupt

    monkeypatch.delitem(sys.modules, "analysis.cli", raising=False)
    monkeypatch.setattr(sys, "meta_path", [Interrupted()] + sys.meta_path)
    monkeypatch.setattr(sys, "argv", ["biped", "reproduce", "--quick", "--out", "X"])
    assert biped_cli.main() == 130
    assert capsys.readouterr().err == "biped reproduce: interrupted\n"


def test_an_import_error_made_of_a_ctrl_c_is_the_interruption(monkeypatch, capsys):
    """An extension module whose initialisation is interrupted raises ImportError
    ('initialization failed', caused by the KeyboardInterrupt): that was a traceback."""
    class Interrupted:
        def find_spec(self, name, path=None, target=None):
            if name == "analysis.cli.app":
                raise ImportError("initialization failed") from KeyboardInterrupt()

    monkeypatch.delitem(sys.modules, "analysis.cli.app", raising=False)
    monkeypatch.setattr(sys, "meta_path", [Interrupted()] + sys.meta_path)
    monkeypatch.setattr(sys, "argv", ["biped", "model"])
    assert biped_cli.main() == 130
    assert capsys.readouterr().err == "biped model: interrupted\n"


def test_a_class_made_while_ctrl_c_is_pressed_is_the_interruption(monkeypatch, capsys):
    """A Ctrl-C while a module makes a dataclass comes out of the class's creation as
    ``RuntimeError: Error calling __set_name__ ...`` (caused by the KeyboardInterrupt):
    a traceback and exit code 1."""
    class Interrupted:
        def find_spec(self, name, path=None, target=None):
            if name == "analysis.cli.app":
                raise RuntimeError("Error calling __set_name__ on 'Field' instance "
                                   "'best' in 'StartScreen'") from KeyboardInterrupt()

    monkeypatch.delitem(sys.modules, "analysis.cli.app", raising=False)
    monkeypatch.setattr(sys, "meta_path", [Interrupted()] + sys.meta_path)
    monkeypatch.setattr(sys, "argv", ["biped", "model"])
    assert biped_cli.main() == 130
    assert capsys.readouterr().err == "biped model: interrupted\n"


@pytest.mark.parametrize("library", ["own error", "dropped"])
def test_a_ctrl_c_a_library_hides_while_the_command_line_loads_is_one_line(library,
                                                                         monkeypatch, capsys):
    """NumPy's extension, interrupted while it loads, raises ``ImportError:
    PyCapsule_Import could not import module "datetime"``, which does not name the
    KeyboardInterrupt (a traceback, exit code 1); a library that drops the Ctrl-C let
    the command run."""
    class Hidden:
        def find_spec(self, name, path=None, target=None):
            if name == "analysis.cli.app":
                try:
                    signal.raise_signal(signal.SIGINT)
                except KeyboardInterrupt:
                    pass
                if library == "own error":
                    raise ImportError('PyCapsule_Import could not import module "datetime"')

    monkeypatch.delitem(sys.modules, "analysis.cli.app", raising=False)
    monkeypatch.setattr(sys, "meta_path", [Hidden()] + sys.meta_path)
    monkeypatch.setattr(sys, "argv", ["biped", "model"])
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        assert biped_cli.main() == 130
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, old)
    assert capsys.readouterr() == ("", "biped model: interrupted\n")


def test_a_ctrl_c_while_the_ctrl_c_handler_is_set_is_one_line(monkeypatch, capsys):
    """Setting the handler that notes a Ctrl-C imports ``signal`` (some ms) first."""
    def interrupted(pressed):
        raise KeyboardInterrupt

    monkeypatch.setattr(biped_cli, "_watch", interrupted)
    monkeypatch.setattr(sys, "argv", ["biped", "model"])
    try:
        rc = biped_cli.main()
    except KeyboardInterrupt:                  # not this session's: fail, do not stop
        pytest.fail("the Ctrl-C left main")
    assert rc == 130
    assert capsys.readouterr().err == "biped model: interrupted\n"


def test_a_ctrl_c_in_a_module_locks_callback_is_noted_not_printed():
    """A Ctrl-C while importlib's weakref callback of a module lock runs: raised there,
    Python prints "Exception ignored in: <function _get_module_lock.<locals>.cb>" and
    its traceback, and drops it; the handler notes it instead (the load's end says
    it), and raises it anywhere else."""
    from types import SimpleNamespace
    in_cb = SimpleNamespace(f_code=SimpleNamespace(co_filename="<frozen importlib._bootstrap>",
                                                   co_name="cb"))
    old, pressed = signal.signal(signal.SIGINT, signal.default_int_handler), []
    try:
        put_back = biped_cli._watch(pressed)
        handler = signal.getsignal(signal.SIGINT)
        try:
            handler(signal.SIGINT, in_cb)
        except KeyboardInterrupt:              # (not this session's: fail, do not stop)
            pytest.fail("raised in the callback, where Python prints and drops it")
        assert pressed == [signal.SIGINT]
        with pytest.raises(KeyboardInterrupt):
            handler(signal.SIGINT, sys._getframe())
        assert len(pressed) == 2
        put_back()
    finally:
        signal.signal(signal.SIGINT, old)


def test_an_import_error_alone_is_not_an_interruption(monkeypatch):
    class Broken:
        def find_spec(self, name, path=None, target=None):
            if name == "analysis.cli.app":
                raise ImportError("a broken installation")

    monkeypatch.delitem(sys.modules, "analysis.cli.app", raising=False)
    monkeypatch.setattr(sys, "meta_path", [Broken()] + sys.meta_path)
    with pytest.raises(ImportError, match="a broken installation"):
        biped_cli.main()


_MODULE = """
import runpy, sys
class Interrupted:                        # a Ctrl-C while the command line loads
    def find_spec(self, name, path=None, target=None):
        if name == "analysis.cli.common":
            raise KeyboardInterrupt
sys.meta_path.insert(0, Interrupted())
sys.argv = ["analysis.cli", "model"]
runpy.run_module("analysis.cli", run_name="__main__", alter_sys=True)
"""


def test_python_m_is_interrupted_as_biped_is(tmp_path):
    """``python -m analysis.cli`` imported the command line (``analysis`` and
    ``analysis.cli``, a second or two) before any of it could catch a Ctrl-C: a
    traceback of the imports.  Importing the packages now loads nothing else."""
    r = subprocess.run([sys.executable, "-c", _MODULE], capture_output=True, text=True,
                       cwd=tmp_path, timeout=120)
    assert (r.returncode, r.stderr) == (130, "biped model: interrupted\n"), r.stderr
    loaded = subprocess.run(
        [sys.executable, "-c", "import sys, analysis.cli; print(sorted(m for m in "
                               "sys.modules if m.split('.')[0] in ('analysis', 'numpy')))"],
        capture_output=True, text=True, cwd=tmp_path, timeout=120).stdout
    assert loaded == "['analysis', 'analysis.cli']\n"


def test_ctrl_c_while_the_parser_is_built_is_one_line(monkeypatch, capsys):
    """Building the parser (some 20 ms) came before the command's handling of a Ctrl-C:
    a traceback and the process killed by the signal."""
    from analysis.cli import app

    def interrupted():
        raise KeyboardInterrupt

    monkeypatch.setattr(app, "build_parser", interrupted)
    try:
        rc = app.main(["reproduce", "--quick"])
    except KeyboardInterrupt:                  # not this session's: fail, do not stop
        pytest.fail("the Ctrl-C left main")
    assert rc == 130
    assert capsys.readouterr().err == "biped reproduce: interrupted\n"


def test_a_ctrl_c_dropped_in_a_callback_is_sent_again(monkeypatch, capsys):
    """A Ctrl-C raised in a weakref's callback (an import's lock, while the Dask cluster
    started) was printed as ignored and dropped: the command ran on to its end."""
    import weakref

    from analysis.cli import app

    class Thing:
        pass

    def command(args):
        thing = Thing()
        ref = weakref.ref(thing, lambda r: signal.raise_signal(signal.SIGINT))
        del thing                        # the callback's Ctrl-C is dropped there
        assert ref() is None
        time.sleep(10)
        return 0

    monkeypatch.setattr(app, "cmd_model", command)
    hook, t = sys.unraisablehook, time.perf_counter()
    # Python's own handler, also where this session was started with Ctrl-C ignored (a
    # shell's background job): the command observes only that one
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        rc = app.main(["model"])
    except KeyboardInterrupt:                  # not this session's: fail, do not stop
        pytest.fail("the Ctrl-C left main")
    finally:
        signal.signal(signal.SIGINT, old)
    assert rc == 130 and time.perf_counter() - t < 5
    assert capsys.readouterr().err.endswith("biped model: interrupted\n")
    assert sys.unraisablehook is hook


def test_a_ctrl_c_a_library_clears_is_sent_again(monkeypatch, capsys):
    """CasADi's operators call Python (``shape``) while they choose an overload and clear
    an error raised there: a Ctrl-C at that moment (building the model) vanished and the
    command ran on to its end with exit code 0."""
    import casadi as ca

    from analysis.cli import app

    size1, calls = ca.SX.size1, []

    def interrupted(self, *args):       # the Ctrl-C comes while CasADi calls shape
        calls.append(1)
        if len(calls) == 1:
            signal.raise_signal(signal.SIGINT)
        return size1(self, *args)

    def command(args):
        x = ca.SX.sym("x", 2)
        monkeypatch.setattr(ca.SX, "size1", interrupted)
        0.5 * ca.dot(x, x)                   # CasADi clears the KeyboardInterrupt
        monkeypatch.setattr(ca.SX, "size1", size1)
        assert calls
        time.sleep(10)
        return 0

    monkeypatch.setattr(app, "cmd_model", command)
    old, t = signal.signal(signal.SIGINT, signal.default_int_handler), time.perf_counter()
    try:
        rc = app.main(["model"])
    except KeyboardInterrupt:                  # not this session's: fail, do not stop
        pytest.fail("the Ctrl-C left main")
    finally:
        signal.signal(signal.SIGINT, old)
    assert rc == 130 and time.perf_counter() - t < 5
    assert capsys.readouterr().err == "biped model: interrupted\n"


def test_a_ctrl_c_while_the_main_thread_keeps_a_result_is_not_a_failed_task(tmp_path,
                                                                          monkeypatch):
    """The engine keeps on the caller's thread (its records, a task's state, close) the
    results the keeper thread has not kept yet: a Ctrl-C in the store's fsynced write
    there was recorded as that task's failure, and the run went on."""
    from analysis.tasks import Engine, TaskRecord, TaskState

    class Arrived:                      # a Dask future whose result is not kept yet
        key = "square-k"

        def done(self):
            return True

        def result(self):
            return 4

    def interrupted(*args):
        raise KeyboardInterrupt

    eng = Engine("synchronous", cache=tmp_path)
    eng._tasks["k"], eng._futures["k"] = TaskRecord("square", "", "k"), Arrived()
    monkeypatch.setattr(eng.store, "write", interrupted)
    with pytest.raises(KeyboardInterrupt):
        eng.records
    monkeypatch.undo()                  # not kept, not failed: kept by the next look
    assert [r.state for r in eng.records] == [TaskState.COMPUTED]
    assert eng.store.read("k")["value"] == 4


_IN_EXEC = """
import sys
class Interrupted:                        # a Ctrl-C while a dataclass's methods are made
    def find_spec(self, name, path=None, target=None):
        if name == "analysis.cli.common":
            exec("raise KeyboardInterrupt")
sys.meta_path.insert(0, Interrupted())
"""


def test_python_m_exits_130_after_a_ctrl_c_inside_exec(tmp_path):
    """A Ctrl-C inside code run by ``exec`` of a string (dataclasses make their methods
    so), caught and said in one line, still ended ``python -m analysis.cli`` by SIGINT
    (exit code -2): CPython kept a record of it that ``python -m`` acts on at exit."""
    (tmp_path / "sitecustomize.py").write_text(_IN_EXEC)
    env = dict(os.environ, PYTHONPATH=str(tmp_path))
    r = subprocess.run([sys.executable, "-m", "analysis.cli", "model"], capture_output=True,
                       text=True, cwd=tmp_path, env=env, timeout=120)
    assert (r.returncode, r.stderr) == (130, "biped model: interrupted\n"), r.stderr


_FINDING = """
import sys
class Interrupted:                        # a Ctrl-C while Python looks for biped_cli
    def find_spec(self, name, path=None, target=None):
        if name == "biped_cli" and self in sys.meta_path:
            sys.meta_path.remove(self)
            raise KeyboardInterrupt
sys.meta_path.insert(0, Interrupted())
"""


def test_python_m_interrupted_while_it_finds_the_entry_point_is_one_line(tmp_path):
    """``python -m analysis.cli`` imports :mod:`biped_cli` first (an editable install's
    import finder looks for it with ``pathlib``, some ms under load): a Ctrl-C then was
    a traceback and the process killed by SIGINT."""
    (tmp_path / "sitecustomize.py").write_text(_FINDING)
    env = dict(os.environ, PYTHONPATH=str(tmp_path))
    r = subprocess.run([sys.executable, "-m", "analysis.cli", "model"], capture_output=True,
                       text=True, cwd=tmp_path, env=env, timeout=120)
    assert (r.returncode, r.stderr) == (130, "biped model: interrupted\n"), r.stderr


def _default_sigint():
    """In the child: Ctrl-C's default action, which Python turns into KeyboardInterrupt
    (a shell's background job, as a CI runner may be, starts its children ignoring it)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


_STARTED = """
import os
fd = os.environ.pop("BIPED_TEST_STARTED_FD", None)   # (not in the workers it starts)
if fd:                                     # Python has started: its Ctrl-C handler is
    os.write(int(fd), b"s")                # set and site has run the .pth files
    os.close(int(fd))
"""

#: the project's files: a frame there is the toolkit's code
_OURS = tuple(os.path.join(os.path.dirname(os.path.realpath(biped_cli.__file__)), p)
              for p in ("biped_cli.py", "analysis/", "biped_casadi/", "gait_opt/"))


def _before_the_toolkit(returncode: int, err: str) -> bool:
    """Whether Python itself ended the process on a Ctrl-C that came before any of the
    toolkit's code could catch it (runpy looking for ``analysis.cli.__main__``, an
    editable install's finder, a late step of Python's start-up): Python's traceback
    of the KeyboardInterrupt without a frame in the project's files, nothing said by
    the toolkit, and Python's exit (SIGINT re-sent by ``python -m``, or 1 for a failed
    start-up)."""
    frames = re.findall(r'^ +File "([^"]+)", line \d+', err, re.M)
    return (returncode in (-signal.SIGINT, 1) and bool(frames)
            and err.rstrip().endswith("KeyboardInterrupt")
            and not any(os.path.realpath(f).startswith(_OURS) for f in frames
                        if os.path.isabs(f))
            and not any(line.startswith("biped") for line in err.splitlines()))


def _interrupt_python_m(tmp_path, delay: float):
    """``python -m analysis.cli running`` sent SIGINT ``delay`` s after Python has
    started (a ``sitecustomize`` writes to a pipe once site is done, before any of the
    toolkit's code): under load the start-up alone took longer than 0.1 s, and a
    Ctrl-C there, before the toolkit, was Python's own traceback or kill."""
    (tmp_path / "sitecustomize.py").write_text(_STARTED)
    started, child_end = os.pipe()
    env = dict(os.environ, BIPED_CACHE_DIR=str(tmp_path / "cache"),
               PYTHONPATH=str(tmp_path), BIPED_TEST_STARTED_FD=str(child_end))
    p = subprocess.Popen([sys.executable, "-m", "analysis.cli", "running", "--no-cache",
                          "--out", "r.json"], cwd=tmp_path, env=env, text=True,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         preexec_fn=_default_sigint, pass_fds=(child_end,))
    os.close(child_end)
    try:
        if not (select.select([started], [], [], 120)[0] and os.read(started, 1) == b"s"):
            p.kill()
            pytest.fail("Python did not start: " + p.communicate(timeout=120)[1])
        time.sleep(delay)
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=120)
    finally:
        os.close(started)
        if p.poll() is None:
            p.kill()
            p.wait()
    return p.returncode, err


@pytest.mark.slow
@pytest.mark.parametrize("delay", (0.1, 0.4, 0.7, 0.9, 1.1, 1.4, 1.8, 2.5))
def test_python_m_interrupted_at_any_time_is_one_line_and_130(tmp_path, delay):
    """A Ctrl-C at times spread over the loading and the command's start (the
    optimisation of a running step, not kept in a cache).  One that Python itself
    ended before any of the toolkit's code ran is tried again (at most 5 times)."""
    for attempt in range(5):
        rc, err = _interrupt_python_m(tmp_path, delay)
        if not _before_the_toolkit(rc, err):
            break
    else:
        pytest.fail(f"5 Ctrl-Cs after {delay} s came before the toolkit:\n{err}")
    assert rc == 130 and "Traceback" not in err, (delay, rc, err)
    assert err.splitlines()[-1] == "biped running: interrupted", (delay, err)
    assert not (tmp_path / "r.json").exists()


_CLUSTER = """
import gc, signal, time
from analysis.cluster import connect
if __name__ == "__main__":
    signal.signal(signal.SIGINT, signal.default_int_handler)
    client, cluster = connect("local", 1)
    client.wait_for_workers(1, timeout=120)
    try:
        print("ready", [getattr(c, "__module__", "") for c in gc.callbacks], flush=True)
        time.sleep(120)
    except KeyboardInterrupt:
        client.close()
        cluster.close()
        print("closed", flush=True)
"""


def test_ctrl_c_of_the_process_group_leaves_the_workers_to_this_process(tmp_path):
    """A terminal's Ctrl-C reaches the local cluster's worker processes too: each printed
    a traceback ("Process Dask Worker process (from Nanny): ... KeyboardInterrupt")
    while this process closed them; they now leave the interruption to it, and this
    process raises it outside any garbage collector's callback."""
    (tmp_path / "run.py").write_text(_CLUSTER)
    p = subprocess.Popen([sys.executable, "run.py"], cwd=tmp_path, text=True,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         start_new_session=True)
    try:
        # no callback of Dask's GC diagnosis in this process: Python drops a
        # KeyboardInterrupt raised in one, and the command ran on to its end
        assert p.stdout.readline() == "ready []\n"
        os.killpg(p.pid, signal.SIGINT)
        out, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
    assert out == "closed\n" and "Traceback" not in err, err
    for _ in range(100):           # the workers and the resource tracker end soon after
        if subprocess.run(["pgrep", "-g", str(p.pid)]).returncode == 1:
            break
        time.sleep(0.1)
    assert subprocess.run(["pgrep", "-a", "-g", str(p.pid)], capture_output=True,
                          text=True).stdout == ""


def test_a_cluster_closed_while_its_workers_start_ends_them_at_once(tmp_path):
    """Closing the engine (as a Ctrl-C does) while its local cluster's worker processes
    were still starting waited for them to start, Dask's nanny closing only a started
    worker (20 s of imports under load, here a minute): they are killed at once."""
    from analysis.tasks import Engine
    (tmp_path / "slow_start.py").write_text("import time\ntime.sleep(60)\n")
    others = set(multiprocessing.active_children())
    eng = Engine("local", 2, cache=False, preload=(str(tmp_path / "slow_start.py"),))
    for _ in range(600):                # its two worker processes spawned (not started)
        if len(workers := set(multiprocessing.active_children()) - others) == 2:
            break
        time.sleep(0.1)
    start = time.monotonic()
    eng.close()
    assert len(workers) == 2 and time.monotonic() - start < 20
    assert not any(w.is_alive() for w in workers)
    assert not set(multiprocessing.active_children()) - others
