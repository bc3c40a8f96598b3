"""Run a grid of training runs (env ids x seeds x scripts) on this machine or on a Slurm cluster.

Each run gets its own folder under --output-dir, named after its identity (env id, algorithm,
seed and a hash of the arguments after `--`). Running the same command again skips finished
runs, resumes interrupted ones (`--resume`) and starts missing ones. On Slurm the grid is one
job array submitted through submitit; a job that is preempted or reaches its time limit
checkpoints its run and is requeued, and the requeued job continues it with `--resume`.
The guide: docs/sweep.md.

    python sweep.py --env-ids Pendulum-v1 --seeds 0 1 --output-dir runs -- --total-timesteps 2000
    python sweep.py --preset paper --launcher slurm --partition gpu --output-dir runs
    python sweep.py status runs
    python sweep.py free runs      # finished runs' checkpoint.pt (their replay buffers) deleted
    python sweep.py restart runs/RUN  # a run whose checkpoint is lost, from its last snapshot
"""

from __future__ import annotations

import contextlib
import dataclasses
import difflib
import functools
import importlib.util
import math
import os
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import gymnasium
import submitit
import tyro

import humanoid_envs  # noqa: F401  (registers the h1hand-*-v0 tasks)
from sac_utils.cli import broken_rule
from sac_utils.sweep_run import (
    EXIT_INTERRUPTED,
    IDENTITY_FILE,
    LAUNCH_ACTIONS,
    LOG_FILE,
    Run,
    SlurmRun,
    action_for,
    last_eval_step,
    lock_holder,
    log_tail,
    prepare_run_dir,
    read_json,
    record_exit,
    run_state,
    squeue_states,
    start_run,
)

ROOT = Path(__file__).resolve().parent
PAPER_ENV_IDS = ("h1hand-powerlift-v0", "h1hand-cube-v0", "h1hand-bookshelf_simple-v0",
                 "h1hand-bookshelf_hard-v0")
CLASSIC_ENV_IDS = ("Hopper-v5", "HalfCheetah-v5", "Ant-v5", "Humanoid-v5")
# The standard suite as the published SACs report it (SAC's paper, SB3 / RL Zoo, CleanRL).
SUITE_ENV_IDS = ("Hopper-v5", "HalfCheetah-v5", "Walker2d-v5", "Ant-v5", "Humanoid-v5")
PAPER_SEEDS = (0, 1, 2, 3, 4)
DEFAULT_SCRIPTS = ("sac_standard.py", "sac_corrected.py")


@dataclass(frozen=True)
class Preset:
    """A named grid. The scripts' defaults are the paper's protocol, so a preset adds a step
    budget for some env ids (the others get the script's 10M) and, where it runs another
    protocol, the flags that make it (`run_args`, before those after `--`, which win)."""

    env_ids: tuple[str, ...]
    seeds: tuple[int, ...]
    scripts: tuple[str, ...]
    total_timesteps: dict[str, int]
    why: str
    run_args: tuple[str, ...] = ()


ONE_RUN_IS_BOTH = ("sac_corrected.py only: each run's paired tanh(mu) evaluation is the "
                   "sac_standard.py run of its seed (identical training decisions), so analyze.py "
                   "gets both algorithms from half the runs")
PRESETS = {
    "paper": Preset(PAPER_ENV_IDS, PAPER_SEEDS, ("sac_corrected.py",), {}, ONE_RUN_IS_BOTH),
    # Beyond the paper: the correction's worth against the action dimension (3 to 61).
    "dimensions": Preset(
        (*CLASSIC_ENV_IDS, *PAPER_ENV_IDS), PAPER_SEEDS, ("sac_corrected.py",),
        dict.fromkeys(CLASSIC_ENV_IDS, 1_000_000),
        ONE_RUN_IS_BOTH + "; classic tasks 1M steps each, h1hand tasks the paper's 10M"),
    # The published SACs' setting (the SAC paper's, as SB3's RL Zoo runs MuJoCo): batch 256 and
    # target entropy -|A| where HumanoidBench's defaults have 64 and -|A|/2; the rest (3e-4,
    # one update per step, 10k random steps, a 1M buffer, 256x256) the scripts' defaults.
    "classic": Preset(
        SUITE_ENV_IDS, PAPER_SEEDS, ("sac_corrected.py",),
        dict.fromkeys(SUITE_ENV_IDS, 1_000_000),
        ONE_RUN_IS_BOTH + "; 1M steps each, the published SACs' batch 256 and target entropy "
        "-|A|, snapshots every 250k",
        ("--batch-size", "256", "--target-entropy-scale", "1.0", "--snapshot-interval", "250000")),
}
# sweep.py sets these for every run itself; the same flags after `--` would contradict them.
SWEEP_FLAGS = ("--env-id", "--seed", "--output-dir", "--run-name", "--resume",
               "--checkpoint-interval", "--track", "--wandb-project-name", "--wandb-entity",
               "--wandb-group")
