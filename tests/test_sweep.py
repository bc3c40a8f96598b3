"""sweep.py with the real training scripts on a small env: the local launcher, a real one-node
Slurm cluster (tests/slurm/start.sh), preemption and cancellation, status, and bad input."""

import csv
import fcntl
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SWEEP = [sys.executable, str(ROOT / "sweep.py")]
# Pendulum episodes are 200 steps: four episodes, gradient updates from step 200, an evaluation
# and (with --checkpoint-interval 200) a checkpoint at every episode end. A stop asked for after
# the first checkpoint leaves at least one episode to resume.
RUN_ARGS = ["--no-compile", "--total-timesteps", "800", "--learning-starts", "200",
            "--eval-interval", "200", "--eval-episodes", "1", "--batch-size", "32"]
CELLS = ["--env-ids", "Pendulum-v1", "--checkpoint-interval", "200"]
GRID = [*CELLS, "--seeds", "0", "1"]
SCRIPTS = ("standard", "corrected")
TIMEOUT = 300


def sweep(*args: str, check: bool = True, env: dict | None = None) -> subprocess.CompletedProcess:
    result = subprocess.run([*SWEEP, *args], capture_output=True, text=True, timeout=TIMEOUT,
                            env=env)
    if check and result.returncode != 0:
        pytest.fail(f"sweep.py {' '.join(args)} exited {result.returncode}:\n"
                    f"{result.stdout}\n{result.stderr}")
    return result


def run_dirs(output_dir: Path) -> dict[tuple[str, int], Path]:
    """(algorithm, seed) -> run folder."""
    found = {}
    for config in output_dir.glob("*/config.json"):
        data = json.loads(config.read_text())
        found[data["algorithm"], data["seed"]] = config.parent
    return found


def eval_rows(run_dir: Path) -> list[dict]:
    """eval.csv without wall_time: what must be identical between identical runs."""
    with open(run_dir / "eval.csv", newline="") as f:
        return [{k: v for k, v in row.items() if k != "wall_time"} for row in csv.DictReader(f)]


def wait_for(predicate, what: str, timeout: float = TIMEOUT) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out waiting for {what}")
        time.sleep(0.2)


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """2 seeds x 2 scripts, uninterrupted, by the local launcher: the runs the others must equal."""
    output_dir = tmp_path_factory.mktemp("reference")
    sweep(*GRID, "--workers", "2", "--output-dir", str(output_dir), "--", *RUN_ARGS)
    return output_dir


