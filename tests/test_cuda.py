"""The SAC scripts on a CUDA GPU: CUDA graphs, the GPU replay buffer, checkpoints across devices.

CI has no GPU, so these tests skip there; they run on a GPU machine (see README, "Speed on a GPU").
"""

import copy
import functools
import signal
import subprocess

import gymnasium as gym
import numpy as np
import pytest
import torch

from mode_search import mode_action
from sac_standard import (
    Actor,
    ReplayBuffer,
    TwinQ,
    cuda_graph,
    make_train_step,
    sac_update,
)
from tests.test_sac import SHORT, command, read_csv, run, wait_for

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
CUDA = torch.device("cuda")
OBS_DIM, ACTION_DIM = 11, 3


def learner(buffer_device: torch.device, seed: int = 0, seeds: int = 2):
    """A small batched SAC learner on the GPU (`seeds` seeds) and replay buffers of random
    transitions (episodes of 20)."""
    torch.manual_seed(seed)
    generators = [torch.Generator().manual_seed(seed + k) for k in range(seeds)]
    space = gym.spaces.Box(-2.0, 2.0, (ACTION_DIM,), np.float32)
    actor = Actor(OBS_DIM, (32, 32), space, -10.0, 2.0, seeds, generators).to(CUDA)
    qf = TwinQ(OBS_DIM, ACTION_DIM, (32, 32), seeds, generators).to(CUDA)
    qf_target = copy.deepcopy(qf)
    log_alpha = torch.zeros(seeds, device=CUDA, requires_grad=True)
    adam = functools.partial(torch.optim.Adam, lr=3e-4, fused=True, capturable=True)
    optimizers = (adam(qf.parameters()), adam(actor.parameters()), adam([log_alpha]))
    rb = ReplayBuffer(seeds, 500, OBS_DIM, ACTION_DIM, buffer_device)
    rng = np.random.default_rng(seed)
    for step in range(400):
        rb.add(rng.normal(size=(seeds, OBS_DIM)), rng.uniform(-2, 2, (seeds, ACTION_DIM)),
               rng.normal(size=seeds), np.full(seeds, step % 40 == 39),
               rng.normal(size=(seeds, OBS_DIM)), np.full(seeds, step % 20 == 19))
    update = functools.partial(sac_update, actor=actor, qf=qf, qf_target=qf_target,
                               log_alpha=log_alpha, optimizers=optimizers, gamma=0.99, tau=0.005,
                               target_entropy=-ACTION_DIM / 2)
    return rb, (lambda batch: update(batch)), (actor, qf, qf_target, log_alpha, *optimizers)


def losses_over_updates(graphs: bool, buffer_device: torch.device, updates: int = 300):
    rb, update, state = learner(buffer_device)
    torch.manual_seed(1)
    torch.cuda.manual_seed(1)
    step = make_train_step(rb, update, 64, CUDA, graphs, state)
    losses = torch.stack([torch.stack([t.detach().float().mean() for t in step()])
                          for _ in range(updates)])
    return losses.cpu(), state[0].state_dict()


@pytest.mark.parametrize("buffer_device", ["cuda", "cpu"])
def test_graph_update_agrees_with_eager(buffer_device):
    eager, eager_actor = losses_over_updates(False, torch.device(buffer_device))
    graph, graph_actor = losses_over_updates(True, torch.device(buffer_device))
    # The same batches and the same losses, update for update: the capture's warm-up left no trace.
    torch.testing.assert_close(graph, eager, rtol=1e-4, atol=1e-5)
    for key, value in eager_actor.items():
        torch.testing.assert_close(graph_actor[key], value, rtol=1e-4, atol=1e-5)
    assert not torch.equal(eager[0], eager[-1])  # the updates changed the networks


def test_graph_replays_see_new_inputs_and_keep_mode_exact():
    mu = torch.randn(4, ACTION_DIM, device=CUDA, dtype=torch.float32) * 2
    log_std = torch.rand(4, ACTION_DIM, device=CUDA) * 3 - 2
    for solver in ("exact", "grid"):
        select = cuda_graph(lambda m, s, solver=solver: mode_action(m, s, solver))
        for scale in (1.0, -0.5, 3.0):
            expected = mode_action(mu.cpu().double() * scale, log_std.cpu().double(), solver)
            torch.testing.assert_close(select(mu * scale, log_std).cpu().double(), expected,
                                       rtol=0, atol=1e-6 if solver == "exact" else 1e-7)


