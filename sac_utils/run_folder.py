"""A run folder from start to finish, behind the one object the SAC scripts hold (RunFolder):
named, locked, started or resumed, logged to (CSVs, TensorBoard, W&B), checkpointed and finished;
the graceful stop on a signal (StopRequest). The layout: docs/scripts.md ("The run folder").
"""

import copy
import csv
import dataclasses
import fcntl
import os
import platform
import signal
import subprocess
import sys
import time
from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np
import torch
import torch.nn as nn
from torch.utils.tensorboard import SummaryWriter

from sac_utils import checkpoints, eval_rounds
from sac_utils.checkpoints import read_checkpoint, save_tensors
from sac_utils.cli import INTERRUPTED_EXIT_CODE, check_finite, fail
from sac_utils.files import atomic_write, complete_lines, write_json

TRAIN_COLUMNS = ("global_step", "wall_time", "sps", "qf1_loss", "qf2_loss", "qf1_value",
                 "qf2_value", "actor_loss", "alpha", "alpha_loss", "entropy", "episodes",
                 "episode_return_mean", "episode_length_mean")


class StopRequest:
    """SIGTERM/SIGUSR1/SIGUSR2: checkpoint after the current step, then exit; a second signal
    exits at once (the last checkpoint stays valid)."""

    def __init__(self):
        self.requested = False
        for s in (signal.SIGTERM, signal.SIGUSR1, signal.SIGUSR2):
            signal.signal(s, self.handle)

    def handle(self, signum, frame) -> None:
        if self.requested:
            print("second signal: exiting now; resume with --resume from the last checkpoint",
                  flush=True)
            os._exit(INTERRUPTED_EXIT_CODE)
        self.requested = True
        print(f"{signal.Signals(signum).name}: checkpointing after this step, then exiting",
              flush=True)


