"""A run folder's files, for sac_standard.py and sac_corrected.py: config.json, the CSV logs
(written row by row), TensorBoard and W&B, checkpoints (written atomically, a batch's in two
phases; what each seed's holds: seed_checkpoint), the folder's lock, the random states, the
graceful stop on a signal, and what an exact resume needs: the episode under way (EpisodeRecord)
and each seed's part of the batch's networks and optimisers. Also the training loop's
bookkeeping: the episodes and statistics train.csv reports, the progress line.

None of it is the algorithm: the two scripts hold that, top to bottom. The layout of a run folder
is described in docs/scripts.md ("The run folder").
"""

import copy
import csv
import dataclasses
import fcntl
import json
import multiprocessing
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


def resume_batch_dirs(given: Path, algorithm: str) -> list[Path]:
    """The folders of the batch that `given` belongs to, each checked before anything is written.

    A run folder is found by where it is now, never by where it was made: a single-seed folder
    is its own batch under any name and path (a copy resumes the copy); the K folders of a
    --num-seeds batch resume together, found beside `given` by the names config.json records."""
    config = read_run_config(given, algorithm)
    batch = config.get("batch", {"first_seed": config.get("seed"), "run_dirs": [given.name]})
    names = batch["run_dirs"]
    if len(names) == 1:
        return [given]
    made_as = names[config["seed"] - batch["first_seed"]]
    if given.name != made_as:
        fail(f"{given} was made as {made_as}, one of a batch of {len(names)} seeds trained "
             f"together ({', '.join(names)}); they resume together, side by side under their own "
             "names: copy or move the whole batch, and resume any one of its folders")
    dirs = [given.parent / name for name in names]
    for run_dir in dirs:
        if not (run_dir / "config.json").is_file():
            fail(f"{run_dir} is missing: the batch of {given} ({len(names)} seeds) resumes only "
                 "with all its folders side by side; put it back beside the others")
        if read_run_config(run_dir, algorithm).get("batch") != batch:
            fail(f"{run_dir} is not a run of the batch {given} belongs to (its config.json "
                 "names another batch); restore the folder, or move it back where it was")
    return dirs


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
    # create_new: the seeds of a batch are W&B runs side by side in one process.
    tracker = wandb.init(reinit="create_new", project=args.wandb_project_name,
                         entity=args.wandb_entity,
                         group=args.wandb_group, name=run_dir.name, dir=run_dir,
                         id=id_file.read_text().strip(), resume="allow",
                         config=dataclasses.asdict(args) | {"algorithm": algorithm})
    tracker.define_metric("*", step_metric="global_step")
    return tracker


def run_metadata(args, obs_dim: int, action_dim: int, algorithm: str, script: str) -> dict:
    """config.json: every argument, the algorithm, the library versions and the git commit."""
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
            "start_time": time.strftime("%Y-%m-%dT%H:%M:%S%z")}


