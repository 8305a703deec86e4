"""Output selection (paper §V-B): swing height, a and b, both groups, the M1 NLP."""
from __future__ import annotations

import numpy as np
import pytest

from analysis import poincare_eigenvalues
from analysis.design import (conjecture_figures, domain_grid, group_of, optimize_m1,
                                    solve_ab, swing_height_at_Td, taylor_ab)
from analysis.sweeps import grid_best


@pytest.fixture(scope="module")
def tay(model, gait):
    return taylor_ab(gait)


def test_taylor_coefficients_against_finite_differences(model, gait, tay):
    """a, b (AD) against z_sw along q^d(T) + M_T dq: the remainder is O(dq^3)."""
    assert abs(tay.z0) < 1e-10
    M1 = np.array([0.5, -1.0, 2.0, 0.3])
    rem = []
    for d in (2e-2, 1e-2, 5e-3):
        z = swing_height_at_Td(gait, M1[None], d)[0]
        rem.append(z - (tay.a(M1)[0] * d + tay.b(M1)[0] * d**2))
    ratios = [rem[0] / rem[1], rem[1] / rem[2]]
    np.testing.assert_allclose(ratios, 8.0, rtol=0.05)


def test_both_groups_satisfy_a_b_zero(model, gait, tay, rng):
    m2, m3 = rng.uniform(-10, 10, (2, 20))
    s = solve_ab(tay, m2, m3)
    for M in (s.group1, s.group2):
        ok = np.all(np.isfinite(M), axis=1)
        assert ok.sum() >= 10
        np.testing.assert_allclose(tay.a(M[ok]), 0, atol=1e-12)
        np.testing.assert_allclose(tay.b(M[ok]), 0, atol=1e-10)
        np.testing.assert_allclose(M[ok, 1], m2[ok])
        np.testing.assert_allclose(M[ok, 2], m3[ok])
    # the two groups are different roots, and group_of tells them apart
    i = np.flatnonzero(s.discriminant > 1e-6)[0]
    assert np.max(np.abs(s.group1[i] - s.group2[i])) > 1e-6
    assert group_of(tay, s.group1[i]) == 1 and group_of(tay, s.group2[i]) == 2
    # and on a group z_sw stays ~0 to third order for an error on q_u
    for d in (1e-2, 5e-3):
        z = swing_height_at_Td(gait, s.group1[i][None], d)[0]
        assert abs(z) < 50 * d**3


def test_conjecture_figures_are_computed(model, gait):
    from analysis.sweeps import grid_results
    r = grid_results(gait)
    P, st, mx = r.points, r.point_status, r.max_abs
    zsw = swing_height_at_Td(gait, P)
    c = conjecture_figures(zsw, mx, st)
    assert c["n_stable"] == int(np.sum(st == "stable")) > 0
    assert c["max_abs_zsw_stable"] >= 0 and 0 <= c["fraction_unstable_below"] <= 1


@pytest.fixture(scope="module")
def nlp2(model, gait):
    return optimize_m1(gait, group=2, n_best=6, n_ipopt=1, n_random=0)


def test_m1_nlp_group2(model, gait, tay, nlp2):
    r = nlp2
    assert r.group == 2
    assert abs(r.a) < 1e-9 and abs(r.b) < 1e-9
    # the reported max|lambda| is the full-AD map's at the returned M1
    check = poincare_eigenvalues(gait, r.M1, method="ad")
    assert check.max_abs == pytest.approx(r.max_abs, rel=1e-9, abs=1e-12)
    assert r.status == "stable"
    # no worse than the best point of the 9^4 grid, nor than the group's coarse map
    gb = grid_best(gait)
    assert r.max_abs <= gb["max_abs"]
    s = domain_grid(tay, 41)
    from analysis import poincare_map
    P = s.group2.reshape(-1, 4)
    P = P[np.all(np.isfinite(P), axis=1)]
    jb = poincare_map(gait).jacobian_batch(P)
    st, mx = jb.status, jb.max_abs
    assert r.max_abs <= np.min(mx[st != "singular"]) + 1e-12
    assert r.eigenvalue_uncertainty < 1e-2


def test_m1_nlp_runs_ipopt_only_until_a_deadbeat_point(model, gait, nlp2):
    """Newton reached deadbeat from the first start: IPOPT (whose epigraph is degenerate
    at rho = 0) is not run; without the Newton step it runs from every start it is
    given (its points kept only where valid and on the group), and the chosen M1 is
    still verified and on the group, never better than deadbeat."""
    assert nlp2.history[1]["how"] == "newton" and nlp2.ipopt_runs == 0
    assert not any(h["how"].startswith("ipopt") for h in nlp2.history)
    r = optimize_m1(gait, group=2, n_best=2, n_ipopt=2, n_random=0, deadbeat=False)
    assert r.ipopt_runs == 2
    assert {h["how"] for h in r.history} <= {"start", "ipopt"}
    assert r.group == 2 and abs(r.a) < 1e-9 and abs(r.b) < 1e-9
    assert r.max_abs >= nlp2.max_abs - nlp2.eigenvalue_uncertainty


def test_m1_nlp_says_when_it_stops_on_its_box(gait3, monkeypatch):
    """The three-link biped's free optimum lies outside a box |M1(i)| <= 1: IPOPT from
    inside the box ends on it, and the result says the search stopped on the bound
    instead of presenting it as an optimum; the default box holds the optimum inside."""
    import analysis.design.m1_nlp as m1_nlp
    free = optimize_m1(gait3, group=None)
    assert not free.at_bound and "bound" not in free.message
    box = 1.0
    assert np.max(np.abs(free.M1)) > 2 * box       # the premise: the optimum lies outside
    monkeypatch.setattr(m1_nlp, "M1_BOX", box)
    r = optimize_m1(gait3, group=None, starts=[[0.3, -0.3]], n_random=0, n_best=0,
                    deadbeat=False)
    assert r.ipopt_runs == 1 and np.max(np.abs(r.M1)) == pytest.approx(box, rel=1e-3)
    assert r.at_bound and "on the NLP's bound 1" in r.message, r.message
    assert r.max_abs > free.max_abs
def test_m1_nlp_names_bad_arguments(gait):
    """Checked before any work: NaN starts were dropped silently (random starts took
    their place), a negative count was taken, a path for the gait failed inside."""
    with pytest.raises(TypeError, match="^gait: a gait is needed"):
        optimize_m1("gait.json")
    with pytest.raises(ValueError, match="^starts must be finite$"):
        optimize_m1(gait, starts=[[np.nan, 0, 0, 0]])
    with pytest.raises(ValueError, match=r"^starts must be an array \(k, 4\) of M1, got shape \(1, 3\)"):
        optimize_m1(gait, starts=[1.0, 2.0, 3.0])
    for name in ("n_random", "n_best", "n_ipopt", "seed"):
        with pytest.raises(ValueError, match=f"^{name} must be a non-negative integer"):
            optimize_m1(gait, **{name: -1})
