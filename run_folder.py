"""A run folder's files, for sac_standard.py and sac_corrected.py: config.json, the CSV logs
(written row by row), TensorBoard and W&B, checkpoints (written atomically; what one holds:
checkpoint), the folder's lock, the random states, the graceful stop on a signal, and what an
exact resume needs besides: the episode under way (EpisodeRecord). Also the training loop's
bookkeeping: the episodes and statistics train.csv reports, the progress line.

None of it is the algorithm: the two scripts hold that, top to bottom. The layout of a run folder
is described in docs/scripts.md ("The run folder").
"""

import copy
import csv
import dataclasses
import fcntl
import json
import os
import platform
import random
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

import gymnasium as gym
import mujoco
import numpy as np
import torch
import torch.nn as nn
from torch.utils.tensorboard import SummaryWriter

INTERRUPTED_EXIT_CODE = 3
CHECKPOINT_KEYS = ("args", "global_step", "elapsed", "progress", "actor", "qf", "qf_target",
                   "log_alpha", "q_optimizer", "actor_optimizer", "alpha_optimizer", "buffer",
                   "rng")


def fail(message: str) -> NoReturn:
    """Bad input: one line naming the problem and the fix on stderr, exit code 2."""
    print(f"{Path(sys.argv[0]).name}: error: {message}", file=sys.stderr, flush=True)
    sys.exit(2)


def read_config_json(run_dir: Path, give_instead: str, restore: str) -> dict:
    """A run folder's config.json as a dict, or one line naming the problem: `give_instead` says
    what to give where the folder is not a run, `restore` what to do about a damaged file."""
    path = run_dir / "config.json"
    if not path.is_file():
        fail(f"{run_dir} is not a run folder (no config.json); {give_instead}")
    try:
        config = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        fail(f"{path} is not valid JSON ({error}); {restore}")
    if not isinstance(config, dict):
        fail(f"{path} does not hold a JSON object; {restore}")
    return config


def read_run_config(run_dir: Path, algorithm: str) -> dict:
    """The config.json of a run folder made by this script, or a clear error."""
    config = read_config_json(
        run_dir, "give --resume a folder made by sac_standard.py or sac_corrected.py",
        "restore it from a copy, or start a new run")
    if config.get("algorithm") != algorithm:
        fail(f"{run_dir} is a run of {config.get('script')}; resume it with that script")
    return config


def open_csv(path: Path, columns: list[str], keep_until_step: int | None):
    """An append-mode CSV writer. Resuming keeps the whole rows up to the checkpoint's step, so
    the file ends up with no duplicate or missing rows."""
    kept = []
    if keep_until_step is not None and path.exists():
        with path.open(newline="") as f:  # rows as written: csv ends them with \r\n
            lines = f.read().splitlines(keepends=True)[1:]
        kept = [r for r in lines if r.endswith("\n") and int(r.split(",")[0]) <= keep_until_step]
    atomic_write(path, lambda tmp: tmp.write_text(",".join(columns) + "\n" + "".join(kept)))
    f = open(path, "a", newline="")  # noqa: SIM115  (kept open for the whole run)
    return f, csv.DictWriter(f, columns)


def check_csv(path: Path, columns: list[str]) -> None:
    """Before a resume writes anything: the CSV must be this run's (its header, whole steps)."""
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


def read_checkpoint(path: Path) -> dict:
    """checkpoint.pt on the CPU (RNG states must stay there; load_state_dict moves the rest to
    the run's device), or one line saying it is damaged."""
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=False, mmap=True)
        missing = [k for k in CHECKPOINT_KEYS if k not in ckpt]
    except Exception as error:  # a truncated or foreign file fails in pickle, zip or torch
        fail(f"{path} cannot be read ({type(error).__name__}: {str(error).splitlines()[0]}); "
             "it is damaged: restore a copy, or delete it to restart the run from step 0")
    if missing:
        fail(f"{path} lacks {missing}: not a checkpoint of this script; restore a copy, or "
             "delete it to restart the run from step 0")
    if "episode" not in ckpt["rng"]:
        fail(f"{path} was written by an older version of this script (before --num-seeds); "
             "finish the run with that version (its commit is in config.json), or delete the "
             "checkpoint to restart it from step 0")
    return ckpt