# ----------------------------------------------------------------------------- local launcher
@pytest.mark.slow
def test_local_grid_runs_every_cell_to_the_end(reference):
    runs = run_dirs(reference)
    # --workers 2: the cores the two training processes leave, shared (at least one each).
    eval_workers = max(1, (len(os.sched_getaffinity(0)) - 2) // 2)
    assert sorted(runs) == [(a, s) for a in sorted(SCRIPTS) for s in (0, 1)]
    for (algorithm, seed), run_dir in runs.items():
        assert (run_dir / "done.json").exists()
        assert [row["global_step"] for row in eval_rows(run_dir)] == ["200", "400", "600", "800"]
        config = json.loads((run_dir / "config.json").read_text())
        assert (config["env_id"], config["total_timesteps"]) == ("Pendulum-v1", 800)
        identity = json.loads((run_dir / "sweep_run.json").read_text())
        assert identity["extra_args"] == RUN_ARGS and identity["seed"] == seed
        assert run_dir.name.startswith(f"Pendulum-v1__{algorithm}__seed{seed}__")
        log = (run_dir / "sweep.log").read_text()
        assert "finished 800 steps" in log  # the script's own output went to its log
        assert log.count("--eval-workers") == 1 and f"--eval-workers {eval_workers}" in log


@pytest.mark.slow
def test_rerun_skips_finished_runs_and_chains_analysis(reference, tmp_path):
    logs_before = {d: (d / "sweep.log").read_text() for d in run_dirs(reference).values()}
    report = tmp_path / "report"
    result = sweep(*GRID, "--output-dir", str(reference), "--analyze", str(report),
                   "--analyze-args=--normalize min-max --reps 100 --curve-reps 50", "--",
                   *RUN_ARGS)
    assert "4 done or under way, 0 to launch" in result.stdout
    assert {d: (d / "sweep.log").read_text() for d in logs_before} == logs_before
    # The analysis read the four runs: two seeds per script, each to step 800; the standard runs
    # equal the corrected runs' paired tanh(mu) evaluation; its numbers are the runs' own.
    summary = (report / "summary.md").read_text()
    assert f"Found 4 runs under {reference}:" in summary
    assert ("| Pendulum-v1 | 2 seeds, to step 800 | 2 seeds, to step 800 | 2 seeds, to step 800 |"
            in summary)
    assert ("Pendulum-v1: the standard runs equal the corrected runs' paired tanh(mu) evaluation "
            "at all 8 shared (seed, step) points.") in summary
    last = {key: eval_rows(run_dir)[-1] for key, run_dir in run_dirs(reference).items()}
    with open(report / "summary.csv", newline="") as f:
        rows = {(r["section"], r["group"], r["metric"]): r for r in csv.DictReader(f)
                if r["task"] == "Pendulum-v1"}
    for algorithm in SCRIPTS:
        final = rows["task_final", algorithm, "return"]
        assert (final["step"], final["n_runs"]) == ("800", "2")
        assert float(final["estimate"]) == pytest.approx(
            sum(float(last[algorithm, s]["return_mean"]) for s in (0, 1)) / 2)
        assert float(final["ci_low"]) <= float(final["estimate"]) <= float(final["ci_high"])
    paired = rows["paired_difference", "corrected", "return"]
    assert (paired["step"], paired["n_runs"]) == ("800", "2")
    assert float(paired["estimate"]) == pytest.approx(sum(
        float(last["corrected", s]["return_mean"]) - float(last["corrected", s][
            "tanh_mu_return_mean"]) for s in (0, 1)) / 2)
    assert (report / "aggregate_metrics.png").stat().st_size > 10_000


@pytest.mark.slow
def test_local_sweep_stopped_by_sigterm_resumes_to_the_same_result(reference, tmp_path):
    command = [*SWEEP, *CELLS, "--seeds", "0", "--scripts", "sac_standard.py",
               "--output-dir", str(tmp_path), "--", *RUN_ARGS]
    sweeper = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                               text=True)
    wait_for(lambda: list(tmp_path.glob("*/checkpoint.pt")), "the first checkpoint")
    sweeper.send_signal(signal.SIGTERM)
    output, _ = sweeper.communicate(timeout=TIMEOUT)
    assert sweeper.returncode == 3, output
    (run_dir,) = run_dirs(tmp_path).values()
    assert not (run_dir / "done.json").exists()
    assert "interrupted" in sweep("status", str(tmp_path)).stdout

    sweep(*CELLS, "--seeds", "0", "--scripts", "sac_standard.py", "--output-dir", str(tmp_path),
          "--", *RUN_ARGS)
    assert "resuming" in (run_dir / "sweep.log").read_text()
    assert eval_rows(run_dir) == eval_rows(run_dirs(reference)["standard", 0])


@pytest.mark.slow
def test_eval_workers_is_no_part_of_a_runs_identity(reference):
    """The runs got --eval-workers from the sweep; the same grid with another --workers, or with
    the user's own --eval-workers, finds them done."""
    for extra in ([], ["--eval-workers", "0"]):
        out = sweep(*GRID, "--workers", "1", "--output-dir", str(reference), "--", *RUN_ARGS,
                    *extra).stdout
        assert "4 done or under way, 0 to launch" in out


