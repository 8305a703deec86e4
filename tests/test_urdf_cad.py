"""URDF files as CAD exporters really write them: angles rounded to a few decimals (rpy
1.5708 for pi/2), and mirrored legs whose masses, centres of mass and inertias differ in
the last digits.  The joint axes then agree only to 1e-6 .. 1e-4 rad: the import takes
axes within ``AXIS_TOL`` (1e-3 rad) as parallel, turns every joint about their mean axis
and says so; legs that differ by less than ``match_tol`` (relative to the leg's size)
import as their mean, and by more are refused with the tolerance that would take them.

The robot is the 3-D biped of tests/urdf_variants.py (``biped3d_urdf``), its sagittal
model locked as in tests/test_urdf_lock.py.  Measured, not assumed: the model of the
rounded file against Pinocchio's reduced model of the same rounded file (which turns each
joint about its own rounded axis) agrees to the size of the rounding.
"""
from __future__ import annotations

import re

import numpy as np
import pytest
from test_urdf_lock import SAGITTAL, _same
from urdf_variants import biped3d_urdf, energy_error, pinocchio_reduced, random_states

from analysis.cli import main
from biped_casadi import BipedModel
from biped_casadi.model.urdf import MAX_MATCH_TOL, import_urdf
from biped_casadi.model.urdf_tree import AXIS_TOL


def _rounded(text: str, decimals: int) -> str:
    """Every rpy written to ``decimals`` decimals, as exporters print them."""
    def fmt(m):
        return 'rpy="' + " ".join(f"{float(v):.{decimals}f}" for v in m.group(1).split()) + '"'
    return re.sub(r'rpy="([^"]*)"', fmt, text)


def _heavier_right(text: str, rel: float) -> str:
    """The right leg's links ``rel`` heavier (a mirrored CAD part's own mass)."""
    def fmt(m):
        return f'{m.group(1)}<mass value="{float(m.group(2)) * (1 + rel)!r}"/>'
    return re.sub(r'(<link name="[a-z_]+_r">\s*<inertial>.*?)<mass value="([^"]*)"/>', fmt,
                  text, flags=re.S)


def _write(tmp_path, text, name):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.fixture(scope="module")
def exact():
    return biped3d_urdf()


@pytest.mark.parametrize("decimals", [3, 4, 6])
def test_rounded_angles_import_about_the_mean_axis(tmp_path, exact, decimals):
    """Angles rounded to a few decimals: imported, the largest deviation of the axes
    from their mean said in the notes, and the robot equals the exact file's to the
    rounding (not exactly: the rounding is seen); the exact file's notes say nothing of
    it."""
    ref = import_urdf(_write(tmp_path, exact, "exact.urdf"), lock=SAGITTAL)
    assert not any("rounded angles" in n for n in ref.notes)
    imp = import_urdf(_write(tmp_path, _rounded(exact, decimals), "r.urdf"), lock=SAGITTAL)
    note = [n for n in imp.notes if n.startswith("the leg joints' axes are parallel within")]
    assert len(note) == 1, imp.notes
    spread = float(re.search(r"within (\S+) rad", note[0]).group(1))
    assert 1e-9 < spread < min(AXIS_TOL, 2 * 10.0 ** -decimals)
    _same(imp.description, ref.description, tol=10.0 ** (1 - decimals))
    with pytest.raises(AssertionError):
        _same(imp.description, ref.description, tol=1e-10)


@pytest.mark.parametrize("decimals", [3, 4, 6])
def test_rounded_model_against_pinocchio_on_the_rounded_file(tmp_path, exact, decimals):
    """The planar model of the rounded file against Pinocchio's reduced model of that file
    (each joint about its own rounded axis): kinetic and potential energy agree within a
    tenth of the axes' spread (measured: 0.016 of it at 3.7e-6 and 3.3e-7 rad), where the
    exact file agrees to round-off (tests/test_urdf_lock.py)."""
    text = _rounded(exact, decimals)
    imp = import_urdf(_write(tmp_path, text, "r.urdf"), lock=SAGITTAL)
    spread = float(re.search(r"parallel within (\S+) rad", " ".join(imp.notes)).group(1))
    m = pinocchio_reduced(text, imp.description.rotor_inertia, imp.urdf_map.names, SAGITTAL)
    model, umap = BipedModel(imp.description), imp.urdf_map
    worst = energy_error(model, umap, m, m.createData(),
                         lambda leg: f"sole_{umap.hips[leg - 1][-1]}",
                         random_states(model.nq, 5, 3))
    assert 1e-10 < worst <= 0.1 * spread, (worst, spread)


def test_a_joint_tilted_beyond_the_tolerance_is_refused(tmp_path, exact):
    """A knee axis 3e-3 rad off the others (a real tilt, not a rounding): refused."""
    text = exact.replace('<joint name="knee_l"', '<joint name="knee_l"', 1)
    m = re.search(r'(<joint name="knee_l".*?<axis xyz=")([^"]*)(")', text, flags=re.S)
    a = np.array([float(v) for v in m.group(2).split()])
    tilt = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 0.0, 1.0])
    b = a + 3e-3 * tilt / np.linalg.norm(tilt)
    text = text[:m.start(2)] + " ".join(repr(float(v)) for v in b) + text[m.end(2):]
    with pytest.raises(ValueError, match=r"joint 'knee_l' turns about .* not a planar robot"):
        import_urdf(_write(tmp_path, text, "tilted.urdf"), lock=SAGITTAL)