# How fast a run goes, not what it computes: it may differ on --resume, no part of the identity.
EVAL_WORKERS_FLAGS = ("--eval-workers", "--eval_workers")


class SweepError(Exception):
    """Bad input or an unusable output folder: a message naming the problem and the fix."""


@dataclass
class Args:
    env_ids: list[str] = field(default_factory=list)
    """gymnasium env ids of the grid (e.g. h1hand-powerlift-v0)"""
    seeds: list[int] = field(default_factory=list)
    """seeds of the grid"""
    scripts: list[str] = field(default_factory=list)
    """training scripts of the grid (paths, or names of the project's scripts; default: both, or
    the preset's)"""
    preset: Literal["paper", "dimensions", "classic"] | None = None
    """`paper`: four h1hand tasks, seeds 0-4, sac_corrected.py (its paired columns are the
    standard runs); `dimensions`: the same on Hopper, HalfCheetah, Ant, Humanoid (3-17 action
    dims, 1M steps) and the h1hand tasks (61); `classic`: Hopper, HalfCheetah, Walker2d, Ant and
    Humanoid, seeds 0-4, 1M steps, with the published SACs' batch 256 and target entropy -|A|;
    --env-ids/--seeds/--scripts override"""
    output_dir: str = "runs"
    """folder that holds one folder per run"""
    launcher: Literal["local", "slurm"] = "local"
    """`local`: runs on this machine, --workers at a time; `slurm`: one Slurm job array"""
    workers: int = 1
    """local launcher: how many runs at a time (each its own process)"""
    mps: bool = False
    """local launcher: run under NVIDIA's Multi-Process Service, so that runs sharing a GPU run
    their kernels side by side instead of taking turns (started here, stopped at the end)"""
    checkpoint_interval: int = 100_000
    """env steps between the runs' checkpoints (bounds the work a node failure loses)"""
    track: bool = False
    """log every run to Weights & Biases (W&B group {env_id}__{algorithm} per cell)"""
    wandb_project_name: str = "corrected-sac"
    """the W&B project of the runs"""
    wandb_entity: str | None = None
    """the W&B entity of the runs"""
    dry_run: bool = False
    """print the grid, the run folders, their state and the env steps left; start nothing"""
    steps_per_second: float | None = None
    """with --dry-run: one run's env steps per second, for the run-hours left (measured speeds
    per env id: docs/sweep.md)"""
    env_steps_per_second: tuple[str, ...] = ()
    """with --dry-run: one run's speed per env id, ENV_ID=STEPS_PER_SECOND (e.g. Hopper-v5=137
    Humanoid-v5=66), for a grid whose tasks differ; --steps-per-second covers those not named"""
    gpu_node_steps_per_second: float | None = None
    """with --dry-run: env steps per second of one GPU node's runs together, for the node-hours
    left (measured: docs/sweep.md)"""
    analyze: str | None = None
    """when all runs are done, run analyze.py on the output folder into this report folder"""
    analyze_args: str = ""
    """further options for analyze.py, e.g. --analyze-args='--normalize min-max --reps 2000'"""
    wait: bool = False
    """slurm launcher: wait until the job array has finished (implied by --analyze)"""
    partition: str | None = None
    """slurm: partition (None: the cluster's default partition)"""
    time_min: int = 1440
    """slurm: time limit of one job in minutes (near it, the run checkpoints and is requeued)"""
    cpus_per_task: int = 1
    """slurm: CPUs per run (the scripts use one torch thread unless given --torch-threads)"""
    gpus_per_task: int = 0
    """slurm: GPUs per run"""
    mem_gb: int = 8
    """slurm: memory per run in GB"""
    account: str | None = None
    """slurm: account to charge"""
    sbatch: list[str] = field(default_factory=list)
    """slurm: further sbatch options as KEY=VALUE or KEY (e.g. qos=high constraint=a100)"""
    max_parallel: int = 256
    """slurm: how many runs of the array may run at once"""
    signal_delay_s: int = 180
    """slurm: seconds before the time limit at which a job is told to checkpoint"""
    max_requeues: int = 100
    """slurm: how often a run may be requeued after reaching the time limit"""


