"""The restart from a snapshot (`sweep.py restart`), for a run whose checkpoint is lost: its
checkpoint.pt rebuilt from its last snapshot, so that `--resume` continues it (docs/scripts.md).
"""

import csv
import dataclasses
import importlib
import json
import random
import time
from pathlib import Path

import numpy as np
import torch

from sac_utils.checkpoints import (
    checkpoint_state,
    policy_weights,
    read_checkpoint,
    rng_states,
    save_tensors,
)
from sac_utils.cli import fail, read_config_json, stored_args
from sac_utils.files import atomic_write, complete_lines
from sac_utils.policies import to_linear_layout
from sac_utils.run_folder import git_commit, machine


def restart_from_snapshot(run_dir: Path, refill: int) -> dict:
    """Writes run_dir/checkpoint.pt from the run's last snapshot, so that `--resume` continues
    it: the snapshot's actor, critics (their target a copy of them) and log alpha, Adam's moments
    from zero, an empty replay buffer that the run refills by acting with its policy for `refill`
    steps (counted as the run's steps, as --learning-starts' are) before updates resume, random
    streams from the seed and the step. A new sample from that step, not the lost run's future:
    config.json's "restarts" records it; train.csv and eval.csv as they were are kept in
    restarts/step<N>/ (the resume cuts them back to the step). Returns the restart's record."""
    if (run_dir / "done.json").exists():
        fail(f"{run_dir} is finished (done.json); there is nothing to restart")
    if (run_dir / "checkpoint.pt").exists():
        fail(f"{run_dir} has its checkpoint.pt: continue it exactly with --resume {run_dir} "
             "(a restart from a snapshot is for a run whose checkpoint is lost)")
    config = read_config_json(run_dir, "give a run folder made by sac_standard.py or "
                              "sac_corrected.py", "restore it from a copy")
    snapshots = sorted((p for p in run_dir.glob("snapshots/step*.pt")
                        if p.stem.removeprefix("step").isdigit()), key=lambda p: int(p.stem[4:]))
    if not snapshots:
        fail(f"{run_dir} has no snapshots/step<N>.pt to restart from; --resume {run_dir} "
             "restarts it from step 0")
    path, step = snapshots[-1], int(snapshots[-1].stem[4:])
    snapshot = torch.load(path, map_location="cpu", weights_only=True)
    snapshot |= {part: to_linear_layout(snapshot[part]) for part in ("actor", "qf")}
    if "log_alpha" not in snapshot:
        fail(f"{path} holds no log alpha (written before snapshots did): it evaluates, but a run "
             f"cannot go on from it; --resume {run_dir} restarts the run from step 0")
    if refill < 1:
        fail(f"--refill {refill}: must be at least 1 (steps of acting before updates resume)")

    script = importlib.import_module(Path(config["script"]).stem)
    args = dataclasses.replace(script.Args(), **stored_args(script.Args, config))
    action_space = script.make_env(args.env_id).action_space
    obs_dim, action_dim = config["obs_dim"], action_space.shape[0]
    agent = script.make_agent(args, obs_dim, action_space, torch.device("cpu"))
    agent["actor"].load_state_dict(snapshot["actor"])
    agent["qf"].load_state_dict(snapshot["qf"])
    agent["qf_target"].load_state_dict(snapshot["qf"])
    with torch.no_grad():
        agent["log_alpha"].copy_(snapshot["log_alpha"])

    seed = int(np.random.SeedSequence([args.seed, step]).generate_state(1)[0])
    random.seed(seed)
    np.random.seed(seed)  # noqa: NPY002
    torch.manual_seed(seed)
    action_space.seed(seed)
    train_rows = logged_rows(run_dir / "train.csv", step)
    eval_rows = logged_rows(run_dir / "eval.csv", step)
    last_eval = eval_rows[-1] if eval_rows else None
    progress = {"episode_returns": [], "episode_lengths": [], "episode_return": 0.0,
                "episode_length": 0, "updates_from": min(step + refill, args.total_timesteps),
                "last_eval": last_eval and (int(last_eval["global_step"]),
                                            float(last_eval["return_mean"]))}
    elapsed = float(train_rows[-1]["wall_time"]) if train_rows else 0.0
    state = checkpoint_state(args, step, elapsed, progress, agent,
                             script.ReplayBuffer(2, obs_dim, action_dim, torch.device("cpu")),
                             action_space, {"seed": seed, "rng": None, "actions": []},
                             rng_states(torch.device("cpu")), [])
    if step % args.eval_interval == 0 and not (last_eval and int(last_eval["global_step"]) == step):
        state["pending_rounds"] = [{"global_step": step, "wall_time": elapsed,
                                    "actor": snapshot["actor"], "qf": snapshot["qf"]}]

    kept = run_dir / "restarts" / f"step{step}"
    kept.mkdir(parents=True, exist_ok=True)
    for name in ("train.csv", "eval.csv"):
        if (run_dir / name).exists():
            atomic_write(kept / name, lambda tmp, name=name: tmp.write_bytes(
                (run_dir / name).read_bytes()))
    record = {"step": step, "snapshot": str(path.relative_to(run_dir)), "refill": refill,
              "updates_from": progress["updates_from"], "seed": seed,
              "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
              "machine": machine(),
              "git_commit": git_commit()}
    save_tensors(run_dir / "checkpoint.pt", state)
    config["restarts"] = [*config.get("restarts", []), record]
    atomic_write(run_dir / "config.json", lambda tmp: tmp.write_text(json.dumps(config, indent=2)))
    return record


def logged_rows(path: Path, step: int) -> list[dict]:
    """A run CSV's whole rows up to `step` (none if the file is missing)."""
    if not path.exists():
        return []
    return [r for r in csv.DictReader(complete_lines(path)) if int(r["global_step"]) <= step]


def snapshot_from_checkpoint(run_dir: Path, out_dir: Path) -> int:
    """Writes out_dir/step<N>.pt, a snapshot of a stopped run's checkpoint, and returns N: small
    enough to commit, it lets `sweep.py restart` go on if the checkpoint is lost."""
    ckpt = read_checkpoint(run_dir / "checkpoint.pt")
    step = ckpt["global_step"]
    out_dir.mkdir(parents=True, exist_ok=True)
    save_tensors(out_dir / f"step{step}.pt", policy_weights(ckpt["actor"], ckpt["qf"],
                                                            ckpt["args"], ckpt["log_alpha"]))
    return step
