"""The two SAC scripts, run as subprocesses with tiny budgets (learning always starts)."""

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from sac_utils.restart import snapshot_from_checkpoint

ROOT = Path(__file__).resolve().parent.parent
# A short Pendulum run: updates start at step 500, evaluation every 500 steps.
SHORT = ["--env-id", "Pendulum-v1", "--total-timesteps", "1500", "--learning-starts", "500",
         "--eval-interval", "500", "--eval-episodes", "2", "--log-interval", "100",
         "--print-interval", "500", "--checkpoint-interval", "0"]


# The scripts compile their update by default (20-60 s per process); the tests run them eager
# unless they ask for --compile (tests/test_compile.py checks that both paths train alike).
EAGER = ("--no-compile",)


def command(script: str, *args: str) -> list[str]:
    eager = EAGER if script.startswith("sac_") and "--compile" not in args else ()
    return [sys.executable, str(ROOT / script), *args, *eager]


def run(script: str, *args: str, check: bool = True) -> subprocess.CompletedProcess:
    result = subprocess.run(command(script, *args), capture_output=True, text=True, cwd=ROOT)
    if check:
        assert result.returncode == 0, result.stderr
    return result


def read_csv(path: Path, drop: tuple[str, ...] = ("wall_time", "sps")) -> list[dict]:
    with open(path, newline="") as f:
        return [{k: v for k, v in row.items() if k not in drop} for row in csv.DictReader(f)]


def wait_for(predicate, timeout: float = 120) -> None:
    deadline = time.time() + timeout
    while not predicate():
        assert time.time() < deadline, "timed out waiting for the run"
        time.sleep(0.05)


@pytest.fixture(scope="module")
def standard_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs")
    run("sac_standard.py", *SHORT, "--output-dir", str(out), "--run-name", "std")
    return out / "std"


@pytest.fixture(scope="module")
def corrected_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs")
    run("sac_corrected.py", *SHORT, "--output-dir", str(out), "--run-name", "cor")
    return out / "cor"


@pytest.mark.slow
def test_learning_on_pendulum(tmp_path):
    run("sac_standard.py", "--env-id", "Pendulum-v1", "--total-timesteps", "6000",
        "--learning-starts", "1000", "--eval-interval", "6000", "--eval-episodes", "5",
        "--log-interval", "1000", "--output-dir", str(tmp_path), "--run-name", "learn")
    train = read_csv(tmp_path / "learn" / "train.csv")
    random_return = float(train[0]["episode_return_mean"])  # episodes of the random start steps
    final_return = float(read_csv(tmp_path / "learn" / "eval.csv")[-1]["return_mean"])
    assert random_return < -900
    assert final_return > -600 and final_return > random_return + 500


@pytest.mark.slow
def test_scripts_train_identically_and_pair_evaluations(standard_run, corrected_run):
    standard, corrected = (read_csv(r / "train.csv") for r in (standard_run, corrected_run))
    assert len(standard) == 15 and standard == corrected
    losses = [float(row["qf1_loss"]) for row in standard if row["qf1_loss"]]
    assert len(losses) == 11 and len(set(losses)) == 11  # updates ran and changed the critic
    # The corrected run's tanh(mu) evaluation is the standard run's evaluation, start for start.
    standard_eval, corrected_eval = (read_csv(r / "eval.csv") for r in (standard_run,
                                                                        corrected_run))
    assert [r["global_step"] for r in corrected_eval] == ["500", "1000", "1500"]
    for s, c in zip(standard_eval, corrected_eval, strict=True):
        assert c["tanh_mu_return_mean"] == s["return_mean"]
        assert c["tanh_mu_return_min"] == s["return_min"]
        assert float(c["mode_shift_abs_mean"]) > 0 and 0 <= float(c["bimodal_fraction"]) <= 1
    # (With one action dimension the shift's sum is its mean: test_smoke_on_humanoid_stand checks
    # the sum over 61.)


