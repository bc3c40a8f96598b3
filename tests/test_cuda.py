"""The SAC scripts on a CUDA GPU: CUDA graphs, the GPU replay buffer, checkpoints across devices.

CI has no GPU, so these tests skip there; they run on a GPU machine (see README, "Speed on a GPU").
"""

import functools
import signal
import subprocess

import gymnasium as gym
import numpy as np
import pytest
import torch

from mode_search import mode_action
from sac_standard import ReplayBuffer, sac_update
from sac_utils.speedups import compiled_update, cuda_graph
from tests.test_sac import SHORT, command, read_csv, run, wait_for

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
CUDA = torch.device("cuda")
OBS_DIM, ACTION_DIM = 11, 3


def learner(buffer_device: torch.device, seed: int = 0, compiled: bool = False):
    """A small SAC learner on the GPU (make_agent's), its update (the textbook sac_update, or the
    compiled one), and a replay buffer of random transitions (episodes of 20)."""
    import sac_standard as sac

    torch.manual_seed(seed)
    space = gym.spaces.Box(-2.0, 2.0, (ACTION_DIM,), np.float32)
    agent = sac.make_agent(sac.Args(seed=seed, hidden_sizes=(32, 32)), OBS_DIM, space, CUDA)
    rb = ReplayBuffer(500, OBS_DIM, ACTION_DIM, buffer_device)
    rng = np.random.default_rng(seed)
    for step in range(400):
        rb.add(rng.normal(size=OBS_DIM), rng.uniform(-2, 2, ACTION_DIM), rng.normal(),
               step % 40 == 39, rng.normal(size=OBS_DIM))
    losses = (sac.critic_loss, sac.actor_loss, sac.alpha_loss)
    if compiled:
        update = compiled_update(agent, losses, 0.99, 0.005, -ACTION_DIM / 2,
                                 (64, OBS_DIM, ACTION_DIM), CUDA)
    else:
        optimizers = (agent["actor_optimizer"], agent["q_optimizer"], agent["alpha_optimizer"])
        update = functools.partial(sac_update, agent["actor"], agent["qf"], agent["qf_target"],
                                   agent["log_alpha"], optimizers, gamma=0.99, tau=0.005,
                                   target_entropy=-ACTION_DIM / 2)
    return rb, update, tuple(agent.values())


def losses_over_updates(graphs: bool, buffer_device: torch.device, updates: int = 300,
                        compiled: bool = False):
    rb, update, state = learner(buffer_device, compiled=compiled)
    torch.manual_seed(1)
    torch.cuda.manual_seed(1)
    if graphs:  # as the scripts: the batch drawn outside the graph, copied into its inputs
        update = cuda_graph(update, state)

    def step():
        batch = rb.sample(64, CUDA)
        return update(batch, torch.randn(2, 64, ACTION_DIM, device=CUDA))

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


def test_compiled_update_in_a_graph_agrees_with_eager():
    """The scripts' default on a GPU: the compiled update, captured in a CUDA graph. Kernels
    fused differently round differently: close, not equal (passed on an H200, 2026-11-30)."""
    eager, eager_actor = losses_over_updates(False, CUDA, updates=100)
    compiled, compiled_actor = losses_over_updates(True, CUDA, updates=100, compiled=True)
    torch.testing.assert_close(compiled, eager, rtol=1e-3, atol=1e-3)
    for key, value in eager_actor.items():
        torch.testing.assert_close(compiled_actor[key], value, rtol=1e-3, atol=1e-3)