@pytest.mark.slow
def test_a_folder_in_use_is_skipped_and_started_once_free(reference, tmp_path):
    """A run folder whose flock another process holds (a sweep started twice, a requeued job
    racing one not dead yet) is running: not started, shown as running; the others run. Once
    the lock is released, the same command starts it."""
    import sweep as sweep_module

    grid = [*CELLS, "--seeds", "0", "--output-dir", str(tmp_path), "--", *RUN_ARGS]
    args = sweep_module.Args(env_ids=["Pendulum-v1"], seeds=[0], scripts=["sac_standard.py"],
                             output_dir=str(tmp_path))
    (busy,) = sweep_module.build_grid(args, tuple(RUN_ARGS))
    sweep_module.prepare_run_dir(busy)
    fd = os.open(busy.run_dir / "lock", os.O_RDWR | os.O_CREAT)
    try:
        os.write(fd, f"{os.getpid()}\n".encode())
        fcntl.flock(fd, fcntl.LOCK_EX)
        result = sweep(*grid, check=False)
        assert result.returncode == 3, result.stdout  # not all done
        assert "1 done or under way, 1 to launch" in result.stdout
        assert f"{busy.name}: in use by process {os.getpid()}" in result.stdout
        assert list(run_dirs(tmp_path)) == [("corrected", 0)]
        assert (run_dirs(tmp_path)["corrected", 0] / "done.json").exists()
        assert not (busy.run_dir / "sweep.log").exists()  # never started
        (row,) = [line for line in sweep("status", str(tmp_path)).stdout.splitlines()
                  if line.startswith(busy.name)]
        assert row.split()[1] == "running"
    finally:
        os.close(fd)
    assert (busy.run_dir / "lock").exists()  # a lock file nobody holds is no lock
    result = sweep(*grid)
    assert "1 done or under way, 1 to launch" in result.stdout and "in use" not in result.stdout
    assert eval_rows(busy.run_dir) == eval_rows(run_dirs(reference)["standard", 0])


@pytest.mark.slow
def test_status_shows_state_progress_and_the_log_of_a_failed_run(reference, tmp_path):
    table = sweep("status", str(reference)).stdout
    assert table.count("done") >= 4 and "800/800" in table
    result = sweep("--env-ids", "Pendulum-v1", "--seeds", "0", "--scripts", "sac_standard.py",
                   "--output-dir", str(tmp_path), "--", "--no-such-flag", check=False)
    assert result.returncode == 1
    table = sweep("status", str(tmp_path)).stdout
    assert "failed" in table and "--no-such-flag" in table  # tyro's complaint, from the log


@pytest.mark.slow
def test_free_deletes_only_finished_runs_checkpoints(reference, tmp_path):
    import shutil

    copy = tmp_path / "runs"
    shutil.copytree(reference, copy)
    runs = run_dirs(copy)
    unfinished = runs["standard", 1]
    (unfinished / "done.json").unlink()  # as a run that is still under way
    assert all((d / "checkpoint.pt").exists() for d in runs.values())
    kept = {p: p.read_bytes() for p in copy.rglob("*") if p.is_file() and p.name != "checkpoint.pt"}
    out = sweep("free", str(copy)).stdout
    assert out.count("deleted checkpoint.pt") == len(runs) - 1 and "freed" in out
    assert [d for d in runs.values() if (d / "checkpoint.pt").exists()] == [unfinished]
    assert {p: p.read_bytes() for p in kept} == kept  # nothing else touched
    assert "freed 0.00 GiB" in sweep("free", str(copy)).stdout  # twice is harmless
    assert "does not exist" in sweep("free", str(tmp_path / "nowhere"), check=False).stderr


