"""GPU speed of the SAC scripts: prints the figures of README.md's "Speed on a GPU" table.

    python bench/bench_gpu.py --env-id h1hand-powerlift-v0 --concurrent 16

Wall-clock times (the GPU is asynchronous: each timing ends with a synchronize), medians over
--repeats: one gradient update eager and as a CUDA graph (batch sampling from the GPU buffer
included), acting on one observation (host to GPU and back included), the mode of one action,
one env step on this CPU, an evaluation round; then whole runs of sac_standard.py as
subprocesses (steps/s of the update phase, from their train.csv): one run on the CPU, eager on
the GPU, with graphs, with graphs and the buffer in host memory; and --concurrent runs at once,
CPU only, sharing the GPU, and sharing it under MPS.
"""

import copy
import csv
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import tyro

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from eval_runner import Round, eval_seeds, run_round  # noqa: E402
from mode_search import mode_action  # noqa: E402
from sac_standard import (  # noqa: E402
    Actor,
    ReplayBuffer,
    TwinQ,
    cuda_graph,
    make_env,
    make_train_step,
    sac_update,
)
from sweep import mps_daemon  # noqa: E402

CUDA = torch.device("cuda")


@dataclass
class Args:
    env_id: str = "h1hand-powerlift-v0"
    """the task to time"""
    batch_size: int = 64
    """batch size of the timed updates (the paper's)"""
    repeats: int = 5
    """repeats of each in-process timing; medians are printed"""
    calls: int = 200
    """calls per in-process timing repeat"""
    learning_starts: int = 1000
    """random steps of each timed run before its updates start"""
    loop_steps: int = 3000
    """update-phase steps of each timed run"""
    eval_episodes: int = 10
    """episodes of the timed evaluation round"""
    concurrent: int = 16
    """runs at once in the concurrency figures (0: skip them)"""


def cuda_time(fn, repeats: int, calls: int) -> float:
    """Median over repeats of the mean wall-clock seconds per call, GPU work included."""
    fn()
    torch.cuda.synchronize()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(calls):
            fn()
        torch.cuda.synchronize()
        times.append((time.perf_counter() - start) / calls)
    return statistics.median(times)


def build_train_step(env, graphs: bool, batch_size: int, buffer_device=CUDA):
    """The scripts' learner at the paper's sizes on the GPU, a buffer of 20k random transitions."""
    obs_dim, action_dim = env.observation_space.shape[0], env.action_space.shape[0]
    actor = Actor(obs_dim, (256, 256), env.action_space, -10.0, 2.0).to(CUDA)
    qf, qf_target = (TwinQ(obs_dim, action_dim, (256, 256)).to(CUDA) for _ in range(2))
    qf_target.load_state_dict(qf.state_dict())
    log_alpha = torch.zeros((), device=CUDA, requires_grad=True)
    optimizers = tuple(torch.optim.Adam(p, lr=3e-4, fused=True, capturable=True) for p in (
        qf.parameters(), actor.parameters(), [log_alpha]))
    rb = ReplayBuffer(20_000, obs_dim, action_dim, buffer_device)
    rng = np.random.default_rng(0)
    for i in range(20_000):
        rb.add(rng.normal(size=obs_dim), rng.uniform(-1, 1, action_dim), rng.normal(), False,
               rng.normal(size=obs_dim), i % 500 == 499)
    return make_train_step(
        rb, lambda batch: sac_update(batch, actor, qf, qf_target, log_alpha, optimizers, 0.99,
                                     0.005, -action_dim / 2),
        batch_size, CUDA, graphs, (actor, qf, qf_target, log_alpha, *optimizers)), actor


def time_env_step(env, repeats: int) -> float:
    env.reset(seed=0)
    env.action_space.seed(0)

    def step():
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()

    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(500):
            step()
        times.append((time.perf_counter() - start) / 500)
    return statistics.median(times)


def update_phase_sps(run_dir: Path, learning_starts: int) -> float:
    """Median steps/s of a run's train.csv rows after the first row of the update phase (which
    holds the captures)."""
    with open(run_dir / "train.csv") as f:
        rows = [r for r in csv.DictReader(f) if int(r["global_step"]) > learning_starts]
    return statistics.median(float(r["sps"]) for r in rows[1:])