def test_scripts_on_gpu_train_identically_and_resume_exactly(tmp_path):
    run("sac_standard.py", *SHORT, "--output-dir", str(tmp_path), "--run-name", "std")
    run("sac_corrected.py", *SHORT, "--output-dir", str(tmp_path), "--run-name", "cor")
    std, cor = tmp_path / "std", tmp_path / "cor"
    assert read_csv(std / "train.csv") == read_csv(cor / "train.csv")
    for s, c in zip(read_csv(std / "eval.csv"), read_csv(cor / "eval.csv"), strict=True):
        assert c["tanh_mu_return_mean"] == s["return_mean"]

    # SIGKILL after a checkpoint, then --resume: the same run as the uninterrupted one.
    killed = tmp_path / "killed"
    process = subprocess.Popen(
        command("sac_standard.py", *SHORT[:-1], "400", "--output-dir", str(tmp_path),
                "--run-name", "killed"), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wait_for(lambda: (killed / "eval.csv").exists()
             and "1000," in (killed / "eval.csv").read_text())
    process.send_signal(signal.SIGKILL)
    process.wait()
    run("sac_standard.py", "--resume", str(killed))
    for name in ("eval.csv", "train.csv"):
        assert read_csv(killed / name) == read_csv(std / name)

    # SIGTERM: checkpoint after the current step, exit 3, resume to the same run.
    term = tmp_path / "term"
    process = subprocess.Popen(
        command("sac_corrected.py", *SHORT, "--output-dir", str(tmp_path), "--run-name", "term"),
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wait_for(lambda: (term / "train.csv").exists() and "\n600," in (term / "train.csv").read_text())
    process.send_signal(signal.SIGTERM)
    assert process.wait() == 3
    run("sac_corrected.py", "--resume", str(term))
    for name in ("eval.csv", "train.csv"):
        assert read_csv(term / name) == read_csv(cor / name)


def test_checkpoints_move_between_gpu_and_cpu(tmp_path):
    half = [*SHORT[:-1], "400", "--total-timesteps", "900"]
    for name, first, second in (("g2c", "--cuda", "--no-cuda"), ("c2g", "--no-cuda", "--cuda")):
        run("sac_corrected.py", *half, first, "--output-dir", str(tmp_path), "--run-name", name)
        run_dir = tmp_path / name
        (run_dir / "done.json").unlink()  # continue from the step-800 checkpoint to step 1500
        config = run_dir / "config.json"
        config.write_text(config.read_text().replace('"total_timesteps": 900',
                                                     '"total_timesteps": 1500'))
        checkpoint = torch.load(run_dir / "checkpoint.pt", weights_only=False)
        checkpoint["args"]["total_timesteps"] = 1500
        torch.save(checkpoint, run_dir / "checkpoint.pt")
        result = run("sac_corrected.py", "--resume", str(run_dir), second)
        assert "resuming" in result.stdout
        assert [r["global_step"] for r in read_csv(run_dir / "eval.csv")][-1] == "1500"
        assert torch.load(run_dir / "final_model.pt", weights_only=True)["actor"]


def test_host_buffer_run_on_gpu(tmp_path):
    run("sac_standard.py", *SHORT, "--no-gpu-buffer", "--output-dir", str(tmp_path),
        "--run-name", "host")
    losses = [float(r["qf1_loss"]) for r in read_csv(tmp_path / "host" / "train.csv")
              if r["qf1_loss"]]
    assert len(losses) == 11 and len(set(losses)) == 11


def test_a_batch_on_gpu_resumes_exactly_after_sigkill(tmp_path):
    batch = [*SHORT[:-1], "500", "--num-seeds", "2", "--eval-workers", "0", "--output-dir",
             str(tmp_path)]
    run("sac_standard.py", *batch, "--run-name", "whole{seed}")
    process = subprocess.Popen(command("sac_standard.py", *batch, "--run-name", "killed{seed}"),
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wait_for(lambda: (tmp_path / "killed1" / "train.csv").exists()
             and "\n700," in (tmp_path / "killed1" / "train.csv").read_text())
    process.send_signal(signal.SIGKILL)
    process.wait()
    run("sac_standard.py", "--resume", str(tmp_path / "killed0"))
    for seed in (0, 1):
        for name in ("eval.csv", "train.csv"):
            assert read_csv(tmp_path / f"killed{seed}" / name) == read_csv(
                tmp_path / f"whole{seed}" / name)