def write_row(f, writer: csv.DictWriter, tb: SummaryWriter, tracker, group: str, row: dict,
              video: Path | None = None) -> None:
    """One row to its CSV (flushed), to TensorBoard and, with --track, to W&B."""
    writer.writerow(row)
    f.flush()
    scalars = {f"{group}/{k}": v for k, v in row.items()
               if v is not None and k not in ("global_step", "wall_time")}
    for k, v in scalars.items():
        tb.add_scalar(k, v, row["global_step"])
    if tracker is not None:
        import wandb  # only with --track

        media = {f"{group}/video": wandb.Video(str(video), format="mp4")} if video else {}
        tracker.log({"global_step": row["global_step"], **scalars, **media})


def atomic_write(path: Path, write: Callable[[Path], object]) -> None:
    """Writes via a temporary file and os.replace: a kill leaves the old file or the new one."""
    tmp = path.with_name(path.name + ".tmp")
    write(tmp)
    os.replace(tmp, path)


def start_tracking(args, run_dir: Path, algorithm: str):
    """With --track, the W&B run, as CleanRL logs it: the config, every scalar that goes to
    TensorBoard (against global_step) and the evaluation videos. wandb is imported only here.
    Its id is kept in the run folder, so a resumed run continues the same W&B run; with
    WANDB_MODE=offline it writes to run_dir/wandb, for `wandb sync` later."""
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


def run_metadata(args, obs_dim: int, action_dim: int, algorithm: str, script: str,
                 device: torch.device) -> dict:
    """config.json: every argument, the algorithm, the library versions, the git commit, and
    under "used" what the run started with where flags only ask (--cuda on a machine without a
    GPU trains on the CPU, without CUDA graphs or a GPU buffer)."""
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=Path(__file__).parent,
                                capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = None
    return {**dataclasses.asdict(args), "algorithm": algorithm, "script": script,
            "obs_dim": obs_dim, "action_dim": action_dim, "git_commit": commit,
            "versions": {"python": platform.python_version(), "torch": torch.__version__,
                         "numpy": np.__version__, "gymnasium": gym.__version__,
                         "mujoco": mujoco.__version__},
            "start_time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "used": {"device": device.type, "compile": args.compile,
                     "cudagraphs": device.type == "cuda" and args.cudagraphs,
                     "gpu_buffer": device.type == "cuda" and args.gpu_buffer,
                     "torch_threads": args.torch_threads}}