@pytest.mark.slow
def test_dimensions_preset_runs_and_analyzes_with_the_default_normalisation(tmp_path):
    """--preset dimensions mixes tasks with and without a HumanoidBench success bar: --analyze
    with analyze.py's defaults (no --normalize) gives a report once every run is done. Two of
    the preset's env ids (3 and 61 action dimensions), one seed, 300 steps each (17 s here)."""
    report = tmp_path / "report"
    result = sweep("--preset", "dimensions", "--env-ids", "Hopper-v5", "h1hand-powerlift-v0",
                   "--seeds", "0", "--workers", "2", "--output-dir", str(tmp_path / "runs"),
                   "--analyze", str(report), "--analyze-args=--reps 200 --curve-reps 20", "--",
                   "--no-compile", "--total-timesteps", "300", "--learning-starts", "200",
                   "--eval-interval", "100", "--eval-episodes", "1", "--batch-size", "32")
    assert "2 done" in result.stdout
    summary = (report / "summary.md").read_text()
    assert "`auto` chose `min-max`: no HumanoidBench success bar for Hopper-v5" in summary
    assert "| Hopper-v5 | 3 | Corrected SAC | mode | 1 | 1 (300) |" in summary
    assert "| h1hand-powerlift-v0 | 61 | Corrected SAC | mode | 1 | 1 (300) |" in summary
    assert (report / "dimension_study.png").stat().st_size > 0


@pytest.mark.slow
def test_dry_run_prints_the_plan_and_starts_nothing(reference, tmp_path):
    out = sweep(*GRID, "--scripts", "sac_standard.py", "--output-dir", str(reference),
                "--dry-run", "--steps-per-second", "100", "--", *RUN_ARGS).stdout
    assert "1 env ids x 2 seeds x 1 scripts = 2 runs" in out
    assert out.count("done") == 2 and "skip" in out
    assert "1,600 env steps in all, 0 still to run" in out

    out = sweep("--preset", "paper", "--output-dir", str(tmp_path / "paper"), "--dry-run",
                "--steps-per-second", "100", "--gpu-node-steps-per-second", "2000").stdout
    # One corrected run is both algorithms: the paper's 40 runs are 20.
    assert "4 env ids x 5 seeds x 1 scripts = 20 runs" in out
    assert "paired tanh(mu) evaluation is the sac_standard.py run of its seed" in out
    assert "h1hand-bookshelf_hard-v0__corrected__seed4__" in out and "__standard__" not in out
    # 20 runs x 10M steps at 100 steps/s = 2e6 s of one run each = 555.6 run-hours; on a GPU
    # node at 2,000 steps/s in all: 1e5 s = 27.8 h.
    assert "200,000,000 env steps in all" in out and "555.6 run-hours" in out
    assert "on one GPU node at 2,000 steps/s in all" in out and "27.8 h (1.2 days)" in out
    # The literal grid, for anyone who wants it.
    out = sweep("--preset", "paper", "--scripts", "sac_standard.py", "sac_corrected.py",
                "--output-dir", str(tmp_path / "paper"), "--dry-run").stdout
    assert "4 env ids x 5 seeds x 2 scripts = 40 runs" in out and "preset paper:" not in out

    out = sweep("--preset", "dimensions", "--output-dir", str(tmp_path / "dims"),
                "--dry-run", "--steps-per-second", "100").stdout
    assert "8 env ids x 5 seeds x 1 scripts = 40 runs" in out
    # 20 classic runs of 1M steps and 20 h1hand runs of 10M steps.
    assert "220,000,000 env steps in all" in out and "Hopper-v5__corrected__seed0__" in out
    out = sweep("--preset", "dimensions", "--output-dir", str(tmp_path / "dims"), "--dry-run",
                "--", "--total-timesteps", "5000").stdout
    assert "200,000 env steps in all" in out  # the budget after `--` wins
    assert not (tmp_path / "paper").exists() and not (tmp_path / "dims").exists()


