"""GPU speed of the SAC scripts: prints the figures of docs/speed.md's "Speed on a GPU" section.

    python bench/bench_gpu.py                 # everything
    python bench/bench_gpu.py --quick         # shorter runs and timings, a few minutes
    python bench/bench_gpu.py --parts mps     # some parts only

Parts (--parts); the runs' figures are steps/s of the update phase (median of a run's train.csv
rows after the first, which holds the CUDA-graph captures) per run and in all:
- micro: in-process wall-clock timings on --micro-env-id (the GPU is asynchronous: each timing
  ends with a synchronize), medians over --repeats, each set up as sac_standard.py's main block
  does (bench_sac.py's script_update and script_act): one training step's learning as its loop
  does it (a batch from the GPU buffer and the policy noise, drawn eagerly, then the update)
  with the update eager and as a CUDA graph, the graph with the buffer in host memory, the
  compiled update in a graph; acting on one observation (host to GPU and back included) eager,
  as a graph and compiled in a graph; the mode of one action; one env step on this CPU; an
  evaluation round (CPU, as sac_utils/eval_rounds.py runs it).
- single: one run of --micro-env-id on the CPU, GPU eager, GPU graphs, graphs with the buffer in
  host memory.
- mps: for each of --env-ids, one run alone and --processes runs sharing the GPU under MPS (as
  `sweep.py --workers N --mps` runs a grid).
"""

import copy
import csv
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import numpy as np
import torch
import tyro

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench_sac import (  # noqa: E402  (bench/ is on the path: the script's folder)
    random_buffer,
    script_act,
    script_agent,
    script_update,
    training_step,
)

import sac_standard  # noqa: E402
from mode_search import mode_action  # noqa: E402
from sac_utils.eval_rounds import Round, eval_seeds, run_round  # noqa: E402
from sac_utils.speedups import cuda_graph  # noqa: E402
from sweep import mps_daemon  # noqa: E402

CUDA, CPU = torch.device("cuda"), torch.device("cpu")
Part = Literal["micro", "single", "mps"]


@dataclass
class Args:
    parts: tuple[Part, ...] = ("micro", "single", "mps")
    """which parts to run (see the module's docstring)"""
    quick: bool = False
    """shorter: --repeats 2 --calls 50 --learning-starts 500 --loop-steps 600 (those not given as
    flags)"""
    env_ids: tuple[str, ...] = ("Hopper-v5", "Humanoid-v5", "h1hand-powerlift-v0")
    """the tasks of the mps part"""
    micro_env_id: str = "h1hand-powerlift-v0"
    """the task of the micro and single parts"""
    processes: int = 16
    """runs sharing the GPU under MPS (a node's 16 cores: one each)"""
    batch_size: int = 64
    """batch size of the timed updates (the paper's)"""
    repeats: int = 5
    """repeats of each in-process timing; medians are printed"""
    calls: int = 200
    """calls per in-process timing repeat"""
    learning_starts: int = 1000
    """random steps of each timed run before its updates start"""
    loop_steps: int = 1500
    """update-phase steps of each timed run"""
    eval_episodes: int = 10
    """episodes of the timed evaluation round"""


QUICK = {"repeats": 2, "calls": 50, "learning_starts": 500, "loop_steps": 600}


def shrink(args: Args) -> Args:
    """--quick: sizes for a GPU session of a few minutes; a size given as a flag stays."""
    if not args.quick:
        return args
    defaults = Args()
    return Args(**{**vars(args), **{k: v for k, v in QUICK.items()
                                    if getattr(args, k) == getattr(defaults, k)}})


def cuda_time(fn: Callable, repeats: int, calls: int) -> float:
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


def script_args(args: Args, **changes) -> sac_standard.Args:
    """sac_standard.py's arguments (its defaults: the paper's sizes, compiled, CUDA graphs, the
    buffer on the GPU) for the micro task and batch size; `changes` on top."""
    return replace(sac_standard.Args(env_id=args.micro_env_id, seed=0),
                   batch_size=args.batch_size, **changes)


