"""Bad input to every script: one line naming the flag or file, what is allowed or what to do,
exit code 2, no traceback, and nothing in a run folder changed."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import sac_corrected
import sac_standard
from sac_utils import cli as flags_module

ROOT = Path(__file__).resolve().parent.parent
SHORT = ["--env-id", "Pendulum-v1", "--total-timesteps", "600", "--learning-starts", "200",
         "--eval-interval", "200", "--eval-episodes", "1", "--log-interval", "100",
         "--checkpoint-interval", "200", "--hidden-sizes", "32", "32"]


def run(script: str, *args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / script), *args], capture_output=True,
                          text=True, cwd=cwd, timeout=300)


def refused(result: subprocess.CompletedProcess, *fragments: str) -> None:
    """Exit code 2, one line on stderr holding every fragment, no traceback."""
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


def snapshot(folder: Path) -> dict:
    """Every file under the folder: its bytes and modification time."""
    return {p.relative_to(folder): (p.read_bytes(), p.stat().st_mtime_ns)
            for p in sorted(folder.rglob("*")) if p.is_file()}


# --------------------------------------------------------------------------- SAC flag ranges
@pytest.mark.parametrize(("flags", "message"), [
    ({"total_timesteps": -5}, "--total-timesteps -5: must be at least 1"),
    ({"batch_size": 0}, "--batch-size 0: must be between 1 and --buffer-size (1000000)"),
    ({"buffer_size": 0}, "--buffer-size 0: must be at least 1"),
    ({"gamma": 1.5}, "--gamma 1.5: must be in [0, 1]"),
    ({"gamma": float("nan")}, "--gamma nan: must be in [0, 1]"),
    ({"tau": 0.0}, "--tau 0.0: must be in (0, 1]"),
    ({"hidden_sizes": ()}, "--hidden-sizes : must be one or more positive layer widths"),
    ({"hidden_sizes": (256, 0)}, "--hidden-sizes 256 0: must be one or more positive"),
    ({"eval_interval": 0}, "--eval-interval 0: must be at least 1"),
    ({"log_interval": 0}, "--log-interval 0: must be at least 1"),
    ({"eval_episodes": 0}, "--eval-episodes 0: must be at least 1 (to skip evaluation"),
    ({"learning_starts": 10_000_000}, "--learning-starts 10000000: must be in [0, "
     "--total-timesteps (10000000)), or no gradient update would run"),
    ({"policy_lr": -3e-4}, "--policy-lr -0.0003: must be a positive number"),
    ({"q_lr": float("inf")}, "--q-lr inf: must be a positive number"),
    ({"alpha_init": 0.0}, "--alpha-init 0.0: must be a positive number"),
    ({"log_std_min": 3.0}, "--log-std-min 3.0: must be a finite number below --log-std-max"),
    ({"seed": -1}, "--seed -1: must be a non-negative integer"),
    ({"checkpoint_interval": -1}, "--checkpoint-interval -1: must be 0 (off) or more"),
    ({"snapshot_interval": -1}, "--snapshot-interval -1: must be 0 (off) or more"),
    ({"eval_reset_noise": -0.01}, "--eval-reset-noise -0.01: must be a finite number >= 0"),
    ({"eval_reset_noise": float("inf")}, "--eval-reset-noise inf: must be a finite number"),
    ({"torch_threads": 0}, "--torch-threads 0: must be at least 1"),
    ({"print_interval": 0}, "--print-interval 0: must be at least 1"),
    ({"run_name": "a/b"}, "--run-name 'a/b': must be a folder name without '/'"),
    ({"wandb_project_name": ""}, "--wandb-project-name '': must be a non-empty name"),
])
@pytest.mark.parametrize("script", [sac_standard, sac_corrected])
def test_every_sac_flag_has_a_range(script, flags, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        flags_module.check_args(script.Args(**flags), script.eval_actions)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err


def test_the_defaults_and_edge_cases_that_are_allowed():
    for args in (sac_standard.Args(),
                 sac_standard.Args(eval_interval=10**9),  # no evaluation at all: allowed
                 sac_standard.Args(buffer_size=100, batch_size=100, learning_starts=0),
                 sac_standard.Args(checkpoint_interval=0, gamma=1.0, tau=1.0)):
        flags_module.check_args(args, sac_standard.eval_actions)


@pytest.mark.parametrize("flags", [
    ["--total-timesteps", "-5"], ["--gamma", "1.5"], ["--eval-interval", "0"],
    ["--hidden-sizes"],
])
def test_bad_flags_stop_before_anything_is_written(flags, tmp_path):
    result = run("sac_corrected.py", "--env-id", "Pendulum-v1", *flags, "--output-dir",
                 str(tmp_path / "runs"))
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert not (tmp_path / "runs").exists()


# --------------------------------------------------------------------------- damaged files
@pytest.fixture(scope="module")
def interrupted_run(tmp_path_factory) -> Path:
    """A run folder as a killed run leaves it: checkpoints, CSVs, no done.json."""
    out = tmp_path_factory.mktemp("runs")
    result = run("sac_standard.py", *SHORT, "--output-dir", str(out), "--run-name", "r")
    assert result.returncode == 0, result.stderr
    (out / "r" / "done.json").unlink()
    return out / "r"


def truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def bad_header(path: Path) -> None:
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("step,foo\n" + "".join(lines[1:]))


def bad_step(path: Path) -> None:
    lines = path.read_text().splitlines(keepends=True)
    path.write_text(lines[0] + "x" + lines[1] + "".join(lines[2:]))


@pytest.mark.parametrize(("file", "damage", "fragments"), [
    ("checkpoint.pt", truncate, ["checkpoint.pt cannot be read", "it is damaged: restore a copy, "
                                 "or delete it to restart the run from step 0"]),
    ("checkpoint.pt", lambda p: p.write_text("not a checkpoint"),
     ["checkpoint.pt cannot be read"]),
    ("checkpoint.pt", lambda p: __import__("torch").save({"args": {}}, p),
     ["checkpoint.pt lacks ['global_step'", "not a checkpoint of this script"]),
    ("config.json", lambda p: p.write_text('{"env_id": "Pendulum-v1",'),
     ["config.json is not valid JSON", "restore it from a copy, or start a new run"]),
    ("config.json", lambda p: p.write_text(json.dumps(
        {**json.loads(p.read_text()), "gamma": "high"})),
     ["config.json holds values of the wrong type for ['gamma']"]),
    ("eval.csv", bad_header, ["eval.csv does not have the header this run writes"]),
    ("train.csv", bad_step, ["train.csv, line 2: global_step 'x100' is not a step number"]),
])
@pytest.mark.slow
def test_damaged_files_are_named_and_nothing_changes(interrupted_run, tmp_path, file, damage,
                                                      fragments):
    run_dir = tmp_path / "r"
    shutil.copytree(interrupted_run, run_dir)
    damage(run_dir / file)
    before = snapshot(run_dir)
    refused(run("sac_standard.py", "--resume", str(run_dir)), *fragments)
    assert snapshot(run_dir) == before


@pytest.mark.slow
def test_an_intact_copy_resumes(interrupted_run, tmp_path):
    """The fixture's folder is resumable as it is: the refusals above come from the damage."""
    run_dir = tmp_path / "r"
    shutil.copytree(interrupted_run, run_dir)
    result = run("sac_standard.py", "--resume", str(run_dir))
    assert result.returncode == 0 and "resuming" in result.stdout, result.stderr


