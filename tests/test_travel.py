"""Run folders that travel: a copy resumes the copy and never touches the original; the .pt
files load without a GPU; evaluation failures end a run in one line."""

import hashlib
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

import tests.toy_envs  # noqa: F401  (registers the toy envs here; workers import them by id)
from sac_utils.checkpoints import episode_state, on_cpu, rng_states
from sac_utils.eval_rounds import EvalPool, Round
from tests.test_sac import ROOT, command, read_csv, run, wait_for
from tests.toy_envs import ToyActor

TINY = ["--env-id", "Pendulum-v1", "--total-timesteps", "1200", "--learning-starts", "200",
        "--eval-interval", "400", "--eval-episodes", "2", "--hidden-sizes", "8",
        "--batch-size", "16", "--log-interval", "100", "--print-interval", "100",
        "--checkpoint-interval", "0", "--eval-workers", "0"]


def contents(folder: Path) -> dict[str, str]:
    """Every file under the folder by relative path, as a hash of its bytes."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def stopped_run(out: Path, *args: str) -> None:
    """A run stopped by SIGTERM after step 600: checkpointed mid-run, no done.json."""
    name = args[args.index("--run-name") + 1].replace("{seed}", "0")
    process = subprocess.Popen(command("sac_standard.py", *TINY, "--output-dir", str(out),
                                       *args), cwd=ROOT, stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL)
    wait_for(lambda: (out / name / "train.csv").exists()
             and "\n600," in (out / name / "train.csv").read_text())
    process.send_signal(signal.SIGTERM)
    assert process.wait() == 3


@pytest.mark.slow
def test_a_copied_folder_resumes_the_copy_and_never_touches_the_original(tmp_path):
    stopped_run(tmp_path, "--run-name", "orig")
    original = tmp_path / "orig"
    assert not (original / "done.json").exists()
    shutil.copytree(original, tmp_path / "copy")
    before = contents(original)
    result = run("sac_standard.py", "--resume", str(tmp_path / "copy"))
    assert f"resuming {tmp_path / 'copy'} at step" in result.stdout
    assert (tmp_path / "copy" / "done.json").exists()
    assert read_csv(tmp_path / "copy" / "eval.csv")[-1]["global_step"] == "1200"
    assert contents(original) == before
    for name in ("eval.csv", "train.csv"):  # the rows before the stop kept byte for byte
        assert (tmp_path / "copy" / name).read_bytes().startswith((original / name).read_bytes())
    # A finished folder under a new name answers for itself.
    (tmp_path / "copy").rename(tmp_path / "renamed")
    result = run("sac_standard.py", "--resume", str(tmp_path / "renamed"))
    assert result.stdout.startswith(f"{tmp_path / 'renamed'}: already finished")
    # analyze.py reads a folder the same wherever it was copied to.
    summaries = []
    for place in (tmp_path / "here", tmp_path / "elsewhere" / "deeper"):
        shutil.copytree(tmp_path / "renamed", place / "runs" / "renamed")
        analysis = subprocess.run([*command("analyze.py", "runs"), "--out", "report", "--reps",
                                   "200", "--curve-reps", "20"], cwd=place,
                                  capture_output=True, text=True)
        assert analysis.returncode == 0, analysis.stderr
        summaries.append({name: (place / "report" / name).read_text()
                          for name in ("summary.csv", "summary.md")})
    assert summaries[0] == summaries[1]
    assert "Pendulum-v1" in summaries[0]["summary.csv"]
    # So does evaluate.py.
    episodes = []
    for place in (tmp_path / "here", tmp_path / "elsewhere" / "deeper"):
        evaluation = subprocess.run([*command("evaluate.py", "runs/renamed"), "--episodes", "2",
                                     "--workers", "0", "--reps", "50", "--out", "eval"],
                                    cwd=place, capture_output=True, text=True)
        assert evaluation.returncode == 0, evaluation.stderr
        episodes.append((place / "eval" / "episodes.csv").read_text())
    assert episodes[0] == episodes[1] and episodes[0].count("\n") == 5  # header, 2 x 2 rows


@pytest.mark.slow
def test_analyze_reads_an_interrupted_run_to_its_last_evaluation(tmp_path):
    """Two seeds, one stopped early: each counts to the last step of its eval.csv, and the final
    return is the mean of the two at the last step they share."""
    import csv

    import analyze

    runs = tmp_path / "runs"
    stopped_run(runs, "--run-name", "s3", "--seed", "3")
    run("sac_standard.py", *TINY, "--seed", "4", "--output-dir", str(runs), "--run-name", "s4")
    finals = {s: {int(r["global_step"]): float(r["return_mean"])
                  for r in read_csv(runs / f"s{s}" / "eval.csv")} for s in (3, 4)}
    last = sorted({max(f) for f in finals.values()})
    shared = max(set(finals[3]) & set(finals[4]))
    assert len(last) == 2  # one run stopped before the other's last evaluation
    out = tmp_path / "report"
    assert analyze.main([str(runs), "--out", str(out), "--reps", "100", "--curve-reps", "20",
                         "--curve-points", "3"]) == 0
    text = (out / "summary.md").read_text()
    assert f"Found 2 runs under {runs}:" in text
    assert f"| Pendulum-v1 | 2 seeds, to step {'-'.join(f'{s:,}' for s in last)} |" in text
    with (out / "summary.csv").open(newline="") as f:
        (final,) = [r for r in csv.DictReader(f)
                    if r["section"] == "task_final" and r["metric"] == "return"]
    assert (final["task"], final["group"], final["step"], final["n_runs"]) == (
        "Pendulum-v1", "standard", str(shared), "2")
    assert float(final["estimate"]) == pytest.approx((finals[3][shared] + finals[4][shared]) / 2)


def test_checkpoint_parts_are_saved_on_the_cpu_and_rng_only_for_cuda_runs():
    tree = {"a": torch.ones(2), "b": [torch.zeros(1), (torch.arange(3), 5)], "c": "text"}
    moved = on_cpu(tree)
    assert moved["b"][1][1] == 5 and isinstance(moved["b"][1], tuple) and moved["c"] == "text"
    assert torch.equal(moved["b"][1][0], torch.arange(3))
    assert rng_states(torch.device("cpu"))["cuda"] is None
    if not torch.cuda.is_available():
        assert not torch.cuda.is_initialized()


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_a_gpu_runs_files_load_with_a_plain_torch_load_on_a_machine_without_a_gpu(tmp_path):
    run("sac_standard.py", *TINY, "--output-dir", str(tmp_path), "--run-name", "gpu",
        "--checkpoint-interval", "600")
    script = ("import torch, sys; [torch.load(p, weights_only=False) for p in sys.argv[1:]]; "
              "assert not torch.cuda.is_available()")
    loaded = subprocess.run([sys.executable, "-c", script,
                             str(tmp_path / "gpu" / "checkpoint.pt"),
                             str(tmp_path / "gpu" / "final_model.pt")],
                            env={"CUDA_VISIBLE_DEVICES": "", "PATH": "/usr/bin:/bin"},
                            capture_output=True, text=True)
    assert loaded.returncode == 0, loaded.stderr


def test_recorded_actions_keep_every_value_exactly():
    record = {"seed": 3, "rng": None,
              "actions": [np.array([0.1, -0.3], np.float64), np.array([0.7, 0.2], np.float32)]}
    actions = episode_state(record, 2)["actions"]
    assert actions.dtype == torch.float64
    assert actions[0].numpy().tolist() == [0.1, -0.3]
    assert actions[1].numpy().tolist() == np.array([0.7, 0.2], np.float32).tolist()


@pytest.mark.parametrize("workers", [0, 1])
def test_an_env_error_in_evaluation_ends_the_run_in_one_line_with_the_pool_shut_down(workers):
    pool = EvalPool(workers, lambda round_, result: None)
    round_ = Round("tests.toy_envs:FailingEval-v0", [2**21], {"": "tanh_mu"}, ToyActor(),
                   label="evaluation of seed 4 at step 3000")
    with pytest.raises(SystemExit) as error:
        pool.submit(round_)
        pool.drain()
    message = str(error.value)
    assert message.startswith("evaluation of seed 4 at step 3000 failed: ValueError: the toy "
                              "env's own failure") and "\n" not in message
    if workers:
        assert pool.executor._shutdown_thread


@pytest.mark.slow
def test_a_physics_blow_up_never_becomes_a_training_transition(tmp_path):
    run("sac_standard.py", "--env-id", "tests.toy_envs:BlowUp-v0", "--total-timesteps", "400",
        "--learning-starts", "100", "--eval-interval", "1000", "--eval-episodes", "1",
        "--hidden-sizes", "8", "--batch-size", "16", "--checkpoint-interval", "400",
        "--output-dir", str(tmp_path), "--run-name", "blow")
    buffer = torch.load(tmp_path / "blow" / "checkpoint.pt", weights_only=False)["buffer"]
    left, next_left = buffer["obs"][:, 0], buffer["next_obs"][:, 0]
    # Each episode: 3 real steps (4 -> 3 -> 2 -> 1 steps left), then the blow-up at 1 left.
    assert buffer["filled"] == len(left) == 300
    assert set(left.tolist()) == {4.0, 3.0, 2.0}
    assert torch.equal(next_left, left - 1)  # every stored transition is a real step
    assert float(buffer["rewards"].min()) == 1.0  # no blow-up's reward 0


def test_a_blow_up_is_told_from_the_vector_envs_final_info():
    from sac_standard import physics_blow_up

    unstable = {"final_info": {"physics_unstable": np.array([True])}}
    assert physics_blow_up(unstable, episode_end=True)
    assert not physics_blow_up({"final_info": {"physics_unstable": np.array([False])}}, True)
    assert not physics_blow_up({}, True) and not physics_blow_up(unstable, episode_end=False)


@pytest.mark.slow
def test_sigterm_checkpoints_at_once_with_rounds_in_flight_and_resumes_them_exactly(
        tmp_path, monkeypatch):
    gate = tmp_path / "gate"
    monkeypatch.setenv("TOY_ENVS_GATE", str(gate))  # the scripts and their workers inherit it
    toy = ["--env-id", "tests.toy_envs:GatedEval-v0", "--total-timesteps", "1200",
           "--learning-starts", "100", "--eval-interval", "300", "--eval-episodes", "2",
           "--hidden-sizes", "8", "--batch-size", "16", "--log-interval", "100",
           "--checkpoint-interval", "0", "--output-dir", str(tmp_path)]
    gate.touch()
    run("sac_standard.py", *toy, "--run-name", "whole", "--eval-workers", "0")
    gate.unlink()  # from now on every evaluation round waits at its episodes' second step
    stopped = tmp_path / "stopped"
    process = subprocess.Popen(command("sac_standard.py", *toy, "--run-name", "stopped",
                                       "--eval-workers", "2"), cwd=ROOT,
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    wait_for(lambda: (stopped / "train.csv").exists()
             and "\n600," in (stopped / "train.csv").read_text())
    process.send_signal(signal.SIGTERM)
    output = process.communicate(timeout=120)[0]
    assert process.returncode == 3, output
    checkpoint = torch.load(stopped / "checkpoint.pt", weights_only=False)
    pending = [r["global_step"] for r in checkpoint["pending_rounds"]]
    assert pending[:2] == [300, 600] and len(read_csv(stopped / "eval.csv")) == 0
    gate.touch()
    run("sac_standard.py", "--resume", str(stopped), "--eval-workers", "1")
    for name in ("eval.csv", "train.csv"):
        assert read_csv(stopped / name) == read_csv(tmp_path / "whole" / name)
