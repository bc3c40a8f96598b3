"""The protocol behind `sweep.py --preset paper` running sac_corrected.py only: a corrected run's
paired tanh(mu) evaluation IS the sac_standard.py run of the same seed. Pinned on real (tiny)
runs of both scripts, so that a change to either script that breaks it fails here."""

import csv
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import analyze
from tests.test_sac import EAGER

ROOT = Path(__file__).resolve().parent.parent
# Pendulum, tiny networks: updates start at step 300, evaluation rounds at 400, 800, 1200.
TINY = ["--env-id", "Pendulum-v1", "--seed", "3", "--total-timesteps", "1200",
        "--learning-starts", "300", "--eval-interval", "400", "--eval-episodes", "2",
        "--hidden-sizes", "32", "32", "--batch-size", "32", "--log-interval", "100",
        "--print-interval", "1200", "--checkpoint-interval", "0"]
# The statistics each evaluation round logs for an evaluation action (eval_rounds.EVAL_STATS).
EVAL_STATS = ("return_mean", "return_std", "return_min", "return_max", "length_mean",
              "success_rate")
# Columns that measure the machine, not the run.
TIMING = ("wall_time", "sps")
# config.json keys that may differ between the two scripts' runs of one seed.
OWN_KEYS = {"algorithm", "script", "mode_solver", "run_name", "start_time", "eval_selectors",
            "eval_workers", "batch"}  # batch: its folders' names


def read_csv(path: Path) -> list[dict]:
    with path.open(newline="") as file:
        return [{k: v for k, v in row.items() if k not in TIMING} for row in csv.DictReader(file)]


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> Path:
    """One run of each script, same seed and flags, in one folder. The corrected run also
    evaluates the paired selectors, in a worker process; the standard run evaluates in-process:
    neither may change training or the tanh(mu) episodes."""
    out = tmp_path_factory.mktemp("protocol")
    for script, name, extra in (
            ("sac_standard.py", "std", ["--eval-workers", "0"]),
            ("sac_corrected.py", "cor", ["--eval-workers", "1", "--eval-selectors", "mean",
                                         "q_best"])):
        result = subprocess.run([sys.executable, str(ROOT / script), *TINY, *extra, *EAGER,
                                 "--output-dir", str(out / "runs"), "--run-name", name],
                                capture_output=True, text=True, cwd=ROOT)
        assert result.returncode == 0, result.stderr
    return out / "runs"


def test_the_scripts_log_the_statistics_compared_here():
    from sac_utils.eval_rounds import EVAL_STATS as logged

    assert tuple(logged) == EVAL_STATS


@pytest.mark.slow
def test_corrected_tanh_mu_columns_are_the_standard_run(runs):
    standard, corrected = read_csv(runs / "std" / "eval.csv"), read_csv(runs / "cor" / "eval.csv")
    assert [row["global_step"] for row in standard] == ["400", "800", "1200"]
    assert len(corrected) == len(standard)
    for s, c in zip(standard, corrected, strict=True):
        assert (c["global_step"], c["eval_round"]) == (s["global_step"], s["eval_round"])
        for stat in EVAL_STATS:  # the same text: the same floats, not merely close ones
            assert c["tanh_mu_" + stat] == s[stat], (s["global_step"], stat)
    for row in corrected:  # the selectors' columns, and q_best's choice shares
        assert float(row["mean_length_mean"]) == 200 and row["q_best_return_mean"]
        shares = [float(row[f"q_best_share_{c}"]) for c in ("tanh_mu", "mode", "mean")]
        assert abs(sum(shares) - 1) < 1e-9
    # The mode is a different action: its own columns are not the standard run's.
    assert any(c["return_mean"] != s["return_mean"] for s, c in zip(standard, corrected,
                                                                    strict=True))


@pytest.mark.slow
def test_both_scripts_train_identically(runs):
    standard, corrected = read_csv(runs / "std" / "train.csv"), read_csv(runs / "cor" / "train.csv")
    assert len(standard) == 12 and standard == corrected
    losses = [row["qf1_loss"] for row in standard if row["qf1_loss"]]
    assert len(losses) == 10 and len(set(losses)) == 10  # updates ran and moved the critic
    configs = [json.loads((runs / name / "config.json").read_text()) for name in ("std", "cor")]
    differ = {k for k in configs[0].keys() | configs[1].keys()
              if configs[0].get(k) != configs[1].get(k)}
    assert differ <= OWN_KEYS and {"algorithm", "script"} <= differ


@pytest.mark.slow
def test_analyze_builds_standard_from_corrected_alone_and_checks_both(runs, tmp_path):
    fast = ["--normalize", "none", "--reps", "200", "--curve-reps", "20", "--curve-points", "3"]
    # Corrected alone: Standard SAC is its paired evaluation, number for number.
    alone = tmp_path / "alone"
    shutil.copytree(runs / "cor", alone / "cor")
    assert analyze.main([str(alone), "--out", str(tmp_path / "alone_report"), *fast]) == 0
    text = (tmp_path / "alone_report" / "summary.md").read_text()
    assert "Standard SAC (tanh(mu), paired)" in text
    with (tmp_path / "alone_report" / "summary.csv").open() as file:
        rows = {(r["section"], r["group"], r["metric"]): r for r in csv.DictReader(file)}
    standard_final = float(rows["task_final", "standard", "return"]["estimate"])
    last = read_csv(runs / "std" / "eval.csv")[-1]
    assert np.isclose(standard_final, float(last["return_mean"]), rtol=1e-12)
    # Both kinds: analyze.py checks them point by point and says they agree.
    assert analyze.main([str(runs), "--out", str(tmp_path / "both_report"), *fast]) == 0
    text = (tmp_path / "both_report" / "summary.md").read_text()
    assert ("Pendulum-v1: the standard runs equal the corrected runs' paired tanh(mu) evaluation "
            "at all 3 shared (seed, step) points.") in text
    assert "Disagreement" not in text
