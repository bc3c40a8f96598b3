"""analyze.py on synthetic run folders written as the README's "The run folder" says."""

from __future__ import annotations

import csv
import json
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import scipy.stats

import analyze
from analysis import data, estimators, figures

EVAL_COLUMNS = ["global_step", "wall_time", "eval_round", "return_mean", "return_std",
                "return_min", "return_max", "length_mean", "success_rate"]
# sac_corrected.py appends the paired tanh(mu) evaluation and the shift statistics.
CORRECTED_EXTRA_COLUMNS = ["tanh_mu_return_mean", "tanh_mu_return_std", "tanh_mu_return_min",
                           "tanh_mu_return_max", "tanh_mu_length_mean", "tanh_mu_success_rate",
                           "mode_shift_abs_mean", "mode_shift_abs_sum", "sigma_mean",
                           "bimodal_fraction"]
TASKS = ["h1hand-powerlift-v0", "h1hand-cube-v0", "h1hand-bookshelf_simple-v0",
         "h1hand-bookshelf_hard-v0"]


def write_run(root: Path, env_id: str, algorithm: str, seed: int, steps: np.ndarray,
              returns: np.ndarray, paired: np.ndarray | None = None,
              name: str | None = None, action_dim: int = 61) -> Path:
    """One run folder as the SAC scripts write it: config.json and eval.csv (paired columns
    when `paired` is given)."""
    run_dir = root / (name or f"{env_id}__{algorithm}__seed{seed}__20261121-120000")
    run_dir.mkdir(parents=True)
    config = {"env_id": env_id, "seed": seed, "algorithm": algorithm,
              "script": f"sac_{algorithm}.py", "total_timesteps": int(steps[-1]),
              "eval_interval": int(steps[1] - steps[0]) if len(steps) > 1 else 0,
              "obs_dim": 164, "action_dim": action_dim, "git_commit": None,
              "versions": {"python": "3.11", "numpy": np.__version__},
              "start_time": "2026-11-21T12:00:00"}
    (run_dir / "config.json").write_text(json.dumps(config, indent=2))
    header = EVAL_COLUMNS + CORRECTED_EXTRA_COLUMNS * (paired is not None)
    with (run_dir / "eval.csv").open("w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(header)
        for i, (step, value) in enumerate(zip(steps, returns, strict=True)):
            row = [int(step), 3.5 * i, i, value, 5.0, value - 9, value + 9, 1000.0, ""]
            if paired is not None:
                row += [paired[i], 5.0, paired[i] - 9, paired[i] + 9, 1000.0, "",
                        0.12, 7.3, 0.45, 0.03]
            writer.writerow(row)
    return run_dir


def learning_curve(rng: np.random.Generator, steps: np.ndarray, final: float,
                   noise: float) -> np.ndarray:
    """A saturating learning curve with evaluation noise."""
    return final * (1 - np.exp(-4 * steps / steps[-1])) + rng.normal(0, noise, steps.size)


def write_paper_like_folder(root: Path, seeds: int = 5, evaluations: int = 100,
                            interval: int = 10_000, seed: int = 0) -> Path:
    """2 algorithms x 4 tasks x `seeds` seeds; corrected ~10% of the bar better than standard,
    its paired tanh(mu) evaluation ~5% worse than its mode evaluation."""
    rng = np.random.default_rng(seed)
    steps = interval * np.arange(1, evaluations + 1)
    for t, task in enumerate(TASKS):
        bar = data.SUCCESS_BARS[task]
        level = 0.3 + 0.2 * t
        for s in range(seeds):
            luck = rng.normal(0, 0.08)
            standard = learning_curve(rng, steps, bar * (level + luck), 0.03 * bar)
            corrected = learning_curve(rng, steps, bar * (level + 0.1 + luck), 0.03 * bar)
            paired = corrected - 0.05 * bar * (1 - np.exp(-4 * steps / steps[-1]))
            paired += rng.normal(0, 0.01 * bar, steps.size)
            write_run(root, task, "standard", s, steps, standard)
            write_run(root, task, "corrected", s, steps, corrected, paired)
    return root


FAST = ["--reps", "300", "--curve-reps", "50", "--curve-points", "5"]


def run_analysis(runs: Path, out: Path, *flags: str) -> int:
    return analyze.main([str(runs), "--out", str(out), *FAST, *flags])


def read_summary(out: Path) -> dict[tuple[str, str, str, str], dict]:
    """summary.csv keyed by (section, task, group, metric)."""
    with (out / "summary.csv").open() as file:
        return {(r["section"], r["task"], r["group"], r["metric"]): r for r in csv.DictReader(file)}


def estimate(summary: dict, *key: str) -> tuple[float, float, float]:
    row = summary[key]
    return float(row["estimate"]), float(row["ci_low"]), float(row["ci_high"])


def write_offset_folder(root: Path, offset: float, paired_gap: float = 0.05, seeds: int = 5,
                        evaluations: int = 12) -> dict:
    """Corrected = standard + offset x bar on every task, seed and step (same noise); its paired
    tanh(mu) evaluation = corrected - paired_gap x bar. Returns standard's returns by task."""
    rng = np.random.default_rng(1)
    steps = 10_000 * np.arange(1, evaluations + 1)
    standard_returns = {}
    for task in TASKS:
        bar = data.SUCCESS_BARS[task]
        standard_returns[task] = []
        for seed in range(seeds):
            standard = bar * (0.4 + rng.uniform(-0.05, 0.05, steps.size))
            corrected = standard + offset * bar
            write_run(root, task, "standard", seed, steps, standard)
            write_run(root, task, "corrected", seed, steps, corrected, corrected - paired_gap * bar)
            standard_returns[task].append(standard)
    return {task: np.array(r) for task, r in standard_returns.items()}


@pytest.mark.slow
def test_offset_gives_certain_improvement_and_iqm_gap(tmp_path):
    standard = write_offset_folder(tmp_path / "runs", offset=0.3)
    assert run_analysis(tmp_path / "runs", tmp_path / "out") == 0
    summary = read_summary(tmp_path / "out")
    p, low, high = estimate(summary, "probability_of_improvement", "all",
                            "corrected > standard", "P(X > Y)")
    assert p == 1.0 and low == 1.0 and high == 1.0
    for metric, shift in [("IQM", 0.3), ("Median", 0.3), ("Mean", 0.3), ("Optimality Gap", -0.3)]:
        s = estimate(summary, "aggregate", "all", "standard", metric)
        c = estimate(summary, "aggregate", "all", "corrected", metric)
        assert np.isclose(c[0] - s[0], shift), metric
        assert s[1] <= s[0] <= s[2]
    # The paired evaluation is its own group, 0.05 below corrected, and the paired difference
    # is exactly 0.05 x bar on every task and seed.
    tanh_mu = estimate(summary, "aggregate", "all", "corrected (tanh(mu) eval)", "Mean")[0]
    corrected = estimate(summary, "aggregate", "all", "corrected", "Mean")[0]
    assert np.isclose(tanh_mu, corrected - 0.05)
    for task in TASKS:
        bar = data.SUCCESS_BARS[task]
        assert np.allclose(estimate(summary, "paired_difference", task, "corrected", "return"),
                           0.05 * bar)
        assert np.allclose(estimate(summary, "paired_difference", task, "corrected", "score"), 0.05)
        # Per-task final returns are the seed means at the last step; CIs bracket them.
        mean, low, high = estimate(summary, "task_final", task, "standard", "return")
        assert np.isclose(mean, standard[task][:, -1].mean())
        assert low <= mean <= high and low >= standard[task][:, -1].min()
        assert np.isclose(estimate(summary, "task_final", task, "standard", "score")[0],
                          mean / bar)
        assert summary[("task_final", task, "standard", "return")]["step"] == "120000"
    names = {p.name for p in (tmp_path / "out").iterdir()}
    assert names == {"summary.csv", "summary.md", "reward_curves.png", "aggregate_metrics.png",
                     "performance_profiles.png", "sample_efficiency.png",
                     "probability_of_improvement.png", "paired_difference.png",
                     "over_training.png"}
    text = (tmp_path / "out" / "summary.md").read_text()
    assert "P(Corrected SAC > Standard SAC) = 1.000 [1.000, 1.000]" in text
    assert "| h1hand-cube-v0 | 5 seeds, to step 120k | 5 seeds, to step 120k |" in text


@pytest.mark.slow
def test_identical_algorithms_give_even_odds(tmp_path):
    write_offset_folder(tmp_path / "runs", offset=0.0)
    assert run_analysis(tmp_path / "runs", tmp_path / "out") == 0
    summary = read_summary(tmp_path / "out")
    p, low, high = estimate(summary, "probability_of_improvement", "all",
                            "corrected > standard", "P(X > Y)")
    assert p == 0.5 and low < 0.5 < high
    for metric in estimators.AGGREGATE_METRICS:
        assert estimate(summary, "aggregate", "all", "standard", metric)[0] == \
            estimate(summary, "aggregate", "all", "corrected", metric)[0]


def test_independent_draws_of_one_algorithm_are_near_even(tmp_path):
    """Two groups drawn from the same distribution: P(X > Y) near 0.5, its CI covers 0.5."""
    rng = np.random.default_rng(7)
    steps = 10_000 * np.arange(1, 6)
    for task in TASKS:
        for algorithm in ("standard", "corrected"):
            for seed in range(10):
                write_run(tmp_path / "runs", task, algorithm, seed, steps,
                          rng.normal(300, 50, steps.size))
    assert run_analysis(tmp_path / "runs", tmp_path / "out") == 0
    p, low, high = estimate(read_summary(tmp_path / "out"), "probability_of_improvement", "all",
                            "corrected > standard", "P(X > Y)")
    assert 0.35 < p < 0.65 and low < 0.5 < high


def test_iqm_per_step_is_rliables_iqm_at_every_step():
    from rliable import metrics

    scores = np.random.default_rng(3).normal(size=(5, 4, 7))
    expected = [metrics.aggregate_iqm(scores[..., i]) for i in range(7)]
    assert np.allclose(estimators.iqm_per_step(scores), expected)


def test_iqm_is_rliables_iqm_to_the_bit():
    from rliable import metrics

    rng = np.random.default_rng(4)
    for shape in [(1, 1), (2, 1), (3, 1), (5, 4), (2, 2), (7, 3), (300, 1), (20, 9)]:
        for k in range(50):
            scores = rng.normal(size=shape) * 10.0 ** rng.integers(-3, 4)
            scores = np.round(scores, 1) if k % 2 else scores  # ties
            assert estimators.iqm(scores) == metrics.aggregate_iqm(scores), (shape, k)
    scores[0, 0] = np.nan
    assert np.isnan(estimators.iqm(scores)) and np.isnan(metrics.aggregate_iqm(scores))


def test_every_task_gets_a_marker_beyond_the_twelve_shapes():
    # The classic suite's five tasks beside HumanoidBench's four are nine; a report over them
    # once raised a KeyError when the shapes ran out at eight.
    tasks = [f"task{i}" for i in range(14)]
    markers = figures.marker_shapes(tasks)
    assert list(markers) == tasks
    assert len(set(markers[t] for t in tasks[:12])) == 12  # distinct while shapes last


def test_a_figures_band_line_says_how_many_runs_and_warns_when_few():
    few = figures.band_line({"a": np.zeros((2, 1)), "b": np.zeros((3, 1))}, "bars")
    assert few.startswith("bars: 95% stratified-bootstrap CIs (rliable), 2 or 3 runs x 1 task")
    assert "narrower than the data allow" in few
    many = figures.band_line({"a": np.zeros((estimators.FEW_SEEDS + 1, 4))}, "bands")
    assert many == ("bands: 95% stratified-bootstrap CIs (rliable), "
                    f"{estimators.FEW_SEEDS + 1} runs x 4 tasks")


@pytest.mark.slow
def test_same_seed_same_report_other_seed_other_intervals(tmp_path):
    write_paper_like_folder(tmp_path / "runs", seeds=3, evaluations=10)
    for name, seed in [("a", "0"), ("b", "0"), ("c", "1")]:
        assert run_analysis(tmp_path / "runs", tmp_path / name, "--seed", seed) == 0
    first = (tmp_path / "a" / "summary.csv").read_text()
    assert first == (tmp_path / "b" / "summary.csv").read_text()
    assert first != (tmp_path / "c" / "summary.csv").read_text()
    # The seed moves the intervals only, never the point estimates.
    a, c = read_summary(tmp_path / "a"), read_summary(tmp_path / "c")
    assert all(a[key]["estimate"] == c[key]["estimate"] for key in a)


def test_ragged_runs_are_cut_to_shared_steps_and_reported(tmp_path):
    runs = tmp_path / "runs"
    steps = 10_000 * np.arange(1, 11)
    task = "h1hand-cube-v0"
    for seed in range(3):
        write_run(runs, task, "standard", seed, steps, np.full(10, 100.0 + seed))
    # Corrected: one run still going (6 evaluations), one evaluated every 5,000 steps.
    write_run(runs, task, "corrected", 0, steps[:6], np.arange(6) * 10.0)
    write_run(runs, task, "corrected", 1, steps, np.full(10, 200.0))
    fine = 5_000 * np.arange(1, 21)
    write_run(runs, task, "corrected", 2, fine, fine / 1_000.0)
    assert run_analysis(runs, tmp_path / "out") == 0
    summary = read_summary(tmp_path / "out")
    row = summary[("task_final", task, "corrected", "return")]
    assert row["step"] == "60000" and row["n_runs"] == "3"
    assert np.isclose(float(row["estimate"]), np.mean([50.0, 200.0, 60.0]))
    assert summary[("task_final", task, "standard", "return")]["step"] == "60000"
    text = (tmp_path / "out" / "summary.md").read_text()
    assert f"{task}: its runs share steps up to 60k (shortest run: {runs}/{task}__corrected__seed0"\
        in text
    cut = [line for line in text.splitlines() if "Cut: " in line][0]
    assert "standard__seed1__20261121-120000 (reached 100k)" in cut
    assert cut.count("reached") == 5  # three standard runs, corrected seeds 1 and 2, once each
    assert "evaluation steps differ between runs (1 run(s)" in text
    assert "| h1hand-cube-v0 | 3 seeds, to step 100k | 3 seeds, to step 60k-100k |" in text


def test_disjoint_eval_steps_are_a_clear_error(tmp_path, capsys):
    runs = tmp_path / "runs"
    write_run(runs, "h1hand-cube-v0", "standard", 0, np.array([1000, 2000]), np.ones(2))
    write_run(runs, "h1hand-cube-v0", "corrected", 0, np.array([1500, 2500]), np.ones(2))
    assert run_analysis(runs, tmp_path / "out") == 2
    assert "share no evaluation step" in capsys.readouterr().err


@pytest.mark.slow
def test_incomplete_last_line_is_dropped(tmp_path):
    write_offset_folder(tmp_path / "runs", offset=0.1, seeds=2, evaluations=5)
    eval_csv = next((tmp_path / "runs").glob("h1hand-cube-v0__standard__seed0*/eval.csv"))
    last_value = float(eval_csv.read_text().splitlines()[-1].split(",")[3])
    with eval_csv.open("a") as file:
        file.write("60000,21.0,5,99")  # killed mid-write: no line end
    assert run_analysis(tmp_path / "runs", tmp_path / "out") == 0
    summary = read_summary(tmp_path / "out")
    assert summary[("task_final", "h1hand-cube-v0", "standard", "return")]["step"] == "50000"
    text = (tmp_path / "out" / "summary.md").read_text()
    assert "incomplete last line" in text and str(eval_csv) in text
    columns, partial = data.read_eval_csv(eval_csv)
    assert partial and columns["global_step"][-1] == 50_000
    assert columns["return_mean"][-1] == last_value


def test_a_restart_from_a_snapshot_is_noted(tmp_path):
    write_offset_folder(tmp_path / "runs", offset=0.1, seeds=2, evaluations=3)
    _, notes = data.load_runs([tmp_path / "runs"])
    assert not any("restarted" in note for note in notes)
    config_path = next((tmp_path / "runs").glob("*__seed1*/config.json"))
    config = json.loads(config_path.read_text())
    config["restarts"] = [{"step": 20_000, "snapshot": "snapshots/step20000.pt", "refill": 500}]
    config_path.write_text(json.dumps(config))
    runs, notes = data.load_runs([tmp_path / "runs"])
    restarted = [note for note in notes if "restarted" in note]
    assert restarted == [f"{config_path.parent}: restarted from snapshots/step20000.pt at step "
                         "20000 (its checkpoint lost; the replay buffer refilled for 500 steps): "
                         "from there a new sample, not the lost run's future"]
    marks = data.restart_marks(runs)
    assert marks == {task: [(1, 20_000)] if task in config_path.parent.name else []
                     for task in runs}
    # The reward curves mark each restart where it happened, with its seed, in one legend entry;
    # runs restarted at the same step share one line and one label.
    task = next(t for t, m in marks.items() if m)
    steps = np.array([10_000, 20_000, 30_000])
    curve = (np.ones(3), (np.zeros(3), 2 * np.ones(3)))
    fig = figures.plot_reward_curves({task: steps}, {task: {"g": curve}}, {"g": "C0"}, str,
                                     {(task, "g"): "-"}, {}, "heading",
                                     {task: [*marks[task], (2, 25_000), (0, 25_000)]})
    lines = [line for line in fig.axes[0].get_lines() if line.get_linestyle() == "--"]
    assert [list(line.get_xdata()) for line in lines] == [[20.0, 20.0], [25.0, 25.0]]  # 1000s
    assert [text.get_text() for text in fig.axes[0].texts] == ["seed 1 ", "seeds 0, 2 "]
    legend = [text.get_text() for text in fig.legends[0].get_texts()]
    assert legend == ["g", "a run restarted from a snapshot"]


@pytest.mark.slow
def test_run_without_rows_or_eval_csv_is_skipped_with_a_note(tmp_path):
    write_offset_folder(tmp_path / "runs", offset=0.1, seeds=2, evaluations=4)
    started = tmp_path / "runs" / "just_started"
    started.mkdir()
    (started / "config.json").write_text(json.dumps(
        {"env_id": "h1hand-cube-v0", "algorithm": "standard", "seed": 9}))
    assert run_analysis(tmp_path / "runs", tmp_path / "out") == 0
    assert f"{started}: no eval.csv yet; skipped" in (tmp_path / "out" / "summary.md").read_text()
    (started / "eval.csv").write_text(",".join(EVAL_COLUMNS) + "\n")
    assert run_analysis(tmp_path / "runs", tmp_path / "out") == 0
    assert "no complete evaluation row yet" in (tmp_path / "out" / "summary.md").read_text()


@pytest.mark.slow
def test_corrected_runs_alone_are_both_algorithms(tmp_path):
    """With no sac_standard.py runs, the corrected runs' paired tanh(mu) evaluation is Standard
    SAC: every comparison works as with two sets of runs, labelled as paired."""
    steps = 10_000 * np.arange(1, 6)
    for task in TASKS[:2]:
        for seed in range(3):
            values = np.linspace(100, 300, 5) + seed
            write_run(tmp_path / "runs", task, "corrected", seed, steps, values, values - 10)
    assert run_analysis(tmp_path / "runs", tmp_path / "out") == 0
    names = {p.name for p in (tmp_path / "out").iterdir()}
    assert {"aggregate_metrics.png", "paired_difference.png", "probability_of_improvement.png",
            "sample_efficiency.png", "summary.csv"} <= names
    text = (tmp_path / "out" / "summary.md").read_text()
    assert "Standard SAC (tanh(mu), paired)" in text
    assert "No sac_standard.py runs for h1hand-cube-v0, h1hand-powerlift-v0" in text
    # The paired analysis is the headline: the first section after the notes.
    sections = [line for line in text.splitlines() if line.startswith("## ")]
    assert sections[sections.index("## Notes") + 2].startswith("## Headline: paired")
    assert "| 3 of 3 |" in text
    summary = read_summary(tmp_path / "out")
    assert np.allclose(estimate(summary, "paired_difference", TASKS[0], "corrected", "return"), 10)
    assert estimate(summary, "paired_difference", TASKS[0], "corrected",
                    "share_above_zero")[0] == 1.0
    # The standard group holds the paired numbers: seeds 0-2 end at 290, 291, 292.
    assert estimate(summary, "task_final", TASKS[0], "standard", "return")[0] == 291.0
    assert estimate(summary, "probability_of_improvement", "all", "corrected > standard",
                    "P(X > Y)")[0] > 0.5
    # Over the two tasks: the mean normalised difference (10 / success bar per task), above zero
    # on 6 of 6.
    bars = [data.SUCCESS_BARS[t] for t in TASKS[:2]]
    mean = estimate(summary, "paired_difference", "all", "corrected", "mean_score")
    assert np.isclose(mean[0], np.mean([10 / b for b in bars]))
    assert estimate(summary, "paired_difference", "all", "corrected", "share_above_zero")[0] == 1.0
    # Standard on one task, corrected on another: nothing to aggregate, per-task results only.
    write_run(tmp_path / "split", TASKS[0], "standard", 0, steps, np.linspace(1, 5, 5))
    write_run(tmp_path / "split", TASKS[1], "corrected", 0, steps, np.linspace(2, 6, 5))
    assert run_analysis(tmp_path / "split", tmp_path / "split_out") == 0
    assert not (tmp_path / "split_out" / "aggregate_metrics.png").exists()
    text = (tmp_path / "split_out" / "summary.md").read_text()
    assert "no task was run by every algorithm: aggregate metrics skipped" in text
    assert estimate(read_summary(tmp_path / "split_out"), "task_final", TASKS[1], "corrected",
                    "return")[0] == 6.0


@pytest.mark.slow
def test_min_max_and_none_normalisation(tmp_path):
    runs = tmp_path / "runs"
    steps = 10_000 * np.arange(1, 4)
    write_run(runs, "Pendulum-v1", "standard", 0, steps, np.array([-1500.0, -900.0, -500.0]))
    write_run(runs, "Pendulum-v1", "corrected", 0, steps, np.array([-1400.0, -600.0, -200.0]))
    assert run_analysis(runs, tmp_path / "mm", "--normalize", "min-max") == 0
    summary = read_summary(tmp_path / "mm")
    # min -1500, max -200 over every logged return of the task.
    assert np.isclose(estimate(summary, "task_final", "Pendulum-v1", "standard", "score")[0],
                      1000 / 1300)
    assert np.isclose(estimate(summary, "aggregate", "all", "corrected", "Mean")[0], 1.0)
    assert run_analysis(runs, tmp_path / "raw", "--normalize", "none") == 0
    summary = read_summary(tmp_path / "raw")
    assert estimate(summary, "aggregate", "all", "standard", "IQM")[0] == -500.0
    assert ("aggregate", "all", "standard", "Optimality Gap") not in summary


@pytest.mark.slow
def test_at_step_and_pdf_output(tmp_path):
    standard = write_offset_folder(tmp_path / "runs", offset=0.2, seeds=2, evaluations=6)
    out = tmp_path / "out"
    assert run_analysis(tmp_path / "runs", out, "--at-step", "30000", "--format", "pdf") == 0
    summary = read_summary(out)
    task = "h1hand-powerlift-v0"
    assert np.isclose(estimate(summary, "task_final", task, "standard", "return")[0],
                      standard[task][:, 2].mean())
    assert {p.suffix for p in out.iterdir()} == {".pdf", ".md", ".csv"}
    assert run_analysis(tmp_path / "runs", out, "--at-step", "35000") == 2


def write_config(run_dir: Path, **config) -> None:
    run_dir.mkdir(parents=True)
    (run_dir / "config.json").write_text(json.dumps(config))


def test_bad_inputs_give_one_clear_message(tmp_path, capsys):
    cases = {}
    cases["empty"] = ([], "no runs found under")
    cases["missing_column"] = ([("h1hand-cube-v0", "standard", 0, "global_step,return\n10,1\n")],
                               "lacks column(s) ['return_mean']")
    cases["mixed_raw"] = ([("h1hand-cube-v0", "standard", 0, None),
                           ("h1hand-stand-v0", "standard", 0, None)],
                          "--normalize none: raw returns of different tasks cannot be aggregated")
    cases["unknown_task"] = ([("Hopper-v5", "standard", 0, None)],
                             "no success bar known for Hopper-v5")
    cases["twin_seeds"] = ([("h1hand-cube-v0", "standard", 0, None),
                            ("h1hand-cube-v0", "standard", 0, None)],
                           "two runs of h1hand-cube-v0, standard, seed 0")
    cases["bad_number"] = ([("h1hand-cube-v0", "standard", 0, "global_step,return_mean\n10,x\n")],
                           "return_mean = 'x' is not a number")
    cases["short_row"] = ([("h1hand-cube-v0", "standard", 0,
                            "global_step,return_mean\n10\n20,2\n")], "row 2: 1 fields")
    for name, (runs, message) in cases.items():
        root = tmp_path / name
        root.mkdir()
        for i, (task, algorithm, seed, text) in enumerate(runs):
            if text is None:
                write_run(root, task, algorithm, seed, np.array([10, 20]), np.ones(2),
                          name=f"run{i}")
            else:
                write_config(root / f"run{i}", env_id=task, algorithm=algorithm, seed=seed)
                (root / f"run{i}" / "eval.csv").write_text(text)
        # The default, auto, falls back to min-max; asked for, success bars must all exist.
        flags = {"mixed_raw": ["--normalize", "none"],
                 "unknown_task": ["--normalize", "success-bar"]}.get(name, [])
        assert run_analysis(root, tmp_path / "out", *flags) == 2, name
        assert message in capsys.readouterr().err, name
    assert analyze.main([str(tmp_path / "empty"), "--reps", "0"]) == 2
    assert "--reps 0: must be at least 1" in capsys.readouterr().err
    write_config(tmp_path / "no_seed" / "run", env_id="h1hand-cube-v0", algorithm="standard")
    (tmp_path / "no_seed" / "run" / "eval.csv").write_text("global_step,return_mean\n10,1\n")
    assert run_analysis(tmp_path / "no_seed", tmp_path / "out") == 2
    assert "lacks key(s) ['seed']" in capsys.readouterr().err
    (tmp_path / "no_seed" / "run" / "config.json").write_text('{"env_id": "h1hand-cube-v0",')
    assert run_analysis(tmp_path / "no_seed", tmp_path / "out") == 2
    assert "config.json is not valid JSON" in capsys.readouterr().err
    (tmp_path / "no_seed" / "run" / "config.json").write_text('["h1hand-cube-v0"]')
    assert run_analysis(tmp_path / "no_seed", tmp_path / "out") == 2
    assert "config.json does not hold a JSON object; fix or remove that run (it needs keys " \
        "['env_id', 'seed', 'algorithm'])" in capsys.readouterr().err


@pytest.mark.slow
def test_several_folders_make_one_report(tmp_path, capsys):
    """One campaign folder per task (results/<task>-1M/runs): named together they give the report
    of one folder holding them all; a folder named twice, or inside another named one, counts
    once."""
    steps = np.arange(10_000, 60_001, 10_000)
    for i, task in enumerate(TASKS[:2]):
        for seed in range(3):
            returns = np.linspace(10, 100 + 20 * seed + 50 * i, steps.size)
            for root in (tmp_path / task, tmp_path / "together"):
                write_run(root, task, "corrected", seed, steps, returns, returns - 5 * seed)
    apart = [str(tmp_path / task) for task in TASKS[:2]]
    assert analyze.main([*apart, "--out", str(tmp_path / "apart"), *FAST]) == 0
    assert run_analysis(tmp_path / "together", tmp_path / "one") == 0
    assert (tmp_path / "apart" / "summary.csv").read_text() == \
        (tmp_path / "one" / "summary.csv").read_text()
    text = (tmp_path / "apart" / "summary.md").read_text()
    assert f"Found 6 runs under {apart[0]}, {apart[1]}:" in text
    twice = [apart[0], apart[0], str(tmp_path / TASKS[0] / os.listdir(apart[0])[0])]
    assert analyze.main([*twice, "--out", str(tmp_path / "twice"), *FAST]) == 0
    assert "Found 3 runs under" in (tmp_path / "twice" / "summary.md").read_text()
    capsys.readouterr()
    assert analyze.main(["--out", str(tmp_path / "none")]) == 2
    assert "no folder given" in capsys.readouterr().err
    assert not (tmp_path / "none").exists()


@pytest.mark.slow
def test_command_line_error_exits_nonzero_without_traceback(tmp_path):
    import subprocess
    import sys

    result = subprocess.run([sys.executable, "analyze.py", str(tmp_path / "nowhere")],
                            cwd=Path(analyze.__file__).parent, capture_output=True, text=True)
    assert result.returncode == 2
    assert "is not a folder" in result.stderr and "Traceback" not in result.stderr


@pytest.mark.slow
def test_reads_what_the_sac_scripts_write(tmp_path):
    """Tiny real runs of both scripts: analyze.py reads them, and since the two scripts train
    identically for a seed and evaluate from the same start states, corrected's paired tanh(mu)
    evaluation equals standard's own evaluation."""
    import subprocess
    import sys

    root = Path(analyze.__file__).parent
    for script in ("sac_standard.py", "sac_corrected.py"):
        subprocess.run([sys.executable, script, "--env-id", "Pendulum-v1", "--seed", "0",
                        "--total-timesteps", "400", "--learning-starts", "200",
                        "--eval-interval", "200", "--eval-episodes", "1",
                        "--checkpoint-interval", "0", "--no-compile",
                        "--output-dir", str(tmp_path / "runs")],
                       cwd=root, check=True, capture_output=True)
    assert run_analysis(tmp_path / "runs", tmp_path / "out", "--normalize", "min-max") == 0
    summary = read_summary(tmp_path / "out")
    standard = summary[("task_final", "Pendulum-v1", "standard", "return")]
    tanh_mu = summary[("task_final", "Pendulum-v1", "corrected (tanh(mu) eval)", "return")]
    assert standard["step"] == "400" and standard["estimate"] == tanh_mu["estimate"]
    mode = estimate(summary, "task_final", "Pendulum-v1", "corrected", "return")[0]
    difference = estimate(summary, "paired_difference", "Pendulum-v1", "corrected", "return")[0]
    assert np.isclose(difference, mode - float(tanh_mu["estimate"]))


@pytest.mark.slow
def test_standard_runs_are_checked_against_the_paired_evaluation(tmp_path):
    steps = 10_000 * np.arange(1, 4)
    for seed in range(3):
        mode, paired = np.array([5.0, 6, 7]) + seed, np.array([4.0, 5, 6]) + seed
        write_run(tmp_path / "runs", TASKS[0], "corrected", seed, steps, mode, paired)
        # Seeds 0 and 1: the standard run is the paired evaluation; seed 2 was made otherwise.
        standard = paired if seed < 2 else paired + np.array([0, 0, 0.5])
        write_run(tmp_path / "runs", TASKS[0], "standard", seed, steps, standard)
    assert run_analysis(tmp_path / "runs", tmp_path / "out") == 0
    text = (tmp_path / "out" / "summary.md").read_text()
    assert "Standard SAC (tanh(mu), paired)" not in text  # the literal standard runs are used
    assert ("Disagreement: h1hand-powerlift-v0, seed 2: " in text
            and "differ at 1 of 3 shared steps (step 30k: 8.5 vs 8); made with other flags or "
            "code? Kept apart" in text)
    assert "standard__seed2" in text and "standard__seed0" not in text.split("Disagreement")[1]
    # Kept apart: the standard group keeps its own numbers, the paired group its own.
    summary = read_summary(tmp_path / "out")
    assert np.isclose(estimate(summary, "task_final", TASKS[0], "standard", "return")[0],
                      (6 + 7 + 8.5) / 3)
    assert estimate(summary, "task_final", TASKS[0], "corrected (tanh(mu) eval)", "return")[0] == 7

    agree = tmp_path / "agree"
    for seed in range(2):
        paired = np.array([4.0, 5, 6]) + seed
        write_run(agree, TASKS[0], "corrected", seed, steps, paired + 1, paired)
        write_run(agree, TASKS[0], "standard", seed, steps, paired)
    assert run_analysis(agree, tmp_path / "agree_out") == 0
    text = (tmp_path / "agree_out" / "summary.md").read_text()
    assert ("h1hand-powerlift-v0: the standard runs equal the corrected runs' paired tanh(mu) "
            "evaluation at all 6 shared (seed, step) points.") in text


def exact_bootstrap_quantiles(values: np.ndarray, qs: tuple[float, ...]) -> np.ndarray:
    """Quantiles of the exact bootstrap distribution of the mean of `values`: every resample
    with replacement (n^n equally likely tuples), so no Monte Carlo error."""
    grid = np.stack(np.meshgrid(*[values] * values.size, indexing="ij"), -1)
    return np.quantile(grid.reshape(-1, values.size).mean(axis=1), qs)


def set_columns(run_dir: Path, **columns: float) -> None:
    """Overwrite (or add) whole eval.csv columns with one value each (the shift columns)."""
    with (run_dir / "eval.csv").open(newline="") as file:
        rows = list(csv.DictReader(file))
    with (run_dir / "eval.csv").open("w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=list({**rows[0], **columns}))
        writer.writeheader()
        writer.writerows({**row, **columns} for row in rows)


@pytest.mark.slow
def test_dimension_study_recovers_known_offsets_per_dimension(tmp_path):
    """Known paired offsets per action dimension and training fraction come back as the study's
    points, normalised by the range of each task's tanh(mu) returns, with the 95% percentile
    bootstrap CI over seeds (checked against the exact bootstrap distribution)."""
    steps = 10_000 * np.arange(1, 9)  # fractions 0.25 / 0.5 / 0.75 / 1 -> steps 20k, 40k, 60k, 80k
    seeds = np.arange(5)
    # Offset of seed s at evaluation k: base x (k + 1) / 8 + spread x (s - 2), mean over seeds
    # base x (k + 1) / 8; the measured shift 0.04 x dims x (1 + 0.1 (s - 2)).
    offsets = {"Hopper-v5": (3, -30.0, 4.0), "Ant-v5": (8, 0.0, 10.0), TASKS[0]: (61, 60.0, 2.0)}
    for task, (dims, base, spread) in offsets.items():
        for seed in seeds:
            paired = 100.0 * np.arange(8) + seed  # range over seeds and steps: 704
            offset = base * np.arange(1, 9) / 8 + spread * (seed - 2)
            run_dir = write_run(tmp_path / "runs", task, "corrected", int(seed), steps,
                                paired + offset, paired, action_dim=dims)
            set_columns(run_dir, mode_shift_abs_sum=0.04 * dims * (1 + 0.1 * (seed - 2)),
                        sigma_mean=0.3, bimodal_fraction=0.01 * seed)
    assert run_analysis(tmp_path / "runs", tmp_path / "out", "--normalize", "min-max",
                        "--reps", "4000") == 0
    assert (tmp_path / "out" / "dimension_study.png").exists()
    summary = read_summary(tmp_path / "out")
    for task, (dims, base, spread) in offsets.items():
        for fraction, k in (("0.25", 1), ("0.5", 3), ("0.75", 5), ("1", 7)):
            row = summary["dimension", task, "corrected", f"normalised_difference@{fraction}"]
            assert int(row["step"]) == steps[k] and int(row["n_runs"]) == 5
            point, low, high = estimate(summary, "dimension", task, "corrected",
                                        f"normalised_difference@{fraction}")
            assert np.isclose(point, base * (k + 1) / 8 / 704)
            per_seed = (base * (k + 1) / 8 + spread * (seeds - 2)) / 704
            # rliable's 4,000 replicates: its 2.5% and 97.5% points lie within the exact
            # distribution's 1.5-3.5% and 96.5-98.5% (four standard errors either way).
            inner_low, outer_low, outer_high, inner_high = exact_bootstrap_quantiles(
                per_seed, (0.015, 0.035, 0.965, 0.985))
            assert inner_low <= low <= outer_low and outer_high <= high <= inner_high
            assert low < point < high
            raw = estimate(summary, "dimension", task, "corrected", f"raw_difference@{fraction}")
            assert np.allclose(raw, np.array([point, low, high]) * 704)
        shift = estimate(summary, "dimension_shift", task, "corrected", "mode_shift_abs_sum")
        assert np.isclose(shift[0], 0.04 * dims) and shift[1] < shift[0] < shift[2]
        assert np.allclose(estimate(summary, "dimension_shift", task, "corrected",
                                    "sigma_mean"), 0.3)
        assert np.isclose(estimate(summary, "dimension_shift", task, "corrected",
                                   "bimodal_fraction")[0], 0.02)
    text = (tmp_path / "out" / "summary.md").read_text()
    assert "## Beyond the paper: the paired difference against the action dimension" in text
    assert text.index("| Hopper-v5 | 3 |") < text.index("| Ant-v5 | 8 |")  # by dimension
    final_rows = {line.split(" | ")[0][2:]: line for line in text.splitlines()
                  if " | 1 (80k) | " in line}
    assert final_rows["Hopper-v5"].startswith(
        "| Hopper-v5 | 3 | Corrected SAC | mode | 5 | 1 (80k) | -30.0 [")
    # Seeds above zero: Hopper's offsets -38..-22, Ant's -20..20, powerlift's 56..64.
    assert [final_rows[t].endswith(f"| {above} of 5 |") for t, above in
            (("Hopper-v5", 0), ("Ant-v5", 2), (TASKS[0], 5))] == [True] * 3


def test_dimension_positions_spread_tasks_that_share_a_dimension():
    study = {t: data.Dimension(d, 1.0, {}, {}, {}) for t, d in
             (("a", 3), ("b", 61), ("c", 61), ("d", 61))}
    xs = figures.dimension_positions(study)
    assert xs["a"] == 3 and np.isclose(xs["c"], 61) and xs["b"] < 61 < xs["d"]
    assert np.isclose(xs["b"] * xs["d"], 61**2)  # symmetric on the log axis


@pytest.mark.slow
def test_dimension_study_needs_two_dimensions(tmp_path):
    steps = 10_000 * np.arange(1, 4)
    for task in TASKS[:2]:
        write_run(tmp_path / "runs", task, "corrected", 0, steps, steps / 1e3, steps / 1e3 - 1)
    assert run_analysis(tmp_path / "runs", tmp_path / "out") == 0
    assert not (tmp_path / "out" / "dimension_study.png").exists()
    assert ("dimension study skipped: it needs paired evaluations against tanh(mu) (corrected "
            "runs, or runs made with --eval-selectors) on tasks of at least two different "
            "action dimensions; found only [61]"
            in (tmp_path / "out" / "summary.md").read_text())


STATS = ["return_mean", "return_std", "return_min", "return_max", "length_mean", "success_rate"]


def write_selector_run(root: Path, env_id: str, algorithm: str, seed: int, steps: np.ndarray,
                       blocks: dict[str, np.ndarray], action_dim: int = 61,
                       **columns: np.ndarray) -> Path:
    """A run whose eval.csv has a block of EVAL_STATS per evaluation action, keyed by column
    prefix ("" is the script's own action), as --eval-selectors writes them, plus further
    columns (q_best's shares, the shift statistics)."""
    run_dir = root / f"{env_id}__{algorithm}__seed{seed}"
    write_config(run_dir, env_id=env_id, seed=seed, algorithm=algorithm,
                 total_timesteps=int(steps[-1]), action_dim=action_dim)
    header = ["global_step", "wall_time", "eval_round"]
    header += [prefix + stat for prefix in blocks for stat in STATS] + list(columns)
    with (run_dir / "eval.csv").open("w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(header)
        for i, step in enumerate(steps):
            row = [int(step), 2.0 * i, i]
            for returns in blocks.values():
                row += [returns[i], 5.0, returns[i] - 9, returns[i] + 9, 1000.0, ""]
            writer.writerow(row + [values[i] for values in columns.values()])
    return run_dir


def test_tasks_with_no_step_in_common_and_other_budgets_share_a_fraction_axis(tmp_path):
    """One task evaluated every 30k steps of 300k, another every 25k of 250k: no step in
    common (but 150k, which is half of one and 60% of the other). The report is written and the
    sample-efficiency curve runs over fractions of each task's budget."""
    runs = tmp_path / "runs"
    grids = {TASKS[0]: 30_000 * np.arange(1, 11), TASKS[1]: 25_000 * np.arange(1, 11)}
    grids[TASKS[1]] = grids[TASKS[1]][grids[TASKS[1]] != 150_000]  # no step in common at all
    for task, steps in grids.items():
        for seed in range(3):
            mode = steps / 1_000.0 + seed
            write_run(runs, task, "corrected", seed, steps, mode, mode - 10)
    assert run_analysis(runs, tmp_path / "out") == 0
    assert (tmp_path / "out" / "sample_efficiency.png").exists()
    text = (tmp_path / "out" / "summary.md").read_text()
    assert ("sample-efficiency curve's x axis is the fraction of each task's budget" in text
            and f"{TASKS[1]} 250k, {TASKS[0]} 300k" in text)
    # By hand: frames from max(30k/300k, 25k/250k) = 0.1 to 1; at 0.5 powerlift's 150k and
    # cube's 125k; at 0.6 cube's last evaluation at or before 150k, which it skipped: 125k.
    loaded, _ = data.load_runs([runs])
    data.standard_from_paired(loaded)
    tasks, _ = data.align(loaded, None)
    norms = data.normalizers(tasks, "success-bar")
    aggregate, _ = data.build_aggregate(tasks, norms, data.ordered_groups(loaded), 19)
    assert aggregate.by_fraction and np.allclose(aggregate.frames, np.linspace(0.1, 1, 19))
    assert aggregate.tasks == [TASKS[1], TASKS[0]]
    seeds = np.arange(3)
    for fraction, cube, powerlift in ((0.5, 125, 150), (0.6, 125, 180)):
        frame = int(np.argmin(np.abs(aggregate.frames - fraction)))
        expected = np.stack([(cube + seeds) / 370, (powerlift + seeds) / 800], axis=1)
        assert np.allclose(aggregate.curves["corrected", "mode"][:, :, frame], expected)


@pytest.mark.slow
def test_auto_normalisation_falls_back_to_min_max_and_says_so(tmp_path):
    runs = tmp_path / "runs"
    steps = 10_000 * np.arange(1, 4)
    for seed in range(2):
        write_run(runs, TASKS[1], "corrected", seed, steps, np.array([100.0, 200, 300]) + seed,
                  np.array([90.0, 190, 290]) + seed)
        write_run(runs, "Hopper-v5", "corrected", seed, steps, np.array([10.0, 20, 40]) + seed,
                  np.array([5.0, 15, 30]) + seed)
    assert run_analysis(runs, tmp_path / "out") == 0
    text = (tmp_path / "out" / "summary.md").read_text()
    assert ("Normalisation `auto` chose `min-max`: no HumanoidBench success bar for Hopper-v5."
            in text)
    # Hopper's returns in the folder span 5 .. 41: seed means at the last step 40.5 -> 35.5/36.
    score = estimate(read_summary(tmp_path / "out"), "task_final", "Hopper-v5", "corrected",
                     "score")[0]
    assert np.isclose(score, (40.5 - 5) / 36)
    only_bars = tmp_path / "bars"
    for seed in range(2):
        write_run(only_bars, TASKS[1], "corrected", seed, steps, steps / 1e3, steps / 1e3 - 1)
    assert run_analysis(only_bars, tmp_path / "bars_out") == 0
    assert "`auto` chose `success-bar`" in (tmp_path / "bars_out" / "summary.md").read_text()


@pytest.mark.slow
def test_every_selector_is_compared_with_tanh_mu(tmp_path):
    """Corrected runs with the mean and q_best blocks, standard runs with mode, mean and q_best
    (one standard seed without them), on tasks of 3 and 61 action dimensions: each selector
    gets its paired difference, its dimension-study rows and q_best its choice shares."""
    runs = tmp_path / "runs"
    steps = 10_000 * np.arange(1, 5)
    rng = np.random.default_rng(5)
    final = {}  # (task, seed) -> action -> return at the last step
    for task, dims in (("Hopper-v5", 3), (TASKS[1], 61)):
        for seed in range(3):
            base = 100.0 * np.arange(1, 5) + 10 * seed
            mode, mean, q_best = (base + rng.normal(0, 5, 4) for _ in range(3))
            final[task, seed] = {"tanh_mu": base[-1], "mode": mode[-1], "q_best": q_best[-1]}
            shares = {"q_best_share_mode": np.full(4, 0.5 + 0.1 * seed),
                      "q_best_share_tanh_mu": np.full(4, 0.3),
                      "q_best_share_mean": np.full(4, 0.2 - 0.1 * seed)}
            write_selector_run(runs, task, "corrected", seed, steps,
                               {"": mode, "tanh_mu_": base, "mean_": mean, "q_best_": q_best},
                               dims, **shares)
            blocks = {"": base, "mode_": mode, "mean_": mean, "q_best_": q_best}
            write_selector_run(runs, task, "standard", seed, steps,
                               blocks if seed < 2 else {"": base}, dims,
                               **(shares if seed < 2 else {}))
    assert run_analysis(runs, tmp_path / "out") == 0
    summary = read_summary(tmp_path / "out")
    groups = ["corrected", "corrected (mean eval)", "corrected (q_best eval)",
              "standard (mode eval)", "standard (mean eval)", "standard (q_best eval)"]
    for task in ("Hopper-v5", TASKS[1]):
        for group in groups:
            row = summary["paired_difference", task, group, "return"]
            assert row["n_runs"] == ("2" if group.startswith("standard") else "3")
            assert ("dimension", task, group, "normalised_difference@1") in summary
    # By hand, at the last step (40k) of cube: q_best minus tanh(mu) over the three corrected
    # seeds; the standard runs' mode_ minus their own tanh(mu) over the two seeds that have it.
    def by_hand(action: str, seeds: range) -> float:
        return float(np.mean([final[TASKS[1], s][action] - final[TASKS[1], s]["tanh_mu"]
                              for s in seeds]))

    assert np.isclose(estimate(summary, "paired_difference", TASKS[1], "corrected (q_best eval)",
                               "return")[0], by_hand("q_best", range(3)))
    assert np.isclose(estimate(summary, "paired_difference", TASKS[1], "standard (mode eval)",
                               "return")[0], by_hand("mode", range(2)))
    assert np.isclose(estimate(summary, "q_best_share", TASKS[1], "corrected (q_best eval)",
                               "mode")[0], 0.6)
    assert np.isclose(estimate(summary, "q_best_share", "Hopper-v5", "standard (q_best eval)",
                               "mean")[0], 0.15)
    text = (tmp_path / "out" / "summary.md").read_text()
    assert "## q_best: which action the critic picked" in text
    assert f"| {TASKS[1]} | 40k | Corrected SAC | q_best | 3 |" in text
    assert f"| {TASKS[1]} | 40k | Standard SAC | mode | 2 |" in text
    names = {p.name for p in (tmp_path / "out").iterdir()}
    assert {"paired_difference.png", "dimension_study.png"} <= names


@pytest.mark.slow
def test_over_training_recovers_known_paired_offsets_and_shift_at_every_step(tmp_path):
    """A paired offset that grows over training, and a shift that shrinks, come back at every
    shared step (summary.csv), not only the last; the figure is written."""
    steps = 10_000 * np.arange(1, 7)
    seeds = np.arange(4)
    for seed in seeds:
        paired = 50.0 * np.arange(6) + seed
        offset = 10.0 * np.arange(6) + 2.0 * (seed - 1.5)  # mean over seeds: 10 x k
        run_dir = write_run(tmp_path / "runs", TASKS[2], "corrected", int(seed), steps,
                            paired + offset, paired)
        with (run_dir / "eval.csv").open(newline="") as file:
            rows = list(csv.DictReader(file))
        for k, row in enumerate(rows):
            row["mode_shift_abs_mean"] = 0.5 / (k + 1) + 0.01 * seed
        with (run_dir / "eval.csv").open("w", newline="") as file:
            writer = csv.DictWriter(file, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    assert run_analysis(tmp_path / "runs", tmp_path / "out", *FAST) == 0
    assert (tmp_path / "out" / "over_training.png").stat().st_size > 10_000
    with (tmp_path / "out" / "summary.csv").open() as file:
        rows = list(csv.DictReader(file))
    paired = [r for r in rows if r["section"] == "paired_over_training"
              and r["metric"] == "return"]
    assert [int(r["step"]) for r in paired] == list(steps)
    for k, row in enumerate(paired):
        assert row["group"] == "corrected" and int(row["n_runs"]) == 4
        assert np.isclose(float(row["estimate"]), 10.0 * k)
        assert float(row["ci_low"]) < float(row["estimate"]) < float(row["ci_high"])
    # Beside each step's bootstrap CI, the t-interval of the four seeds' offsets (spread 2).
    t_rows = [r for r in rows if r["section"] == "paired_over_training"
              and r["metric"] == "return_t"]
    assert [int(r["step"]) for r in t_rows] == list(steps)
    half = scipy.stats.t.ppf(0.975, 3) * np.std(2.0 * (seeds - 1.5), ddof=1) / 2
    for k, row in enumerate(t_rows):
        assert np.allclose([float(row[c]) for c in ("estimate", "ci_low", "ci_high")],
                           [10.0 * k, 10.0 * k - half, 10.0 * k + half])
    shift = [r for r in rows if r["section"] == "shift_over_training"
             and r["metric"] == "mode_shift_abs_mean"]
    assert [int(r["step"]) for r in shift] == list(steps)
    for k, row in enumerate(shift):
        assert np.isclose(float(row["estimate"]), 0.5 / (k + 1) + 0.015)
        assert np.isclose(float(row["ci_low"]), 0.5 / (k + 1))  # the runs' range
        assert np.isclose(float(row["ci_high"]), 0.5 / (k + 1) + 0.03)
    text = (tmp_path / "out" / "summary.md").read_text()
    assert "## Over training: paired differences and the measured shift" in text
    assert "| 60k | 50.0 [" in text  # the last step's row of the table


def test_found_counts_run_folders_not_groups(tmp_path):
    """Corrected runs alone: each folder also gives the derived standard group and its paired
    columns, but it is one run."""
    steps = 10_000 * np.arange(1, 4)
    for seed in range(3):
        write_run(tmp_path / "runs", TASKS[0], "corrected", seed, steps, steps / 1e3,
                  steps / 1e3 - 1)
    assert run_analysis(tmp_path / "runs", tmp_path / "out", *FAST) == 0
    assert f"Found 3 runs under {tmp_path / 'runs'}:" in (tmp_path / "out" /
                                                          "summary.md").read_text()


def write_alternating_folder(root: Path, offsets: list[float], rounds: int = 60,
                             episodes: int | None = 1) -> np.ndarray:
    """Corrected runs whose mode minus tanh(mu) at round k is offset + 100 (-1)^k: an even
    window of rounds averages to the seed's offset, the last (odd) round is offset - 100."""
    steps = 10_000 * np.arange(1, rounds + 1)
    swing = 100.0 * (-1.0) ** np.arange(rounds)
    for seed, offset in enumerate(offsets):
        tanh_mu = 200.0 + 10.0 * seed + steps / 1e4
        run_dir = write_run(root, TASKS[2], "corrected", seed, steps, tanh_mu + offset + swing,
                            tanh_mu)
        if episodes is not None:
            set_columns(run_dir, distinct_episodes=episodes)
    return steps


def test_last_rounds_average_with_t_interval_and_seeds_above_zero(tmp_path):
    offsets = [-30.0, -10.0, 5.0, 20.0, 40.0]
    write_alternating_folder(tmp_path / "runs", offsets)
    assert run_analysis(tmp_path / "runs", tmp_path / "out") == 0
    summary = read_summary(tmp_path / "out")
    last = np.array(offsets) - 100.0
    key = ("paired_difference", TASKS[2], "corrected")
    assert np.allclose(estimate(summary, *key, "return_t"), estimators.t_interval(last))
    assert np.allclose(estimate(summary, *key, "score_t"),
                       np.array(estimators.t_interval(last)) / 2000)
    for k in (20, 50):
        key = ("paired_last_rounds", TASKS[2], "corrected")
        point, low, high = estimate(summary, *key, f"return_last{k}")
        assert np.isclose(point, np.mean(offsets)) and low < point < high
        assert np.allclose(estimate(summary, *key, f"return_last{k}_t")[1:],
                           scipy.stats.t.interval(0.95, 4, loc=np.mean(offsets),
                                                  scale=scipy.stats.sem(offsets)))
        assert estimate(summary, *key, f"share_above_zero_last{k}")[0] == 0.6
        assert summary[(*key, f"return_last{k}")]["step"] == "600000"
    text = (tmp_path / "out" / "summary.md").read_text()
    assert "With 5 seeds or fewer a percentile bootstrap CI is narrower" in text
    assert "each seed's evaluation at 600k is one episode" in text
    t_low, t_high = estimators.t_interval(np.array(offsets))[1:]
    assert ("| last 20 (410k-600k), one episode each | 5.0 [" in text
            and f"| [{t_low:.1f}, {t_high:.1f}] | 3 of 5 |" in text)
    assert "| last 50 (110k-600k), one episode each | 5.0 [" in text
    assert "| last (600k) | -95.0 [" in text
    assert "over the last 20 / 50" not in text  # no task was short of rounds
    assert (tmp_path / "out" / "paired_difference.png").exists()


def test_last_rounds_need_the_rounds_and_two_seeds_are_a_range(tmp_path):
    write_alternating_folder(tmp_path / "runs", [-30.0, 12.0], rounds=30, episodes=None)
    assert run_analysis(tmp_path / "runs", tmp_path / "out") == 0
    summary = read_summary(tmp_path / "out")
    assert ("paired_last_rounds", TASKS[2], "corrected", "return_last20") in summary
    assert ("paired_last_rounds", TASKS[2], "corrected", "return_last50") not in summary
    text = (tmp_path / "out" / "summary.md").read_text()
    assert (f"averages over the last 20 / 50 evaluation rounds left out where a task has fewer "
            f"shared rounds up to its scored step: {TASKS[2]} (30 rounds)") in text
    # Two seeds: the two values in place of the bootstrap CI; the t-interval, one degree of
    # freedom: -9 +- 12.706 * 21 (their standard error).
    assert "| last 20 (110k-300k) | -9.0 (two seeds: -30.0 to 12.0) | [-275.8, 257.8] | 1 of 2 |" \
        in text
    assert "-109.0 (two seeds: -130.0 to -88.0) | [-375.8, 157.8] |" in text  # the last round
    assert "one episode" not in text  # the runs did not log distinct_episodes


def test_one_shared_step_leaves_the_sample_efficiency_curve_out(tmp_path):
    """Tasks evaluated every 25k and every 20k steps of 100k share only the last step."""
    for task, interval in ((TASKS[0], 25_000), (TASKS[1], 20_000)):
        steps = np.arange(interval, 100_001, interval)
        for seed in range(3):
            mode = steps / 1e3 + seed
            write_run(tmp_path / "runs", task, "corrected", seed, steps, mode, mode - 5)
    assert run_analysis(tmp_path / "runs", tmp_path / "out") == 0
    assert not (tmp_path / "out" / "sample_efficiency.png").exists()
    assert ("sample-efficiency curve left out: the aggregated tasks share one evaluation point "
            "(100k)" in (tmp_path / "out" / "summary.md").read_text())


def test_success_bar_is_drawn_only_near_the_returns():
    assert figures.success_bar_drawn(800.0, 600.0)
    assert not figures.success_bar_drawn(2000.0, 650.0)  # bookshelf_simple at 1M: named instead
    assert not figures.success_bar_drawn(800.0, -5.0)


TOY_TASK, TOY_BAR = "toy-reach-v0", 50.0


def write_toy_folder(root: Path) -> dict[tuple[str, int], dict[str, float]]:
    """Corrected runs with the paired tanh(mu) block and a `median_` block (a new evaluation
    action) on a new task (2 action dimensions) and on cube (61). Returns, per (task, seed), each
    action's return at the last step."""
    steps = 10_000 * np.arange(1, 5)
    rng = np.random.default_rng(11)
    final = {}
    for task, dims in ((TOY_TASK, 2), (TASKS[1], 61)):
        for seed in range(3):
            base = 10.0 * np.arange(1, 5) + seed
            mode, median = (base + rng.normal(0, 2, 4) for _ in range(2))
            final[task, seed] = {"mode": mode[-1], "tanh_mu": base[-1], "median": median[-1]}
            write_selector_run(root, task, "corrected", seed, steps,
                               {"": mode, "tanh_mu_": base, "median_": median}, dims)
    return final


@pytest.mark.slow
def test_a_new_task_and_a_new_evaluation_action_are_one_entry_each(tmp_path, monkeypatch):
    """docs/analyze.md: a task with a success bar is one entry in SUCCESS_BARS, an evaluation
    action one entry in ACTIONS; with them, both go through every report."""
    final = write_toy_folder(tmp_path / "runs")
    # Without the two entries: the toy task has no bar (auto falls back to min-max) and the
    # median_ columns are not read.
    assert run_analysis(tmp_path / "runs", tmp_path / "before") == 0
    assert "`auto` chose `min-max`: no HumanoidBench success bar for toy-reach-v0" in \
        (tmp_path / "before" / "summary.md").read_text()
    assert not any("median" in key[2] for key in read_summary(tmp_path / "before"))

    monkeypatch.setitem(data.SUCCESS_BARS, TOY_TASK, TOY_BAR)
    monkeypatch.setitem(data.ACTIONS, "median", "median")
    out = tmp_path / "out"
    assert run_analysis(tmp_path / "runs", out) == 0
    summary = read_summary(out)
    text = (out / "summary.md").read_text()
    # The task: scored against its bar, in every table.
    assert "`auto` chose `success-bar`" in text and f"{TOY_TASK} {TOY_BAR:g}" in text
    mode = np.mean([final[TOY_TASK, s]["mode"] for s in range(3)])
    assert np.isclose(estimate(summary, "task_final", TOY_TASK, "corrected", "return")[0], mode)
    assert np.isclose(estimate(summary, "task_final", TOY_TASK, "corrected", "score")[0],
                      mode / TOY_BAR)
    # The action: its own group, compared with tanh(mu) of the same actors everywhere.
    group = "corrected (median eval)"
    by_hand = np.mean([final[TOY_TASK, s]["median"] - final[TOY_TASK, s]["tanh_mu"]
                       for s in range(3)])
    assert np.isclose(estimate(summary, "paired_difference", TOY_TASK, group, "return")[0],
                      by_hand)
    assert np.isclose(estimate(summary, "paired_difference", TOY_TASK, group, "score")[0],
                      by_hand / TOY_BAR)
    for key in [("paired_difference", "all", group, "mean_score"),
                ("paired_over_training", TOY_TASK, group, "return"),
                ("task_final", TOY_TASK, group, "return"),
                ("aggregate", "all", group, "IQM"),
                ("dimension", TOY_TASK, group, "normalised_difference@1")]:
        assert key in summary, key
    assert f"| {TOY_TASK} | 40k | Corrected SAC | median | 3 |" in text  # the headline table
    assert "median minus tanh(mu)" in text  # the over-training table
    assert f"| {TOY_TASK} | 2 | Corrected SAC | median | 3 | 1 (40k) |" in text  # dimensions
    assert {"paired_difference.png", "over_training.png", "reward_curves.png",
            "dimension_study.png"} <= {p.name for p in out.iterdir()}


def test_an_analysis_changes_no_module_state(tmp_path):
    """The standard group's label ("Standard SAC (tanh(mu), paired)" here) is passed to the
    reports, not written into the module: every module-level setting is the same afterwards."""
    import copy

    def settings() -> dict:
        return {name: copy.deepcopy(value) for name, value in vars(analyze).items()
                if name.isupper() and not callable(value)}

    before = settings()
    steps = 10_000 * np.arange(1, 4)
    for seed in range(2):
        write_run(tmp_path / "runs", TASKS[0], "corrected", seed, steps, steps / 1e3 + seed,
                  steps / 1e3 - 1)
    assert run_analysis(tmp_path / "runs", tmp_path / "out") == 0
    assert "Standard SAC (tanh(mu), paired)" in (tmp_path / "out" / "summary.md").read_text()
    assert settings() == before


def test_no_report_section_calls_another():
    """analyze.py's layout (docs/analyze.md): within it, a report's section (a `# --- N. title`
    banner under `# === the reports`) uses the data (analysis/data.py) and the shared tools,
    never another report's section; the shared tools use no report's, and the data imports
    nothing that draws or reports."""
    import ast
    import re

    source = Path(analyze.__file__).read_text()
    banners = [(i + 1, line) for i, line in enumerate(source.splitlines())
               if re.match(r"# [=-]{5,} ", line)]

    def part(lineno: int) -> str:
        major = minor = ""
        for start, line in banners:
            if start > lineno:
                break
            if line.startswith("# ="):
                major, minor = line.split("= ", 1)[1], ""
            else:
                minor = line.split("- ", 1)[1]
        return f"report {minor}" if major == "the reports" else major

    defined = {}
    for node in ast.parse(source).body:
        targets = [node] if isinstance(node, ast.FunctionDef | ast.ClassDef) else \
            getattr(node, "targets", [getattr(node, "target", None)])
        for target in targets:
            name = getattr(target, "name", None) or getattr(target, "id", None)
            if name:
                defined[name] = (part(node.lineno), node)
    sections = {where for where, _ in defined.values() if where.startswith("report ")}
    assert len(sections) >= 9 and "shared tools" in {w for w, _ in defined.values()}
    tree = ast.parse(Path(data.__file__).read_text())
    imported = {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import)
                for alias in node.names}
    imported |= {f"{node.module}.{alias.name}" for node in ast.walk(tree)
                 if isinstance(node, ast.ImportFrom) for alias in node.names}
    assert not {name for name in imported
                if name.split(".")[0] in ("analyze", "matplotlib", "seaborn", "rliable")
                or name.startswith(("analysis.figures", "analysis.report.Report"))}, imported
    crossings = []
    for name, (where, node) in defined.items():
        for used in {n.id for n in ast.walk(node) if isinstance(n, ast.Name)} & set(defined):
            other = defined[used][0]
            if other.startswith("report ") and other != where and where != "the pipeline":
                crossings.append(f"{name} ({where}) uses {used} ({other})")
    assert not crossings, crossings


# ------------------------------------------------------------- the robust evaluation (--robust)
ROBUST_TASKS = ["h1hand-cube-v0", "h1hand-stand-v0"]  # success bars 370 and 800
ROBUST_STEPS = (500_000, 1_000_000)
ROBUST_HEADER = "step,selector,episode,reset_seed,return,length,success"


def robust_returns(task: int, seed: int, step: int, episodes: int) -> dict[str, np.ndarray]:
    """Known returns by selector in episode order: the mode beats tanh(mu) by a task-, seed- and
    step-dependent amount with episode-to-episode scatter, the mean loses a little."""
    tanh_mu = 100.0 + 50 * seed + 20 * np.arange(episodes) + step / 1e4
    scatter = np.array([-3.0, 1.0, 4.0, -1.0])[:episodes]
    return {"mode": tanh_mu + (10 + 7 * task) * (seed + 1) + step / 1e5 + scatter,
            "tanh_mu": tanh_mu, "mean": tanh_mu - 2.0 - seed + 0.5 * scatter}


def write_robust_folder(root: Path, tasks: list[str], seeds: int = 3, episodes: int = 4,
                        steps: tuple[int, ...] = ROBUST_STEPS) -> dict:
    """evaluate.py's campaign folder, by hand: evaluation.json and one episodes.csv per run (rows
    in reverse episode order, selectors interleaved). Returns (task, seed, step) -> returns."""
    settings = {"episodes": episodes, "reset_noise": 0.01, "selectors": ["mode", "tanh_mu", "mean"],
                "runs": {}}
    written = {}
    for t, task in enumerate(tasks):
        for seed in range(seeds):
            run = f"{task}__corrected__seed{seed}__0000"
            settings["runs"][run] = {"env_id": task, "seed": seed}
            lines = [ROBUST_HEADER]
            for step in steps:
                written[task, seed, step] = robust_returns(t, seed, step, episodes)
                for k in reversed(range(episodes)):
                    lines += [f"{step},{selector},{k},{1000 + k},{float(values[k])!r},1000,False"
                              for selector, values in written[task, seed, step].items()]
            (root / run).mkdir(parents=True)
            (root / run / "episodes.csv").write_text("\n".join(lines) + "\n")
    (root / "evaluation.json").write_text(json.dumps(settings))
    write_per_seed(root)
    return written


def write_per_seed(folder: Path) -> None:
    """The folder's per_seed.csv from its episodes.csv files, as evaluate.py writes it (what
    analyze.py --robust reads)."""
    import evaluate

    settings, episodes = evaluate.read_campaign(folder)
    evaluate.write_rows(folder / "per_seed.csv", evaluate.per_seed_rows(settings, episodes))


def write_small_runs(root: Path) -> Path:
    for seed in range(2):
        write_run(root, TASKS[0], "corrected", seed, 10_000 * np.arange(1, 4), np.ones(3),
                  np.zeros(3))
    return root


def read_rows(out: Path) -> list[dict]:
    with (out / "summary.csv").open() as file:
        return list(csv.DictReader(file))


def row_at(rows: list[dict], section: str, task: str, group: str, metric: str, step: int
           ) -> tuple[float, float, float]:
    """summary.csv's (estimate, ci_low, ci_high) of one estimate at one step."""
    [row] = [r for r in rows if (r["section"], r["task"], r["group"], r["metric"], r["step"])
             == (section, task, group, metric, str(step))]
    return float(row["estimate"]), float(row["ci_low"]), float(row["ci_high"])


def test_robust_evaluation_matches_a_hand_computation(tmp_path):
    runs = write_small_runs(tmp_path / "runs")
    written = write_robust_folder(tmp_path / "robust", ROBUST_TASKS)
    out = tmp_path / "out"
    assert run_analysis(runs, out, "--robust", str(tmp_path / "robust")) == 0
    rows = read_rows(out)
    quantile = scipy.stats.t.ppf(0.975, 2)  # three seeds
    last = ROBUST_STEPS[-1]
    normalised = {action: [] for action in ("mode", "mean")}  # the last step's mean / bar
    for task in ROBUST_TASKS:
        for step in ROBUST_STEPS:
            episodes = [written[task, seed, step] for seed in range(3)]
            for action in normalised:
                per_seed = np.array([np.mean(e[action] - e["tanh_mu"]) for e in episodes])
                mean, half = per_seed.mean(), quantile * per_seed.std(ddof=1) / np.sqrt(3)
                assert np.allclose(row_at(rows, "robust_difference", task, action, "return_t",
                                          step), (mean, mean - half, mean + half))
                assert np.isclose(row_at(rows, "robust_difference", task, action, "return",
                                         step)[0], mean)
                if step == last:
                    normalised[action].append(mean / data.SUCCESS_BARS[task])
            assert np.isclose(row_at(rows, "robust_return", task, "tanh_mu", "return", step)[0],
                              np.mean([e["tanh_mu"].mean() for e in episodes]))
    for action, values in normalised.items():
        for metric in ("mean_score", "mean_score_t"):
            assert np.isclose(row_at(rows, "robust_difference", "all", action, metric, last)[0],
                              np.mean(values)), (metric, action)
    assert row_at(rows, "robust_difference", "all", "mode", "share_above_zero", last)[0] == 1.0
    assert {r["metric"] for r in rows if r["section"] == "robust_aggregate"} == \
        {"IQM", "Median", "Mean", "Optimality Gap"}
    for action in ("mode", "tanh_mu", "mean"):  # (seeds x tasks) mean returns / success bar
        matrix = np.array([[written[task, seed, last][action].mean() / data.SUCCESS_BARS[task]
                            for task in ROBUST_TASKS] for seed in range(3)])
        assert np.isclose(row_at(rows, "robust_aggregate", "all", action, "Mean", last)[0],
                          matrix.mean())
        assert np.isclose(row_at(rows, "robust_aggregate", "all", action, "Optimality Gap",
                                 last)[0], np.maximum(1 - matrix, 0).mean())
    for step in ROBUST_STEPS:  # rliable's IQM: the 25% trimmed mean of all (seed, task) scores
        matrix = [written[task, seed, step]["mode"].mean() / data.SUCCESS_BARS[task]
                  for task in ROBUST_TASKS for seed in range(3)]
        assert np.isclose(row_at(rows, "robust_sample_efficiency", "all", "mode", "IQM", step)[0],
                          scipy.stats.trim_mean(matrix, 0.25))
    for figure in ("robust_evaluation", "robust_per_seed", "robust_aggregate_metrics",
                   "robust_performance_profiles", "robust_sample_efficiency"):
        assert (out / f"{figure}.png").is_file(), figure
    text = (out / "summary.md").read_text()
    assert "## The robust evaluation" in text
    assert "3 runs x 2 tasks: IQM is the mean of the middle 4 of 6 runs" in text


def test_per_seed_figure_fills_the_seeds_the_three_se_rule_decides():
    """robust_per_seed: one marker per (step, action, seed) at its value, +-3 SE whiskers,
    filled exactly where estimators.verdict is ahead or behind, and an axis that holds every
    whisker (the mean's t-interval, which hides them in robust_evaluation, plays no part)."""
    import matplotlib.colors

    values = {(0, "mode"): [-2.0, 0.5], (0, "mean"): [0.1, 4.0], (1, "mode"): [1.0, -0.3]}
    errors = {(0, "mode"): [0.5, 0.4], (0, "mean"): [0.2, 1.0], (1, "mode"): [0.3, 0.2]}
    cells = {key: figures.PairedCell(np.array(v), (0.0, -50.0, 50.0), (0.0, -90.0, 90.0),
                                     np.array(errors[key]), seeds=[2, 3])
             for key, v in values.items()}
    row = figures.PairedRow("task", ["1M", "2M"], cells, "return minus tanh(mu)'s", (10.0, "2M"))
    colors = {"mode": (0.9, 0.6, 0.0), "mean": (0.0, 0.6, 0.5)}
    fig = figures.plot_per_seed([row], colors, {"mode": "mode", "mean": "mean"}, "test")
    ax = fig.axes[0]
    markers = [line for line in ax.lines if line.get_marker() not in ("None", "", None)]
    drawn = {}
    for line in markers:
        [x], [y] = line.get_data()
        filled = matplotlib.colors.to_rgba(line.get_markerfacecolor()) != (1.0, 1.0, 1.0, 1.0)
        drawn[round(float(y), 6)] = (filled, line.get_marker())
    expected = {}
    for key, vs in values.items():
        for seed, v, e in zip([2, 3], vs, errors[key], strict=True):
            decided = estimators.verdict(v, e) in ("ahead", "behind")
            expected[round(v, 6)] = (decided, "o" if seed == 2 else "s")
    assert drawn == expected
    low, high = ax.get_ylim()
    ends = [v + sign * 3 * e for key in values
            for v, e in zip(values[key], errors[key], strict=True) for sign in (-1, 1)]
    assert low <= min(ends) and high >= max(ends)
    assert high < 50.0  # scaled to the seeds, not to the t-interval
    figures.plt.close(fig)


def test_robust_folders_read_alike_with_and_without_physics_unstable(tmp_path):
    """evaluate.py's episodes.csv gained physics_unstable (empty where not recorded), then end:
    folders written before them and after read to the same per-seed returns and differences."""
    from evaluate import EPISODES_HEADER

    written = write_robust_folder(tmp_path / "old", ROBUST_TASKS, seeds=2)
    new = tmp_path / "new"
    write_robust_folder(new, ROBUST_TASKS, seeds=2)
    assert ROBUST_HEADER.split(",") == EPISODES_HEADER[:-2]
    for path in new.glob("*/episodes.csv"):
        header, *rows = path.read_text().splitlines()
        path.write_text("\n".join([",".join(EPISODES_HEADER), *(
            f"{row},{('', '0', '1')[k % 3]},{('', 'fell', 'blow_up')[k % 3]}"
            for k, row in enumerate(rows))]) + "\n")
    write_per_seed(new)
    old, fresh = (data.load_robust([tmp_path / name]).rows for name in ("old", "new"))
    assert len(old) == len(fresh) == sum(map(len, written.values()))
    for (task, seed, step), selectors in written.items():
        for selector, values in selectors.items():
            for rows in (old, fresh):
                [row] = rows[(rows.env_id == task) & (rows.seed == seed) & (rows.step == step)
                             & (rows.selector == selector)].itertuples()
                assert row.return_mean == values.mean()
                if selector != "tanh_mu":
                    assert row.difference_mean == (values - selectors["tanh_mu"]).mean()


def mark_blowups(folder: Path, unstable: Callable[[int, str, int], str]) -> None:
    """Give every episodes.csv under folder evaluate.py's physics_unstable column (last, as
    before `end` followed it), the cell of (step, selector, episode) from unstable."""
    from evaluate import EPISODES_HEADER

    for path in folder.glob("*/episodes.csv"):
        _, *rows = path.read_text().splitlines()
        marked = [f"{row},{unstable(int(step), selector, int(k))}"
                  for row in rows for step, selector, k, *_ in [row.split(",")]]
        path.write_text("\n".join([",".join(EPISODES_HEADER[:-1]), *marked]) + "\n")
    write_per_seed(folder)


def test_robust_counts_physics_blowups_per_action_and_step(tmp_path):
    """The episodes a physics blow-up ended, summed over seeds, per task, step and action; a
    policy evaluated before physics_unstable existed makes its (task, step, action) n/r."""
    runs = write_small_runs(tmp_path / "runs")
    write_robust_folder(tmp_path / "new", ROBUST_TASKS[:1], seeds=2, steps=(1_000_000,))
    # the mode blows up in episodes 0 and 2 of each seed, the mean in episode 3, tanh(mu) never
    mark_blowups(tmp_path / "new", lambda step, selector, k: str(int(
        (selector == "mode" and k in (0, 2)) or (selector == "mean" and k == 3))))
    write_robust_folder(tmp_path / "old", ROBUST_TASKS[:1], seeds=2, steps=(500_000,))
    out = tmp_path / "out"
    assert run_analysis(runs, out, "--robust", str(tmp_path / "new"), str(tmp_path / "old")) == 0
    ends = {(r["step"], r["group"]): float(r["estimate"]) for r in read_rows(out)
            if r["section"] == "robust_unstable_ends"}
    assert ends == {("1000000", "mode"): 4.0, ("1000000", "tanh_mu"): 0.0,
                    ("1000000", "mean"): 2.0}
    text = (out / "summary.md").read_text()
    assert "| blow-ups |" in text and "| 4 of 8 |" in text and "| 2 of 8 |" in text
    assert "| n/r |" in text  # the 500k policies, evaluated without the column
    # without any recorded blow-up there is no column
    assert run_analysis(runs, tmp_path / "out2", "--robust", str(tmp_path / "old")) == 0
    assert "blow-ups" not in (tmp_path / "out2" / "summary.md").read_text()


def test_without_robust_the_section_writes_nothing(tmp_path):
    out = tmp_path / "out"
    assert run_analysis(write_small_runs(tmp_path / "runs"), out) == 0
    assert not [r for r in read_rows(out) if r["section"].startswith("robust")]
    assert not list(out.glob("robust_*.png"))
    assert "robust evaluation" not in (out / "summary.md").read_text()


def test_robust_task_without_a_bar_is_left_out_of_the_aggregate(tmp_path):
    write_robust_folder(tmp_path / "robust", ["h1hand-cube-v0", "Hopper-v5"])
    out = tmp_path / "out"
    assert run_analysis(write_small_runs(tmp_path / "runs"), out, "--robust",
                        str(tmp_path / "robust")) == 0
    rows = read_rows(out)
    assert [r for r in rows if r["task"] == "Hopper-v5" and r["metric"] == "return"]
    assert {r["n_runs"] for r in rows if r["section"] == "robust_aggregate"} == {"3"}
    assert "No success bar for Hopper-v5" in (out / "summary.md").read_text()


def test_robust_ticks_name_the_cpu_only_where_a_task_changed_machine(tmp_path):
    """On another kind of CPU an evaluation plays other draws of its episodes: a task whose steps
    were evaluated on two kinds says which on each step's tick, and summary.md names each
    folder's CPU where evaluation.json records it."""
    machines = {500_000: "AMD EPYC", 1_000_000: "Intel(R) Xeon(R) Processor @ 2.80GHz"}
    folders = []
    for step, cpu in machines.items():
        folders.append(tmp_path / f"robust-{step}")
        write_robust_folder(folders[-1], ROBUST_TASKS, seeds=2, steps=(step,))
        settings = json.loads((folders[-1] / "evaluation.json").read_text())
        (folders[-1] / "evaluation.json").write_text(json.dumps(
            {**settings, "machine": {"cpu": cpu, "cores": 2}}))
    by_task = data.robust_paired_differences(data.load_robust(folders))
    assert analyze.robust_ticks(by_task[ROBUST_TASKS[0]]) == [
        "500k\n4 starts\nx 2 seeds\nAMD EPYC", "1M\n4 starts\nx 2 seeds\nIntel Xeon"]
    one_kind = data.robust_paired_differences(data.load_robust(folders[:1]))
    assert analyze.robust_ticks(one_kind[ROBUST_TASKS[0]]) == ["500k\n4 starts\nx 2 seeds"]
    out = tmp_path / "out"
    assert run_analysis(write_small_runs(tmp_path / "runs"), out, "--robust",
                        *map(str, folders)) == 0
    text = (out / "summary.md").read_text()
    assert "actions mode, tanh_mu, mean, on AMD EPYC (2 cores)" in text
    assert "on Intel Xeon (2 cores)" in text


@pytest.mark.slow
def test_robust_curve_leaves_out_a_task_evaluated_at_one_step(tmp_path):
    """A task whose final weights alone were evaluated (no snapshots) cannot join the robust
    sample-efficiency curve: the curve is over the others, and summary.md names it; with no task
    evaluated twice there is no curve."""
    runs = write_small_runs(tmp_path / "runs")
    write_robust_folder(tmp_path / "curve", ROBUST_TASKS[:1])
    write_robust_folder(tmp_path / "final", ROBUST_TASKS[1:], steps=(1_000_000,))
    out = tmp_path / "out"
    assert run_analysis(runs, out, "--robust", str(tmp_path / "curve"),
                        str(tmp_path / "final")) == 0
    curve = [r for r in read_rows(out) if r["section"] == "robust_sample_efficiency"]
    assert {r["step"] for r in curve} == {str(s) for s in ROBUST_STEPS}
    assert (out / "robust_sample_efficiency.png").is_file()
    assert f"{ROBUST_TASKS[1]} left out (evaluated at one step only)" in \
        (out / "summary.md").read_text()
    assert run_analysis(runs, tmp_path / "out2", "--robust", str(tmp_path / "final")) == 0
    assert not (tmp_path / "out2" / "robust_sample_efficiency.png").exists()
    assert (tmp_path / "out2" / "robust_aggregate_metrics.png").is_file()
    write_robust_folder(tmp_path / "apart", ROBUST_TASKS[1:], steps=(250_000, 1_000_000))
    assert run_analysis(runs, tmp_path / "out3", "--robust", str(tmp_path / "curve"),
                        str(tmp_path / "apart")) == 0  # the two share 1M only
    assert not (tmp_path / "out3" / "robust_sample_efficiency.png").exists()
    assert "No robust sample-efficiency curve" in (tmp_path / "out3" / "summary.md").read_text()


def test_bad_robust_folders_give_one_clear_line(tmp_path, capsys):
    runs = write_small_runs(tmp_path / "runs")
    cases = {"no_settings": "no evaluation.json there", "no_per_seed": "per_seed.csv is missing",
             "bad_header": "lacks ['selector']", "no_tanh_mu": "no tanh_mu episodes at step 500k",
             "not_a_number": "column return_mean holds something that is not a number",
             "twice": "step 500k is in two --robust folders"}
    for name, message in cases.items():
        folder = tmp_path / name
        write_robust_folder(folder, ROBUST_TASKS[:1], seeds=1, steps=(500_000,))
        per_seed = folder / "per_seed.csv"
        folders = [folder]
        if name == "no_settings":
            (folder / "evaluation.json").unlink()
        elif name == "no_per_seed":
            per_seed.unlink()
        elif name == "bad_header":
            per_seed.write_text(per_seed.read_text().replace("selector", "action", 1))
        elif name == "no_tanh_mu":
            per_seed.write_text("\n".join(line for line in per_seed.read_text().splitlines()
                                          if ",tanh_mu," not in line) + "\n")
        elif name == "not_a_number":
            lines = per_seed.read_text().splitlines()
            cells = lines[1].split(",")
            cells[6] = "lots"
            per_seed.write_text("\n".join([lines[0], ",".join(cells), *lines[2:]]) + "\n")
        else:
            write_robust_folder(tmp_path / "again", ROBUST_TASKS[:1], seeds=1, steps=(500_000,))
            folders.append(tmp_path / "again")
        assert run_analysis(runs, tmp_path / "out", "--robust", *map(str, folders)) == 2, name
        error = capsys.readouterr().err.strip()
        assert message in error and len(error.splitlines()) == 1, (name, error)


def test_robust_tells_seeds_ahead_level_behind_and_how_episodes_ended(tmp_path):
    """Per task, step and action, the seeds more than three standard errors of their paired
    episodes above zero, within, or below (estimators.verdict); and, where evaluate.py's `end`
    column records it, how each seed's episodes ended."""
    from evaluate import EPISODES_HEADER

    runs = write_small_runs(tmp_path / "runs")
    folder = tmp_path / "robust"
    written = write_robust_folder(folder, ROBUST_TASKS[:1], seeds=3, steps=(1_000_000,))
    for path in folder.glob("*/episodes.csv"):
        _, *rows = path.read_text().splitlines()
        ends = ["fell" if row.split(",")[1:3] == ["mode", "0"] else "time_limit" for row in rows]
        path.write_text("\n".join([",".join(EPISODES_HEADER), *(
            f"{row},0,{end}" for row, end in zip(rows, ends, strict=True))]) + "\n")
    write_per_seed(folder)
    assert run_analysis(runs, tmp_path / "out", "--robust", str(folder)) == 0
    text = (tmp_path / "out" / "summary.md").read_text()
    counts = {"ahead": 0, "level": 0, "behind": 0}
    for seed in range(3):
        diffs = written[ROBUST_TASKS[0], seed, 1_000_000]["mode"] - \
            written[ROBUST_TASKS[0], seed, 1_000_000]["tanh_mu"]
        se = diffs.std(ddof=1) / np.sqrt(diffs.size)
        counts["level" if abs(diffs.mean()) <= 3 * se else
               "ahead" if diffs.mean() > 0 else "behind"] += 1
    assert f"| {counts['ahead']} / {counts['level']} / {counts['behind']} |" in text
    # per seed (report.per_seed_tables, evaluate.py's too): fell, time limit, the paired falls
    assert "| 0 | 1M | mode | 1 | 3 | +0.25 +- 0.25: level, 1.0 SE | 0 |" in text
    assert "| 0 | 1M | tanh_mu | 0 | 4 |  | 0 |" in text
    assert "| fell (mode / tanh(mu)) | time limit (mode / tanh(mu)) |" in text


def test_robust_aggregate_from_one_seed_prints_no_interval(tmp_path):
    """A bootstrap over one run resamples that run alone: the robust aggregate table says n/a,
    as the main tables do."""
    write_robust_folder(tmp_path / "robust", ROBUST_TASKS, seeds=1)
    out = tmp_path / "out"
    assert run_analysis(write_small_runs(tmp_path / "runs"), out, "--robust",
                        str(tmp_path / "robust")) == 0
    text = (out / "summary.md").read_text()
    table = [line for line in text.splitlines() if line.startswith("| tanh_mu |")][-1]
    assert table.count("(n/a)") == 4, table


def write_dimension_runs(root: Path, tasks: dict[str, int]) -> None:
    """Three seeds' training logs per task, each config.json with the task's action dimension."""
    for task, dim in tasks.items():
        for seed in range(3):
            write_run(root, task, "corrected", seed, 10_000 * np.arange(1, 4), np.ones(3),
                      np.zeros(3), action_dim=dim)


def test_robust_dimension_says_where_shares_and_returns_disagree_about_zero(tmp_path):
    """Dividing by each seed's return weighs the seeds differently: on cube below every seed's
    mode loses 10% of its return (the shares' interval excludes zero) while the losses in return,
    0.1 to 10, leave zero inside theirs (the task's verdict). summary.md names that pair, and
    only that pair."""
    tasks = {"Hopper-v5": 3, "h1hand-cube-v0": 61}
    settings = {"episodes": 4, "reset_noise": 0.01, "selectors": ["mode", "tanh_mu", "mean"],
                "runs": {}}
    write_dimension_runs(tmp_path / "runs", tasks)
    for task, dim in tasks.items():
        for seed in range(3):
            scale = 10.0 ** seed if dim == 61 else 100.0
            tanh_mu = scale * (1 + 0.01 * np.arange(4))
            returns = {"mode": 0.9 * tanh_mu if dim == 61 else tanh_mu + 1, "tanh_mu": tanh_mu,
                       "mean": tanh_mu + np.array([1.0, -1.0, 1.0, -1.0])}
            name = f"{task}__corrected__seed{seed}__0000"
            settings["runs"][name] = {"env_id": task, "seed": seed}
            lines = [ROBUST_HEADER] + [
                f"1000000,{selector},{k},{1000 + k},{float(values[k])!r},1000,False"
                for selector, values in returns.items() for k in range(4)]
            (tmp_path / "robust" / name).mkdir(parents=True)
            (tmp_path / "robust" / name / "episodes.csv").write_text("\n".join(lines) + "\n")
    (tmp_path / "robust" / "evaluation.json").write_text(json.dumps(settings))
    write_per_seed(tmp_path / "robust")
    out = tmp_path / "out"
    assert run_analysis(tmp_path / "runs", out, "--robust", str(tmp_path / "robust")) == 0
    text = (out / "summary.md").read_text()
    assert "disagree on whether zero is inside for cube mode: shares -10.0% to -10.0%" in text
    assert "cube mean:" not in text and "Hopper mode:" not in text
    assert "Hopper mean:" not in text


def test_robust_dimension_study_is_each_seeds_share_of_its_tanh_mu_return(tmp_path):
    """With robust evaluations of tasks of two action dimensions: per task at its last robust
    step, each action's paired difference over that seed's tanh(mu) return, mean over seeds
    with its t-interval; with one dimension there is none."""
    tasks = {"Hopper-v5": 3, "h1hand-cube-v0": 61}
    write_dimension_runs(tmp_path / "runs", tasks)
    written = write_robust_folder(tmp_path / "robust", list(tasks))
    out = tmp_path / "out"
    assert run_analysis(tmp_path / "runs", out, "--robust", str(tmp_path / "robust")) == 0
    rows = read_rows(out)
    quantile = scipy.stats.t.ppf(0.975, 2)  # three seeds
    last = ROBUST_STEPS[-1]
    for task in tasks:
        for action in ("mode", "mean"):
            shares = np.array([np.mean(e[action] - e["tanh_mu"]) / e["tanh_mu"].mean()
                               for e in (written[task, seed, last] for seed in range(3))])
            mean, half = shares.mean(), quantile * shares.std(ddof=1) / np.sqrt(3)
            assert np.allclose(row_at(rows, "robust_dimension", task, action,
                                      "relative_difference_t", last),
                               (mean, mean - half, mean + half))
            assert np.isclose(row_at(rows, "robust_dimension", task, action,
                                     "relative_difference", last)[0], mean)
    assert (out / "robust_dimension.png").is_file()
    text = (out / "summary.md").read_text()
    assert "## Beyond the paper: the robust evaluation against the action dimension" in text
    assert "| Hopper-v5 | 3 | 1M | mode | 3 |" in text and "| h1hand-cube-v0 | 61 | 1M |" in text

    one = tmp_path / "one"
    write_robust_folder(tmp_path / "robust-one", ["h1hand-cube-v0"])
    assert run_analysis(tmp_path / "runs", one, "--robust", str(tmp_path / "robust-one")) == 0
    assert not (one / "robust_dimension.png").exists()
    assert "robust evaluation against the action dimension" not in (one / "summary.md").read_text()
