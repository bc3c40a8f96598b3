"""The statistics analyze.py and evaluate.py share: plain functions over arrays.

A paired difference is an action's return minus tanh(mu)'s from the same start state (per
episode) or the mean of those (per seed). Over seeds: Student's t-interval, Welch's interval
over tasks, and the percentile bootstrap of a mean with an explicit generator. Per seed: the
verdict, ahead / level / behind by three standard errors of its paired episodes. An estimate
from one run has no interval: `interval_text` prints "n/a" for it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import scipy.stats

CONFIDENCE = 0.95
BASELINE = "tanh_mu"  # the action every other one is compared with: Standard SAC's
VERDICT_SE = 3.0  # a seed is ahead or behind when its difference is this many SEs from zero
# Up to this many seeds a percentile bootstrap of the mean is narrower than the data allow: it
# only resamples the few values seen, so a t-interval goes beside it or the figure says so.
FEW_SEEDS = 5


def paired_difference(returns: np.ndarray, baseline: np.ndarray) -> np.ndarray:
    """Returns minus the baseline's, element by element: the same start state, or the same
    seed's actor."""
    returns, baseline = np.asarray(returns, dtype=float), np.asarray(baseline, dtype=float)
    if returns.shape != baseline.shape:
        raise ValueError(f"unpaired: {returns.shape} values against {baseline.shape}")
    return returns - baseline


def standard_error(values: np.ndarray) -> float:
    """sd / sqrt(n); NaN for one value."""
    values = np.asarray(values, dtype=float)
    return float(values.std(ddof=1) / math.sqrt(values.size)) if values.size > 1 else math.nan


def verdict(mean: float, se: float) -> str:
    """A seed's paired difference (the mean over its episodes, with their standard error):
    "ahead" or "behind" when more than VERDICT_SE standard errors from zero, else "level";
    "n/a" without a standard error (one episode)."""
    if math.isnan(se):
        return "n/a"
    if abs(mean) <= VERDICT_SE * se:
        return "level"
    return "ahead" if mean > 0 else "behind"


def fall_verdict(mean: float, se: float) -> str:
    """verdict() for a paired difference in the share of episodes that fell, where more is
    worse: "more" or "fewer" beyond VERDICT_SE standard errors, else "level"."""
    word = verdict(mean, se)
    return {"ahead": "more", "behind": "fewer"}.get(word, word)


def t_interval(values: np.ndarray, confidence: float = CONFIDENCE) -> tuple[float, float, float]:
    """(mean, low, high) of one value per seed: mean +- t_{n-1} * sd / sqrt(n).

    Unlike a percentile bootstrap, Student's interval widens as the seeds get few, which is what
    five seeds allow. NaN bounds with one seed, where no spread is seen.
    """
    values = np.asarray(values, dtype=float)
    mean = float(values.mean())
    if values.size < 2:
        return mean, math.nan, math.nan
    quantile = scipy.stats.t.ppf(0.5 + confidence / 2, values.size - 1)
    half = float(quantile * values.std(ddof=1) / math.sqrt(values.size))
    return mean, mean - half, mean + half


def welch_interval(per_task: Sequence[np.ndarray], confidence: float = CONFIDENCE
                   ) -> tuple[float, float, float]:
    """(mean, low, high) of the mean over tasks of each task's mean over seeds: Welch's interval
    with Satterthwaite's degrees of freedom, each task's seeds independent of the others' (as
    rliable's stratified bootstrap draws them). NaN bounds when a task has one seed."""
    mean = float(np.mean([np.mean(v) for v in per_task]))
    if any(np.size(v) < 2 for v in per_task):
        return mean, math.nan, math.nan
    terms = np.array([np.var(v, ddof=1) / np.size(v) for v in per_task])
    total = float(terms.sum())
    if total == 0:
        return mean, mean, mean
    df = total**2 / sum(term**2 / (np.size(v) - 1) for term, v in zip(terms, per_task,
                                                                       strict=True))
    half = scipy.stats.t.ppf(0.5 + confidence / 2, df) * math.sqrt(total) / len(per_task)
    return mean, mean - half, mean + half


def bootstrap_mean(values: np.ndarray, reps: int, rng: np.random.RandomState,
                   confidence: float = CONFIDENCE) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean, low, high) of each column of a (runs,) or (runs, tasks) array: the percentile
    bootstrap, runs resampled within each column, `reps` replications.

    A legacy RandomState seeded s draws what rliable's get_interval_estimates draws after
    np.random.seed(s) (rliable ignores its random_state), so the numbers are rliable's. With
    one run the interval collapses onto the point: print it with `interval_text(..., runs=1)`."""
    values = np.asarray(values, dtype=float)
    flat = values.ndim == 1
    matrix = values[:, None] if flat else values
    runs, columns = matrix.shape
    means = matrix[rng.choice(runs, (reps, runs, columns)), np.arange(columns)].mean(axis=1)
    tail = 100 * (1 - confidence) / 2
    low, high = np.percentile(means, [tail, 100 - tail], axis=0)
    point = matrix.mean(axis=0)
    return (point[0], low[0], high[0]) if flat else (point, low, high)


def interval_text(point: float, low: float, high: float, digits: int = 3, runs: int = 2
                  ) -> str:
    """"0.123 [0.100, 0.150]"; "0.123 (n/a)" where there is no interval: NaN bounds, or an
    estimate from one run, whose bootstrap resamples that run alone."""
    if runs < 2 or math.isnan(low) or math.isnan(high):
        return f"{point:.{digits}f} (n/a)"
    return f"{point:.{digits}f} [{low:.{digits}f}, {high:.{digits}f}]"


def seed_mean_estimates(samples: dict[tuple, np.ndarray], reps: int, seed: int
                        ) -> dict[tuple, tuple[float, float, float]]:
    """(task, group) -> (mean, low, high) of one value per seed: bootstrap_mean, each batch
    drawn from RandomState(seed), as rliable's get_interval_estimates draws after
    np.random.seed(seed).

    The tasks of a group with equal seed counts share one bootstrap: it resamples each task's
    seeds independently, so each task's interval is distributed as in a bootstrap of its own,
    at a fraction of the cost.
    """
    batches: dict[tuple, list] = {}
    for (task, group), values in samples.items():
        batches.setdefault((group, values.size), []).append(task)
    estimates = {}
    for (group, _), batch in batches.items():
        scores = np.stack([samples[task, group] for task in batch], axis=1)
        point, low, high = bootstrap_mean(scores, reps, np.random.RandomState(seed))
        for i, task in enumerate(batch):
            estimates[task, group] = (float(point[i]), float(low[i]), float(high[i]))
    return estimates