@pytest.mark.slow
def test_run_folder_outputs(standard_run):
    config = json.loads((standard_run / "config.json").read_text())
    assert config["algorithm"] == "standard" and config["script"] == "sac_standard.py"
    assert config["batch_size"] == 64 and config["env_id"] == "Pendulum-v1"
    assert (config["obs_dim"], config["action_dim"]) == (3, 1)
    assert set(config["versions"]) == {"python", "torch", "numpy", "gymnasium", "mujoco"}
    assert config["machine"]["cores"] == os.cpu_count() and config["machine"]["cpu"].strip()
    # the vector instruction sets beside the name, which a VM may reduce to "AMD EPYC"
    flags = next(line.split(":", 1)[1].split() for line in
                 Path("/proc/cpuinfo").read_text().splitlines() if line.startswith("flags"))
    assert config["machine"]["isa"] == sorted(
        {f for f in flags if f.startswith(("avx", "amx")) or f == "fma"})
    # The flags ask for CUDA, graphs and a GPU buffer; on this CPU run none was used.
    assert config["cuda"] and config["cudagraphs"] and config["gpu_buffer"]
    expected_device = "cuda" if torch.cuda.is_available() else "cpu"
    assert config["used"] == {"device": expected_device, "compile": False,
                              "cudagraphs": expected_device == "cuda",
                              "gpu_buffer": expected_device == "cuda", "torch_threads": 1}
    assert json.loads((standard_run / "done.json").read_text())["global_step"] == 1500
    with open(standard_run / "eval.csv") as f:
        assert f.readline().strip().split(",") == [
            "global_step", "wall_time", "eval_round", "distinct_episodes", "return_mean",
            "return_std", "return_min", "return_max", "length_mean", "success_rate"]
    eval_rows = read_csv(standard_run / "eval.csv")
    assert [r["success_rate"] for r in eval_rows] == ["", "", ""]  # Pendulum reports no success
    model = torch.load(standard_run / "final_model.pt", weights_only=True)  # cannot run code
    assert set(model) == {"actor", "qf", "config"}
    assert model["config"] == {"env_id": "Pendulum-v1", "hidden_sizes": (256, 256),
                               "log_std_min": -10.0, "log_std_max": 2.0}

    events = EventAccumulator(str(standard_run))
    events.Reload()
    returns = events.Scalars("eval/return_mean")
    assert [e.step for e in returns] == [500, 1000, 1500]
    assert [e.value for e in returns] == pytest.approx(
        [float(r["return_mean"]) for r in eval_rows])
    assert len(events.Scalars("train/qf1_loss")) == 11