@dataclass
class StatusArgs:
    output_dir: Annotated[str, tyro.conf.Positional]
    """the sweep's output folder"""


@dataclass
class RestartArgs:
    run_dir: Annotated[str, tyro.conf.Positional]
    """the run folder whose checkpoint.pt is lost (it restarts from its last snapshot)"""
    refill: int = 100_000
    """steps of acting with the snapshot's policy, refilling the replay buffer, before the
    updates resume (counted as the run's steps)"""


# The grid and its checks: nothing is written until all of them pass.


def resolve_script(script: str) -> Path:
    for candidate in (Path(script), ROOT / script):
        if candidate.is_file():
            return candidate.resolve()
    raise SweepError(f"unknown script {script!r}: no such file here or in {ROOT}; "
                     f"the project's scripts are {' and '.join(DEFAULT_SCRIPTS)}")


def check_env_ids(env_ids: list[str]) -> None:
    known = list(gymnasium.registry)
    for env_id in env_ids:
        if env_id not in known:
            close = difflib.get_close_matches(env_id, known, n=3)
            hint = f"did you mean {', '.join(close)}?" if close else "check its spelling"
            raise SweepError(f"unknown env id {env_id!r}: {hint}")


def split_eval_workers(extra_args: tuple[str, ...]) -> tuple[tuple[str, ...], int | None]:
    """The arguments after `--` without --eval-workers, and its last value (None: not given);
    a flag that sweep.py sets itself is refused."""
    for flag in (arg.split("=", 1)[0] for arg in extra_args):
        if flag in SWEEP_FLAGS:
            raise SweepError(f"{flag} after `--` is set by sweep.py for every run: use sweep.py's "
                             "own --env-ids, --seeds, --output-dir, --checkpoint-interval or "
                             "--track instead")
    kept: list[str] = []
    value: int | None = None
    args = iter(extra_args)
    for arg in args:
        flag, sep, given = arg.partition("=")
        if flag not in EVAL_WORKERS_FLAGS:
            kept.append(arg)
            continue
        given = given if sep else next(args, "")
        if not (given.isascii() and given.isdigit()):
            raise SweepError(f"{flag} {given or '(no value)'} after `--`: must be 0 (in-process) "
                             "or a number of evaluation processes")
        value = int(given)
    return tuple(kept), value


def build_grid(args: Args, extra_args: tuple[str, ...]) -> list[Run]:
    """The runs of the sweep, seed-major so that every cell gets its first seed early."""
    # No --preset: no env ids or seeds unless given, the project's two scripts.
    preset = PRESETS.get(args.preset, Preset((), (), DEFAULT_SCRIPTS, {}, ""))
    env_ids = args.env_ids or list(preset.env_ids)
    seeds = args.seeds or list(preset.seeds)
    if not env_ids:
        raise SweepError("no env ids: pass --env-ids ID [ID ...] (or --preset paper)")
    if not seeds:
        raise SweepError("no seeds: pass --seeds 0 1 2 (or --preset paper)")
    check_ranges(args)
    env_speeds(args, env_ids)  # its errors before anything is written
    if args.mps and args.launcher != "local":
        raise SweepError("--mps is for --launcher local (on Slurm, the cluster decides how jobs "
                         "share a GPU); drop --mps")
    scripts = [resolve_script(script) for script in dict.fromkeys(args.scripts or preset.scripts)]
    check_env_ids(env_ids)
    run_args, eval_workers = split_eval_workers(extra_args)
    run_args = with_preset_args(preset.run_args, run_args)
    output_dir = Path(args.output_dir).resolve()
    entity = ("--wandb-entity", args.wandb_entity) if args.wandb_entity else ()
    tracking = ("--track", "--wandb-project-name", args.wandb_project_name, *entity) \
        if args.track else ()
    # The preset's step budget for an env id, unless the arguments after `--` give one.
    steps = preset.total_timesteps if given_total_timesteps(run_args) is None else {}
    budget = {env_id: ("--total-timesteps", str(steps[env_id])) if env_id in steps else ()
              for env_id in env_ids}
    return [Run(script, env_id, seed, budget[env_id] + run_args, output_dir,
                args.checkpoint_interval, tracking, eval_workers)
            for seed in dict.fromkeys(seeds) for env_id in dict.fromkeys(env_ids)
            for script in scripts]


