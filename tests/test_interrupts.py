"""Ctrl-C ends a command with one line and exit code 130 whenever it comes: while the
command line loads, and when a terminal sends it to the whole process group (the local
Dask cluster's workers too)."""
from __future__ import annotations

import os
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