class RunFolder:
    """One run's folder and bookkeeping (a finished run exits on creation, code 0): `open`,
    `resume`, then the loop's count_step, log_train, evaluate, save_snapshot, checkpoint (a stop's
    ends the run); `finish`."""

    def __init__(self, args, algorithm: str, script: str, eval_actions: dict):
        self.args, self.algorithm, self.script = args, algorithm, Path(script).name
        self.eval_actions = eval_actions
        self.eval_columns = ["global_step", "wall_time", "eval_round", *eval_rounds.eval_columns(
            eval_actions, shift=eval_rounds.shift_measured_at(eval_actions) is not None)]
        self.dir = run_dir(args, algorithm)
        if (self.dir / "done.json").exists():
            print(f"{self.dir}: already finished (done.json); nothing to do")
            sys.exit(0)

    def open(self, obs_dim: int, action_dim: int, device: torch.device) -> None:
        """Locks the folder and checks it before writing: a fresh run writes config.json, a
        resumed one (--resume and a checkpoint.pt) has its CSVs cut back to the checkpoint's step;
        then the logs and the evaluation workers open."""
        args, self.device = self.args, device
        print(f"device: {device}", flush=True)
        lock = lock_run_folder(self.dir)
        path = self.dir / "checkpoint.pt"  # none yet: the run restarts from step 0
        self.ckpt = read_checkpoint(path) if args.resume is not None and path.exists() else None
        self.elapsed = 0.0
        self.progress = {"episode_returns": [], "episode_lengths": [], "last_eval": None,
                         "episode_return": 0.0, "episode_length": 0}
        if self.ckpt is not None:
            checkpoints.check_resumable(path, self.ckpt, args)
            check_csv(self.dir / "eval.csv", self.eval_columns)
            check_csv(self.dir / "train.csv", list(TRAIN_COLUMNS))
        else:
            for old in self.dir.glob("events.out.tfevents.*"):  # a restart from step 0
                old.unlink()
            write_json(self.dir / "config.json", run_metadata(
                args, obs_dim, action_dim, self.algorithm, self.script, device))
        os.ftruncate(lock, 0)  # this process's pid, for a refused second process to name
        os.pwrite(lock, f"{os.getpid()}\n".encode(), 0)
        global_step = 0 if self.ckpt is None else self.ckpt["global_step"]
        self.open_logs(global_step)
        self.session_start = self.row_start = time.time()
        self.row_step = global_step
        free_cores = max(1, len(os.sched_getaffinity(0)) - 1)  # all but training's, at least one
        workers = free_cores if args.eval_workers is None else args.eval_workers
        self.eval_pool = eval_rounds.EvalPool(workers, self.log_round)

    @property
    def resuming(self) -> bool:
        return self.ckpt is not None

    def resume(self, agent: dict, buffer, action_space: gym.Space,
               envs: gym.vector.VectorEnv) -> tuple[int, np.ndarray, int]:
        """checkpoint.pt into `agent`, the buffer and the random streams, the episode under way
        replayed, the rounds a stop left unfinished resubmitted. Returns the step, the observation
        and the first update's step (later than --learning-starts after a restart's refill)."""
        ckpt = self.ckpt
        global_step, obs, self.elapsed, self.progress = checkpoints.load_checkpoint(
            ckpt, agent, buffer, action_space, envs, self.device)
        print(f"resuming {self.dir} at step {global_step}", flush=True)
        updates_from = self.progress.get("updates_from", self.args.learning_starts)
        if updates_from > global_step:
            print(f"restarted from a snapshot: acting to refill the replay buffer, updates "
                  f"resume at step {updates_from}", flush=True)
        for state in ckpt.get("pending_rounds", []):  # on the networks' weights of their step
            round_ = self.evaluation_round(state["global_step"], state["wall_time"],
                                           agent["actor"], agent["qf"])
            round_.actor.load_state_dict(state["actor"])
            if round_.critic is not None:
                round_.critic.load_state_dict(state["qf"])
            self.eval_pool.submit(round_)
        self.ckpt = None  # mmapped: let it go
        return global_step, obs, updates_from

    def evaluate(self, global_step: int, actor: nn.Module, qf: nn.Module) -> None:
        """Submits this step's evaluation round; its eval.csv row comes in step order."""
        self.eval_pool.submit(self.evaluation_round(global_step, self.wall_time(), actor, qf))

    def poll_evaluations(self) -> None:
        """Logs the rounds that have finished, in step order (never waits)."""
        self.eval_pool.poll()

    def evaluation_round(self, global_step: int, wall_time: float, actor: nn.Module,
                         qf: nn.Module) -> eval_rounds.Round:
        """The round at this step, on CPU copies of the networks."""
        args, actions = self.args, self.eval_actions
        eval_round = global_step // args.eval_interval
        seeds = eval_rounds.eval_seeds(args.seed, eval_round, args.eval_episodes)
        video = self.dir / "videos" / f"eval_step{global_step}.mp4"
        return eval_rounds.Round(
            args.env_id, seeds, actions, copy.deepcopy(actor).cpu(),
            copy.deepcopy(qf).cpu() if "q_best" in actions.values() else None,
            mode_solver=args.mode_solver, reset_noise=args.eval_reset_noise,
            shift_of=eval_rounds.shift_measured_at(actions),
            videos={"": video} if args.capture_video else {},
            label=f"evaluation of seed {args.seed} at step {global_step}",
            info={"global_step": global_step, "wall_time": wall_time, "eval_round": eval_round})

    def log_round(self, round_: eval_rounds.Round, result: dict) -> None:
        """A finished round's eval.csv row."""
        row = round_.info | eval_rounds.round_row(result, round_.actions)
        self.write_row("eval", row, round_.videos.get(""))
        self.progress["last_eval"] = (row["global_step"], row["return_mean"])

    def wall_time(self) -> float:
        """Seconds of training so far, over every session of the run."""
        return self.elapsed + time.time() - self.session_start

    def count_step(self, reward: float, episode_end: bool) -> None:
        """A step's reward into the episode under way; an ended one into the next train.csv row."""
        progress = self.progress
        progress["episode_return"] += float(reward)
        progress["episode_length"] += 1
        if episode_end:
            progress["episode_returns"].append(progress["episode_return"])
            progress["episode_lengths"].append(progress["episode_length"])
            progress["episode_return"], progress["episode_length"] = 0.0, 0

    def log_train(self, global_step: int, losses: tuple[torch.Tensor, ...] | None) -> None:
        """A train.csv row: steps/s, the last update's losses, the episodes ended since the last."""
        now = time.time()
        returns, lengths = self.progress["episode_returns"], self.progress["episode_lengths"]
        row = {"global_step": global_step, "wall_time": self.wall_time(),
               "sps": (global_step - self.row_step) / (now - self.row_start),
               "episodes": len(returns),
               "episode_return_mean": np.mean(returns) if returns else None,
               "episode_length_mean": np.mean(lengths) if lengths else None}
        returns.clear()
        lengths.clear()
        if losses is not None:
            qf_losses, qf_values, actor_loss, alpha, alpha_loss, log_pi = losses
            check_finite(qf_losses.detach().cpu().numpy(), "critic loss")
            row |= {"qf1_loss": qf_losses[0].item(), "qf2_loss": qf_losses[1].item(),
                    "qf1_value": qf_values[0].mean().item(),
                    "qf2_value": qf_values[1].mean().item(), "actor_loss": actor_loss.item(),
                    "alpha": alpha.item(), "alpha_loss": alpha_loss.item(),
                    "entropy": -log_pi.mean().item()}
        self.write_row("train", row)
        self.row_start, self.row_step = now, global_step

    def print_progress(self, global_step: int) -> None:
        last = self.progress["last_eval"]
        print(f"step {global_step:,}/{self.args.total_timesteps:,} | "
              f"{global_step / self.wall_time():.0f} SPS | "
              + (f"last eval {last[1]:.1f} at step {last[0]:,}" if last else "no eval yet"),
              flush=True)

    def save_snapshot(self, global_step: int, actor: nn.Module, qf: nn.Module,
                      log_alpha: torch.Tensor) -> None:
        """snapshots/step<N>.pt: final_model.pt's content plus log alpha, what a restart needs."""
        (self.dir / "snapshots").mkdir(exist_ok=True)
        save_tensors(self.dir / "snapshots" / f"step{global_step}.pt", checkpoints.policy_weights(
            actor.state_dict(), qf.state_dict(), dataclasses.asdict(self.args), log_alpha))

    def checkpoint(self, global_step: int, agent: dict, buffer, action_space: gym.Space,
                   envs: gym.vector.VectorEnv, stopping: bool) -> None:
        """checkpoint.pt; the running rounds finish first, except on a stop, which keeps them in
        it and then ends the run (exit code 3)."""
        unfinished = self.eval_pool.abandon() if stopping else []
        self.eval_pool.drain()
        save_tensors(self.dir / "checkpoint.pt", checkpoints.checkpoint_state(
            self.args, global_step, self.wall_time(), self.progress, agent, buffer,
            action_space, envs.get_attr("record")[0], checkpoints.rng_states(self.device),
            unfinished))
        if stopping:
            self.close_logs()
            print(f"interrupted at step {global_step}; resume with --resume {self.dir}", flush=True)
            sys.exit(INTERRUPTED_EXIT_CODE)

    def finish(self, global_step: int, actor: nn.Module, qf: nn.Module) -> None:
        """final_model.pt, the logs closed, done.json last (a finished run: sweep.py skips it)."""
        self.eval_pool.drain()
        self.eval_pool.close()
        wall_time = self.wall_time()
        save_tensors(self.dir / "final_model.pt", checkpoints.policy_weights(
            actor.state_dict(), qf.state_dict(), dataclasses.asdict(self.args)))
        self.close_logs()
        write_json(self.dir / "done.json", {"global_step": global_step, "wall_time": wall_time})
        print(f"finished {global_step} steps in {wall_time:.0f} s: {self.dir}", flush=True)

    def open_logs(self, global_step: int) -> None:
        """eval.csv and train.csv (a resume keeps their rows up to its step), TensorBoard, W&B."""
        keep = global_step if self.resuming else None
        self.tb = SummaryWriter(self.dir, purge_step=global_step + 1 if self.resuming else None)
        if not self.resuming:
            self.tb.add_text("hyperparameters", "|param|value|\n|-|-|\n" + "\n".join(
                f"|{name}|{value}|" for name, value in dataclasses.asdict(self.args).items()))
        self.csvs = {"eval": open_csv(self.dir / "eval.csv", self.eval_columns, keep),
                     "train": open_csv(self.dir / "train.csv", list(TRAIN_COLUMNS), keep)}
        self.tracker = start_tracking(self.args, self.dir, self.algorithm)

    def write_row(self, group: str, row: dict, video: Path | None = None) -> None:
        """One row to its CSV (flushed), to TensorBoard and, with --track, to W&B."""
        f, writer = self.csvs[group]
        writer.writerow(row)
        f.flush()
        scalars = {f"{group}/{k}": v for k, v in row.items()
                   if v is not None and k not in ("global_step", "wall_time")}
        for k, v in scalars.items():
            self.tb.add_scalar(k, v, row["global_step"])
        if self.tracker is not None:
            import wandb  # only with --track

            media = {f"{group}/video": wandb.Video(str(video), format="mp4")} if video else {}
            self.tracker.log({"global_step": row["global_step"], **scalars, **media})

    def close_logs(self) -> None:
        self.tb.close()
        if self.tracker is not None:
            self.tracker.finish()
        for f, _ in self.csvs.values():
            f.close()