def test_mirrored_legs_that_differ_import_as_their_mean_within_match_tol(tmp_path, exact):
    """The right leg 5e-5 heavier: refused by default naming the tolerance that takes it;
    with it, the model's link masses are the two legs' means (said in the notes); a
    difference beyond any tolerance names none."""
    path = _write(tmp_path, _heavier_right(exact, 5e-5), "heavy.urdf")
    with pytest.raises(ValueError, match=r"legs differ: link 'thigh_l' has mass .* of the "
                                         r"leg's mass\); match_tol 1e-09 allows less: "
                                         r"--match-tol 5e-05 \(match_tol=\) takes their "
                                         r"mean"):
        import_urdf(path, lock=SAGITTAL)
    ref = import_urdf(_write(tmp_path, exact, "exact.urdf"), lock=SAGITTAL).description
    imp = import_urdf(path, lock=SAGITTAL, match_tol=1e-4)
    for a, b in zip(imp.description.leg, ref.leg):
        assert a.mass == pytest.approx(b.mass * (1 + 2.5e-5), rel=1e-12)
    assert any(n.startswith("the legs differ by up to") and "the model's leg is their mean"
               in n for n in imp.notes), imp.notes
    with pytest.raises(ValueError, match=r"beyond any match_tol, at most 0\.05: too different"):
        import_urdf(_write(tmp_path, _heavier_right(exact, 0.3), "h2.urdf"), lock=SAGITTAL,
                    match_tol=MAX_MATCH_TOL)


@pytest.mark.parametrize("bad", [0.0, -1e-3, 0.06, float("nan"), "1e-3", True])
def test_bad_match_tol(tmp_path, exact, bad):
    with pytest.raises(ValueError, match=r"match_tol must be a number in \(0, 0\.05\]"):
        import_urdf(_write(tmp_path, exact, "e.urdf"), lock=SAGITTAL, match_tol=bad)


def test_cli_match_tol(tmp_path, exact, capsys):
    path = str(_write(tmp_path, _rounded(_heavier_right(exact, 5e-5), 4), "cad.urdf"))
    locks = [f"{k}" for k in SAGITTAL]
    out = str(tmp_path / "r.toml")
    assert main(["robot", "import", path, "--lock", *locks, "--out", out]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--match-tol 5e-05" in err[0], err
    assert main(["robot", "import", path, "--lock", *locks, "--match-tol", "1e-4",
                 "--out", out]) == 0
    text = capsys.readouterr().out
    assert "note: the legs differ by up to" in text and "rounded angles" in text
    for bad in ("0", "0.5", "nan"):
        assert main(["robot", "import", path, "--lock", *locks, "--match-tol", bad,
                     "--out", out]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--match-tol must be a number in (0, 0.05]" in err[0], err


def test_foot_beyond_the_locked_ankle(tmp_path, exact):
    """Without a sole frame the foot is the locked ankle; ``foot_beyond`` moves it along
    the shin's line: the shin exactly that much longer, every other number the same;
    one line and exit 2 for a bad distance."""
    text = biped3d_urdf(sole=False)
    path = _write(tmp_path, text, "nosole.urdf")
    ankle = import_urdf(path, lock=SAGITTAL)
    assert any("--foot-beyond D" in n for n in ankle.notes)
    imp = import_urdf(path, lock=SAGITTAL, foot_beyond=0.05)
    a, b = ankle.description, imp.description
    assert b.leg[-1].length == pytest.approx(a.leg[-1].length + 0.05, abs=1e-12)
    for x, y in zip((a.torso,) + a.leg, (b.torso,) + b.leg):
        for f in ("mass", "com", "com_offset", "inertia") + (("length",) if x is not a.leg[-1]
                                                             else ()):
            assert getattr(x, f) == pytest.approx(getattr(y, f), abs=1e-12), (x.name, f)
    assert imp.foot.endswith("+ 0.05 m") and any("foot_beyond" in n for n in imp.notes)
    for bad in (-0.01, float("nan"), 11.0, True):
        with pytest.raises(ValueError, match=r"foot_beyond must be a number of metres"):
            import_urdf(path, lock=SAGITTAL, foot_beyond=bad)


def test_cli_foot_beyond(tmp_path, capsys):
    path = str(_write(tmp_path, biped3d_urdf(sole=False), "nosole.urdf"))
    locks = [f"{k}" for k in SAGITTAL]
    out = str(tmp_path / "r.toml")
    assert main(["robot", "import", path, "--lock", *locks, "--foot-beyond", "0.05",
                 "--out", out, "--json"]) == 0
    assert capsys.readouterr().out.count("+ 0.05 m") >= 1
    assert main(["robot", "import", path, "--lock", *locks, "--foot-beyond", "-1",
                 "--out", out]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--foot-beyond must be a distance in [0, 10] m" in err[0], err