def test_dry_run_counts_the_steps_left_and_takes_its_speeds_from_the_user(tmp_path):
    """sweep.py holds no table of speeds (docs/sweep.md does): --dry-run counts the env steps
    still to run (an interrupted run's from its last evaluation) and gives hours only for a
    speed it is given."""
    import sweep as sweep_module

    budget = ("--total-timesteps", "3600000")
    grid = ["--env-ids", "Pendulum-v1", "Hopper-v5", "--seeds", "0", "1", "--scripts",
            "sac_corrected.py", "--output-dir", str(tmp_path), "--dry-run"]
    args = sweep_module.Args(env_ids=["Pendulum-v1"], seeds=[0], scripts=["sac_corrected.py"],
                             output_dir=str(tmp_path))
    (started,) = sweep_module.build_grid(args, budget)
    sweep_module.prepare_run_dir(started)
    (started.run_dir / "config.json").write_text("{}")
    (started.run_dir / "eval.csv").write_text("global_step,return_mean\n900000,1.0\n")

    out = sweep(*grid, "--", *budget).stdout
    assert f"{started.name:<60} interrupted  resume" in out
    assert "14,400,000 env steps in all, 13,500,000 still to run" in out
    assert "run-hours" not in out and "GPU node" not in out and "docs/sweep.md" in out
    # 13.5M steps at 250 steps/s per run: 15 run-hours, a whole run 4 h.
    out = sweep(*grid, "--steps-per-second", "250", "--", *budget).stdout
    assert "at 250 steps/s per run: 15.0 run-hours (the longest run 4.0 h)" in out
    # Per env id: Pendulum's 6.3M steps left at 500 steps/s (3.5 h) and Hopper's 7.2M at 250
    # (8 h), its runs the longest (4 h each).
    out = sweep(*grid, "--env-steps-per-second", "Pendulum-v1=500", "Hopper-v5=250", "--",
                *budget).stdout
    assert ("at Pendulum-v1 500, Hopper-v5 250 steps/s per run: 11.5 run-hours (the longest "
            "run 4.0 h)") in out
    # --steps-per-second covers the env ids not named; with neither, it says what is missing.
    out = sweep(*grid, "--steps-per-second", "250", "--env-steps-per-second", "Pendulum-v1=500",
                "--", *budget).stdout
    assert "at Pendulum-v1 500, Hopper-v5 250 steps/s per run: 11.5 run-hours" in out
    result = sweep(*grid, "--env-steps-per-second", "Pendulum-v1=500", "--", *budget,
                   check=False)
    assert result.returncode != 0 and ("--env-steps-per-second gives no speed for Hopper-v5: "
                                       "name them too") in result.stderr
    assert [p.name for p in tmp_path.iterdir()] == [started.name]


def test_a_preset_with_per_env_budgets_accepts_its_own_runs(tmp_path):
    """--preset dimensions gives classic tasks 1M steps and h1hand tasks the default: a folder
    holding some of its runs is its own (rerun, resume), and the paper preset's h1hand runs are
    the same runs; a run of a grid env id made with other arguments is still refused."""
    import sweep as sweep_module

    def grid(preset: str, *extra: str) -> list:
        args = sweep_module.Args(preset=preset, output_dir=str(tmp_path / "runs"))
        return sweep_module.build_grid(args, extra)

    dims = grid("dimensions")
    assert {r.env_id: r.extra_args for r in dims}["Hopper-v5"] == ("--total-timesteps",
                                                                   "1000000")
    paper_run = grid("paper")[0]
    for run in (dims[0], paper_run):  # Hopper-v5 (1M) and an h1hand run (no arguments)
        sweep_module.prepare_run_dir(run)
    assert paper_run in dims
    sweep_module.check_output_dir(dims)  # no error: both are runs of this grid
    with pytest.raises(sweep_module.SweepError, match=r"Hopper-v5__corrected__seed0__\w+ "
                       r"\(arguments: --total-timesteps 1000000\)"):
        sweep_module.check_output_dir(grid("dimensions", "--total-timesteps", "5000"))


