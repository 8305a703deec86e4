"""The step count of s* from the virtual constraints' eigenvalue (``biped robust --steps
auto``): RABBIT keeps today's 10, a slowly converging gait gets enough steps for the
largest perturbation tried to decay below the tolerance."""
from __future__ import annotations

import math

import pytest

from analysis.robustness import RobustnessSettings, decay_steps
from analysis.stability.vc_map import vc_eigenvalue
from biped_casadi.simulation.perturbation import PAPER_SIZES


def test_rabbit_keeps_ten_steps(gait):
    st = RobustnessSettings()
    lam = vc_eigenvalue(gait).eigenvalue
    assert decay_steps(lam, st) == st.steps == 10


def test_slow_gait_gets_the_decay_count(gait3):
    st = RobustnessSettings()
    lam = abs(vc_eigenvalue(gait3).eigenvalue)
    n = decay_steps(lam, st)
    start = st.s_max * max(PAPER_SIZES)
    assert n > st.steps
    assert start * lam ** n <= st.tol < start * lam ** (n - 1)


def test_settings_steps_are_the_floor_and_bad_eigenvalues_refused():
    assert decay_steps(0.5, RobustnessSettings(steps=50)) == 50
    assert decay_steps(0.0) == RobustnessSettings().steps
    for bad in (1.0, -1.2, math.nan):
        with pytest.raises(ValueError, match="eigenvalue"):
            decay_steps(bad)


def test_m1_robust_notes_too_few_steps():
    """``biped m1 --robust`` says when its 10 steps only measure the convergence rate, and
    which ``biped robust`` command walks enough steps; nothing on a RABBIT-like rate."""
    from types import SimpleNamespace

    from analysis.cli.m1 import decay_note
    from analysis.design.codesign import CodesignSettings
    st = CodesignSettings()
    design = SimpleNamespace(M1=(0.5, -1.25), rejoin=0.75)
    slow = SimpleNamespace(vc_eigenvalue=0.85, design=design, gait_file="g.json")
    n = decay_steps(0.85, st.robustness_settings())
    note = decay_note(slow, st)
    assert f"--m1 0.5 -1.25 --rejoin 0.75 --steps auto' walks {n} steps" in note
    assert "--gait g.json" in note
    assert decay_note(SimpleNamespace(vc_eigenvalue=0.54, design=design,
                                      gait_file="g.json"), st) is None
    assert decay_note(SimpleNamespace(vc_eigenvalue=1.2, design=design,
                                      gait_file="g.json"), st) is None
