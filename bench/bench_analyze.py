"""Time analyze.py's full analysis, at its default settings, on a paper-sized results folder.

    .venv/bin/python bench/bench_analyze.py [--repeats 3]

The folder is synthetic: 2 algorithms x 4 tasks x 5 seeds x 1,000 evaluations (10M steps at
the paper's 10,000-step interval), corrected runs carrying the paired tanh(mu) evaluation, as
sac_corrected.py writes them. Prints the median wall time of the whole analysis (loading,
every bootstrap, every figure, the summaries) over the repeats, and its CPU time: the analysis
runs in one thread, so on a shared, busy machine the CPU time is the steadier figure.
"""

import contextlib
import dataclasses
import io
import statistics
import sys
import tempfile
import time
from pathlib import Path

import tyro

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import analyze  # noqa: E402
from tests.test_analyze import write_paper_like_folder  # noqa: E402


@dataclasses.dataclass
class Args:
    repeats: int = 3
    """how many times to time the analysis (the median is reported)"""
    evaluations: int = 1_000
    """evaluations per run"""


def main() -> None:
    args = tyro.cli(Args)
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