# --------------------------------------------------------------------------- analyze, sweep
@pytest.mark.parametrize(("flags", "message"), [
    (["--reps", "0"], "--reps 0: must be at least 1"),
    (["--curve-reps", "0"], "--curve-reps 0: must be at least 1"),
    (["--curve-points", "1"], "--curve-points 1: must be at least 2"),
    (["--at-step", "0"], "--at-step 0: must be a step of at least 1"),
    (["--seed", "-1"], "--seed -1: must be in [0, 2**32)"),
])
@pytest.mark.slow
def test_analyze_flag_ranges(flags, message, tmp_path):
    result = run("analyze.py", str(tmp_path), *flags, "--out", str(tmp_path / "out"))
    refused(result, message)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(("flags", "message"), [
    (["--workers", "0"], "--workers 0: must be at least 1"),
    (["--seeds", "-1"], "--seeds -1: must be non-negative integers"),
    (["--steps-per-second", "0"], "--steps-per-second 0.0: must be a positive number"),
    (["--checkpoint-interval", "0"], "--checkpoint-interval 0: must be at least 1"),
    (["--time-min", "0"], "--time-min 0: must be at least 1 minute"),
    (["--mem-gb", "0"], "--mem-gb 0: must be at least 1"),
    (["--max-parallel", "0"], "--max-parallel 0: must be at least 1"),
    (["--signal-delay-s", "99999"], "--signal-delay-s 99999: must be at least 1 and below"),
    (["--max-requeues", "-1"], "--max-requeues -1: must be 0 or more"),
    (["--env-steps-per-second", "Pendulum-v1"],
     "--env-steps-per-second Pendulum-v1: must be ENV_ID=STEPS_PER_SECOND with a positive"),
    (["--env-steps-per-second", "Pendulum-v1=-5"],
     "--env-steps-per-second Pendulum-v1=-5: must be ENV_ID=STEPS_PER_SECOND"),
    (["--env-steps-per-second", "Hopper-v5=100"],
     "--env-steps-per-second Hopper-v5=100: Hopper-v5 is not in the grid (Pendulum-v1)"),
])
def test_sweep_flag_ranges(flags, message, tmp_path):
    args = ["--env-ids", "Pendulum-v1", "--seeds", "0", *flags] if "--seeds" not in flags \
        else ["--env-ids", "Pendulum-v1", *flags]
    result = run("sweep.py", *args, "--output-dir", str(tmp_path / "runs"))
    refused(result, message)
    assert not (tmp_path / "runs").exists()