@pytest.mark.slow
def test_sigkill_then_resume_equals_uninterrupted(standard_run, tmp_path):
    args = [*SHORT[:-1], "400", "--output-dir", str(tmp_path), "--run-name", "killed"]
    run_dir = tmp_path / "killed"
    process = subprocess.Popen(command("sac_standard.py", *args), cwd=ROOT,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    # Kill once the checkpoint at step 800 (past the start of learning) is on disk: it is saved
    # before the evaluation at step 1000.
    wait_for(lambda: (run_dir / "eval.csv").exists()
             and "1000," in (run_dir / "eval.csv").read_text())
    process.send_signal(signal.SIGKILL)
    process.wait()
    assert not (run_dir / "done.json").exists()
    # weights_only: a checkpoint loads without unpickling code (numpy's state is plain lists).
    assert torch.load(run_dir / "checkpoint.pt", weights_only=True)["global_step"] in (800, 1200)
    run("sac_standard.py", "--resume", str(run_dir))
    for name in ("eval.csv", "train.csv"):
        assert read_csv(run_dir / name) == read_csv(standard_run / name)
    # TensorBoard purged the events logged after the checkpoint: one value per step.
    events = EventAccumulator(str(run_dir))
    events.Reload()
    assert [e.step for e in events.Scalars("eval/return_mean")] == [500, 1000, 1500]
    assert [e.step for e in events.Scalars("train/alpha")] == list(range(500, 1501, 100))
    resumed, uninterrupted = (torch.load(r / "final_model.pt") for r in (run_dir, standard_run))
    for part in ("actor", "qf"):
        for key, value in uninterrupted[part].items():
            assert torch.equal(resumed[part][key], value), key


@pytest.mark.slow
def test_sigterm_checkpoints_exits_3_and_resumes(corrected_run, tmp_path):
    args = [*SHORT, "--output-dir", str(tmp_path), "--run-name", "term"]
    run_dir = tmp_path / "term"
    process = subprocess.Popen(command("sac_corrected.py", *args), cwd=ROOT,
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    wait_for(lambda: (run_dir / "train.csv").exists()
             and "\n600," in (run_dir / "train.csv").read_text())
    process.send_signal(signal.SIGTERM)
    output = process.communicate()[0]
    assert process.returncode == 3, output
    assert "resume with --resume" in output
    stopped_at = torch.load(run_dir / "checkpoint.pt", weights_only=False)["global_step"]
    assert 600 <= stopped_at < 1500  # after the step the signal came in, mid-episode or not
    assert not (run_dir / "done.json").exists()
    run("sac_corrected.py", "--resume", str(run_dir), "--print-interval", "100")
    for name in ("eval.csv", "train.csv"):
        assert read_csv(run_dir / name) == read_csv(corrected_run / name)


def test_replay_buffer_samples_stored_transitions_uniformly():
    import numpy as np

    from sac_standard import ReplayBuffer

    rb = ReplayBuffer(size=4, obs_dim=1, action_dim=1, device=torch.device("cpu"))
    # Episode 1: obs 0 -> 1 -> 2 (truncated: its true final observation); 2: 10 -> 11
    # (terminated); 3: 20 -> 21. Five transitions in a ring of four: the first is overwritten.
    for obs, next_obs, terminated in [(0, 1, False), (1, 2, False), (10, 11, True),
                                      (20, 21, False), (21, 22, False)]:
        rb.add(np.array([obs]), np.array([obs]), obs, terminated, np.array([next_obs]))
    assert (rb.ptr, rb.filled) == (1, 4)
    torch.manual_seed(0)
    obs, actions, rewards, next_obs, not_done = rb.sample(2000, torch.device("cpu"))
    assert obs.shape == (2000, 1) and rewards.shape == not_done.shape == (2000,)
    pairs = [(int(o), int(n), int(d)) for o, n, d in zip(obs[:, 0], next_obs[:, 0], not_done,
                                                         strict=True)]
    assert set(pairs) == {(1, 2, 1), (10, 11, 0), (20, 21, 1), (21, 22, 1)}
    assert all(400 < pairs.count(p) < 600 for p in set(pairs))  # uniform: 500 each expected
    assert torch.equal(actions[:, 0], obs[:, 0]) and torch.equal(rewards, obs[:, 0])


def test_replay_buffer_state_round_trip():
    import numpy as np

    from sac_standard import ReplayBuffer
    from sac_utils.checkpoints import buffer_state, load_buffer_state

    cpu = torch.device("cpu")
    rb = ReplayBuffer(size=50, obs_dim=3, action_dim=2, device=cpu)
    for i in range(30):
        rb.add(np.full(3, i), np.array([i, -i]), float(i), i % 7 == 6, np.full(3, i + 1))
    copy = ReplayBuffer(size=50, obs_dim=3, action_dim=2, device=cpu)
    load_buffer_state(copy, buffer_state(rb))
    torch.manual_seed(3)
    original = rb.sample(16, cpu)
    torch.manual_seed(3)  # the buffer draws from torch's generator, saved in the checkpoint
    for a, b in zip(original, copy.sample(16, cpu), strict=True):
        assert torch.equal(a, b)


@pytest.mark.parametrize(("args", "message"), [
    (["--env-id", "Pendulum-v2"], "close matches: ['Pendulum-v1'"),
    (["--env-id", "CartPole-v1"], "Discrete action space"),
    (["--env-id", "Pendulum-v1", "--batch-size", "128", "--buffer-size", "100"],
     "--batch-size 128: must be between 1 and --buffer-size (100)"),
    (["--resume", "tests"], "is not a run folder"),
    (["--env-id", "Pendulum-v1", "--eval-reset-noise", "0.01"],
     "Pendulum-v1 is not an h1hand task, which alone take it"),
])
def test_bad_input_fails_with_one_clear_line(args, message, tmp_path):
    result = run("sac_standard.py", *args, "--output-dir", str(tmp_path), check=False)
    assert result.returncode == 2
    assert message in result.stderr and "Traceback" not in result.stderr


@pytest.mark.slow
def test_snapshots_keep_the_policy_at_each_interval_and_survive_a_resume(tmp_path):
    args = [*SHORT, "--snapshot-interval", "500", "--checkpoint-interval", "600",
            "--output-dir", str(tmp_path), "--run-name", "snap"]
    run_dir = tmp_path / "snap"
    process = subprocess.Popen(command("sac_corrected.py", *args), cwd=ROOT,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wait_for(lambda: (run_dir / "checkpoint.pt").exists())  # at step 600, past snapshot 500
    process.send_signal(signal.SIGKILL)
    process.wait()
    # A copy whose checkpoint is lost once its snapshot was taken (a campaign's stop commits it)
    # restarts from that snapshot: the same policy, in the format `sweep.py restart` reads.
    lost = tmp_path / "lost"
    shutil.copytree(run_dir, lost)
    assert snapshot_from_checkpoint(lost, lost / "snapshots") == 600
    (lost / "checkpoint.pt").unlink()
    ckpt = torch.load(run_dir / "checkpoint.pt", weights_only=False)
    at_stop = torch.load(lost / "snapshots" / "step600.pt", weights_only=True)
    assert set(at_stop) == {"actor", "qf", "config", "log_alpha"}
    assert at_stop["config"] == torch.load(run_dir / "snapshots" / "step500.pt")["config"]
    assert all(torch.equal(v, ckpt["actor"][k]) for k, v in at_stop["actor"].items())
    restarted = run("sweep.py", "restart", str(lost), "--refill", "100")
    assert "checkpoint.pt written from snapshots/step600.pt" in restarted.stdout

    run("sac_corrected.py", "--resume", str(run_dir))
    snapshots = {p.name: torch.load(p, weights_only=True)
                 for p in sorted((run_dir / "snapshots").iterdir())}
    assert set(snapshots) == {"step500.pt", "step1000.pt", "step1500.pt"}
    final = torch.load(run_dir / "final_model.pt", weights_only=True)
    uninterrupted = run("sac_corrected.py", *args[:-1], "whole")  # the same run, not killed
    for name, snapshot in snapshots.items():
        assert set(snapshot) == {"actor", "qf", "config", "log_alpha"}
        whole = torch.load(tmp_path / "whole" / "snapshots" / name, weights_only=True)
        assert torch.equal(snapshot["log_alpha"], whole["log_alpha"])
        same_as_final = True
        for part in ("actor", "qf"):
            for key, value in snapshot[part].items():
                assert torch.equal(value, whole[part][key]), (name, key)
                same_as_final &= torch.equal(value, final[part][key])
        assert same_as_final is (name == "step1500.pt"), name  # training moved the weights
    assert uninterrupted.returncode == 0


@pytest.mark.slow
def test_a_run_whose_checkpoint_is_lost_restarts_from_its_last_snapshot(tmp_path):
    """The fallback when a machine is lost with a run's checkpoint: checkpoint.pt rebuilt from the
    last snapshot, the buffer refilled by acting before updates resume, the logs going on from
    the snapshot's step, the restart recorded."""
    args = [*SHORT, "--snapshot-interval", "500", "--log-interval", "100",
            "--output-dir", str(tmp_path), "--run-name", "lost"]
    run_dir = tmp_path / "lost"
    process = subprocess.Popen(command("sac_corrected.py", *args), cwd=ROOT,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wait_for(lambda: (run_dir / "snapshots" / "step1000.pt").exists())
    process.send_signal(signal.SIGKILL)  # no checkpoint: --checkpoint-interval 0
    process.wait()
    before = read_csv(run_dir / "train.csv")
    restarted = run("sweep.py", "restart", str(run_dir), "--refill", "200")
    assert "checkpoint.pt written from snapshots/step1000.pt" in restarted.stdout
    (record,) = json.loads((run_dir / "config.json").read_text())["restarts"]
    assert (record["step"], record["refill"], record["updates_from"]) == (1000, 200, 1200)
    assert read_csv(run_dir / "restarts" / "step1000" / "train.csv") == before  # kept as it was
    twice = run("sweep.py", "restart", str(run_dir), check=False)  # its checkpoint is there now
    assert twice.returncode == 2 and "continue it exactly with --resume" in twice.stderr
    resumed = run("sac_corrected.py", "--resume", str(run_dir))
    assert "updates resume at step 1200" in resumed.stdout

    config = json.loads((run_dir / "config.json").read_text())
    assert config["restarts"] == [record]
    train = read_csv(run_dir / "train.csv")
    assert [int(r["global_step"]) for r in train] == list(range(100, 1600, 100))
    assert train[:10] == before[:10]  # up to the snapshot's step, the run as it was
    losses = {int(r["global_step"]): r["qf1_loss"] for r in train}
    assert losses[1100] == "" and losses[1200] != "" and losses[1500] != ""  # the refill
    assert [int(r["global_step"]) for r in read_csv(run_dir / "eval.csv")] == [500, 1000, 1500]
    snapshot = torch.load(run_dir / "snapshots" / "step1000.pt", weights_only=True)
    final = torch.load(run_dir / "final_model.pt", weights_only=True)
    assert any(not torch.equal(v, final["actor"][k]) for k, v in snapshot["actor"].items())

    # A finished run has nothing to restart: one line, exit code 2.
    again = run("sweep.py", "restart", str(run_dir), check=False)
    assert again.returncode == 2 and "finished (done.json)" in again.stderr
    assert len(again.stderr.strip().splitlines()) == 1


@pytest.mark.slow
def test_bad_resumes_fail_clearly(standard_run, tmp_path):
    result = run("sac_standard.py", *SHORT, "--output-dir", str(standard_run.parent),
                 "--run-name", "std", check=False)
    assert "already holds a run" in result.stderr
    result = run("sac_corrected.py", "--resume", str(standard_run), check=False)
    assert "resume it with that script" in result.stderr
    result = run("sac_standard.py", "--resume", str(standard_run), "--seed", "5", check=False)
    assert "['seed'] contradict" in result.stderr
    # A checkpoint whose arguments differ from the run's config.json.
    run_dir = tmp_path / "mismatch"
    run("sac_standard.py", *SHORT[:-1], "300", "--total-timesteps", "400", "--learning-starts",
        "100", "--output-dir", str(tmp_path), "--run-name", "mismatch")
    (run_dir / "done.json").unlink()
    config = json.loads((run_dir / "config.json").read_text())
    (run_dir / "config.json").write_text(json.dumps({**config, "gamma": 0.5}))
    result = run("sac_standard.py", "--resume", str(run_dir), check=False)
    assert "made with other arguments" in result.stderr


def test_nan_is_a_clear_error():
    from sac_utils.cli import check_finite

    with pytest.raises(SystemExit, match="training diverged"):
        check_finite(torch.tensor([0.0, float("nan")]).numpy(), "action")
    check_finite(torch.zeros(3).numpy(), "action")


@pytest.mark.slow
def test_capture_video_writes_a_readable_mp4(tmp_path):
    run("sac_standard.py", "--env-id", "InvertedPendulum-v5", "--total-timesteps", "300",
        "--learning-starts", "200", "--eval-interval", "300", "--eval-episodes", "1",
        "--capture-video", "--output-dir", str(tmp_path), "--run-name", "video")
    import imageio

    videos = list((tmp_path / "video" / "videos").glob("*.mp4"))
    assert [v.name for v in videos] == ["eval_step300.mp4"]
    frames = imageio.mimread(videos[0])
    length = float(read_csv(tmp_path / "video" / "eval.csv")[0]["length_mean"])
    assert len(frames) == length and frames[0].ndim == 3


@pytest.mark.slow
def test_smoke_on_humanoid_stand(tmp_path):
    run("sac_corrected.py", "--env-id", "h1hand-stand-v0", "--total-timesteps", "300",
        "--learning-starts", "200", "--eval-interval", "300", "--eval-episodes", "1",
        "--log-interval", "100", "--output-dir", str(tmp_path), "--run-name", "h1")
    config = json.loads((tmp_path / "h1" / "config.json").read_text())
    assert config["action_dim"] == 61
    [row] = read_csv(tmp_path / "h1" / "eval.csv")
    shift_sum, shift_mean = float(row["mode_shift_abs_sum"]), float(row["mode_shift_abs_mean"])
    assert shift_sum == pytest.approx(61 * shift_mean, rel=1e-4) and shift_mean > 0
    train = read_csv(tmp_path / "h1" / "train.csv")
    assert [r["global_step"] for r in train] == ["100", "200", "300"]
    assert train[0]["qf1_loss"] == ""  # no update before learning starts
    # The updates from step 200 to 300 moved the critics, the actor and the temperature.
    for column in ("qf1_loss", "qf2_loss", "actor_loss", "alpha"):
        assert float(train[1][column]) != float(train[2][column]), column


def test_glorot_uniform_init_and_zero_biases():
    import gymnasium as gym
    import numpy as np

    from sac_standard import Actor, TwinQ

    space = gym.spaces.Box(-1.0, 1.0, (17,), np.float32)
    layers = [m for net in (Actor(40, (256, 256), space, -10.0, 2.0), TwinQ(40, 17, (256, 256)))
              for m in net.modules() if isinstance(m, torch.nn.Linear)]
    assert len(layers) == 4 + 6  # actor: two hidden, mean and log-sigma heads; critics: 3 each
    for layer in layers:
        fan_out, fan_in = layer.weight.shape
        bound = (6 / (fan_in + fan_out)) ** 0.5
        assert torch.count_nonzero(layer.bias) == 0
        # Uniform on [-bound, bound]: within it, and reaching near it (PyTorch's default would
        # stay within 1/sqrt(fan_in), 1.7-2.4x narrower here).
        assert layer.weight.abs().max() <= bound
        assert layer.weight.abs().max() > 0.95 * bound


def test_update_scores_the_actor_with_the_pre_update_critic():
    """A hand-computed update on a tiny network: each loss from the parameters as they were before
    the update (HumanoidBench's jaxrl_m order), and the target towards the pre-update critic."""
    import copy
    import functools

    import gymnasium as gym
    import numpy as np

    from sac_standard import Actor, TwinQ, sac_update

    torch.manual_seed(0)
    actor = Actor(3, (8,), gym.spaces.Box(-1.0, 1.0, (2,), np.float32), -10.0, 2.0)
    qf, log_alpha = TwinQ(3, 2, (8,)), torch.tensor(0.3, requires_grad=True)
    qf_target = copy.deepcopy(qf)
    with torch.no_grad():  # a target apart from the critic, so that the Polyak step shows
        for p in qf_target.parameters():
            p.add_(0.1)
    batch = (torch.randn(16, 3), torch.rand(16, 2) * 2 - 1, torch.randn(16),
             torch.randn(16, 3), (torch.rand(16) > 0.2).float())
    before = [copy.deepcopy(m) for m in (actor, qf, qf_target)]
    old_actor, old_qf = copy.deepcopy(actor), copy.deepcopy(qf)
    adam = functools.partial(torch.optim.Adam, lr=0.05)
    optimizers = (adam(actor.parameters()), adam(qf.parameters()), adam([log_alpha]))
    noise = torch.randn(2, 16, 2)  # the next action's, then the action's
    sac_update(actor, qf, qf_target, log_alpha, optimizers, batch, noise, 0.99, 0.1, -1.0)

    # By hand: the actor's gradient step against the pre-update critic.
    ref_actor, ref_qf, ref_target = before
    pi, log_pi = ref_actor.squash(*ref_actor(batch[0]), noise[1])
    alpha = torch.tensor(0.3).exp()
    actor_loss = (alpha * log_pi - ref_qf(batch[0], pi).min(0).values).mean()
    ref_optimizer = adam(ref_actor.parameters())
    actor_loss.backward(inputs=list(ref_actor.parameters()))
    ref_optimizer.step()
    for p, ref in zip(actor.parameters(), ref_actor.parameters(), strict=True):
        torch.testing.assert_close(p, ref)
    # The same actor step against the updated critic lands elsewhere: the order matters here.
    stale_actor = copy.deepcopy(before[0])
    pi, log_pi = stale_actor.squash(*stale_actor(batch[0]), noise[1])
    stale_loss = (alpha * log_pi - qf(batch[0], pi).min(0).values).mean()
    stale_optimizer = adam(stale_actor.parameters())
    stale_loss.backward(inputs=list(stale_actor.parameters()))
    stale_optimizer.step()
    assert not torch.allclose(next(stale_actor.parameters()), next(actor.parameters()))
    # The critics stepped on their own loss alone (the actor loss's gradient never reached them).
    ref_qf_optimizer = adam(ref_qf.parameters())
    with torch.no_grad():
        next_pi, next_log_pi = old_actor.squash(*old_actor(batch[3]), noise[0])
        target = batch[2] + batch[4] * 0.99 * (ref_target(batch[3], next_pi).min(0).values
                                               - alpha * next_log_pi)
    (ref_qf(batch[0], batch[1]) - target).pow(2).mean(-1).sum().backward()
    ref_qf_optimizer.step()
    for p, ref in zip(qf.parameters(), ref_qf.parameters(), strict=True):
        torch.testing.assert_close(p, ref)
    # The target moved a tenth of the way towards the critic as it was before its step.
    for p, old_target, old_critic in zip(qf_target.parameters(), ref_target.parameters(),
                                         old_qf.parameters(), strict=True):
        torch.testing.assert_close(p, old_target + 0.1 * (old_critic - old_target))


def test_terminated_and_truncated_transitions_are_bootstrapped():
    import numpy as np

    from sac_standard import ends_without_bootstrap

    terminated, truncated = np.array([True, True, False, False]), np.array([False, True, True,
                                                                            False])
    # Bootstrapped unless terminated alone; both at once is bootstrapped, as HumanoidBench.
    assert ends_without_bootstrap(terminated, truncated).tolist() == [True, False, False, False]


@pytest.mark.slow
def test_a_folder_in_use_refuses_a_second_process_until_its_holder_dies(tmp_path):
    run_dir = tmp_path / "busy"
    args = [*SHORT[:-1], "400", "--total-timesteps", "3000", "--eval-workers", "0",
            "--output-dir", str(tmp_path), "--run-name", "busy"]
    holder = subprocess.Popen(command("sac_standard.py", *args), cwd=ROOT,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_for(lambda: (run_dir / "checkpoint.pt").exists())
        holder.send_signal(signal.SIGSTOP)  # frozen, so that its files hold still
        before = {p.name: p.read_bytes() for p in run_dir.iterdir() if p.is_file()}
        second = run("sac_standard.py", "--resume", str(run_dir), check=False)
        assert second.returncode == 2 and "Traceback" not in second.stderr
        assert f"is in use by process {holder.pid}" in second.stderr
        assert {p.name: p.read_bytes() for p in run_dir.iterdir() if p.is_file()} == before
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    # The kernel released the lock with its holder: the resume goes ahead at once.
    run("sac_standard.py", "--resume", str(run_dir), "--eval-workers", "0")
    assert (run_dir / "done.json").exists()