def check_ranges(args: Args) -> None:
    def positive(speed: float | None) -> bool:
        return speed is None or (math.isfinite(speed) and speed > 0)

    rules = (
        ("seeds", all(seed >= 0 for seed in args.seeds), "non-negative integers"),
        ("workers", args.workers >= 1, "at least 1"),
        ("checkpoint_interval", args.checkpoint_interval >= 1,
         "at least 1 (a run is only resumable from a checkpoint)"),
        ("steps_per_second", positive(args.steps_per_second), "a positive number"),
        ("gpu_node_steps_per_second", positive(args.gpu_node_steps_per_second),
         "a positive number"),
        ("time_min", args.time_min >= 1, "at least 1 minute"),
        ("cpus_per_task", args.cpus_per_task >= 1, "at least 1"),
        ("gpus_per_task", args.gpus_per_task >= 0, "0 or more"),
        ("mem_gb", args.mem_gb >= 1, "at least 1"),
        ("max_parallel", args.max_parallel >= 1, "at least 1"),
        ("signal_delay_s", 1 <= args.signal_delay_s < 60 * args.time_min,
         f"at least 1 and below --time-min ({args.time_min} min) in seconds"),
        ("max_requeues", args.max_requeues >= 0, "0 or more"),
    )
    if message := broken_rule(args, rules):
        raise SweepError(message)


def env_speeds(args: Args, env_ids: list[str]) -> dict[str, float]:
    """--env-steps-per-second as {env id: steps/s}, --steps-per-second for the env ids it does
    not name; empty when neither is given."""
    speeds = {}
    for entry in args.env_steps_per_second:
        env_id, _, value = entry.partition("=")
        try:
            speed = float(value)
        except ValueError:
            speed = math.nan
        if not (math.isfinite(speed) and speed > 0):
            raise SweepError(f"--env-steps-per-second {entry}: must be ENV_ID=STEPS_PER_SECOND "
                             "with a positive number, e.g. Hopper-v5=137")
        if env_id not in env_ids:
            raise SweepError(f"--env-steps-per-second {entry}: {env_id} is not in the grid "
                             f"({' '.join(env_ids)})")
        speeds[env_id] = speed
    if not (speeds or args.steps_per_second):
        return {}
    missing = [env_id for env_id in env_ids if env_id not in speeds]
    if missing and not args.steps_per_second:
        raise SweepError(f"--env-steps-per-second gives no speed for {' '.join(missing)}: name "
                         "them too (ENV_ID=STEPS_PER_SECOND) or add --steps-per-second for them")
    return {env_id: speeds.get(env_id, args.steps_per_second) for env_id in env_ids}


def with_preset_args(preset_args: tuple[str, ...], run_args: tuple[str, ...]) -> tuple[str, ...]:
    """The preset's flags, less those the arguments after `--` give too, then those arguments."""
    given = {arg.partition("=")[0] for arg in run_args if arg.startswith("--")}
    kept, i = [], 0
    while i < len(preset_args):  # the preset's flags each take one value: "--flag value"
        if preset_args[i] not in given:
            kept += preset_args[i : i + 2]
        i += 2
    return (*kept, *run_args)


def given_total_timesteps(extra_args: tuple[str, ...]) -> str | None:
    """The first --total-timesteps' value after `--` ("" with none after it); None: not given."""
    for i, arg in enumerate(extra_args):
        flag, sep, value = arg.partition("=")
        if flag == "--total-timesteps":
            return value if sep else "".join(extra_args[i + 1 : i + 2])
    return None


