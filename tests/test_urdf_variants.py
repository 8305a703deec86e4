"""URDFs as other tools write them, against Pinocchio built from the same file.

Variants of the packaged RABBIT and three-link robots (tests/urdf_variants.py): the zero
pose turned per joint (legs up, links across), link frames upside down, one leg's axes
flipped, the torso's centre of mass off its frame's z axis, a floating or planar root
with a world link, sensor frames (a massless IMU, a sensor with mass merged into its
link), continuous joints without limits, the legs listed right first, and centres of
mass off the links' lines (com_offset).  Each imports; at random states of the pinned
model, mapped to the file's coordinates for either stance leg by the imported joint map
(pitch and URDF joint angles) and to Pinocchio's floating base with the stance foot at
rest at the origin, the model's kinetic and potential energy equal Pinocchio's, and its D
and H equal Pinocchio's mass matrix and bias forces projected on the pinned motions
(D = G' M G, H = G' rnea(q, v, dG dq)), all to 1e-10.  The maps are the ones the geometry
implies (signs and offsets per joint), and variants of the same robot import to its own
description (1e-12).
"""
from __future__ import annotations

import math

import pytest
from urdf_variants import (dynamics_error, energy_error, pinocchio_model, random_states,
                           torque_error, variant_urdf)

from biped_casadi import BipedModel, Link, robot
from biped_casadi.model.urdf import import_urdf
from biped_casadi.model.urdf_map import wrap_angle

PI = math.pi


def _offsets(d, **kw):
    """The description with centres of mass off the links' lines."""
    t = d.torso
    leg = tuple(Link(link.name, link.mass, link.length, link.com, link.inertia,
                     com_offset=0.03 * (i + 1) * (-1) ** i) for i, link in enumerate(d.leg))
    torso = Link(t.name, t.mass, t.length, t.com, t.inertia, com_offset=0.0)
    return type(d)(d.name, torso, leg, d.point_masses, d.rotor_inertia, d.gravity,
                   d.torque_limit)


#: name -> (robot, variant keywords, changes the description?)
VARIANTS = {
    "rabbit-straight": ("rabbit", {}),
    "rabbit-turned": ("rabbit", dict(beta={("left", 0): 0.7, ("left", 1): -0.4,
                                           ("right", 0): PI, ("right", 1): 2.0},
                                     roll={("left", 1): True, ("right", 0): True},
                                     torso_tilt=0.3)),
    "rabbit-flipped-floating": ("rabbit", dict(axis={("right", 0): -1, ("right", 1): -1},
                                               beta={("left", 0): PI, ("right", 0): PI},
                                               floating=True, frames=True, continuous=True,
                                               right_first=True)),
    "rabbit-planar": ("rabbit", dict(planar=True, beta={("left", 1): -1.2})),
    "rabbit-offsets": ("rabbit+offsets", dict(beta={("left", 0): 0.5, ("right", 1): -2.5},
                                              axis={("left", 1): -1}, torso_tilt=-0.2)),
    "three_link-straight": ("three_link", {}),
    "three_link-turned": ("three_link", dict(beta={("left", 0): 2.0, ("right", 0): -PI / 3},
                                             roll={("right", 0): True},
                                             axis={("left", 0): -1}, continuous=True)),
    "three_link-offsets": ("three_link+offsets", dict(floating=True, frames=True,
                                                      beta={("right", 0): 1.0})),
}


def _description(which):
    name, _, extra = which.partition("+")
    d = robot(name).description
    return _offsets(d) if extra else d


@pytest.fixture(scope="module", params=sorted(VARIANTS))
def case(request, tmp_path_factory):
    which, kw = VARIANTS[request.param]
    d = _description(which)
    text = variant_urdf(d, **kw)
    path = tmp_path_factory.mktemp("variants") / f"{request.param}.urdf"
    path.write_text(text)
    imp = import_urdf(path)
    m = pinocchio_model(text, imp.description.rotor_inertia, imp.urdf_map.names)
    return dict(name=request.param, d=d, kw=kw, imp=imp, model=BipedModel(imp.description),
                pin=(m, m.createData()))


def _foot(umap, leg):
    return "foot_" + ("left" if "left" in umap.hips[leg - 1] else "right")


def _foot_of(case):
    return lambda leg: _foot(case["imp"].urdf_map, leg)


def _check(case, what, states, tol):
    model, umap, (m, data) = case["model"], case["imp"].urdf_map, case["pin"]
    worst = what(model, umap, m, data, _foot_of(case), states)
    assert worst <= tol, (case["name"], worst)


def test_energies_equal_pinocchio(case):
    _check(case, energy_error, random_states(case["model"].nq, 6, 3, span=1.2), 1e-10)


def test_D_and_H_equal_pinocchio_on_the_pinned_motions(case):
    _check(case, dynamics_error, random_states(case["model"].nq, 3, 5, span=1.2), 1e-10)


def test_the_map_is_the_geometry(case):
    """Signs and offsets per joint as the variant turned and flipped them; the robot
    itself as the base description (unless sensors with mass were merged in)."""
    kw, umap, d = case["kw"], case["imp"].urdf_map, case["d"]
    beta, axis = kw.get("beta", {}), kw.get("axis", {})
    tilt = kw.get("torso_tilt", 0.0)
    assert umap.pitch_offset == pytest.approx(tilt, abs=1e-12)
    for j in umap.joints:
        side = "left" if "left" in j.name else "right"
        i = j.position - 1
        want = wrap_angle(beta.get((side, i), 0.0) - (beta.get((side, i - 1), 0.0) if i else tilt))
        assert j.sign == axis.get((side, i), 1)
        assert abs(wrap_angle(j.offset - want)) <= 1e-12, (j, want)
    legs = [[j.name for j in umap.joints if j.leg == leg] for leg in (1, 2)]
    assert ("right" in legs[0][0]) == bool(kw.get("right_first"))
    got = case["imp"].description
    if not kw.get("frames"):
        for a, b in zip((got.torso,) + got.leg, (d.torso,) + d.leg):
            for f in ("mass", "length", "com", "com_offset", "inertia"):
                assert getattr(a, f) == pytest.approx(getattr(b, f), abs=1e-12), (a, f)
        assert got.rotor_inertia == pytest.approx(d.rotor_inertia, rel=1e-12)
    limit = math.inf if kw.get("continuous") else d.torque_limit
    assert got.torque_limit == limit
    assert any("no torque limit" in n for n in case["imp"].notes) == (limit == math.inf)


def test_torques_map_to_pinocchio_joint_torques(case):
    """The URDF joints' torques of the map deliver the model's generalised forces: with
    Pinocchio's joint torques tau (zero on the base), G' tau = B u."""
    model, umap, (m, data) = case["model"], case["imp"].urdf_map, case["pin"]
    assert torque_error(model, umap, m, data, _foot_of(case)) <= 1e-12