def test_graph_replays_see_new_inputs_and_keep_mode_exact():
    # Seeded inputs; the graph against eager mode_action on the same CUDA tensors (a float32 grid
    # mode and a float64 reference can round to neighbouring grid points).
    generator = torch.Generator(device=CUDA).manual_seed(0)
    mu = torch.randn(4, ACTION_DIM, device=CUDA, generator=generator) * 2
    log_std = torch.rand(4, ACTION_DIM, device=CUDA, generator=generator) * 3 - 2
    for solver in ("exact", "grid"):
        select = cuda_graph(lambda m, s, solver=solver: mode_action(m, s, solver))
        replays = []
        for scale in (1.0, -0.5, 3.0):
            # clone: the graph's outputs are overwritten by its next replay.
            graph = select(mu * scale, log_std).clone()
            eager = mode_action(mu * scale, log_std, solver)
            torch.testing.assert_close(graph, eager, rtol=0, atol=1e-6)
            if solver == "exact":  # the float32 mode is the float64 one, to the solver's 1e-6
                expected = mode_action(mu.cpu().double() * scale, log_std.cpu().double(), solver)
                torch.testing.assert_close(graph.cpu().double(), expected, rtol=0, atol=1e-6)
            replays.append(graph)
        # Each replay computed from its own inputs, not the capture's.
        assert not torch.equal(replays[0], replays[1]) and not torch.equal(replays[0], replays[2])


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
    # Killed before the end, or the resume would have nothing to do and the run would equal the
    # uninterrupted one whatever --resume does.
    assert not (killed / "done.json").exists()
    step = torch.load(killed / "checkpoint.pt", map_location="cpu",
                      weights_only=True)["global_step"]
    assert step in (800, 1200)
    result = run("sac_standard.py", "--resume", str(killed))
    assert f"resuming {killed} at step {step}\n" in result.stdout
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


def device_line(result: subprocess.CompletedProcess) -> str:
    """The device a run of the scripts ran on, from the line it prints at the start."""
    (line,) = [x for x in result.stdout.splitlines() if x.startswith("device: ")]
    return line


def ran_on(checkpoint: dict) -> str:
    """The device of the run that wrote a checkpoint (which holds CPU tensors either way): it
    keeps the CUDA generators' states only for a run on CUDA, and Adam is capturable there."""
    groups = checkpoint["q_optimizer"]["param_groups"]
    device = "cpu" if checkpoint["rng"]["cuda"] is None else "cuda"
    assert {g["capturable"] for g in groups} == {device == "cuda"}
    return device


def lines_up_to(path, step: int) -> list[str]:
    """A CSV's header and its rows up to `step`, as written (wall_time included; read as text,
    so that only the rows' contents compare: tests/test_travel.py checks the bytes)."""
    lines = path.read_text().splitlines(keepends=True)
    return lines[:1] + [x for x in lines[1:] if int(x.split(",")[0]) <= step]


def test_checkpoints_move_between_gpu_and_cpu(tmp_path):
    half = [*SHORT[:-1], "400", "--total-timesteps", "900"]
    device_of = {"--cuda": "cuda", "--no-cuda": "cpu"}
    for name, first, second in (("g2c", "--cuda", "--no-cuda"), ("c2g", "--no-cuda", "--cuda")):
        result = run("sac_corrected.py", *half, first, "--output-dir", str(tmp_path),
                     "--run-name", name)
        assert device_line(result) == f"device: {device_of[first]}"
        run_dir = tmp_path / name
        (run_dir / "done.json").unlink()  # continue from the step-800 checkpoint to step 1500
        config = run_dir / "config.json"
        config.write_text(config.read_text().replace('"total_timesteps": 900',
                                                     '"total_timesteps": 1500'))
        checkpoint = torch.load(run_dir / "checkpoint.pt", weights_only=False)
        assert checkpoint["global_step"] == 800
        assert ran_on(checkpoint) == device_of[first]
        checkpoint["args"]["total_timesteps"] = 1500
        torch.save(checkpoint, run_dir / "checkpoint.pt")
        # The first part's rows up to the checkpoint (its step-900 train row is dropped).
        kept = {f: lines_up_to(run_dir / f, 800) for f in ("train.csv", "eval.csv")}
        assert len(kept["train.csv"]) == 1 + 8 and len(kept["eval.csv"]) == 1 + 1

        # (--checkpoint-interval is no part of a run's identity: given again.)
        result = run("sac_corrected.py", "--resume", str(run_dir), second,
                     "--checkpoint-interval", "400")
        assert f"resuming {run_dir} at step 800\n" in result.stdout
        assert device_line(result) == f"device: {device_of[second]}"
        # The resumed part's checkpoint (step 1200) was written on the other device.
        resumed = torch.load(run_dir / "checkpoint.pt", weights_only=True)
        assert resumed["global_step"] == 1200 and ran_on(resumed) == device_of[second]
        # The rows before the checkpoint are kept as written, wall_time included; the resumed
        # part follows.
        for f, lines in kept.items():
            after = (run_dir / f).read_text().splitlines(keepends=True)
            assert after[:len(lines)] == lines, f
            assert [int(x.split(",")[0]) for x in after[len(lines):]] == (
                list(range(900, 1501, 100)) if f == "train.csv" else [1000, 1500]), f
        assert torch.load(run_dir / "final_model.pt", weights_only=True)["actor"]