def build_train_step(args: Args, env, **changes) -> tuple[Callable, sac_standard.Actor]:
    """What the scripts' training loop does per step to learn (draw a batch and the noise, then
    the update), on the GPU, set up as sac_standard.py's main block does with these flags
    (compile, cudagraphs, gpu_buffer); a buffer of 20k random transitions. Returns it and the
    actor."""
    script = script_args(args, **changes)
    obs_dim, action_dim = env.observation_space.shape[0], env.action_space.shape[0]
    rb = random_buffer(20_000, obs_dim, action_dim, CUDA if script.gpu_buffer else CPU)
    agent = script_agent(script, obs_dim, env.action_space, CUDA)
    update = script_update(script, agent, rb, CUDA)
    return training_step(script, rb, update, CUDA), agent["actor"]


def time_updates(args: Args, env) -> sac_standard.Actor:
    """Prints the update's times; returns the actor (for the acting timings)."""
    for graphs in (False, True):
        step, actor = build_train_step(args, env, compile=False, cudagraphs=graphs)
        print(f"update, {'CUDA graph' if graphs else 'eager':<10} (GPU buffer): "
              f"{cuda_time(step, args.repeats, args.calls) * 1e3:7.3f} ms", flush=True)
    step, _ = build_train_step(args, env, compile=False, gpu_buffer=False)
    print(f"update, CUDA graph (host buffer): "
          f"{cuda_time(step, args.repeats, args.calls) * 1e3:7.3f} ms", flush=True)
    step, _ = build_train_step(args, env)
    print(f"update, compiled, CUDA graph (GPU buffer): "
          f"{cuda_time(step, args.repeats, args.calls) * 1e3:7.3f} ms", flush=True)
    return actor


def time_acting(args: Args, env, actor: sac_standard.Actor) -> None:
    """Acting as the scripts' loop does (one observation and its noise, copies in and out;
    their act, eager, as a CUDA graph, compiled in a graph) and the mode."""
    obs = env.observation_space.sample()[None].astype(np.float32)
    obs_dim, action_dim = obs.shape[1], env.action_space.shape[0]
    mu, log_std = (t.detach() for t in actor(torch.as_tensor(obs, device=CUDA)))
    for compiled, graphs in ((False, False), (False, True), (True, True)):
        act = script_act(script_args(args, compile=compiled, cudagraphs=graphs), actor, obs_dim,
                         action_dim, CUDA)
        acting = cuda_time(lambda act=act: act(torch.as_tensor(obs, device=CUDA),
                                               torch.randn((1, action_dim), device=CUDA)
                                               ).cpu().numpy(), args.repeats, args.calls)
        label = ("compiled, " if compiled else "") + ("CUDA graph" if graphs else "eager")
        line = f"act, one obs, {label:<10} (copies in and out): {acting * 1e3:7.3f} ms"
        if not compiled:
            mode = cuda_graph(mode_action) if graphs else mode_action
            mode_time = cuda_time(lambda mode=mode: mode(mu, log_std), args.repeats, args.calls)
            line += f"; mode of one action (exact): {mode_time * 1e3:7.3f} ms"
        print(line, flush=True)


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


def micro(args: Args) -> None:
    env = sac_standard.make_env(args.micro_env_id)
    obs_dim, action_dim = env.observation_space.shape[0], env.action_space.shape[0]
    print(f"micro: {args.micro_env_id}: obs {obs_dim}, actions {action_dim}, batch "
          f"{args.batch_size}", flush=True)
    actor = time_updates(args, env)
    time_acting(args, env, actor)
    print(f"env step on this CPU: {time_env_step(env, args.repeats) * 1e3:7.3f} ms", flush=True)
    # Evaluation runs on CPU workers (sac_utils/eval_rounds.py); one round, in-process, one thread.
    start = time.perf_counter()
    actions = {"": "mode", "tanh_mu_": "tanh_mu"}
    result = run_round(Round(args.micro_env_id, eval_seeds(0, 1, args.eval_episodes), actions,
                             copy.deepcopy(actor).cpu()))
    steps = sum(sum(result[p]["lengths"]) for p in actions)
    print(f"eval round, mode and tanh(mu), CPU: {args.eval_episodes} episodes each, {steps} "
          f"steps in {time.perf_counter() - start:.2f} s", flush=True)