def run_dir(args, algorithm: str) -> Path:
    """--resume's folder, or a fresh one under --output-dir (--run-name or the default name)."""
    if args.resume is not None:
        return Path(args.resume)
    name = args.run_name or (f"{args.env_id}__{algorithm}__seed{args.seed}__"
                             f"{time.strftime('%Y%m%d-%H%M%S')}")
    path = Path(args.output_dir) / name
    if (path / "config.json").exists():
        fail(f"{path} already holds a run; continue it with --resume {path} or choose another "
             "--run-name")
    return path


def lock_run_folder(run_dir: Path) -> int:
    """An OS lock on run_dir/lock while this process lives (one writer; never stale: the kernel
    drops it at any death). Returns the fd."""
    run_dir.mkdir(parents=True, exist_ok=True)
    fd = os.open(run_dir / "lock", os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
        then = "then --resume" if (run_dir / "config.json").exists() else \
            "or choose another --run-name"
        fail(f"{run_dir} is in use by process {holder} (it holds {run_dir / 'lock'}); let it "
             f"finish or stop it, {then}")
    return fd


def run_metadata(args, obs_dim: int, action_dim: int, algorithm: str, script: str,
                 device: torch.device) -> dict:
    """config.json: the arguments, versions, commit, and "used": what the flags got (--cuda
    without a GPU trains on the CPU)."""
    return {**dataclasses.asdict(args), "algorithm": algorithm, "script": script,
            "obs_dim": obs_dim, "action_dim": action_dim, "git_commit": git_commit(),
            "versions": {"python": platform.python_version(), "torch": torch.__version__,
                         "numpy": np.__version__, "gymnasium": gym.__version__,
                         "mujoco": mujoco.__version__},
            "start_time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "machine": machine(),
            "used": {"device": device.type, "compile": args.compile,
                     "cudagraphs": device.type == "cuda" and args.cudagraphs,
                     "gpu_buffer": device.type == "cuda" and args.gpu_buffer,
                     "torch_threads": args.torch_threads}}


def git_commit() -> str | None:
    """The code's commit (None outside a git checkout)."""
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], cwd=Path(__file__).parent,
                              capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None


