"""What a run keeps on disk as tensors, and what an exact resume needs: checkpoint.pt (the
networks, temperature, optimizers, replay buffer, random states, the episode under way and the
evaluation rounds a stop left unfinished), read back and checked; the weights files
(final_model.pt, snapshots), all written atomically as CPU tensors.

An exact resume: a run killed at any point and resumed from its last checkpoint computes what the
uninterrupted run computes, bit for bit (tests/test_sac.py). RunFolder (run_folder.py) calls
this module; the scripts do not.
"""

import copy
import dataclasses
import os
import random
from collections.abc import Callable
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn

from flags import fail

CHECKPOINT_KEYS = ("args", "global_step", "elapsed", "progress", "actor", "qf", "qf_target",
                   "log_alpha", "q_optimizer", "actor_optimizer", "alpha_optimizer", "buffer",
                   "rng")


def atomic_write(path: Path, write: Callable[[Path], object]) -> None:
    """Writes via a temporary file and os.replace: a kill leaves the old file or the new one."""
    tmp = path.with_name(path.name + ".tmp")
    write(tmp)
    os.replace(tmp, path)


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


def save_tensors(path: Path, tree: dict) -> None:
    """torch.save of the tree's tensors moved to the CPU, atomically (atomic_write)."""
    atomic_write(path, lambda tmp: torch.save(on_cpu(tree), tmp))


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


def find_checkpoint(run_dir: Path) -> dict | None:
    """The run's checkpoint.pt, or None where it has none yet (it restarts from step 0)."""
    path = run_dir / "checkpoint.pt"
    return read_checkpoint(path) if path.exists() else None


# The random streams and the episode under way.


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


def replay_episode(envs: gym.vector.VectorEnv, seed: int, ckpt: dict) -> np.ndarray:
    """The episode so far, replayed (the checkpoint may fall mid-episode); returns the
    observations the run goes on from."""
    envs.reset(seed=seed)
    envs.set_attr("record", [ckpt["rng"]["episode"]])
    return np.stack(envs.call("replay"))


# Evaluation rounds that a stop left unfinished.


def pending_round_state(round_) -> dict:
    """An evaluation round that a stop left unfinished, as its checkpoint keeps it: everything
    the resumed run needs to rerun it exactly (the round is a function of these and the run's
    arguments)."""
    return {"global_step": round_.info["global_step"], "wall_time": round_.info["wall_time"],
            "actor": round_.actor.state_dict(),
            "qf": None if round_.critic is None else round_.critic.state_dict()}


def pending_round_networks(actor: nn.Module, qf: nn.Module,
                           state: dict) -> tuple[nn.Module, nn.Module]:
    """CPU copies of the networks as an unfinished evaluation round had them
    (pending_round_state)."""
    round_actor, round_qf = copy.deepcopy(actor).cpu(), copy.deepcopy(qf).cpu()
    round_actor.load_state_dict(fit_shapes(state["actor"], round_actor.state_dict()))
    if state["qf"] is not None:
        round_qf.load_state_dict(fit_shapes(state["qf"], round_qf.state_dict()))
    return round_actor, round_qf


def fit_shapes(state: dict, like: dict) -> dict:
    """A checkpoint's tensors in the shapes of the run's own (`like`, by name): checkpoints
    written between --num-seeds and its removal (issue 37) hold each with a leading seed axis of
    1, and the same numbers."""
    return {k: v.reshape(like[k].shape) if k in like else v for k, v in state.items()}


# The checkpoint as a whole.


def checkpoint_state(args, global_step: int, elapsed: float, progress: dict, training: dict,
                     buffer, action_space: gym.Space, episode: dict, rng: dict,
                     unfinished: list) -> dict:
    """checkpoint.pt: the networks, temperature and optimizers (`training`, by their names in the
    file: modules and optimizers by state_dict, log_alpha as a tensor), the replay buffer, and what
    an exact resume needs besides (the random states, the episode under way, the evaluation
    rounds a stop left unfinished)."""
    return {"args": dataclasses.asdict(args), "global_step": global_step, "elapsed": elapsed,
            "progress": progress,
            **{name: obj.detach().clone() if torch.is_tensor(obj) else obj.state_dict()
               for name, obj in training.items()},
            "buffer": buffer.state_dict(),
            "rng": rng | {"action_space": action_space.np_random.bit_generator.state,
                          "episode": episode_state(episode, action_space.shape[0])},
            "pending_rounds": [pending_round_state(r) for r in unfinished]}


def load_checkpoint(ckpt: dict, training: dict, buffer, action_space: gym.Space,
                    device: torch.device) -> tuple[int, float, dict]:
    """The run's state from its checkpoint (checkpoint_state), in place into the objects of
    `training` and the buffer; returns the step, the training time so far and the progress."""
    for name, obj in training.items():
        if torch.is_tensor(obj):
            with torch.no_grad():
                obj.copy_(ckpt[name].reshape(obj.shape))
        elif isinstance(obj, nn.Module):
            obj.load_state_dict(fit_shapes(ckpt[name], obj.state_dict()))
        else:  # an optimizer
            params, state = obj.param_groups[0]["params"], ckpt[name]
            obj.load_state_dict({"state": {
                i: fit_shapes(s, {"exp_avg": params[i], "exp_avg_sq": params[i]})
                for i, s in state["state"].items()}, "param_groups": state["param_groups"]})
            for group in obj.param_groups:
                group["capturable"] = device.type == "cuda"  # the checkpoint's is its device's
    buffer.load_state_dict(ckpt["buffer"])
    action_space.np_random.bit_generator.state = ckpt["rng"]["action_space"]
    set_rng_states(ckpt["rng"], device)
    return ckpt["global_step"], ckpt["elapsed"], ckpt["progress"]