def update_phase_sps(run_dir: Path, learning_starts: int) -> float:
    """Median steps/s of a run's train.csv rows after the first row of the update phase (which
    holds the captures)."""
    with open(run_dir / "train.csv") as f:
        rows = [r for r in csv.DictReader(f) if int(r["global_step"]) > learning_starts]
    return statistics.median(float(r["sps"]) for r in rows[1:])


def run_command(args: Args, env_id: str, out: str, name: str, flags: list[str]) -> list[str]:
    """A run with evaluation and checkpoints off: only the training loop is timed."""
    total = args.learning_starts + args.loop_steps
    return [sys.executable, str(ROOT / "sac_standard.py"), "--env-id", env_id,
            "--total-timesteps", str(total), "--learning-starts", str(args.learning_starts),
            "--eval-interval", str(10 * total), "--eval-workers", "0",
            "--log-interval", str(max(1, args.loop_steps // 6)), "--print-interval", str(total),
            "--checkpoint-interval", "0", "--output-dir", out, "--run-name", name, *flags]


def runs_sps(args: Args, env_id: str, flags: list[str], processes: int) -> list[float]:
    """Update-phase steps/s of each of `processes` runs, started together (seeds apart)."""
    with tempfile.TemporaryDirectory() as out:
        children = [subprocess.Popen(run_command(args, env_id, out, f"r{i}",
                                                 [*flags, "--seed", str(i)]),
                                     stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
                    for i in range(processes)]
        errors = [child.communicate()[1] for child in children]
        for child, error in zip(children, errors, strict=True):
            if child.returncode != 0:
                raise SystemExit(error.decode())
        return [update_phase_sps(Path(out) / f"r{i}", args.learning_starts)
                for i in range(processes)]


def report_runs(label: str, sps: list[float]) -> float:
    """Prints steps/s per run and in all; returns the latter."""
    print(f"  {label:<46} {statistics.median(sps):7.0f} steps/s per run "
          f"(min {min(sps):.0f}, max {max(sps):.0f}), {sum(sps):7.0f} in all", flush=True)
    return sum(sps)


def single(args: Args) -> None:
    print(f"single: one run of {args.micro_env_id}", flush=True)
    env_id = args.micro_env_id
    report_runs("CPU (--no-cuda)", runs_sps(args, env_id, ["--no-cuda"], 1))
    report_runs("GPU eager (--no-cudagraphs)", runs_sps(args, env_id, ["--no-cudagraphs"], 1))
    report_runs("GPU, CUDA graphs", runs_sps(args, env_id, [], 1))
    report_runs("GPU, graphs, --no-gpu-buffer", runs_sps(args, env_id, ["--no-gpu-buffer"], 1))


def mps(args: Args) -> None:
    for env_id in args.env_ids:
        print(f"mps: {env_id}", flush=True)
        report_runs("one run, CUDA graphs", runs_sps(args, env_id, [], 1))
        with mps_daemon():
            report_runs(f"{args.processes} runs under MPS",
                        runs_sps(args, env_id, [], args.processes))


if __name__ == "__main__":
    args = shrink(tyro.cli(Args))
    assert torch.cuda.is_available(), "bench_gpu.py needs a CUDA GPU"
    print(f"{torch.cuda.get_device_name()}, torch {torch.__version__}, parts {args.parts}, "
          f"{args.learning_starts} random + {args.loop_steps} update steps per run", flush=True)
    parts = {"micro": micro, "single": single, "mps": mps}
    for part in args.parts:
        parts[part](args)
