import json
import subprocess
import sys

import numpy as np


def run(*args):
    return subprocess.run([sys.executable, "-m", "analysis.cli", *args],
                          capture_output=True, text=True, timeout=120)


def test_model_json():
    r = run("model", "--q", "0.1", "0", "0", "0", "0", "--json")
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    assert s["total_mass"] == 32.0
    D = np.array(s["D"])
    assert D.shape == (5, 5) and np.allclose(D, D.T)


def test_model_bad_inputs(tmp_path):
    r = run("model", "--q", "1", "2")
    assert r.returncode == 2 and "5 numbers" in r.stderr and "Traceback" not in r.stderr
    r = run("model", "--robot", str(tmp_path / "missing.toml"))
    assert r.returncode == 2 and "not found" in r.stderr and "Traceback" not in r.stderr
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    r = run("model", "--robot", str(bad))
    assert r.returncode == 2 and "cannot parse" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