def machine() -> dict:
    """The machine a run (or its restart) trains on, as config.json records it: a seed's run
    repeats only on the same kind of CPU (kernels and MuJoCo round by its instruction set). A
    VM's model name may hide the model ("AMD EPYC"), so its vector instruction sets go beside
    it (`isa`: /proc/cpuinfo's avx*, amx* and fma flags; absent where it cannot be read)."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        lines = []
    def first(key: str) -> str | None:  # the first CPU's entry
        return next((line.split(":", 1)[1] for line in lines if line.startswith(key)), None)

    name, flags = first("model name"), first("flags")
    found = {"cpu": name.strip() if name else platform.processor() or platform.machine(),
             "cores": os.cpu_count()}
    if flags is not None:
        found["isa"] = sorted({f for f in flags.split()
                               if f.startswith(("avx", "amx")) or f == "fma"})
    return found


def open_csv(path: Path, columns: list[str], keep_until_step: int | None):
    """An append-mode CSV writer; a resume keeps the whole rows up to its step."""
    kept = []
    if keep_until_step is not None and path.exists():
        kept = [r for r in complete_lines(path)[1:] if int(r.split(",")[0]) <= keep_until_step]
    atomic_write(path, lambda tmp: tmp.write_text(",".join(columns) + "\n" + "".join(kept)))
    f = open(path, "a", newline="")  # noqa: SIM115  (kept open for the whole run)
    return f, csv.DictWriter(f, columns)


def check_csv(path: Path, columns: list[str]) -> None:
    """Before a resume writes: the CSV must be this run's (its header, step numbers)."""
    if not path.exists():
        return
    lines = path.read_text(errors="replace").splitlines(keepends=True)
    if not lines or lines[0].rstrip("\r\n").split(",") != columns:
        fail(f"{path} does not have the header this run writes ({len(columns)} columns: "
             f"{', '.join(columns[:3])}, ...); it was edited or belongs to another run: restore "
             "it, or move it away to drop its rows")
    for number, line in enumerate(lines[1:], start=2):
        if line.endswith("\n") and not line.split(",")[0].isdigit():
            fail(f"{path}, line {number}: global_step {line.split(',')[0]!r} is not a step "
                 "number; restore the file, or delete that line")


def start_tracking(args, run_dir: Path, algorithm: str):
    """With --track, the W&B run as CleanRL logs it; its id kept in the folder for a resume."""
    if not args.track:
        return None
    import wandb
    from wandb.sdk.lib.runid import generate_id

    id_file = run_dir / "wandb_run_id.txt"
    if not id_file.exists():
        atomic_write(id_file, lambda tmp: tmp.write_text(generate_id() + "\n"))
    tracker = wandb.init(project=args.wandb_project_name, entity=args.wandb_entity,
                         group=args.wandb_group, name=run_dir.name, dir=run_dir,
                         id=id_file.read_text().strip(), resume="allow",
                         config=dataclasses.asdict(args) | {"algorithm": algorithm})
    tracker.define_metric("*", step_metric="global_step")
    return tracker

