"""analysis.estimators: the intervals are Student's and Welch's, the bootstrap is rliable's with an
explicit generator, and the verdict counts three standard errors."""

import math

import numpy as np
import scipy.stats
from rliable import library as rly

from analysis import estimators, report


def test_t_interval_is_students_and_welchs():
    values = np.array([-414.3, -169.0, -0.8, 125.9, -559.3])
    mean, low, high = estimators.t_interval(values)
    expected = scipy.stats.t.interval(0.95, values.size - 1, loc=values.mean(),
                                      scale=scipy.stats.sem(values))
    assert np.isclose(mean, values.mean()) and np.allclose((low, high), expected)
    assert np.allclose((low, high), (-555.7, 148.7), atol=0.05)  # bookshelf_simple at 1M
    assert np.isnan(estimators.t_interval(np.array([3.0]))[1:]).all()
    assert estimators.t_interval(np.full(4, 2.0)) == (2.0, 2.0, 2.0)
    # Zero inside [-555.7, 148.7]; a bound on zero leaves it inside; one seed decides nothing.
    assert not estimators.excludes_zero((mean, low, high))
    assert estimators.excludes_zero((-1.0, -2.0, -0.5)) and estimators.excludes_zero((1, 0.5, 2))
    assert not estimators.excludes_zero((1.0, 0.0, 2.0))
    assert not estimators.excludes_zero(estimators.t_interval(np.array([3.0])))
    # Over tasks: one task is Student's interval; two are Welch's, Satterthwaite's df.
    assert np.allclose(estimators.welch_interval([values]), (mean, low, high))
    other = np.array([0.1, 0.4, 0.2])
    v1, v2 = values.var(ddof=1) / 5, other.var(ddof=1) / 3
    df = (v1 + v2) ** 2 / (v1**2 / 4 + v2**2 / 2)
    half = scipy.stats.t.ppf(0.975, df) * np.sqrt(v1 + v2) / 2
    centre = (values.mean() + other.mean()) / 2
    assert np.allclose(estimators.welch_interval([values, other]),
                       (centre, centre - half, centre + half))


def test_the_bootstrap_draws_what_rliable_draws_after_seeding_the_global_generator():
    """The committed reports' bootstrap numbers were rliable's: the explicit generator keeps
    them, for one column (evaluate.py's episodes) and several (analyze.py's tasks at once)."""
    rng = np.random.default_rng(7)
    for values in (rng.normal(size=300), rng.normal(size=(5, 4))):
        matrix = values[:, None] if values.ndim == 1 else values
        np.random.seed(3)  # noqa: NPY002
        point, interval = rly.get_interval_estimates(
            {"x": matrix}, lambda s: s.mean(axis=0), reps=500, confidence_interval_size=0.95)
        mean, low, high = estimators.bootstrap_mean(values, 500, np.random.RandomState(3))
        assert np.array_equal(np.ravel(mean), point["x"])
        assert np.array_equal(np.ravel(low), interval["x"][0])
        assert np.array_equal(np.ravel(high), interval["x"][1])
    # the generator is the caller's: another seed, another interval
    values = rng.normal(size=20)
    assert estimators.bootstrap_mean(values, 200, np.random.RandomState(0)) != \
        estimators.bootstrap_mean(values, 200, np.random.RandomState(1))


def test_paired_difference_verdict_and_one_run_without_interval():
    assert np.array_equal(estimators.paired_difference([3.0, 1.0], [1.0, 1.5]), [2.0, -0.5])
    try:
        estimators.paired_difference([1.0, 2.0], [1.0])
    except ValueError as error:
        assert "unpaired" in str(error)
    else:
        raise AssertionError("unpaired returns were accepted")
    assert estimators.standard_error(np.array([1.0, 3.0])) == 1.0
    assert math.isnan(estimators.standard_error(np.array([1.0])))
    assert estimators.verdict(3.1, 1.0) == "ahead" and estimators.verdict(-3.1, 1.0) == "behind"
    assert estimators.verdict(3.0, 1.0) == "level" and estimators.verdict(1.0, math.nan) == "n/a"
    assert report.interval_text(0.02, 0.02, 0.02, runs=1) == "0.020 (n/a)"
    assert report.interval_text(0.5, 0.25, 0.75) == "0.500 [0.250, 0.750]"
    assert report.interval_text(0.5, math.nan, math.nan) == "0.500 (n/a)"