def run_command(args: Args, out: str, name: str, flags: list[str]) -> list[str]:
    total = args.learning_starts + args.loop_steps
    return [sys.executable, str(ROOT / "sac_standard.py"), "--env-id", args.env_id,
            "--total-timesteps", str(total), "--learning-starts", str(args.learning_starts),
            "--eval-interval", str(10 * total), "--log-interval", str(args.loop_steps // 6),
            "--checkpoint-interval", "0", "--output-dir", out, "--run-name", name, *flags]


def runs_sps(args: Args, flags: list[str], n: int) -> list[float]:
    """Update-phase steps/s of each of n runs started together."""
    with tempfile.TemporaryDirectory() as out:
        children = [subprocess.Popen(run_command(args, out, f"r{i}", [*flags, "--seed", str(i)]),
                                     stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
                    for i in range(n)]
        for child in children:
            if child.wait() != 0:
                raise SystemExit(child.stderr.read().decode())
        return [update_phase_sps(Path(out) / f"r{i}", args.learning_starts) for i in range(n)]


def report_runs(label: str, sps: list[float]) -> None:
    print(f"{label:<44} {statistics.median(sps):7.0f} steps/s per run "
          f"(min {min(sps):.0f}, max {max(sps):.0f}), {sum(sps):7.0f} in all")


if __name__ == "__main__":
    args = tyro.cli(Args)
    assert torch.cuda.is_available(), "bench_gpu.py needs a CUDA GPU"
    env = make_env(args.env_id)
    obs_dim, action_dim = env.observation_space.shape[0], env.action_space.shape[0]
    print(f"{args.env_id}: obs {obs_dim}, actions {action_dim}, batch {args.batch_size}, "
          f"{torch.cuda.get_device_name()}, torch {torch.__version__}")
    for graphs in (False, True):
        step, _ = build_train_step(env, graphs, args.batch_size)
        print(f"update, {'CUDA graph' if graphs else 'eager':<10} (GPU buffer):   "
              f"{cuda_time(step, args.repeats, args.calls) * 1e3:6.3f} ms")
    step, actor = build_train_step(env, True, args.batch_size, torch.device("cpu"))
    host = cuda_time(step, args.repeats, args.calls)
    print(f"update, CUDA graph (host buffer):  {host * 1e3:6.3f} ms")

    obs = env.observation_space.sample().astype(np.float32)
    sample = torch.no_grad()(lambda o: actor.get_action(o)[0])
    mu, log_std = (t.detach() for t in actor(torch.as_tensor(obs, device=CUDA)[None]))
    for graphs in (False, True):
        act = cuda_graph(sample) if graphs else sample
        mode = cuda_graph(mode_action) if graphs else mode_action
        acting = cuda_time(lambda act=act: act(torch.as_tensor(obs, device=CUDA)[None]).cpu()
                           .numpy(), args.repeats, args.calls)
        mode_time = cuda_time(lambda mode=mode: mode(mu, log_std), args.repeats, args.calls)
        label = "CUDA graph" if graphs else "eager"
        print(f"act on one obs, {label:<10} (copies in and out): {acting * 1e3:6.3f} ms; "
              f"mode of one action (exact): {mode_time * 1e3:6.3f} ms")
    env_step = time_env_step(env, args.repeats)
    print(f"env step on this CPU:              {env_step * 1e3:6.3f} ms")
    # Evaluation runs on CPU workers (eval_runner.py); one round, in-process, one thread.
    start = time.perf_counter()
    result = run_round(Round(args.env_id, eval_seeds(0, 1, args.eval_episodes),
                             {"": "mode", "tanh_mu_": "tanh_mu"}, copy.deepcopy(actor).cpu()))
    steps = sum(sum(r["lengths"]) for r in result.values())
    print(f"eval round, mode and tanh(mu), CPU: {args.eval_episodes} episodes each, {steps} "
          f"steps in {time.perf_counter() - start:.2f} s")

    report_runs("one run, CPU (--no-cuda)", runs_sps(args, ["--no-cuda"], 1))
    report_runs("one run, GPU eager (--no-cudagraphs)", runs_sps(args, ["--no-cudagraphs"], 1))
    report_runs("one run, GPU, CUDA graphs", runs_sps(args, [], 1))
    report_runs("one run, GPU, graphs, --no-gpu-buffer", runs_sps(args, ["--no-gpu-buffer"], 1))
    if args.concurrent:
        n = args.concurrent
        report_runs(f"{n} runs, CPU only", runs_sps(args, ["--no-cuda"], n))
        report_runs(f"{n} runs sharing the GPU, graphs", runs_sps(args, [], n))
        with mps_daemon():
            report_runs(f"{n} runs sharing the GPU under MPS, graphs", runs_sps(args, [], n))
