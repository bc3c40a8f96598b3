"""SAC's cost per env step on one CPU core, side by side with its peers: prints a markdown table.

    python3 -m venv .venv-peers
    .venv-peers/bin/pip install -r requirements.txt -r bench/requirements-peers.txt
    .venv-peers/bin/python bench/bench_peers.py [--cleanrl PATH]
    .venv-peers/bin/python bench/bench_peers.py --impls sb3 sbx --env-ids Hopper-v5 --cores 0 1

Implementations (--impls): sac_corrected.py --compile and --no-compile, Stable-Baselines3's SAC,
SBX's SAC (JAX) and, given a CleanRL checkout (--cleanrl), its cleanrl/sac_continuous_action.py;
all at the paper's shape: batch 64 (--batch-size), 256x256 MLPs for the actor and both critics,
one gradient update per env step, learning starting at 1,000 steps, gamma 0.99, tau 0.005,
lr 3e-4, no evaluation. Every run is a process of its own, pinned to one core (taskset) with one
thread (OMP/MKL/OpenBLAS, torch and XLA); runs on different --cores go at the same time.

The figure is the update phase's ms per env step (acting, env step, buffer and update): two runs
of 1,000 + --short and 1,000 + --long steps, differenced, so that start-up, imports, compiling
and the random start steps cancel; each implementation and task first gets a throwaway warm-up
run (sac_corrected.py's compiled update is cached on disk after its first run; the compile
seconds it prints are taken out of its runs' times, as they vary from run to run). Medians over
--repeats; with the defaults, roughly 10 to 15 minutes on one idle core (--cores 0 1: about half).
Each row gives the speed-up over Stable-Baselines3 and over SBX, and the compute floor as a
share of it: the matmul FLOPs of one update at batch 64 (from the task's observation and action
sizes) over this core's float32 matmul rate (torch, one thread, 64x256 @ 256x256), with XLA's
rate for the same product beside it when SBX is timed.

CleanRL's script is written for gymnasium 0.29; on gymnasium 1.x its vector env reports no
"final_observation", so the runner adds it (the returned observation, which is the final one
under gymnasium 1's next-step autoreset) rather than let the first truncation crash it.
"""

import importlib.metadata
import os
import queue
import re
import runpy
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from datetime import date
from itertools import pairwise
from pathlib import Path
from typing import Literal

import gymnasium as gym
import tyro

SCRIPT = Path(__file__).resolve()
ROOT = SCRIPT.parent.parent
sys.path.insert(0, str(ROOT))

import humanoid_envs  # noqa: E402, F401  (registers the h1hand tasks)

# The paper's shape, shared by every implementation; the batch from --batch-size, which main
# puts in the environment so that the runners' own processes read it too.
LEARNING_STARTS, HIDDEN, GAMMA, TAU, LR = 1000, (256, 256), 0.99, 0.005, 3e-4
BATCH_SIZE = int(os.environ.get("BENCH_PEERS_BATCH_SIZE", "64"))
# One thread per run: torch (and numpy) through OpenMP/MKL/OpenBLAS, JAX through XLA's flags;
# JAX_PLATFORMS keeps JAX from probing for accelerators (the torch runs are on the CPU too).
ONE_THREAD_ENV = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
                  "XLA_FLAGS": "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1",
                  "JAX_PLATFORMS": "cpu"}
Impl = Literal["corrected-compiled", "corrected-eager", "sb3", "sbx", "cleanrl"]
LABELS: dict[str, str] = {"corrected-compiled": "sac_corrected.py --compile",
                          "corrected-eager": "sac_corrected.py --no-compile",
                          "sb3": "Stable-Baselines3 SAC", "sbx": "SBX SAC (JAX)",
                          "cleanrl": "CleanRL sac_continuous_action.py"}
VERSIONS = ("torch", "jax", "jaxlib", "stable-baselines3", "sbx-rl", "gymnasium", "mujoco", "numpy")


