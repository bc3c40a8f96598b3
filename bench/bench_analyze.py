"""Time analyze.py's full analysis, at its default settings, on a paper-sized results folder.

    .venv/bin/python bench/bench_analyze.py [--repeats 3]
    .venv/bin/python bench/bench_analyze.py --copies   # the estimators' copies against rliable

The folder is synthetic: 2 algorithms x 4 tasks x 5 seeds x 1,000 evaluations (10M steps at
the paper's 10,000-step interval), corrected runs carrying the paired tanh(mu) evaluation, as
sac_corrected.py writes them. Prints the median wall time of the whole analysis (loading,
every bootstrap, every figure, the summaries) over the repeats, and its CPU time: the analysis
runs in one thread, so on a shared, busy machine the CPU time is the steadier figure.

--copies times each copy analysis/estimators.py keeps of an rliable estimator, for speed only,
against rliable's own call on the same numbers (tests pin them equal): bootstrap_mean against
get_interval_estimates of a mean, iqm against metrics.aggregate_iqm, iqm_per_step against
aggregate_iqm at each step.
"""

import contextlib
import dataclasses
import functools
import io
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import tyro
from rliable import library as rly
from rliable import metrics

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import analyze  # noqa: E402
from analysis import estimators  # noqa: E402
from tests.test_analyze import write_paper_like_folder  # noqa: E402


@dataclasses.dataclass
class Args:
    repeats: int = 3
    """how many times to time the analysis (the median is reported)"""
    evaluations: int = 1_000
    """evaluations per run"""
    copies: bool = False
    """time the estimators' copies of rliable's estimators against rliable's instead"""


def cpu_seconds(call: Callable[[], object], repeats: int) -> tuple[float, object]:
    """The median CPU time of `call` over the repeats, and its last result."""
    times = []
    for _ in range(repeats):
        start = time.process_time()
        result = call()
        times.append(time.process_time() - start)
    return statistics.median(times), result


def time_copies(repeats: int) -> None:
    """Each copy beside rliable's call, at the sizes a report asks of it: a task's five seeds
    with 20,000 replications; an IQM of 5 seeds x 4 tasks, as a bootstrap calls it; the IQM of
    (5, 4, 51) scores at every step."""
    scores = np.random.default_rng(0).normal(size=(5, 4))

    def rliable_mean() -> tuple:
        np.random.seed(0)  # noqa: NPY002
        return rly.get_interval_estimates({"x": scores}, functools.partial(np.mean, axis=0),
                                          reps=20_000)

    curves = np.random.default_rng(1).normal(size=(5, 4, 51))
    pairs = {
        "bootstrap_mean, (5, 4), 20,000 reps": (
            rliable_mean, lambda: estimators.bootstrap_mean(scores, 20_000,
                                                            np.random.RandomState(0))),
        "iqm, (5, 4), 10,000 calls": (
            lambda: [metrics.aggregate_iqm(scores) for _ in range(10_000)][-1],
            lambda: [estimators.iqm(scores) for _ in range(10_000)][-1]),
        "iqm_per_step, (5, 4, 51), 1,000 calls": (
            lambda: [[metrics.aggregate_iqm(curves[..., i]) for i in range(51)]
                     for _ in range(1_000)][-1],
            lambda: [estimators.iqm_per_step(curves) for _ in range(1_000)][-1]),
    }
    for name, (theirs, ours) in pairs.items():
        (slow, expected), (fast, got) = cpu_seconds(theirs, repeats), cpu_seconds(ours, repeats)
        same = np.allclose(np.ravel(got[0] if isinstance(got, tuple) else got),
                           np.ravel(expected[0]["x"] if isinstance(expected, tuple)
                                    else expected))
        print(f"{name}: rliable {slow:.3f} s CPU, the copy {fast:.3f} s "
              f"({slow / max(fast, 1e-9):.0f}x), same numbers: {same}")


def main() -> None:
    args = tyro.cli(Args)
    if args.copies:
        time_copies(args.repeats)
        return
    with tempfile.TemporaryDirectory() as tmp:
        runs = Path(tmp) / "runs"
        start = time.perf_counter()
        write_paper_like_folder(runs, seeds=5, evaluations=args.evaluations)
        print(f"wrote 40 runs x {args.evaluations} evaluations in "
              f"{time.perf_counter() - start:.1f} s")
        wall, cpu = [], []
        for i in range(args.repeats):
            start, start_cpu = time.perf_counter(), time.process_time()
            with contextlib.redirect_stdout(io.StringIO()):
                code = analyze.main([str(runs), "--out", str(Path(tmp) / f"report{i}")])
            wall.append(time.perf_counter() - start)
            cpu.append(time.process_time() - start_cpu)
            assert code == 0, "analysis failed"
            print(f"run {i + 1}: {wall[-1]:.1f} s wall, {cpu[-1]:.1f} s CPU")
        defaults = analyze.Args(runs_dirs=(runs,))
        print(f"full analysis at defaults (reps {defaults.reps:,}, curve reps "
              f"{defaults.curve_reps:,}, {defaults.curve_points} curve points), median of "
              f"{args.repeats}: {statistics.median(wall):.1f} s wall, "
              f"{statistics.median(cpu):.1f} s CPU")


if __name__ == "__main__":
    main()
