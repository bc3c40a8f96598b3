"""Wall time of evaluate.py before and after it ran its episodes through eval_runner.py.

Run from the repository root: `python bench/bench_evaluate.py [--run RUN_DIR] [--baseline REV]
[--episodes 50] [--repeat 3]`. It times the whole command, start-up and bootstrap CIs included,
on one Hopper-v5 run of ours with the selectors mode and tanh_mu: evaluate.py as it was at
--baseline (extracted with `git archive` into a temporary folder, so it runs with that
revision's own sac_corrected.py), then the current one with --workers 0, 1 and 2. Each variant
runs --repeat times, interleaved, and the fastest is kept: other load on a shared machine only
ever adds time. Without --run it first trains a small run (3000 steps, about 15 s).

Besides the command's wall time it prints the part that this change is about: main() less the
bootstrap CIs (loading the policy, the episodes, writing the files), without the interpreter's
imports (~5 s) and rliable's CIs (~2 s), which both versions pay alike. A small driver runs
evaluate.main for that; a worker process imports evaluate.py as the command line's would.
"""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def make_run(folder: Path) -> Path:
    """A small Hopper-v5 run of sac_corrected.py: enough for a policy whose episodes vary."""
    subprocess.run([sys.executable, str(ROOT / "sac_corrected.py"), "--env-id", "Hopper-v5",
                    "--total-timesteps", "3000", "--learning-starts", "1000", "--eval-interval",
                    "100000", "--eval-workers", "0", "--output-dir", str(folder), "--run-name",
                    "hopper"], check=True, capture_output=True, cwd=ROOT)
    return folder / "hopper"


def extract(rev: str, folder: Path) -> Path:
    """The repository at rev, as files (no worktree to clean up)."""
    archive = subprocess.run(["git", "archive", rev], check=True, capture_output=True, cwd=ROOT)
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive.stdout, check=True)
    return folder / "evaluate.py"


DRIVER = """import sys, time
sys.path.insert(0, {folder!r})
import evaluate

if __name__ == "__main__":
    spent, ci = [0.0], evaluate.mean_with_ci

    def timed_ci(*args):
        start = time.perf_counter()
        try:
            return ci(*args)
        finally:
            spent[0] += time.perf_counter() - start

    evaluate.mean_with_ci = timed_ci
    start = time.perf_counter()
    evaluate.main(sys.argv[1:])
    print("BENCH", time.perf_counter() - start - spent[0], file=sys.stderr)
"""


def driver(script: Path, path: Path) -> Path:
    """A script that runs script's evaluate.main and reports its time less the CIs'."""
    path.write_text(DRIVER.format(folder=str(script.parent)))
    return path


def timed(command: list[str], cwd: Path) -> tuple[float, float]:
    """The command's wall time, and the driver's main() time less the bootstrap CIs."""
    start = time.perf_counter()
    result = subprocess.run(command, capture_output=True, text=True, cwd=cwd)
    wall = time.perf_counter() - start
    if result.returncode != 0:
        sys.exit(f"{' '.join(command)} failed:\n{result.stderr}")
    return wall, float(result.stderr.rsplit("BENCH", 1)[1])


def returns(out: Path) -> list[float]:
    with open(out / "episodes.csv", newline="") as f:
        return [float(r["return"]) for r in csv.DictReader(f)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, help="a Hopper-v5 run folder (default: train one)")
    parser.add_argument("--baseline", default="1a028f6", help="the revision to compare with")
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--repeat", type=int, default=3, help="runs per variant; the fastest")
    options = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        run = options.run.resolve() if options.run else make_run(tmp / "runs")
        (tmp / "baseline").mkdir()
        baseline = extract(options.baseline, tmp / "baseline")
        flags = ["--episodes", str(options.episodes), "--selectors", "mode", "tanh_mu"]
        variants = {f"baseline {options.baseline}": (driver(baseline, tmp / "old.py"), [])}
        variants |= {f"--workers {w}": (driver(ROOT / "evaluate.py", tmp / "new.py"),
                                        ["--workers", str(w)]) for w in (0, 1, 2)}
        times: dict[str, list[tuple[float, float]]] = {name: [] for name in variants}
        for _ in range(options.repeat):
            for i, (name, (script, extra)) in enumerate(variants.items()):
                command = [sys.executable, str(script), str(run), *flags, *extra, "--out",
                           str(tmp / f"out{i}")]
                times[name].append(timed(command, tmp))
        print(f"evaluate.py {run} {' '.join(flags)}: fastest of {options.repeat} runs each")
        print(f"{'':<18} {'wall time':>16}  {'main() less the CIs':>22}")
        base = [min(t[j] for t in times[f"baseline {options.baseline}"]) for j in (0, 1)]
        for name, runs in times.items():
            best = [min(t[j] for t in runs) for j in (0, 1)]
            print(f"{name:<18} {best[0]:6.2f} s (x{base[0] / best[0]:4.2f})  "
                  f"{best[1]:10.2f} s (x{base[1] / best[1]:5.2f})")
        # Batched actor calls may round differently from one-at-a-time ones.
        old, new = returns(tmp / "out0"), returns(tmp / "out1")
        print(f"largest |return difference| vs the baseline over {len(old)} episodes: "
              f"{max(abs(a - b) for a, b in zip(old, new, strict=True)):.3g}")


if __name__ == "__main__":
    main()
