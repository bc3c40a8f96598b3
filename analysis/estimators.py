"""Every estimate analyze.py and evaluate.py make, each with its interval: plain functions over
arrays, as rliable's library and metrics are.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence

import numpy as np
import scipy.stats
from rliable import library as rly
from rliable import metrics

CONFIDENCE = 0.95
BASELINE = "tanh_mu"  # the action every other one is compared with: Standard SAC's
VERDICT_SE = 3.0  # a seed is ahead or behind when its difference is this many SEs from zero
# Up to this many seeds a percentile bootstrap of the mean is narrower than the data allow: it
# only resamples the few values seen, so a t-interval goes beside it or the figure says so.
FEW_SEEDS = 5


def paired_difference(returns: np.ndarray, baseline: np.ndarray) -> np.ndarray:
    """Returns minus the baseline's, element by element (the same start, or the same actor)."""
    returns, baseline = np.asarray(returns, dtype=float), np.asarray(baseline, dtype=float)
    if returns.shape != baseline.shape:
        raise ValueError(f"unpaired: {returns.shape} values against {baseline.shape}")
    return returns - baseline


def standard_error(values: np.ndarray) -> float:
    """sd / sqrt(n); NaN for one value."""
    values = np.asarray(values, dtype=float)
    return float(values.std(ddof=1) / math.sqrt(values.size)) if values.size > 1 else math.nan


def verdict(mean: float, se: float) -> str:
    """A seed's paired difference (mean over its episodes, their standard error): "ahead" or
    "behind" beyond VERDICT_SE standard errors from zero, else "level"; "n/a" for one episode."""
    if math.isnan(se):
        return "n/a"
    if abs(mean) <= VERDICT_SE * se:
        return "level"
    return "ahead" if mean > 0 else "behind"


def fall_verdict(mean: float, se: float) -> str:
    """verdict() for a paired difference in the share of episodes that fell: "more", "fewer"."""
    word = verdict(mean, se)
    return {"ahead": "more", "behind": "fewer"}.get(word, word)


def t_interval(values: np.ndarray) -> tuple[float, float, float]:
    """(mean, low, high) of one value per seed: mean +- t_{n-1} * sd / sqrt(n), which unlike a
    percentile bootstrap widens as the seeds get few. NaN bounds with one seed."""
    values = np.asarray(values, dtype=float)
    mean = float(values.mean())
    if values.size < 2:
        return mean, math.nan, math.nan
    quantile = scipy.stats.t.ppf(0.5 + CONFIDENCE / 2, values.size - 1)
    half = float(quantile * values.std(ddof=1) / math.sqrt(values.size))
    return mean, mean - half, mean + half


def excludes_zero(interval: tuple[float, float, float]) -> bool:
    """Whether a (mean, low, high) interval lies wholly on one side of zero (False with NaN
    bounds: one seed decides nothing)."""
    _, low, high = interval
    return bool(low > 0 or high < 0)


def welch_interval(per_task: Sequence[np.ndarray]) -> tuple[float, float, float]:
    """(mean, low, high) of the mean over tasks of each task's mean over seeds: Welch's interval
    with Satterthwaite's degrees of freedom, the tasks' seeds independent (as rliable's
    stratified bootstrap draws them). NaN bounds when a task has one seed."""
    mean = float(np.mean([np.mean(v) for v in per_task]))
    if any(np.size(v) < 2 for v in per_task):
        return mean, math.nan, math.nan
    terms = np.array([np.var(v, ddof=1) / np.size(v) for v in per_task])
    total = float(terms.sum())
    if total == 0:
        return mean, mean, mean
    df = total**2 / sum(term**2 / (np.size(v) - 1) for term, v in zip(terms, per_task,
                                                                       strict=True))
    half = scipy.stats.t.ppf(0.5 + CONFIDENCE / 2, df) * math.sqrt(total) / len(per_task)
    return mean, mean - half, mean + half


def bootstrap_mean(values: np.ndarray, reps: int, rng: np.random.RandomState
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean, low, high) of each column of a (runs,) or (runs, tasks) array: the percentile
    bootstrap, runs resampled within each column. A RandomState(s) draws what rliable's
    get_interval_estimates draws after np.random.seed(s), so the numbers are rliable's."""
    values = np.asarray(values, dtype=float)
    flat = values.ndim == 1
    matrix = values[:, None] if flat else values
    runs, columns = matrix.shape
    means = matrix[rng.choice(runs, (reps, runs, columns)), np.arange(columns)].mean(axis=1)
    tail = 100 * (1 - CONFIDENCE) / 2
    low, high = np.percentile(means, [tail, 100 - tail], axis=0)
    point = matrix.mean(axis=0)
    return (point[0], low[0], high[0]) if flat else (point, low, high)