def test_the_classic_preset_runs_the_published_sacs_setting(tmp_path):
    """--preset classic: the five standard tasks x seeds 0-4, sac_corrected.py, 1M steps, batch
    256, target entropy -|A|, snapshots every 250k; a flag after `--` replaces the preset's."""
    import sweep as sweep_module

    def grid(*extra: str) -> list:
        args = sweep_module.Args(preset="classic", output_dir=str(tmp_path / "runs"))
        return sweep_module.build_grid(args, extra)

    runs = grid()
    assert len(runs) == 25
    assert {r.env_id for r in runs} == {"Hopper-v5", "HalfCheetah-v5", "Walker2d-v5", "Ant-v5",
                                        "Humanoid-v5"}
    assert {r.seed for r in runs} == {0, 1, 2, 3, 4}
    assert {r.script.name for r in runs} == {"sac_corrected.py"}
    assert {r.extra_args for r in runs} == {(
        "--total-timesteps", "1000000", "--batch-size", "256", "--target-entropy-scale", "1.0",
        "--snapshot-interval", "250000")}
    mine = grid("--batch-size", "64", "--eval-interval", "5000")[0].extra_args
    assert mine == ("--total-timesteps", "1000000", "--target-entropy-scale", "1.0",
                    "--snapshot-interval", "250000", "--batch-size", "64", "--eval-interval",
                    "5000")
    assert grid("--total-timesteps", "2000")[0].extra_args[-2:] == ("--total-timesteps", "2000")


# ----------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(("args", "message"), [
    (["--env-ids", "Pendulum-v1", "--seeds", "0", "--scripts", "sac_nope.py"],
     "unknown script 'sac_nope.py'"),
    (["--env-ids", "Pendulum-v7", "--seeds", "0"],
     "unknown env id 'Pendulum-v7': did you mean Pendulum-v1"),
    (["--env-ids", "Pendulum-v1", "--seeds"], "no seeds: pass --seeds"),
    (["--env-ids", "Pendulum-v1", "--seeds", "0", "--", "--seed", "3"],
     "--seed after `--` is set by sweep.py"),
    (["--env-ids", "Pendulum-v1", "--seeds", "0", "--", "--eval-workers", "-1"],
     "--eval-workers -1 after `--`: must be 0 (in-process) or a number"),
    (["--env-ids", "Pendulum-v1", "--seeds", "0", "--launcher", "slurm", "--dry-run",
      "--sbatch", "cpus-per-task=two"], "--sbatch cpus-per-task=two: must be a whole number"),
])
def test_bad_input_is_a_clear_error_and_starts_nothing(tmp_path, args, message):
    result = sweep("--output-dir", str(tmp_path / "runs"), *args, check=False)
    assert result.returncode == 2
    assert message in result.stderr
    assert not (tmp_path / "runs").exists()


@pytest.mark.slow
def test_folder_with_runs_of_other_arguments_is_refused(reference):
    before = sorted(p.name for p in reference.iterdir())
    result = sweep(*GRID, "--output-dir", str(reference), "--",
                   *RUN_ARGS[:-1], "64", check=False)
    assert result.returncode == 2
    assert "holds runs made with other arguments" in result.stderr
    assert "--batch-size 32" in result.stderr  # names what the folder's runs used
    assert sorted(p.name for p in reference.iterdir()) == before


# ----------------------------------------------------------------------------- Slurm
@pytest.fixture(scope="module")
def slurm() -> None:
    """The one-node Slurm cluster of tests/slurm/ (started here when it is not running)."""
    started = subprocess.run([str(ROOT / "tests" / "slurm" / "start.sh")], capture_output=True,
                             text=True, timeout=120)
    if started.returncode != 0:
        pytest.fail(f"could not start Slurm (tests/slurm/start.sh):\n{started.stderr}")


SLURM = ["--launcher", "slurm", "--cpus-per-task", "1", "--mem-gb", "1", "--wait"]