@dataclass
class Args:
    impls: tuple[Impl, ...] | None = None
    """implementations to time (default: all but cleanrl, and cleanrl too with --cleanrl)"""
    env_ids: tuple[str, ...] = ("Hopper-v5", "h1hand-powerlift-v0")
    """the tasks"""
    cleanrl: str | None = None
    """a checkout of github.com/vwxyzjn/cleanrl: time its cleanrl/sac_continuous_action.py too"""
    batch_size: int = 64
    """the batch of every update (64 the paper's, 256 the SAC paper's and SB3's)"""
    cores: tuple[int, ...] = (0,)
    """cores to run on: one run per core at a time, pinned to it (two cores: two runs at once)"""
    short: int = 500
    """steps after the 1,000 start steps in the short run"""
    long: int = 2500
    """steps after the 1,000 start steps in the long run"""
    repeats: int = 2
    """short/long pairs per implementation and task; the median is printed"""
    cpu_time: bool = False
    """time the runs by their CPU seconds instead of wall clock (on a shared machine, where
    other processes take turns on the pinned core)"""


# --- Runners: each runs in a process of its own (`bench_peers.py --run-peer NAME ...`). ---

def make_env(env_id: str) -> gym.Env:
    return gym.make(env_id)


def sb3_kwargs(total_timesteps: int) -> dict:
    """SAC's arguments for Stable-Baselines3 and SBX alike: the paper's shape."""
    return dict(learning_rate=LR, buffer_size=total_timesteps, learning_starts=LEARNING_STARTS,
                batch_size=BATCH_SIZE, tau=TAU, gamma=GAMMA, train_freq=1, gradient_steps=1,
                policy_kwargs=dict(net_arch=list(HIDDEN)), device="cpu", seed=0, verbose=0)


def run_sb3(env_id: str, total_timesteps: str) -> None:
    import torch
    from stable_baselines3 import SAC

    torch.set_num_threads(1)
    total = int(total_timesteps)
    SAC("MlpPolicy", make_env(env_id), **sb3_kwargs(total)).learn(total)


def run_sbx(env_id: str, total_timesteps: str) -> None:
    from sbx import SAC

    total = int(total_timesteps)
    SAC("MlpPolicy", make_env(env_id), **sb3_kwargs(total)).learn(total)


def add_final_observation() -> None:
    """Makes gymnasium 1.x's SyncVectorEnv report infos["final_observation"] on a truncation, as
    0.29's did (CleanRL reads it): with next-step autoreset the returned obs is the final one."""
    step = gym.vector.SyncVectorEnv.step

    def step_with_final_observation(self, actions):
        obs, rewards, terminations, truncations, infos = step(self, actions)
        if truncations.any() and "final_observation" not in infos:
            infos["final_observation"] = obs
        return obs, rewards, terminations, truncations, infos

    gym.vector.SyncVectorEnv.step = step_with_final_observation


def run_cleanrl(env_id: str, total_timesteps: str, checkout: str) -> None:
    import torch

    torch.set_num_threads(1)
    if int(gym.__version__.split(".")[0]) >= 1:
        add_final_observation()
    sys.path.insert(0, checkout)  # its cleanrl_utils
    script = str(Path(checkout) / "cleanrl" / "sac_continuous_action.py")
    sys.argv = [script, "--env-id", env_id, "--total-timesteps", total_timesteps,
                "--buffer-size", total_timesteps, "--learning-starts", str(LEARNING_STARTS),
                "--batch-size", str(BATCH_SIZE), "--gamma", str(GAMMA), "--tau", str(TAU),
                "--policy-lr", str(LR), "--q-lr", str(LR), "--policy-frequency", "1",
                "--target-network-frequency", "1", "--seed", "0", "--no-cuda"]
    runpy.run_path(script, run_name="__main__")