def check_output_dir(runs: list[Run]) -> None:
    """Refuse a folder that holds runs made with other arguments: they would mix in analysis.
    A preset gives each env id its own step budget, so a run of an env id in the grid must have
    that env id's arguments; a run of another env id, one of the grid's argument lists."""
    output_dir = runs[0].output_dir
    if not output_dir.is_dir():
        return
    expected = {run.env_id: list(run.extra_args) for run in runs}
    allowed = list(expected.values())
    others = []
    for run_dir in sorted(output_dir.iterdir()):
        if run_dir.name.startswith(".") or not run_dir.is_dir():
            continue
        identity = read_json(run_dir / IDENTITY_FILE)
        if identity is None and (run_dir / "config.json").exists():
            others.append(f"{run_dir.name} (not made by sweep.py)")
        elif identity is not None and (
            identity["extra_args"] != expected[identity["env_id"]]
            if identity.get("env_id") in expected else identity["extra_args"] not in allowed
        ):
            others.append(f"{run_dir.name} (arguments: {shlex.join(identity['extra_args'])})")
    if others:
        shown = others[:10] + ([f"... and {len(others) - 10} more"] if len(others) > 10 else [])
        theirs = sorted({shlex.join(args) or "none" for args in allowed})
        raise SweepError(f"{output_dir} holds runs made with other arguments than this sweep's "
                         f"({'; '.join(theirs)}):\n  " + "\n  ".join(shown) + "\nUse another "
                         "--output-dir, or rerun with the same arguments after `--`.")


def eval_workers_per_run(cores: int, runs_at_once: int) -> int:
    # At least one: in-process evaluation stops training for every round, which costs more than
    # one worker on an oversubscribed core.
    return max(1, (cores - runs_at_once) // runs_at_once)


def plural(count: int, noun: str) -> str:
    return f"{count} {noun}{'' if count == 1 else 's'}"


def eval_division(args: Args, given: int | None, to_launch: int) -> tuple[int, str]:
    """Each run's --eval-workers (the user's, after `--`, stands), and the division in words. Why
    sweep.py passes a count, even on Slurm: docs/sweep.md, "Cores for evaluation"."""
    if given is not None:
        return given, f"evaluation: {plural(given, 'worker')} per run (--eval-workers after `--`)"
    if args.launcher == "slurm":
        # submitit writes additional sbatch parameters over its own: --sbatch cpus-per-task=N wins.
        asked = str(sbatch_options(args.sbatch).get("cpus_per_task", args.cpus_per_task))
        if not (asked.isascii() and asked.isdigit()) or int(asked) < 1:
            raise SweepError(f"--sbatch cpus-per-task={asked}: must be a whole number, at least 1")
        cpus = int(asked)
        count = eval_workers_per_run(cpus, 1)
        why = f"{plural(cpus, 'CPU')} per Slurm task, one for training"
    else:
        cores = len(os.sched_getaffinity(0))
        # Fewer runs to launch than --workers: only that many run at once.
        at_once = max(1, min(args.workers, to_launch))
        count = eval_workers_per_run(cores, at_once)
        why = f"{plural(cores, 'core')}, {plural(at_once, 'run')} at a time"
    return count, f"evaluation: {plural(count, 'worker')} per run ({why})"


@contextlib.contextmanager
def mps_daemon() -> Iterator[None]:
    """NVIDIA's Multi-Process Service while the block runs, for the CUDA processes started in it
    (docs/speed.md). A private pipe folder keeps it apart from any MPS daemon already there."""
    if shutil.which("nvidia-cuda-mps-control") is None:
        raise SweepError("--mps needs nvidia-cuda-mps-control (NVIDIA's driver tools) on PATH; "
                         "drop --mps on a machine without it")
    folder = Path(tempfile.mkdtemp(prefix="mps-"))  # short: the pipe is a Unix socket path
    variables = {"CUDA_MPS_PIPE_DIRECTORY": str(folder / "pipe"),
                 "CUDA_MPS_LOG_DIRECTORY": str(folder / "log")}
    for path in variables.values():
        Path(path).mkdir()
    environment = {**os.environ, **variables}
    subprocess.run(["nvidia-cuda-mps-control", "-d"], env=environment, check=True)
    print(f"sweep.py: MPS started (pipe folder {variables['CUDA_MPS_PIPE_DIRECTORY']})", flush=True)
    saved = {k: os.environ.get(k) for k in variables}
    os.environ.update(variables)  # the runs started in the block inherit it
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key)
            else:
                os.environ[key] = value
        subprocess.run(["nvidia-cuda-mps-control"], input="quit\n", text=True, env=environment,
                       check=False)
        print("sweep.py: MPS stopped", flush=True)
        shutil.rmtree(folder, ignore_errors=True)