def test_host_buffer_run_on_gpu(tmp_path):
    """--no-gpu-buffer keeps the buffer in host memory: ReplayBuffer.sample draws its slots from
    the random generator of the buffer's device, so the batches come from the CPU's generator,
    not the GPU's, and both generators end elsewhere than in the same run with the GPU buffer."""
    args = [*SHORT[:-1], "1000", "--output-dir", str(tmp_path)]
    run("sac_standard.py", *args, "--no-gpu-buffer", "--run-name", "host")
    run("sac_standard.py", *args, "--run-name", "device")
    losses = [float(r["qf1_loss"]) for r in read_csv(tmp_path / "host" / "train.csv")
              if r["qf1_loss"]]
    assert len(losses) == 11 and len(set(losses)) == 11
    host, device = (torch.load(tmp_path / name / "checkpoint.pt", map_location="cpu",
                               weights_only=True) for name in ("host", "device"))
    assert host["global_step"] == device["global_step"] == 1000
    # 500 updates: the host buffer drew 500 batches from the CPU generator, the GPU buffer none.
    assert not torch.equal(host["rng"]["torch"], device["rng"]["torch"])
    assert not torch.equal(host["rng"]["cuda"][0], device["rng"]["cuda"][0])
    assert read_csv(tmp_path / "host" / "train.csv") != read_csv(tmp_path / "device" / "train.csv")


def test_a_run_with_cuda_graphs_is_the_eager_run(tmp_path):
    """A whole run, transitions added between updates, with the update and the action as CUDA
    graphs and with --no-cudagraphs: the same losses and evaluations, up to float rounding."""
    args = [*SHORT, "--total-timesteps", "1000", "--output-dir", str(tmp_path)]
    run("sac_standard.py", *args, "--run-name", "graphs")
    run("sac_standard.py", *args, "--no-cudagraphs", "--run-name", "eager")
    graphs, eager = (read_csv(tmp_path / name / "train.csv") for name in ("graphs", "eager"))
    assert [r["global_step"] for r in graphs] == [r["global_step"] for r in eager]
    columns = ("qf1_loss", "qf2_loss", "qf1_value", "qf2_value", "actor_loss", "alpha",
               "alpha_loss", "entropy", "episodes", "episode_return_mean")
    for g, e in zip(graphs, eager, strict=True):
        for column in columns:
            assert (g[column] == "") == (e[column] == ""), (g["global_step"], column)
            if g[column]:
                assert float(g[column]) == pytest.approx(float(e[column]), rel=1e-3, abs=1e-4), (
                    g["global_step"], column)
    losses = [float(r["qf1_loss"]) for r in graphs if r["qf1_loss"]]
    assert len(losses) == len(set(losses)) == 6  # steps 500 to 1000: the updates moved the critic
    graph_eval, eager_eval = (read_csv(tmp_path / name / "eval.csv")
                              for name in ("graphs", "eager"))
    assert [r["global_step"] for r in graph_eval] == [r["global_step"] for r in eager_eval] == [
        "500", "1000"]
    for g, e in zip(graph_eval, eager_eval, strict=True):
        for column in ("return_mean", "return_min", "return_max", "length_mean"):
            assert float(g[column]) == pytest.approx(float(e[column]), rel=1e-3), column
