"""Every Poincaré method checks the fixed point: on a trajectory that is not a periodic
orbit of the model (the default gait with its initial velocity changed by 0.01 rad/s)
the default ('variational') method, the AD method, the batch and the
virtual-constraint map say 'open_orbit' with the residual; on the gait itself they do
not."""
from __future__ import annotations

import json

import numpy as np
import pytest

from analysis import poincare_eigenvalues, vc_eigenvalue
from analysis.cli import main
from analysis.stability import poincare_map
from analysis.stability.poincare import FIXED_POINT_TOL
from gait_opt import Gait

M1 = np.array([0.2, -0.3, 0.1, 0.0])


@pytest.fixture(scope="module")
def open_gait(model, gait):
    g = Gait(model, gait.options, gait.alpha, gait.x0 + np.array([0.0, 0.01]), gait.T)
    assert g.orbit_residual()["worst"] > 1e-3
    return g


@pytest.mark.parametrize("method", ["variational", "ad"])
def test_open_orbit_is_reported(model, gait, open_gait, method):
    ok = poincare_eigenvalues(gait, M1, method=method)
    assert ok.status in ("stable", "unstable") and ok.fixed_point_residual < 1e-8
    r = poincare_eigenvalues(open_gait, M1, method=method)
    assert r.status == "open_orbit" and not r.success
    assert r.fixed_point_residual > 1e-2 > FIXED_POINT_TOL
    assert "not a fixed point" in r.message and "not a periodic orbit" in r.message


def test_open_orbit_batch_and_vc(model, gait, open_gait):
    batch = poincare_map(open_gait).jacobian_batch(np.array([M1, 0.5 * M1]))
    assert list(batch.status) == ["open_orbit", "open_orbit"]
    assert set(poincare_map(gait).jacobian_batch(np.array([M1])).status) <= {
        "stable", "unstable"}
    vc = vc_eigenvalue(open_gait)
    assert vc.status == "open_orbit" and vc.orbit_mismatch > 1e-2
    assert vc_eigenvalue(gait).status == "stable"


def test_cli_eig_reports_the_open_orbit(open_gait, tmp_path, capsys):
    path = open_gait.save(tmp_path / "open.json")
    assert main(["eig", "--gait", str(path), "--m1", *map(str, M1), "--json"]) == 2
    assert "not a periodic orbit" in capsys.readouterr().err       # refused by default
    assert main(["eig", "--gait", str(path), "--allow-open-orbit", "--m1", *map(str, M1),
                 "--json"]) == 0
    body = json.loads(capsys.readouterr().out)
    assert body["status"] == "open_orbit" and body["fixed_point_residual"] > 1e-2


def test_open_orbit_residual_says_for_which_M1(open_gait):
    """The variational method checks the fixed point once, with M1 = 0: its message says
    so (the residual differs from the AD method's, taken with the M1 asked for)."""
    v = poincare_eigenvalues(open_gait, M1)
    a = poincare_eigenvalues(open_gait, M1, method="ad")
    assert "(with M1 = 0)" in v.message and "(with M1 = 0)" not in a.message
    assert abs(v.fixed_point_residual - a.fixed_point_residual) > 1e-6
