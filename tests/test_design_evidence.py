"""The design's evidence arithmetic (stickslip_jax/design/evidence.py, plan._greedy):
against a least-squares fit done directly, and the greedy choice on cases whose answer
is known."""

import numpy as np
import pytest

from stickslip_jax.design.evidence import Separation, absorbed, tolerance_rss
from stickslip_jax.design.hypotheses import Hypothesis, Question
from stickslip_jax.design.plan import _Asked, _greedy
from stickslip_jax.significance import Significance


def _blocks(rng, sizes, p):
    rows, start = [], 0
    for n in sizes:
        rows.append(slice(start, start + n))
        start += n
    return rng.standard_normal(start), rng.standard_normal((start, p)), rows


def test_the_separation_is_the_rivals_least_squares_misfit_with_recordings_repeated():
    rng = np.random.default_rng(3)
    e, jac, rows = _blocks(rng, [40, 25, 60, 33], 5)
    sep = Separation.of(e, jac, rows)
    weights = np.array([1, 0, 3, 2])
    # The same fit done directly: each recording's rows stacked as many times as taken.
    keep = np.concatenate([np.arange(r.start, r.stop) for r, w in zip(rows, weights,
                                                                      strict=True)
                           for _ in range(w)])
    delta = np.linalg.lstsq(jac[keep], -e[keep], rcond=None)[0]
    direct = float(np.sum((e[keep] + jac[keep] @ delta) ** 2))
    assert sep.at(weights) == pytest.approx(direct, rel=1e-9)
    assert sep.at(np.zeros(4)) == 0.0


def test_a_difference_the_rival_can_mimic_is_no_evidence_and_one_it_cannot_is_all():
    rng = np.random.default_rng(5)
    jac = rng.standard_normal((50, 3))
    rows = [slice(0, 50)]
    mimicked = jac @ np.array([0.3, -1.0, 2.0])
    assert Separation.of(mimicked, jac, rows).at([1.0]) == pytest.approx(0.0, abs=1e-9)
    q, _ = np.linalg.qr(jac)
    other = rng.standard_normal(50)
    other -= q @ (q.T @ other)
    assert Separation.of(other, jac, rows).at([1.0]) == pytest.approx(other @ other,
                                                                      rel=1e-9)


def test_a_quantity_the_recordings_do_not_determine_moves_nowhere():
    # Two identical columns (a scale the data fix only as a product): the fit is the
    # least-norm one, and the misfit that of either column alone.
    rng = np.random.default_rng(8)
    col = rng.standard_normal(30)
    e = rng.standard_normal(30)
    both = np.stack([col, col], axis=1)
    one = col[:, None]
    assert absorbed(both.T @ both, both.T @ e) == pytest.approx(
        absorbed(one.T @ one, one.T @ e), rel=1e-6)


def test_the_tolerance_on_the_recordings_as_taken_is_the_significance_modules():
    counts = np.array([1000, 2500, 1250])
    sigmas = np.array([1e-9, 1.2e-9, 0.8e-9])
    se = np.array([0.03, 0.05, 0.04])
    numerical = np.array([1e-12, 3e-12, 2e-12])
    sig = Significance(counts, sigmas, se, numerical, 3.0)
    chi2_num = (numerical / sigmas) ** 2
    assert tolerance_rss(np.ones(3), counts, se, chi2_num, 3.0) == pytest.approx(
        sig.tolerance_rss, rel=1e-12)
    # A recording taken twice: twice the samples, its σ known √2 better.
    doubled = Significance(np.array([1000, 5000, 1250]), sigmas,
                           np.array([0.03, 0.05 / np.sqrt(2), 0.04]), numerical, 3.0)
    assert tolerance_rss([1, 2, 1], counts, se, chi2_num, 3.0) == pytest.approx(
        doubled.tolerance_rss, rel=1e-12)


def _asked(e, jac, rows):
    dummy = Hypothesis("m", None, {})
    return _Asked(Question("limit", "x", dummy, dummy, 1.0), (Separation.of(e, jac, rows),))


def test_the_greedy_plan_takes_what_the_rival_cannot_mimic_within_the_time_given():
    rng = np.random.default_rng(11)
    jac_old = rng.standard_normal((40, 2))
    # The rival moved by -(1, 1) is the truth on the old recordings and on candidate 0:
    # only candidate 1 tells them apart.
    e_old = jac_old @ np.array([1.0, 1.0])
    jac_c = rng.standard_normal((20, 2))
    e_blind = jac_c @ np.array([1.0, 1.0])
    e_seen = rng.standard_normal(20)
    e = np.concatenate([e_old, e_blind, e_seen])
    jac = np.vstack([jac_old, jac_c, jac_c])
    rows = [slice(0, 40), slice(40, 60), slice(60, 80)]
    asked = [_asked(e, jac, rows)]
    w, taken = _greedy(asked, np.array([0.1, 0.1]), np.array([1.0, 0.0, 0.0]),
                       lambda w: 1.0, budget_s=0.35)
    assert [c for c, _ in taken] == [1, 1, 1]  # three units fit in 0.35 s
    np.testing.assert_array_equal(w, [1.0, 0.0, 3.0])
    # Nothing to gain: no unit taken, whatever the time.
    w, taken = _greedy([_asked(np.concatenate([e_old, e_blind, e_blind]), jac, rows)],
                       np.array([0.1, 0.1]), np.array([1.0, 0.0, 0.0]),
                       lambda w: 1.0, budget_s=1.0)
    assert taken == []