def print_matmul_gflops(library: str = "torch", calls: str = "4000", repeats: str = "7") -> None:
    """Prints this core's float32 matmul rate in GFLOP/s: a 64x256 @ 256x256 product (a hidden
    layer's forward at batch 64), one thread, with torch (ours, SB3's) or "jax" (XLA's, SBX's);
    the best of the repeats, as a floor asks."""
    if library == "jax":
        import jax
        import jax.numpy as jnp

        x, w = jnp.ones((BATCH_SIZE, 256)), jnp.ones((256, 256))
        product = jax.jit(jnp.matmul)
        def matmul() -> None:
            product(x, w).block_until_ready()
    else:
        import torch

        torch.set_num_threads(1)
        x, w = torch.randn(BATCH_SIZE, 256), torch.randn(256, 256)
        out = torch.empty(BATCH_SIZE, 256)
        def matmul() -> None:
            torch.mm(x, w, out=out)
    for _ in range(500):
        matmul()
    best = float("inf")
    for _ in range(int(repeats)):
        start = time.perf_counter()
        for _ in range(int(calls)):
            matmul()
        best = min(best, (time.perf_counter() - start) / int(calls))
    print(2 * BATCH_SIZE * 256 * 256 / best / 1e9)


def print_update_ms(env_id: str, path: str) -> None:
    """Prints the milliseconds of one gradient update of the scripts alone (batch sampling and
    noise included; bench_sac.time_update), "compiled" or "eager": medians of 5 x 200 updates,
    in the process's CPU seconds (bench_sac's clock: on its pinned core, with one thread, the
    wall clock of an idle core)."""
    import torch

    sys.path.insert(0, str(ROOT / "bench"))
    import bench_sac

    torch.set_num_threads(1)
    seconds = bench_sac.time_update(bench_sac.Args(env_id=env_id, batch_size=BATCH_SIZE),
                                    make_env(env_id),
                                    compiled=path == "compiled")
    print(1e3 * seconds)


PEERS: dict[str, Callable[..., None]] = {"sb3": run_sb3, "sbx": run_sbx, "cleanrl": run_cleanrl,
                                         "matmul-gflops": print_matmul_gflops,
                                         "update-ms": print_update_ms}


# --- The bench. ---

def run_command(impl: str, env_id: str, total_timesteps: int, checkout: str | None) -> list[str]:
    """The command line of one run of `impl`, run in a scratch folder (its working directory)."""
    if impl.startswith("corrected"):
        return [sys.executable, str(ROOT / "sac_corrected.py"), "--env-id", env_id,
                "--total-timesteps", str(total_timesteps), "--buffer-size", str(total_timesteps),
                "--learning-starts", str(LEARNING_STARTS), "--batch-size", str(BATCH_SIZE),
                "--hidden-sizes", *map(str, HIDDEN), "--gamma", str(GAMMA), "--tau", str(TAU),
                "--policy-lr", str(LR), "--q-lr", str(LR), "--alpha-lr", str(LR), "--seed", "0",
                "--eval-interval", str(total_timesteps + 1), "--eval-workers", "0",
                "--checkpoint-interval", "0", "--print-interval", str(total_timesteps + 1),
                "--torch-threads", "1", "--no-cuda", "--output-dir", "runs",
                "--compile" if impl == "corrected-compiled" else "--no-compile"]
    peer = [sys.executable, str(SCRIPT), "--run-peer", impl, env_id, str(total_timesteps)]
    return peer + [checkout] if impl == "cleanrl" else peer


class RunFailed(Exception):
    """A run exited non-zero: its command line and the end of its output."""


# sac_corrected.py prints what compiling cost ("compiled the update in 5.6 s"): with inductor's
# on-disk cache it varies by seconds from run to run, which differencing would not cancel.
COMPILE_LINE = re.compile(r"^compiled .+ in ([0-9.]+) s$", re.MULTILINE)


