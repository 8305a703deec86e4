"""`biped reproduce --quick` end to end into a temporary folder."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest


@pytest.mark.slow
def test_reproduce_quick(tmp_path, gait):
    out = tmp_path / "rep"
    r = subprocess.run([sys.executable, "-m", "analysis.cli", "reproduce", "--quick",
                        "--out", str(out), "--json"], capture_output=True, text=True,
                       timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    head = json.loads(r.stdout)
    assert all(v["status"] == "ok" for v in head["stages"].values()), head["stages"]
    s = json.loads((out / "summary.json").read_text())
    for key in ("gait", "singular", "fig2", "grid", "conjecture", "taylor", "domains",
                "m1_nlp", "vc_comparison", "simulation", "stages", "figures", "paper",
                "total_time"):
        assert key in s, key
    assert sum(s["grid"]["counts"].values()) == 9**4
    assert s["m1_nlp"]["group1"]["group"] == 1 and s["m1_nlp"]["group2"]["group"] == 2
    for name in ("gait_stick", "gait_profiles", "fig2", "fig3", "fig4", "fig5_qu_error",
                 "fig6_swing_torques"):
        for ext in (".png", ".pdf"):
            f = out / "figures" / f"{name}{ext}"
            assert f.is_file() and f.stat().st_size > 1000, f
    assert (out / "figures" / "walk_tv.gif").stat().st_size > 1000
    report = (out / "report.md").read_text()
    assert "| quantity | paper | ours |" in report and "figures/fig4.png" in report
    assert (out / "gait.json").is_file()


@pytest.mark.slow
def test_reproduce_quick_three_link(tmp_path, gait3):
    """The same kind of report for the second robot: gait, 1-D sweeps, the stable domain
    in the (M1(1), M1(2)) plane with every solution of a = b = 0, the M1 NLP, VC vs TV."""
    out = tmp_path / "rep3"
    r = subprocess.run([sys.executable, "-m", "analysis.cli", "reproduce", "--quick",
                        "--robot", "three_link", "--out", str(out), "--json"],
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    head = json.loads(r.stdout)
    assert all(v["status"] == "ok" for v in head["stages"].values()), head["stages"]
    s = json.loads((out / "summary.json").read_text())
    assert s["robot"]["name"] == "three_link" and s["robot"]["nu"] == 2
    assert "paper" not in s                  # the paper's numbers are RABBIT's
    assert s["grid"]["dim"] == 2 and sum(s["grid"]["counts"].values()) == s["grid"]["n"] ** 2
    assert s["domains"]["plane"] and s["domains"]["ab_set"]["kind"] == "line"
    assert set(s["m1_nlp"]) >= {"ab_line", "free"}
    assert s["m1_nlp"]["free"]["max_abs"] <= s["domains"]["best"]["max_abs"]
    assert s["vc_comparison"]["vc"]["status"] == "stable"
    for name in ("gait_stick", "fig2", "fig3", "m1_plane", "fig5_qu_error", "fig6_swing_torques"):
        assert (out / "figures" / f"{name}.png").stat().st_size > 1000, name
    report = (out / "report.md").read_text()
    assert "three_link" in report and "| quantity | ours | note |" in report
    assert "figures/m1_plane.png" in report