def seed_mean_estimates(samples: dict[tuple, np.ndarray], reps: int, seed: int
                        ) -> dict[tuple, tuple[float, float, float]]:
    """(task, group) -> (mean, low, high) of one value per seed: bootstrap_mean from
    RandomState(seed). The tasks of a group with equal seed counts share one bootstrap, which
    resamples each task's seeds independently: each interval is distributed as on its own."""
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


# ---------------------------------------------------------------------- rliable's estimators
# Seeded so that a folder and --seed give the same numbers. A copy of rliable's own (bootstrap_mean,
# iqm, iqm_per_step) is for speed only: bench/bench_analyze.py --copies times both, tests pin them.
def seed_bootstrap(seed: int) -> None:
    """rliable's bootstraps draw from NumPy's legacy global generator (random_state is ignored)."""
    np.random.seed(seed)  # noqa: NPY002


def interval_estimates(
    score_dict: dict, func: Callable[..., np.ndarray], reps: int, seed: int
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """rliable's stratified-bootstrap point and interval estimates, reproducible by `seed`."""
    seed_bootstrap(seed)
    return rly.get_interval_estimates(
        score_dict, func, reps=reps, confidence_interval_size=CONFIDENCE)


def difference_over_tasks(per_task: Sequence[np.ndarray], reps: int, seed: int
                          ) -> tuple[np.ndarray, tuple[float, float, float],
                                     tuple[float, float, float]]:
    """A paired difference over tasks, each task's per-seed values already scaled: the (seeds,
    tasks) matrix (the lowest seeds, where tasks have more), the mean over tasks with rliable's
    stratified bootstrap CI (seeds resampled within each fixed task) and Welch's interval."""
    seeds = min(values.size for values in per_task)
    matrix = np.stack([values[:seeds] for values in per_task], axis=1)
    point, interval = interval_estimates({"": matrix}, metrics.aggregate_mean, reps, seed)
    boot = (float(point[""]), *map(float, interval[""].ravel()))
    return matrix, boot, welch_interval(list(matrix.T))


AGGREGATE_METRICS = ("IQM", "Median", "Mean", "Optimality Gap")


def iqm(scores: np.ndarray) -> np.float64:
    """metrics.aggregate_iqm (scipy's 25% trimmed mean): the same partition and mean, the same
    bits, without scipy's per-call checks (~0.3 ms, most of a bootstrap's time)."""
    flat = scores.ravel()
    if np.isnan(flat).any():  # scipy's default nan_policy, "propagate"
        return np.float64(np.nan)
    cut = int(0.25 * flat.size)
    return np.mean(np.partition(flat, (cut, flat.size - cut - 1))[cut:flat.size - cut])


def aggregate_metrics(scores: np.ndarray, gap: bool = True) -> np.ndarray:
    """IQM, median, mean (and optimality gap) of a (runs x tasks) score matrix."""
    values = [iqm(scores), metrics.aggregate_median(scores), metrics.aggregate_mean(scores)]
    return np.array(values + [metrics.aggregate_optimality_gap(scores)] * gap)


def iqm_per_step(scores: np.ndarray) -> np.ndarray:
    """metrics.aggregate_iqm at each step of a (runs x tasks x steps) score array: one trimmed
    mean along the step axis, the same numbers as a call per step, 6x (21 steps) to 15x faster."""
    return scipy.stats.trim_mean(scores.reshape(-1, scores.shape[-1]), 0.25, axis=0)


def aggregate_estimates(scores: dict, gap: bool, reps: int, seed: int
                        ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Each group's AGGREGATE_METRICS (without the optimality gap where scores are raw returns,
    whose threshold 1 means nothing) of its (runs, tasks) scores with their bootstrap CIs."""
    return interval_estimates(scores, functools.partial(aggregate_metrics, gap=gap), reps, seed)


def performance_profiles(scores: dict, taus: np.ndarray, reps: int, seed: int
                         ) -> tuple[dict, dict]:
    """rliable's create_performance_profile with its bootstrap CIs, reproducible by `seed`."""
    seed_bootstrap(seed)
    return rly.create_performance_profile(scores, taus, reps=reps)


def mean_curves(curves: dict, reps: int, seed: int, t_up_to: int = 0) -> dict:
    """group -> (mean, (low, high)) over seeds at every step of its (seeds, steps) values: with
    `t_up_to` seeds or fewer the t-interval, else rliable's bootstrap of metrics.aggregate_mean."""
    estimates = {g: (v.mean(0), np.array([t_interval(v[:, i])[1:] for i in range(v.shape[1])]).T)
                 for g, v in curves.items() if v.shape[0] <= t_up_to}
    scores = {g: v[:, None, :] for g, v in curves.items() if g not in estimates}
    if scores:  # (seeds, 1 task, steps)
        point, interval = interval_estimates(scores, metrics.aggregate_mean, reps, seed)
        estimates |= {g: (point[g], interval[g]) for g in scores}
    return estimates