def run_seconds(command: list[str], core: int, cpu_time: bool) -> float:
    """Wall-clock (or CPU) seconds of one run, pinned to `core` with one thread, less the
    seconds it says it spent compiling."""
    with tempfile.TemporaryDirectory() as scratch, open(Path(scratch) / "output", "w+") as log:
        start = time.perf_counter()
        child = subprocess.Popen(["taskset", "-c", str(core), *command], cwd=scratch,
                                 env=os.environ | ONE_THREAD_ENV, stdout=log, stderr=log)
        _, status, usage = os.wait4(child.pid, 0)  # the child's own rusage: runs overlap
        wall = time.perf_counter() - start
        child.returncode = os.waitstatus_to_exitcode(status)
        log.seek(0)
        output = log.read()
        if child.returncode != 0:
            raise RunFailed(f"exit {child.returncode}: {shlex.join(command)}\n"
                            + "\n".join(output.splitlines()[-15:]))
    compiling = sum(float(seconds) for seconds in COMPILE_LINE.findall(output))
    return (usage.ru_utime + usage.ru_stime if cpu_time else wall) - compiling


def seconds_per_step(args: Args, impl: str, env_id: str, core: int) -> float:
    """Seconds per env step of the update phase: a long run minus a short one, per extra step."""
    short, long = (run_seconds(run_command(impl, env_id, LEARNING_STARTS + steps, args.cleanrl),
                               core, args.cpu_time) for steps in (args.short, args.long))
    return (long - short) / (args.long - args.short)


def on_free_cores(jobs: Sequence[Callable[[int], object]], cores: Sequence[int]) -> list:
    """Runs each job(core) on the next free core, one job per core at a time; results in order
    (a job's RunFailed as its result)."""
    free = queue.Queue()
    for core in cores:
        free.put(core)

    def run(job: Callable[[int], object]) -> object:
        core = free.get()
        try:
            return job(core)
        except RunFailed as failure:
            print(f"failed: {failure}", file=sys.stderr, flush=True)
            return failure
        finally:
            free.put(core)

    with ThreadPoolExecutor(len(cores)) as pool:
        return list(pool.map(run, jobs))


def update_flops(obs_dim: int, action_dim: int) -> int:
    """Matmul FLOPs of one SAC update at BATCH_SIZE: a layer's forward is 2*B*in*out, and so are
    its weight gradient and its input gradient, each counted only where needed."""
    def layers(sizes: tuple[int, ...]) -> list[int]:
        return [2 * BATCH_SIZE * i * o for i, o in pairwise(sizes)]

    actor = layers((obs_dim, *HIDDEN, 2 * action_dim))  # the mean and log-std heads as one layer
    critic = layers((obs_dim + action_dim, *HIDDEN, 1))
    # Target: the actor on next_obs and both target critics, forward only.
    target = sum(actor) + 2 * sum(critic)
    # Critic loss: both critics forward and backward; (obs, action) needs no input gradient.
    critic_loss = 2 * (2 * sum(critic) + sum(critic[1:]))
    # Actor loss: the actor forward, both critics forward and back to pi (of their first layer's
    # input only the action columns: no weight gradients), the actor's weight gradients and its
    # input gradients above the first layer.
    to_pi = 2 * BATCH_SIZE * action_dim * HIDDEN[0]
    actor_loss = (2 * sum(actor) + sum(actor[1:])
                  + 2 * (sum(critic) + sum(critic[1:]) + to_pi))
    return target + critic_loss + actor_loss


def matmul_gflops(core: int, library: str = "torch") -> float:
    """This core's float32 matmul rate (print_matmul_gflops in a pinned, one-thread process)."""
    result = subprocess.run(["taskset", "-c", str(core), sys.executable, str(SCRIPT), "--run-peer",
                             "matmul-gflops", library], env=os.environ | ONE_THREAD_ENV,
                            capture_output=True, text=True, check=True)
    return float(result.stdout.split()[-1])


def update_ms(env_id: str, path: str, core: int) -> float:
    """The scripts' update alone (print_update_ms in a pinned, one-thread process)."""
    result = subprocess.run(["taskset", "-c", str(core), sys.executable, str(SCRIPT), "--run-peer",
                             "update-ms", env_id, path], env=os.environ | ONE_THREAD_ENV,
                            capture_output=True, text=True, check=True)
    return float(result.stdout.split()[-1])