def lock_run_folder(run_dir: Path) -> int:
    """An exclusive OS lock on run_dir/lock, held while this process lives: one writer per run
    folder (a Slurm requeue racing a job that has not died yet, a sweep started twice). The
    kernel drops it when the process dies, SIGKILL included, so it is never stale. Returns the
    fd, for record_holder once the folder has been checked. A refusal changes nothing: a folder
    and lock file made here for it are removed again."""
    made = not run_dir.exists()
    run_dir.mkdir(parents=True, exist_ok=True)
    fd = os.open(run_dir / "lock", os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
        if made:
            (run_dir / "lock").unlink(missing_ok=True)
            run_dir.rmdir()
        then = "then --resume" if (run_dir / "config.json").exists() else \
            "or choose another --run-name"
        fail(f"{run_dir} is in use by process {holder} (it holds {run_dir / 'lock'}); let it "
             f"finish or stop it, {then}")
    return fd


def record_holder(lock_fd: int) -> None:
    """Writes this process's pid into the lock file it holds, for a refused second process."""
    os.ftruncate(lock_fd, 0)
    os.pwrite(lock_fd, f"{os.getpid()}\n".encode(), 0)


class StopRequest:
    """SIGTERM/SIGUSR1/SIGUSR2 ask for a graceful stop after the current step (checkpoint, then
    exit); a second signal exits at once (the last checkpoint stays valid)."""

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


def rng_states(device: torch.device) -> dict:
    """The process's random streams: torch draws the actions and the batches. Nothing of ours
    uses the global numpy and python generators; libraries might. The CUDA generators only for a
    run on CUDA: reading them elsewhere would create a CUDA context (and fail on a GPU in
    exclusive-process mode that another process holds)."""
    name, keys, pos, has_gauss, gauss = np.random.get_state()  # noqa: NPY002
    # Plain lists, not arrays: a checkpoint then loads with torch.load(weights_only=True).
    return {"python": random.getstate(), "numpy": (name, keys.tolist(), pos, has_gauss, gauss),
            "torch": torch.get_rng_state(),
            "cuda": torch.cuda.get_rng_state_all() if device.type == "cuda" else None}


def set_rng_states(states: dict, device: torch.device) -> None:
    random.setstate(states["python"])
    name, keys, pos, has_gauss, gauss = states["numpy"]
    np.random.set_state((name, np.array(keys, np.uint32), pos, has_gauss, gauss))  # noqa: NPY002
    torch.set_rng_state(states["torch"])
    if states["cuda"] is not None and device.type == "cuda":
        torch.cuda.set_rng_state_all(states["cuda"])


def on_cpu(tree):
    """A copy of nested dicts, lists and tuples with every tensor moved to the CPU: what the run
    folder's .pt files hold, so that a plain torch.load reads them on a machine without a GPU."""
    if torch.is_tensor(tree):
        return tree.cpu()
    if isinstance(tree, dict):
        return {k: on_cpu(v) for k, v in tree.items()}
    if isinstance(tree, list | tuple):
        return type(tree)(on_cpu(v) for v in tree)
    return tree


def find_checkpoint(run_dir: Path) -> dict | None:
    """The run's checkpoint.pt, or None where it has none yet (it restarts from step 0)."""
    path = run_dir / "checkpoint.pt"
    return read_checkpoint(path) if path.exists() else None


def save_tensors(path: Path, tree: dict) -> None:
    """torch.save of the tree's tensors moved to the CPU, atomically (atomic_write)."""
    atomic_write(path, lambda tmp: torch.save(on_cpu(tree), tmp))


def save_checkpoint(run_dir: Path, state: dict) -> None:
    save_tensors(run_dir / "checkpoint.pt", state)


# Resuming exactly: the episode under way.


class EpisodeRecord(gym.Wrapper):
    """Remembers how the current episode began (its reset seed, or the env's random state before
    an unseeded reset) and every action since, so that a checkpoint taken mid-episode rebuilds
    the episode exactly: `replay` resets the same way and steps the same actions (MuJoCo is
    deterministic). Any gymnasium env, whatever state it keeps."""

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        rng = None if seed is not None else self.env.unwrapped.np_random.bit_generator.state
        self.record = {"seed": seed, "rng": copy.deepcopy(rng), "actions": []}
        return self.env.reset(seed=seed, options=options)

    def step(self, action):
        self.record["actions"].append(np.array(action, copy=True))
        return self.env.step(action)

    def replay(self) -> np.ndarray:
        """Rebuilds the episode of `self.record` (a checkpoint's, put there by the vector env's
        set_attr) and returns its current observation."""
        seed, rng = self.record["seed"], self.record["rng"]
        actions = [np.asarray(a) for a in self.record["actions"]]
        if rng is not None:
            self.env.unwrapped.np_random.bit_generator.state = rng
        obs, _ = self.env.reset(seed=seed)
        for action in actions:
            obs = self.env.step(action)[0]
        self.record = {"seed": seed, "rng": rng, "actions": actions}
        return obs


def episode_state(record: dict, action_dim: int) -> dict:
    """An EpisodeRecord's record for a checkpoint: the actions as one tensor (weights_only), in
    the dtype numpy promotes them to, which holds each exactly (a float32 policy action and a
    float64 random one in one episode: float64), so the replay steps the very same actions."""
    actions = np.array(record["actions"]).reshape(len(record["actions"]), action_dim)
    return {"seed": record["seed"], "rng": record["rng"], "actions": torch.from_numpy(actions)}


def pending_round_state(round_) -> dict:
    """An evaluation round that a stop left unfinished, as its checkpoint keeps it: everything
    the resumed run needs to rerun it exactly (the round is a function of these and the run's
    arguments)."""
    return {"global_step": round_.info["global_step"], "wall_time": round_.info["wall_time"],
            "actor": round_.actor.state_dict(),
            "qf": None if round_.critic is None else round_.critic.state_dict()}


def fit_shapes(state: dict, like: dict) -> dict:
    """A checkpoint's tensors in the shapes of the run's own (`like`, by name): checkpoints
    written between --num-seeds and its removal (issue 37) hold each with a leading seed axis of
    1, and the same numbers."""
    return {k: v.reshape(like[k].shape) if k in like else v for k, v in state.items()}


# The scripts' run folders, from start to finish: named, written fresh or resumed, logged to,
# checkpointed and finished.


def run_dir(args, algorithm: str) -> Path:
    """With --resume, the folder given (wherever it is now: a copy resumes the copy); else a
    fresh one, --run-name or the default name under --output-dir, which must not hold a run."""
    if args.resume is not None:
        return Path(args.resume)
    name = args.run_name or (f"{args.env_id}__{algorithm}__seed{args.seed}__"
                             f"{time.strftime('%Y%m%d-%H%M%S')}")
    path = Path(args.output_dir) / name
    if (path / "config.json").exists():
        fail(f"{path} already holds a run; continue it with --resume {path} or choose another "
             "--run-name")
    return path


def write_config(args, run_dir: Path, obs_dim: int, action_dim: int, algorithm: str,
                 script: str, device: torch.device) -> None:
    """config.json (run_metadata), at a fresh start; TensorBoard files of an earlier start are
    removed (a restart from step 0)."""
    for old in run_dir.glob("events.out.tfevents.*"):
        old.unlink()
    config = run_metadata(args, obs_dim, action_dim, algorithm, script, device)
    atomic_write(run_dir / "config.json",
                 lambda tmp: tmp.write_text(json.dumps(config, indent=2)))


def new_progress() -> dict:
    """The training episodes as train.csv reports them, and the last evaluation."""
    return {"episode_returns": [], "episode_lengths": [], "last_eval": None,
            "episode_return": 0.0, "episode_length": 0}


def count_episode(progress: dict, reward: float, episode_end: bool) -> None:
    """Adds a step's reward to the episode under way; an ended one joins the list that the next
    train.csv row averages."""
    progress["episode_return"] += float(reward)
    progress["episode_length"] += 1
    if episode_end:
        progress["episode_returns"].append(progress["episode_return"])
        progress["episode_lengths"].append(progress["episode_length"])
        progress["episode_return"], progress["episode_length"] = 0.0, 0


def progress_line(global_step: int, total: int, elapsed: float, progress: dict) -> str:
    """The line printed every --print-interval steps."""
    last = progress["last_eval"]
    return (f"step {global_step:,}/{total:,} | {global_step / elapsed:.0f} SPS | "
            + (f"last eval {last[1]:.1f} at step {last[0]:,}" if last else "no eval yet"))


def open_logs(args, run_dir: Path, eval_header: list[str], train_header: list[str],
              global_step: int, resumed: bool, algorithm: str) -> dict:
    """The eval.csv and train.csv writers (a resume keeps their rows up to its step),
    TensorBoard and, with --track, W&B."""
    keep = global_step if resumed else None
    tb = SummaryWriter(run_dir, purge_step=global_step + 1 if resumed else None)
    if not resumed:
        tb.add_text("hyperparameters", "|param|value|\n|-|-|\n" + "\n".join(
            f"|{name}|{value}|" for name, value in dataclasses.asdict(args).items()))
    return {"eval": open_csv(run_dir / "eval.csv", eval_header, keep),
            "train": open_csv(run_dir / "train.csv", train_header, keep), "tb": tb,
            "tracker": start_tracking(args, run_dir, algorithm)}


def close_logs(logs: dict) -> None:
    logs["tb"].close()
    if logs["tracker"] is not None:
        logs["tracker"].finish()
    for f, _ in (logs["eval"], logs["train"]):
        f.close()


def checkpoint(args, global_step: int, elapsed: float, progress: dict,
               networks: dict[str, nn.Module], log_alpha: torch.Tensor,
               optimizers: dict[str, torch.optim.Optimizer], buffer, action_space: gym.Space,
               episode: dict, rng: dict, unfinished: list) -> dict:
    """checkpoint.pt: the networks, temperature, optimizers and replay buffer, and what an exact
    resume needs besides (the random states, the episode under way, the evaluation rounds a
    stop left unfinished)."""
    return {"args": dataclasses.asdict(args), "global_step": global_step, "elapsed": elapsed,
            "progress": progress,
            **{name: net.state_dict() for name, net in networks.items()},
            "log_alpha": log_alpha.detach().clone(),
            **{name: opt.state_dict() for name, opt in optimizers.items()},
            "buffer": buffer.state_dict(),
            "rng": rng | {"action_space": action_space.np_random.bit_generator.state,
                          "episode": episode_state(episode, action_space.shape[0])},
            "pending_rounds": [pending_round_state(r) for r in unfinished]}


def load_checkpoint(ckpt: dict, networks: dict[str, nn.Module], log_alpha: torch.Tensor,
                    optimizers: dict[str, torch.optim.Optimizer], buffer,
                    action_space: gym.Space, device: torch.device) -> tuple[int, float, dict]:
    """The run's state from its checkpoint (checkpoint); returns the step, the training time so
    far and the progress."""
    for name, net in networks.items():
        net.load_state_dict(fit_shapes(ckpt[name], net.state_dict()))
    for name, optimizer in optimizers.items():
        params, state = optimizer.param_groups[0]["params"], ckpt[name]
        optimizer.load_state_dict({"state": {
            i: fit_shapes(s, {"exp_avg": params[i], "exp_avg_sq": params[i]})
            for i, s in state["state"].items()}, "param_groups": state["param_groups"]})
        for group in optimizer.param_groups:
            group["capturable"] = device.type == "cuda"  # the checkpoint's is its device's
    with torch.no_grad():
        log_alpha.copy_(ckpt["log_alpha"].reshape(log_alpha.shape))
    buffer.load_state_dict(ckpt["buffer"])
    action_space.np_random.bit_generator.state = ckpt["rng"]["action_space"]
    set_rng_states(ckpt["rng"], device)
    return ckpt["global_step"], ckpt["elapsed"], ckpt["progress"]


def replay_episode(envs: gym.vector.VectorEnv, seed: int, ckpt: dict) -> np.ndarray:
    """The episode so far, replayed (the checkpoint may fall mid-episode); returns the
    observations the run goes on from."""
    envs.reset(seed=seed)
    envs.set_attr("record", [ckpt["rng"]["episode"]])
    return np.stack(envs.call("replay"))


def pending_round_networks(actor: nn.Module, qf: nn.Module,
                           state: dict) -> tuple[nn.Module, nn.Module]:
    """CPU copies of the networks as an unfinished evaluation round had them
    (pending_round_state)."""
    round_actor, round_qf = copy.deepcopy(actor).cpu(), copy.deepcopy(qf).cpu()
    round_actor.load_state_dict(fit_shapes(state["actor"], round_actor.state_dict()))
    if state["qf"] is not None:
        round_qf.load_state_dict(fit_shapes(state["qf"], round_qf.state_dict()))
    return round_actor, round_qf


def finish_run(run_dir: Path, logs: dict, final_model: dict, global_step: int,
               wall_time: float) -> None:
    """final_model.pt, the logs closed, and done.json last: a folder with done.json is a
    finished run (sweep.py skips it)."""
    save_tensors(run_dir / "final_model.pt", final_model)
    close_logs(logs)
    atomic_write(run_dir / "done.json", lambda tmp: tmp.write_text(json.dumps(
        {"global_step": global_step, "wall_time": wall_time})))


def save_snapshot(run_dir: Path, model: dict, global_step: int) -> None:
    """The weights at this step, as final_model.pt holds them. Written atomically, so a run
    killed mid-write leaves the last whole one; a resumed run rewrites the snapshots after its
    checkpoint with the same numbers."""
    (run_dir / "snapshots").mkdir(exist_ok=True)
    save_tensors(run_dir / "snapshots" / f"step{global_step}.pt", model)


def check_finite(x: np.ndarray, what: str) -> None:
    if not np.isfinite(x).all():
        raise SystemExit(f"non-finite {what} (NaN/inf): training diverged; try lower learning "
                         "rates or resume from an earlier checkpoint")


def train_statistics(progress: dict, losses: tuple[torch.Tensor, ...] | None) -> dict:
    """train.csv's statistics: the last update's losses (sac_losses's logs; none before learning
    starts) and the training episodes that ended since the previous row (taken out of
    `progress`)."""
    returns, lengths = progress["episode_returns"], progress["episode_lengths"]
    row = {"episodes": len(returns),
           "episode_return_mean": np.mean(returns) if returns else None,
           "episode_length_mean": np.mean(lengths) if lengths else None}
    returns.clear()
    lengths.clear()
    if losses is not None:
        qf_losses, qf_values, actor_loss, alpha, alpha_loss, log_pi = losses
        check_finite(qf_losses.detach().cpu().numpy(), "critic loss")
        row |= {"qf1_loss": qf_losses[0].item(), "qf2_loss": qf_losses[1].item(),
                "qf1_value": qf_values[0].mean().item(), "qf2_value": qf_values[1].mean().item(),
                "actor_loss": actor_loss.item(), "alpha": alpha.item(),
                "alpha_loss": alpha_loss.item(), "entropy": -log_pi.mean().item()}
    return row
