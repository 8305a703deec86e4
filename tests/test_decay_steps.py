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


def test_vc_s_star_says_its_steps_when_they_are_too_few():
    """Virtual constraints' s* beside the design's is measured over the same steps; where
    those are too few for their rate (its 0 is then a rate, not a fall) the lines say
    'over the same N steps' and the note names the command for their s* over enough; at
    a RABBIT-like rate nothing is added."""
    from types import SimpleNamespace

    import numpy as np

    from analysis.cli.m1 import decay_note, no_design_reason
    from analysis.design.codesign import CodesignSettings
    from analysis.design.codesign.method import same_steps
    from analysis.robustness import steps_short
    st = CodesignSettings()
    rs = st.robustness_settings()
    assert steps_short(0.85, rs) == decay_steps(0.85, rs) > rs.steps
    assert steps_short(0.54, rs) is None and steps_short(1.2, rs) is None
    assert same_steps(0.54, rs) == same_steps(-1.2, rs) == ""
    design = SimpleNamespace(M1=np.array([0.5, -1.25]), rejoin=0.75)
    for lam, tail in ((0.85, f"s* 0 over the same {rs.steps} steps"), (0.54, "s* 0")):
        r = SimpleNamespace(status="target_not_met", max_abs=0.9, vc_eigenvalue=lam,
                            s_star=0.0, vc_s_star=0.0, binds={}, steps_to_converge=None,
                            check=SimpleNamespace(failure="fell", paper_status="fell"),
                            settings=st.to_dict(), design=design, gait_free=False,
                            gait_file="g.json")
        assert no_design_reason(r, st).endswith(f"virtual constraints reach {tail}")
    r.vc_eigenvalue = 0.85
    assert "--controller vc instead of --m1 and --rejoin: virtual constraints' s* there" \
        in decay_note(r, st)