def task_dims(env_id: str) -> tuple[int, int]:
    env = make_env(env_id)
    return env.observation_space.shape[0], env.action_space.shape[0]


def versions() -> str:
    def version(package: str) -> str:
        try:
            return importlib.metadata.version(package)
        except importlib.metadata.PackageNotFoundError:
            return "not installed"

    return ", ".join(f"{package} {version(package)}" for package in VERSIONS)


def cleanrl_revision(checkout: str) -> str:
    result = subprocess.run(["git", "-C", checkout, "rev-parse", "--short", "HEAD"],
                            capture_output=True, text=True)
    return result.stdout.strip() if result.returncode == 0 else "(not a git checkout)"


def speed_up(reference: float | None, ms: float) -> str:
    return f"{reference / ms:.2f}x" if reference is not None else "-"


def print_report(args: Args, impls: Sequence[str], ms: dict, floors: dict, gflops: float,
                 jax_gflops: float | None, updates: dict) -> None:
    """The markdown report: setup, one row per task and implementation, the floor per task."""
    # Imported here, not at the top: the peers' processes start from this file and must not
    # load torch (run_folder's) beside JAX or another library's own.
    from sac_utils.run_folder import machine  # the CPU's name as config.json records it
    clock = "CPU seconds" if args.cpu_time else "wall clock"
    print(f"### SAC on one CPU core: ms per env step ({date.today().isoformat()})\n")
    print(f"- machine: {machine()['cpu']}, {os.cpu_count()} cores; each run pinned to one core "
          f"(taskset -c; cores {', '.join(map(str, args.cores))}) with one thread")
    print(f"- versions: {versions()}"
          + (f"; CleanRL {cleanrl_revision(args.cleanrl)}" if args.cleanrl else ""))
    print(f"- command: `{shlex.join([Path(sys.executable).name, *sys.argv])}`")
    print(f"- shape: batch {BATCH_SIZE}, {'x'.join(map(str, HIDDEN))} actor and twin critics, one "
          f"update per env step, learning starts {LEARNING_STARTS:,}, gamma {GAMMA}, tau {TAU}, "
          f"lr {LR:.0e}, no evaluation")
    print(f"- ms per env step: (T({LEARNING_STARTS:,} + {args.long:,} steps) - "
          f"T({LEARNING_STARTS:,} + {args.short:,})) / {args.long - args.short:,}, {clock}, "
          f"median of {args.repeats} after a warm-up run; it includes acting, the env step and "
          "the replay buffer, the floor only the update's matmuls\n")
    print("| task | implementation | ms / env step | vs SB3 | vs SBX | floor / measured |")
    print("|---|---|---:|---:|---:|---:|")
    for env_id in args.env_ids:
        sb3, sbx = ms.get((env_id, "sb3")), ms.get((env_id, "sbx"))
        for impl in impls:
            value = ms[env_id, impl]
            if value is None:
                print(f"| {env_id} | {LABELS[impl]} | failed | | | |")
                continue
            print(f"| {env_id} | {LABELS[impl]} | {value:.2f} | {speed_up(sb3, value)} | "
                  f"{speed_up(sbx, value)} | {100 * floors[env_id][2] / value:.0f}% |")
    print(f"\nCompute floor: one update's matmul FLOPs at batch {BATCH_SIZE} over {gflops:.1f} "
          f"GFLOP/s (float32 {BATCH_SIZE}x256 @ 256x256, torch, one thread, core {args.cores[0]}; "
          "the best of 7 timings"
          + (f"; XLA, SBX's, runs the same product at {jax_gflops:.1f} GFLOP/s" if jax_gflops
             else "") + ").\n")
    print("| task | obs | actions | MFLOP / update | floor ms | our update alone, compiled / "
          "eager (ms) | floor / compiled |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for env_id, (obs_dim, action_dim, floor_ms) in floors.items():
        compiled, eager = updates[env_id]
        print(f"| {env_id} | {obs_dim} | {action_dim} | "
              f"{update_flops(obs_dim, action_dim) / 1e6:.1f} | {floor_ms:.3f} | "
              f"{compiled:.2f} / {eager:.2f} | {100 * floor_ms / compiled:.0f}% |")


def main(args: Args) -> None:
    global BATCH_SIZE
    BATCH_SIZE = args.batch_size
    os.environ["BENCH_PEERS_BATCH_SIZE"] = str(args.batch_size)
    impls = args.impls or ("corrected-compiled", "corrected-eager", "sb3", "sbx",
                           *(("cleanrl",) if args.cleanrl else ()))
    if "cleanrl" in impls and not args.cleanrl:
        sys.exit("--impls cleanrl needs --cleanrl PATH (a CleanRL checkout)")
    if args.cleanrl:
        args.cleanrl = str(Path(args.cleanrl).resolve())
        if not (Path(args.cleanrl) / "cleanrl" / "sac_continuous_action.py").is_file():
            sys.exit(f"--cleanrl {args.cleanrl}: no cleanrl/sac_continuous_action.py there")
    if not 0 < args.short < args.long:
        sys.exit("--short and --long: 0 < short < long")
    gflops = matmul_gflops(args.cores[0])
    # XLA's rate too: whether SBX's lead could come from its matmuls.
    jax_gflops = matmul_gflops(args.cores[0], "jax") if "sbx" in impls else None
    floors = {}
    for env_id in args.env_ids:
        obs_dim, action_dim = task_dims(env_id)
        floors[env_id] = (obs_dim, action_dim, update_flops(obs_dim, action_dim) / gflops / 1e6)
    pairs = [(env_id, impl) for env_id in args.env_ids for impl in impls]

    def warm_up(env_id: str, impl: str) -> Callable[[int], float]:
        return lambda core: run_seconds(
            run_command(impl, env_id, LEARNING_STARTS + args.short, args.cleanrl), core, False)

    # Every warm-up ends before any timed run starts (the compiled update's cache is written).
    warm = on_free_cores([warm_up(*pair) for pair in pairs], args.cores)
    pairs = [pair for pair, result in zip(pairs, warm, strict=True)
             if not isinstance(result, RunFailed)]
    print(f"warm: {len(pairs)} of {len(warm)}", file=sys.stderr, flush=True)

    def timed(env_id: str, impl: str, repeat: int) -> Callable[[int], float]:
        def job(core: int) -> float:
            seconds = seconds_per_step(args, impl, env_id, core)
            print(f"{env_id} {impl} repeat {repeat + 1}: {1e3 * seconds:.2f} ms/step "
                  f"(core {core})", file=sys.stderr, flush=True)
            return seconds
        return job

    # Repeats interleaved, so that a change of the machine's load falls on all alike.
    jobs = [(pair, repeat) for repeat in range(args.repeats) for pair in pairs]
    results = on_free_cores([timed(*pair, repeat) for pair, repeat in jobs], args.cores)
    ms = {}
    for pair in ((env_id, impl) for env_id in args.env_ids for impl in impls):
        seconds = [r for (p, _), r in zip(jobs, results, strict=True) if p == pair]
        ok = seconds and not any(isinstance(s, RunFailed) for s in seconds)
        ms[pair] = 1e3 * statistics.median(seconds) if ok else None
    # The update alone (no env), on an otherwise idle set of cores.
    updates = {env_id: tuple(update_ms(env_id, path, args.cores[0])
                             for path in ("compiled", "eager")) for env_id in args.env_ids}
    print_report(args, impls, ms, floors, gflops, jax_gflops, updates)


if __name__ == "__main__":
    if sys.argv[1:2] == ["--run-peer"]:
        PEERS[sys.argv[2]](*sys.argv[3:])
    else:
        main(tyro.cli(Args, description=__doc__.splitlines()[0]))