@pytest.mark.slow
def test_slurm_sweep_survives_preemption_and_cancellation(slurm, reference, tmp_path):
    """A job array of two runs: one is preempted (USR2: checkpoint, requeue, resume), the other
    cancelled; rerunning the sweep resumes the cancelled one. Both equal the local runs."""
    grid = [*CELLS, "--seeds", "1", *SLURM, "--output-dir", str(tmp_path), "--", *RUN_ARGS]
    sweeper = subprocess.Popen([*SWEEP, *grid], stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True)
    # Signal each job as soon as its run has a checkpoint: well before its last episode.
    how = {"corrected": ["scancel", "--signal=USR2"], "standard": ["scancel"]}
    deadline = time.monotonic() + TIMEOUT
    while how and time.monotonic() < deadline:
        for (algorithm, _), run_dir in run_dirs(tmp_path).items():
            if algorithm in how and (run_dir / "checkpoint.pt").exists():
                job_id = json.loads((run_dir / "sweep_run.json").read_text())["slurm_job_id"]
                subprocess.run([*how.pop(algorithm), job_id], check=True)
        time.sleep(0.1)
    assert not how, f"no checkpoint to signal {list(how)} at"
    output, _ = sweeper.communicate(timeout=TIMEOUT)
    runs = run_dirs(tmp_path)
    preempted, cancelled = runs["corrected", 1], runs["standard", 1]
    assert (preempted / "done.json").exists(), output
    assert not (cancelled / "done.json").exists(), output
    assert sweeper.returncode == 3, output  # not all done: one run is interrupted
    preempted_log = (preempted / "sweep.log").read_text()
    assert "resume on" in preempted_log and "exit code 3" in preempted_log  # requeued, resumed
    # One CPU per task: one evaluation worker, on start and on resume.
    assert preempted_log.count("--eval-workers 1") == preempted_log.count("=== sweep.py start") \
        + preempted_log.count("=== sweep.py resume") >= 2
    assert "interrupted" in sweep("status", str(tmp_path)).stdout

    result = sweep(*grid)
    assert "1 done or under way, 1 to launch" in result.stdout
    assert "resuming" in (cancelled / "sweep.log").read_text()
    for key, run_dir in run_dirs(tmp_path).items():
        assert (run_dir / "done.json").exists()
        assert eval_rows(run_dir) == eval_rows(run_dirs(reference)[key]), key


def test_unreachable_slurm_is_a_clear_error_and_starts_nothing(tmp_path):
    conf = tmp_path / "slurm.conf"
    # A controller that is not there: the port nobody listens on, and no long retrying.
    conf.write_text("ClusterName=gone\nSlurmctldHost=localhost\nSlurmctldPort=9\n"
                    "MessageTimeout=1\nNodeName=localhost\nPartitionName=p Nodes=ALL\n")
    result = sweep(*GRID, *SLURM, "--output-dir", str(tmp_path / "runs"), "--", *RUN_ARGS,
                   check=False, env={**os.environ, "SLURM_CONF": str(conf)})
    assert result.returncode == 2
    assert "Slurm not reachable" in result.stderr
    assert not (tmp_path / "runs").exists()


@pytest.mark.slow
def test_unknown_partition_is_a_clear_error(slurm, tmp_path):
    result = sweep(*GRID, *SLURM, "--partition", "nosuch", "--output-dir", str(tmp_path),
                   "--", *RUN_ARGS, check=False)
    assert result.returncode == 2
    assert "unknown Slurm partition 'nosuch'" in result.stderr
    assert not list(tmp_path.iterdir())


def test_progress_ignores_a_row_cut_off_mid_write(tmp_path):
    import sweep

    (tmp_path / "eval.csv").write_text("global_step,return_mean\n1000,1.0\n2000,2.0\n30")
    assert sweep.last_eval_step(tmp_path) == 2000
    (tmp_path / "eval.csv").write_text("global_step,return_mean\n")
    assert sweep.last_eval_step(tmp_path) is None