def launch_local(runs: list[Run], workers: int) -> None:
    """Run on this machine, `workers` at a time. SIGINT/SIGTERM: every running run checkpoints
    after its current step and stops (a second signal stops them at once)."""
    stopping = threading.Event()
    children: set[subprocess.Popen] = set()

    def stop(signum: int, frame: object) -> None:
        print(f"sweep.py: {signal.Signals(signum).name}: stopping the runs (checkpointing)",
              flush=True)
        stopping.set()
        for child in list(children):
            child.send_signal(signal.SIGTERM)

    def work(run: Run) -> None:
        if stopping.is_set():
            return
        # A queued run may have been taken up meanwhile by another sweep of the same folder.
        state = run_state(run.run_dir)
        if action_for(state) not in LAUNCH_ACTIONS:
            print(f"{run.name}: {state} by now (another process took it up): skipped", flush=True)
            return
        # Own session: a Ctrl-C at the terminal reaches the children once, through stop().
        child = start_run(run, new_session=True, block_user_signals=False)
        children.add(child)
        if stopping.is_set():
            child.send_signal(signal.SIGTERM)
        returncode = child.wait()
        children.discard(child)
        record_exit(run, returncode)
        print(f"{run.name}: {run_state(run.run_dir)} (exit code {returncode})", flush=True)

    for run in runs:
        prepare_run_dir(run)
    previous = {s: signal.signal(s, stop) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            list(pool.map(work, runs))
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def check_slurm(partition: str | None) -> None:
    """Fail before anything is written when Slurm is not there or not answering."""
    for tool in ("sbatch", "squeue", "srun", "sinfo"):
        if shutil.which(tool) is None:
            raise SweepError(f"Slurm not found: `{tool}` is not on PATH. Run sweep.py on a login "
                             "node of the cluster, or use --launcher local.")
    try:
        result = subprocess.run(["sinfo", "-h", "-o", "%P"], capture_output=True, text=True,
                                timeout=60)
    except subprocess.TimeoutExpired as error:
        raise SweepError("Slurm not reachable: `sinfo` did not answer within 60 s") from error
    if result.returncode != 0:
        raise SweepError(f"Slurm not reachable: `sinfo` failed: {result.stderr.strip()}\n"
                         "Check that slurmctld is up (`scontrol ping`), or use --launcher local.")
    partitions = [name.rstrip("*") for name in result.stdout.split()]
    if partition is not None and partition not in partitions:
        raise SweepError(
            f"unknown Slurm partition {partition!r}: this cluster has {', '.join(partitions)}")


def sbatch_options(options: list[str]) -> dict[str, str | bool]:
    split = (option.removeprefix("--").partition("=") for option in options)
    return {key.replace("-", "_"): value if sep else True for key, sep, value in split}


def launch_slurm(runs: list[Run], args: Args) -> str:
    """Submit the runs as one job array (each task a sweep_run.SlurmRun); returns its job id."""
    executor = submitit.SlurmExecutor(folder=runs[0].output_dir / ".submitit" / "%j",
                                      max_num_timeout=args.max_requeues)
    optional = {"partition": args.partition, "account": args.account,
                "gpus_per_task": args.gpus_per_task or None}
    executor.update_parameters(
        job_name="sweep", time=args.time_min, cpus_per_task=args.cpus_per_task,
        mem=f"{args.mem_gb}GB", signal_delay_s=args.signal_delay_s,
        array_parallelism=args.max_parallel, stderr_to_stdout=True,
        # The job unpickles SlurmRun from sac_utils/sweep_run.py, wherever the sweep started.
        setup=[f"export PYTHONPATH={shlex.quote(str(ROOT))}${{PYTHONPATH:+:$PYTHONPATH}}"],
        additional_parameters=sbatch_options(args.sbatch),
        **{key: value for key, value in optional.items() if value is not None})
    for run in runs:
        prepare_run_dir(run)
    jobs = executor.map_array(SlurmRun(), runs)
    for run, job in zip(runs, jobs, strict=True):
        prepare_run_dir(run, slurm_job_id=job.job_id)
    return jobs[0].job_id.split("_")[0]


def wait_for_slurm(job_id: str) -> None:
    last = None
    while True:
        states = squeue_states(job_id)
        if states is not None and not states:  # none left (None: squeue failed; ask again)
            return
        summary = ", ".join(f"{states.count(s)} {s.lower()}" for s in sorted(set(states or [])))
        if summary != last:
            print(f"Slurm job {job_id}: {summary}", flush=True)
            last = summary
        time.sleep(2.0)


@functools.cache
def script_default_total_timesteps(script: Path) -> int:
    spec = importlib.util.spec_from_file_location(f"_sweep_{script.stem}", script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.Args().total_timesteps


def print_plan(runs: list[Run], states: dict[Run, str], args: Args,
               extra_args: tuple[str, ...]) -> None:
    """--dry-run: the grid, each run's folder, state and action, and the env steps left; a time
    only from speeds the user gives (measured ones: docs/sweep.md)."""
    n_env, n_seed, n_script = (len({getattr(run, key) for run in runs})
                               for key in ("env_id", "seed", "script"))
    print(f"grid: {n_env} env ids x {n_seed} seeds x {n_script} scripts = {len(runs)} runs, "
          f"arguments after --: {shlex.join(extra_args) or '(none)'}")
    print(f"output folder: {runs[0].output_dir}")
    if args.preset and not args.scripts:
        print(f"preset {args.preset}: {PRESETS[args.preset].why}")
    if args.preset and PRESETS[args.preset].run_args:
        print(f"each run also gets: {shlex.join(runs[0].extra_args)}")
    speeds = env_speeds(args, list(dict.fromkeys(run.env_id for run in runs)))
    total = steps_left = 0
    run_hours = []  # each run's hours left, at its env id's speed
    for run in runs:
        given = given_total_timesteps(run.extra_args)
        budget = int(given) if given else script_default_total_timesteps(run.script)
        left = 0 if states[run] == "done" else budget - (last_eval_step(run.run_dir) or 0)
        total, steps_left = total + budget, steps_left + left
        run_hours.append(left / speeds[run.env_id] / 3600 if speeds else 0)
        print(f"  {run.name:<60} {states[run]:<12} {action_for(states[run])}")
    print(f"compute: {len(runs)} runs, {total:,} env steps in all, {steps_left:,} still to run")
    if speeds:
        at = (f"{args.steps_per_second:g}" if not args.env_steps_per_second else
              ", ".join(f"{env_id} {speed:g}" for env_id, speed in speeds.items()))
        print(f"at {at} steps/s per run: {sum(run_hours):,.1f} run-hours (the longest run "
              f"{max(run_hours):,.1f} h)")
    if args.gpu_node_steps_per_second:
        hours = steps_left / args.gpu_node_steps_per_second / 3600
        print(f"on one GPU node at {args.gpu_node_steps_per_second:,g} steps/s in all: "
              f"{hours:,.1f} h ({hours / 24:,.1f} days)")
    if not (speeds or args.gpu_node_steps_per_second):
        print("for the time it takes, give --steps-per-second (one run) or "
              "--gpu-node-steps-per-second; measured speeds: docs/sweep.md")


def print_status(output_dir: Path) -> None:
    run_dirs = [d for d in sorted(output_dir.iterdir()) if d.is_dir() and not d.name.startswith(".")
                and ((d / IDENTITY_FILE).exists() or (d / "config.json").exists())]
    if not run_dirs:
        raise SweepError(f"{output_dir} holds no runs")
    width = max(len(d.name) for d in run_dirs)
    print(f"{'run':<{width}}  {'state':<12} progress (last eval step / total)")
    counts: dict[str, int] = {}
    for run_dir in run_dirs:
        state = run_state(run_dir)
        counts[state] = counts.get(state, 0) + 1
        total = (read_json(run_dir / "config.json") or {}).get("total_timesteps")
        progress = f"{last_eval_step(run_dir) or 0}/{total if total is not None else '?'}"
        print(f"{run_dir.name:<{width}}  {state:<12} {progress}")
        if state == "failed":
            for line in log_tail(run_dir):
                print(f"    | {line}")
    print(", ".join(f"{n} {state}" for state, n in counts.items()))


def free_checkpoints(output_dir: Path) -> None:
    """Deletes the checkpoint.pt (the replay buffer) of every finished run: it never resumes,
    and its final_model.pt and snapshots hold what evaluation needs."""
    freed = 0
    for done in sorted(output_dir.rglob("done.json")):
        run_dir = done.parent
        checkpoint = run_dir / "checkpoint.pt"
        if not checkpoint.exists():
            continue
        if not (run_dir / "final_model.pt").is_file():
            print(f"{run_dir.name}: done.json but no final_model.pt: checkpoint.pt kept")
            continue
        size = checkpoint.stat().st_size
        checkpoint.unlink()
        freed += size
        print(f"{run_dir.name}: deleted checkpoint.pt ({size / 2**30:.2f} GiB)")
    print(f"freed {freed / 2**30:.2f} GiB")


def sweep(args: Args, extra_args: tuple[str, ...]) -> int:
    runs = build_grid(args, extra_args)
    check_output_dir(runs)
    if args.launcher == "slurm" and not args.dry_run:
        check_slurm(args.partition)
    states = {run: run_state(run.run_dir) for run in runs}
    todo = [run for run in runs if action_for(states[run]) in LAUNCH_ACTIONS]
    count, division = eval_division(args, runs[0].eval_workers, len(todo))
    if args.dry_run:
        print_plan(runs, states, args, extra_args)
        print(division)
        return 0
    todo = [dataclasses.replace(run, eval_workers=count) for run in todo]
    print(f"{len(runs)} runs: {len(runs) - len(todo)} done or under way, {len(todo)} to launch")
    for run in runs:
        holder = lock_holder(run.run_dir) if states[run] == "running" else None
        if holder is not None:
            print(f"{run.name}: in use by process {holder} (it holds {run.run_dir / 'lock'}): "
                  "skipped", flush=True)
    if todo:
        print(division, flush=True)
    if todo and args.launcher == "local":
        with mps_daemon() if args.mps else contextlib.nullcontext():
            launch_local(todo, args.workers)
    elif todo:
        job_id = launch_slurm(todo, args)
        print(f"submitted Slurm job array {job_id} ({len(todo)} runs); "
              f"follow it with: python sweep.py status {runs[0].output_dir}")
        if not (args.wait or args.analyze):
            return 0
        try:
            wait_for_slurm(job_id)
        except KeyboardInterrupt:
            print(f"stopped waiting; the jobs go on (scancel {job_id} stops them)")
            return EXIT_INTERRUPTED
    return finish(runs, args)


def finish(runs: list[Run], args: Args) -> int:
    states = [run_state(run.run_dir) for run in runs]
    print(", ".join(f"{states.count(s)} {s}" for s in sorted(set(states))))
    for run, state in zip(runs, states, strict=True):
        if state == "failed":
            print(f"{run.name} failed; last lines of {run.run_dir / LOG_FILE}:")
            print("\n".join(f"    | {line}" for line in log_tail(run.run_dir)))
    if all(state == "done" for state in states):
        if not args.analyze:
            return 0
        command = [sys.executable, str(ROOT / "analyze.py"), str(runs[0].output_dir),
                   "--out", args.analyze, *shlex.split(args.analyze_args)]
        print(f"all runs done: {shlex.join(command)}", flush=True)
        return subprocess.run(command).returncode
    if args.analyze:
        print("not all runs are done: analysis skipped; run this command again to finish them")
    return 1 if "failed" in states else EXIT_INTERRUPTED


def main(argv: list[str]) -> int:
    """`sweep.py status DIR`, `sweep.py free DIR`, `sweep.py restart RUN_DIR` or `sweep.py
    [OPTIONS] [-- ARGS FOR EVERY RUN]`; the exit code (2: bad input, one line on stderr)."""
    try:
        if argv[:1] in (["status"], ["free"]):
            given = tyro.cli(StatusArgs, args=argv[1:], prog=f"sweep.py {argv[0]}")
            output_dir = Path(given.output_dir)
            if not output_dir.is_dir():
                raise SweepError(f"{output_dir} does not exist: give the --output-dir of a sweep")
            (print_status if argv[0] == "status" else free_checkpoints)(output_dir)
            return 0
        if argv[:1] == ["restart"]:
            given = tyro.cli(RestartArgs, args=argv[1:], prog="sweep.py restart")
            from sac_utils.restart import restart_from_snapshot  # torch: only here

            record = restart_from_snapshot(Path(given.run_dir), given.refill)
            print(f"{given.run_dir}: checkpoint.pt written from {record['snapshot']}; the run "
                  f"acts until step {record['updates_from']:,}, then updates resume (recorded in "
                  "config.json's restarts); continue it with the sweep's command, or --resume")
            return 0
        split = argv.index("--") if "--" in argv else len(argv)
        args = tyro.cli(Args, args=argv[:split], prog="sweep.py", description=__doc__)
        return sweep(args, tuple(argv[split + 1 :]))
    except SweepError as error:
        print(f"sweep.py: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