def lock_run_folders(dirs: list[Path]) -> list[int]:
    """An exclusive OS lock on each run_dir/lock, held while this process lives: one writer per
    run folder (a Slurm requeue racing a job that has not died yet, a sweep started twice). The
    kernel drops it when the process dies, SIGKILL included, so it is never stale. Returns the
    fds, for record_holder once the folders have been checked. A refusal changes nothing: the
    folders and lock files made here for it are removed again."""
    fds, made = [], []
    for run_dir in dirs:
        if not run_dir.exists():
            made.append(run_dir)
        run_dir.mkdir(parents=True, exist_ok=True)
        fd = os.open(run_dir / "lock", os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
            for mine in made:
                (mine / "lock").unlink(missing_ok=True)
                mine.rmdir()
            then = "then --resume" if (run_dir / "config.json").exists() else \
                "or choose another --run-name"
            fail(f"{run_dir} is in use by process {holder} (it holds {run_dir / 'lock'}); let it "
                 f"finish or stop it, {then}")
        fds.append(fd)
    return fds


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


def ignore_stop_signals_in_worker() -> None:
    """In an env worker process (not in the trainer): the signals that stop a run are left to
    the trainer, which checkpoints and then stops its workers."""
    if multiprocessing.parent_process() is not None:
        for s in (signal.SIGINT, signal.SIGTERM, signal.SIGUSR1, signal.SIGUSR2):
            signal.signal(s, signal.SIG_IGN)


def rng_states(device: torch.device) -> dict:
    """The process's random streams (the batch's): torch draws the actions and batches of every
    seed. Nothing of ours uses the global numpy and python generators; libraries might. The CUDA
    generators only for a run on CUDA: reading them elsewhere would create a CUDA context (and
    fail on a GPU in exclusive-process mode that another process holds)."""
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


def read_batch_checkpoints(dirs: list[Path]) -> list[dict] | None:
    """Every seed's checkpoint.pt, all at one step; None where the batch has none yet.

    A batch checkpoint is written in two phases (see save_batch_checkpoint): every seed's
    checkpoint.pt.tmp first, then each is moved into place. A kill in the second phase leaves
    some seeds at the new step and the others' complete .tmp files: those are moved in now."""
    paths = [d / "checkpoint.pt" for d in dirs]
    if not any(p.exists() for p in paths):
        return None
    steps = {p: read_checkpoint(p)["global_step"] if p.exists() else None for p in paths}
    newest = max(s for s in steps.values() if s is not None)
    for path, step in steps.items():
        tmp = path.with_name(path.name + ".tmp")
        if step != newest and tmp.exists() and read_checkpoint(tmp)["global_step"] == newest:
            os.replace(tmp, path)
        elif step != newest:
            fail(f"{path} is {'missing' if step is None else f'at step {step}'} while the batch "
                 f"it belongs to checkpointed at step {newest}; restore it, or delete the batch's "
                 "checkpoint.pt files to restart it from step 0")
    return [read_checkpoint(p) for p in paths]


def save_batch_checkpoint(dirs: list[Path], states: list[dict]) -> None:
    """Every seed's checkpoint.pt, in two phases so that a kill leaves the batch resumable: all
    the .tmp files first, then the moves (read_batch_checkpoints finishes an interrupted one)."""
    tmps = [d / "checkpoint.pt.tmp" for d in dirs]
    for tmp, state in zip(tmps, states, strict=True):
        torch.save(on_cpu(state), tmp)
    for tmp in tmps:
        os.replace(tmp, tmp.with_name("checkpoint.pt"))


# Resuming exactly: the episode under way, and each seed's part of the batch's networks.


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


def seed_slice(module: nn.Module, k: int) -> nn.Module:
    """Seed k's networks alone, as a K = 1 module that shares no tensor with the batch."""
    memo = {id(p): nn.Parameter(p.detach()[k:k + 1].clone(), p.requires_grad)
            for p in module.parameters()}
    return copy.deepcopy(module, memo)


def load_seed_states(module: nn.Module, states: list[dict]) -> None:
    """The batch's parameters from each seed's K = 1 state dict (seed_slice's layout)."""
    params = dict(module.named_parameters())
    module.load_state_dict({n: torch.cat([s[n] for s in states]) if n in params else v
                            for n, v in states[0].items()})


def optimizer_seed_state(optimizer: torch.optim.Optimizer, k: int) -> dict:
    """Seed k's part of an optimizer over stacked parameters (its step counts are shared)."""
    state = optimizer.state_dict()
    return {"state": {i: {n: (v if v.dim() == 0 else v[k:k + 1]).clone() for n, v in s.items()}
                      for i, s in state["state"].items()},
            "param_groups": state["param_groups"]}


def load_optimizer_seed_states(optimizer: torch.optim.Optimizer, states: list[dict]) -> None:
    optimizer.load_state_dict({
        "state": {i: {n: v.clone() if v.dim() == 0
                      else torch.cat([s["state"][i][n] for s in states])
                      for n, v in state.items()} for i, state in states[0]["state"].items()},
        "param_groups": states[0]["param_groups"]})


# The scripts' run folders, from start to finish: named, written fresh or resumed, logged to,
# checkpointed and finished.


def run_dirs(args, algorithm: str) -> list[Path]:
    """Each seed's run folder: --run-name with {seed} filled in, or the default name."""
    name = args.run_name or (f"{args.env_id}__{algorithm}__seed{{seed}}__"
                             f"{time.strftime('%Y%m%d-%H%M%S')}")
    return [Path(args.output_dir) / name.replace("{seed}", str(args.seed + k))
            for k in range(args.num_seeds)]


def batch_run_dirs(args, algorithm: str) -> list[Path]:
    """With --resume, the folders of the batch the given one belongs to, each checked before
    anything is written; else fresh folders, none of which may hold a run."""
    if args.resume is None:
        dirs = run_dirs(args, algorithm)
        for run_dir in dirs:
            if (run_dir / "config.json").exists():
                fail(f"{run_dir} already holds a run; continue it with --resume {run_dir} or "
                     "choose another --run-name")
        return dirs
    return resume_batch_dirs(Path(args.resume), algorithm)


def write_configs(args, dirs: list[Path], obs_dim: int, action_dim: int, algorithm: str,
                  script: str) -> None:
    """Each seed's config.json (run_metadata, and the batch it is trained in), at a fresh start;
    TensorBoard files of an earlier start are removed (a restart from step 0)."""
    batch = {"first_seed": args.seed, "num_seeds": args.num_seeds,
             "run_dirs": [d.name for d in dirs]}
    for k, run_dir in enumerate(dirs):
        for old in run_dir.glob("events.out.tfevents.*"):
            old.unlink()
        config = run_metadata(dataclasses.replace(args, seed=args.seed + k), obs_dim, action_dim,
                              algorithm, script)
        atomic_write(run_dir / "config.json", lambda tmp, c=config: tmp.write_text(
            json.dumps(c | {"batch": batch}, indent=2)))


def new_progress() -> dict:
    """A seed's training episodes as train.csv reports them, and its last evaluation."""
    return {"episode_returns": [], "episode_lengths": [], "last_eval": None,
            "episode_return": 0.0, "episode_length": 0}


def count_episodes(progress: list[dict], reward: np.ndarray, episode_end: np.ndarray) -> None:
    """Adds a step's rewards to each seed's episode under way; an ended one joins the list that
    the next train.csv row averages."""
    for k, seed_progress in enumerate(progress):
        seed_progress["episode_return"] += float(reward[k])
        seed_progress["episode_length"] += 1
        if episode_end[k]:
            seed_progress["episode_returns"].append(seed_progress["episode_return"])
            seed_progress["episode_lengths"].append(seed_progress["episode_length"])
            seed_progress["episode_return"], seed_progress["episode_length"] = 0.0, 0


def progress_line(global_step: int, total: int, elapsed: float, progress: list[dict]) -> str:
    """The line printed every --print-interval steps."""
    last = [p["last_eval"] for p in progress if p["last_eval"] is not None]
    return (f"step {global_step:,}/{total:,} | {global_step / elapsed:.0f} SPS per seed | "
            + (f"last eval {np.mean([r for _, r in last]):.1f}"
               + (f" (mean over {len(last)} seeds)" if len(last) > 1 else "")
               + f" at step {last[0][0]:,}" if last else "no eval yet"))


def open_logs(args, dirs: list[Path], eval_header: list[str], train_header: list[str],
              global_step: int, resumed: bool, algorithm: str) -> list[dict]:
    """Per seed: the eval.csv and train.csv writers (a resume keeps their rows up to its step),
    TensorBoard and, with --track, W&B."""
    logs = []
    keep = global_step if resumed else None
    for k, run_dir in enumerate(dirs):
        tb = SummaryWriter(run_dir, purge_step=global_step + 1 if resumed else None)
        if not resumed:
            tb.add_text("hyperparameters", "|param|value|\n|-|-|\n" + "\n".join(
                f"|{name}|{value}|" for name, value in dataclasses.asdict(args).items()))
        logs.append({"eval": open_csv(run_dir / "eval.csv", eval_header, keep),
                     "train": open_csv(run_dir / "train.csv", train_header, keep), "tb": tb,
                     "tracker": start_tracking(dataclasses.replace(args, seed=args.seed + k),
                                               run_dir, algorithm)})
    return logs


def close_logs(logs: list[dict]) -> None:
    for log in logs:
        log["tb"].close()
        if log["tracker"] is not None:
            log["tracker"].finish()
        for f, _ in (log["eval"], log["train"]):
            f.close()


def seed_checkpoint(k: int, args, global_step: int, elapsed: float, progress: dict,
                    networks: dict[str, nn.Module], log_alpha: torch.Tensor,
                    optimizers: dict[str, torch.optim.Optimizer], buffer, space: gym.Space,
                    episode: dict, rng: dict, unfinished: list) -> dict:
    """Seed k's checkpoint.pt: its part of the batch's networks, temperature, optimizers and
    replay buffer, and what an exact resume needs besides (the random states, the episode under
    way, the evaluation rounds a stop left unfinished)."""
    return {"args": dataclasses.asdict(args), "global_step": global_step, "elapsed": elapsed,
            "progress": progress,
            **{name: seed_slice(net, k).state_dict() for name, net in networks.items()},
            "log_alpha": log_alpha.detach()[k:k + 1].clone(),
            **{name: optimizer_seed_state(opt, k) for name, opt in optimizers.items()},
            "buffer": buffer.seed_state_dict(k),
            "rng": rng | {"action_space": space.np_random.bit_generator.state,
                          "episode": episode_state(episode, space.shape[0])},
            "pending_rounds": [pending_round_state(r) for r in unfinished
                               if r.info["seed_index"] == k]}


def load_checkpoints(ckpts: list[dict], networks: dict[str, nn.Module], log_alpha: torch.Tensor,
                     optimizers: dict[str, torch.optim.Optimizer], buffer, spaces: list,
                     device: torch.device) -> tuple[int, float, list[dict]]:
    """The batch's state from its seeds' checkpoints (seed_checkpoint); returns the step, the
    training time so far and each seed's progress."""
    for name, net in networks.items():
        load_seed_states(net, [c[name] for c in ckpts])
    for name, optimizer in optimizers.items():
        load_optimizer_seed_states(optimizer, [c[name] for c in ckpts])
        for group in optimizer.param_groups:
            group["capturable"] = device.type == "cuda"  # the checkpoint's is its device's
    with torch.no_grad():
        log_alpha.copy_(torch.cat([c["log_alpha"] for c in ckpts]))
    for k, ckpt in enumerate(ckpts):
        buffer.load_seed_state_dict(k, ckpt["buffer"])
        spaces[k].np_random.bit_generator.state = ckpt["rng"]["action_space"]
    set_rng_states(ckpts[0]["rng"], device)
    return ckpts[0]["global_step"], ckpts[0]["elapsed"], [c["progress"] for c in ckpts]


def replay_episodes(envs: gym.vector.VectorEnv, seeds: list[int], ckpts: list[dict]) -> np.ndarray:
    """Every env's episode so far, replayed (the checkpoint may fall mid-episode); returns the
    observations the run goes on from."""
    envs.reset(seed=seeds)
    envs.set_attr("record", [c["rng"]["episode"] for c in ckpts])
    return np.stack(envs.call("replay"))


def pending_round_networks(actor: nn.Module, qf: nn.Module, k: int,
                           state: dict) -> tuple[nn.Module, nn.Module]:
    """Seed k's networks as an unfinished evaluation round had them (pending_round_state)."""
    seed_actor, seed_qf = seed_slice(actor, k).cpu(), seed_slice(qf, k).cpu()
    seed_actor.load_state_dict(state["actor"])
    if state["qf"] is not None:
        seed_qf.load_state_dict(state["qf"])
    return seed_actor, seed_qf


def finish_runs(dirs: list[Path], logs: list[dict], final_models: list[dict], global_step: int,
                wall_time: float) -> None:
    """Each seed's final_model.pt, its logs closed, and done.json last: a folder with done.json
    is a finished run (sweep.py skips it)."""
    for run_dir, model in zip(dirs, final_models, strict=True):
        atomic_write(run_dir / "final_model.pt", lambda tmp, m=model: torch.save(on_cpu(m), tmp))
    close_logs(logs)
    for run_dir in dirs:
        atomic_write(run_dir / "done.json", lambda tmp: tmp.write_text(json.dumps(
            {"global_step": global_step, "wall_time": wall_time})))


def snapshot_path(run_dir: Path, global_step: int) -> Path:
    return run_dir / "snapshots" / f"step{global_step}.pt"


def save_snapshots(dirs: list[Path], models: list[dict], global_step: int) -> None:
    """Each seed's weights at this step, as final_model.pt holds them. Written atomically, so a
    run killed mid-write leaves the last whole one; a resumed run rewrites the snapshots after its
    checkpoint with the same numbers."""
    for run_dir, model in zip(dirs, models, strict=True):
        path = snapshot_path(run_dir, global_step)
        path.parent.mkdir(exist_ok=True)
        atomic_write(path, lambda tmp, m=model: torch.save(on_cpu(m), tmp))


def check_finite(x: np.ndarray, what: str) -> None:
    if not np.isfinite(x).all():
        raise SystemExit(f"non-finite {what} (NaN/inf): training diverged; try lower learning "
                         "rates or resume from an earlier checkpoint")


def train_statistics(progress: dict, losses: tuple[torch.Tensor, ...] | None, k: int) -> dict:
    """Seed k's train.csv statistics: the last update's losses (sac_losses's logs; none before
    learning starts) and the training episodes that ended since the previous row (taken out of
    its `progress`)."""
    returns, lengths = progress["episode_returns"], progress["episode_lengths"]
    row = {"episodes": len(returns),
           "episode_return_mean": np.mean(returns) if returns else None,
           "episode_length_mean": np.mean(lengths) if lengths else None}
    returns.clear()
    lengths.clear()
    if losses is not None:
        qf_losses, qf_values, actor_losses, alpha, alpha_losses, log_pi = losses
        check_finite(qf_losses[:, k].detach().cpu().numpy(), "critic loss")
        row |= {"qf1_loss": qf_losses[0, k].item(), "qf2_loss": qf_losses[1, k].item(),
                "qf1_value": qf_values[0, k].mean().item(),
                "qf2_value": qf_values[1, k].mean().item(), "actor_loss": actor_losses[k].item(),
                "alpha": alpha[k].item(), "alpha_loss": alpha_losses[k].item(),
                "entropy": -log_pi[k].mean().item()}
    return row
