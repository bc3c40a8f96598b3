"""What a run keeps on disk as CPU tensors, written atomically: the weights files and
checkpoint.pt, with all an exact resume needs (networks, optimizers, buffer, random states, the
episode under way, unfinished rounds): a run killed anywhere and resumed is the same, bit for bit.
"""

import copy
import dataclasses
import random
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
import torch.utils._pytree as pytree

from sac_utils.cli import RUNTIME_FIELDS, fail
from sac_utils.files import atomic_write

# What final_model.pt keeps of the arguments, so that it alone rebuilds the actor (evaluate.py).
MODEL_FIELDS = ("env_id", "hidden_sizes", "log_std_min", "log_std_max")
CHECKPOINT_KEYS = ("args", "global_step", "elapsed", "progress", "actor", "qf", "qf_target",
                   "log_alpha", "q_optimizer", "actor_optimizer", "alpha_optimizer", "buffer",
                   "rng")


def on_cpu(tree):
    """The tree with every tensor on the CPU (a plain torch.load reads it without a GPU)."""
    return pytree.tree_map_only(torch.Tensor, torch.Tensor.cpu, tree)


def save_tensors(path: Path, tree: dict) -> None:
    """torch.save of the tree on the CPU, atomically."""
    atomic_write(path, lambda tmp: torch.save(on_cpu(tree), tmp))


def read_checkpoint(path: Path) -> dict:
    """checkpoint.pt on the CPU (where RNG states must stay), or one line saying it is damaged."""
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=False, mmap=True)
        missing = [k for k in CHECKPOINT_KEYS if k not in ckpt]
    except Exception as error:  # a truncated or foreign file fails in pickle, zip or torch
        fail(f"{path} cannot be read ({type(error).__name__}: {str(error).splitlines()[0]}); "
             "it is damaged: restore a copy, or delete it to restart the run from step 0")
    if missing:
        fail(f"{path} lacks {missing}: not a checkpoint of this script; restore a copy, or "
             "delete it to restart the run from step 0")
    return ckpt


def rng_states(device: torch.device) -> dict:
    """The random streams; CUDA's only on CUDA (reading them creates a CUDA context)."""
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
    """Remembers how the episode began (its seed or the env's random state) and every action
    since, so that a checkpoint taken mid-episode rebuilds it exactly (`replay`): any env."""

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        rng = None if seed is not None else self.env.unwrapped.np_random.bit_generator.state
        self.record = {"seed": seed, "rng": copy.deepcopy(rng), "actions": []}
        return self.env.reset(seed=seed, options=options)

    def step(self, action):
        self.record["actions"].append(np.array(action, copy=True))
        return self.env.step(action)

    def replay(self) -> np.ndarray:
        """Rebuilds the episode of `self.record` (a checkpoint's), recorded anew; its last obs."""
        record = self.record
        if record["rng"] is not None:
            self.env.unwrapped.np_random.bit_generator.state = record["rng"]
        obs, _ = self.reset(seed=record["seed"])
        for action in record["actions"]:
            obs = self.step(np.asarray(action))[0]
        return obs


def episode_state(record: dict, action_dim: int) -> dict:
    """An EpisodeRecord's record for a checkpoint: the actions as one tensor, in numpy's
    promoted dtype (float64 where random and policy actions mix: each held exactly)."""
    actions = np.array(record["actions"]).reshape(len(record["actions"]), action_dim)
    return {"seed": record["seed"], "rng": record["rng"], "actions": torch.from_numpy(actions)}


def buffer_state(buffer) -> dict:
    """A ReplayBuffer's filled slots as CPU tensors of their own (a view saves all storage)."""
    return {"ptr": buffer.ptr, "filled": buffer.filled,
            **{a: getattr(buffer, a)[: buffer.filled].to("cpu", copy=True) for a in buffer.ARRAYS}}


def load_buffer_state(buffer, state: dict) -> None:
    buffer.ptr, buffer.filled = state["ptr"], state["filled"]
    for a in buffer.ARRAYS:
        getattr(buffer, a)[: buffer.filled].copy_(state[a])


def checkpoint_state(args, global_step: int, elapsed: float, progress: dict, agent: dict,
                     buffer, action_space: gym.Space, episode: dict, rng: dict,
                     unfinished: list) -> dict:
    """checkpoint.pt: `agent` by name (state_dicts), the buffer, the random states, the episode
    under way, the unfinished rounds."""
    return {"args": dataclasses.asdict(args), "global_step": global_step, "elapsed": elapsed,
            "progress": progress,
            **{name: obj.detach().clone() if torch.is_tensor(obj) else obj.state_dict()
               for name, obj in agent.items()},
            "buffer": buffer_state(buffer),
            "rng": rng | {"action_space": action_space.np_random.bit_generator.state,
                          "episode": episode_state(episode, action_space.shape[0])},
            # A round a stop left unfinished: with the run's arguments, all a rerun needs.
            "pending_rounds": [{"global_step": r.info["global_step"],
                                "wall_time": r.info["wall_time"], "actor": r.actor.state_dict(),
                                "qf": None if r.critic is None else r.critic.state_dict()}
                               for r in unfinished]}


def check_resumable(path: Path, ckpt: dict, args) -> None:
    """A resume's checkpoint must be of this version, made with config.json's arguments."""
    if "next_obs" not in ckpt["buffer"]:  # every checkpoint before issue 87, and none since
        fail(f"{path} was written by an earlier version of this script (before issue 87); resume "
             "it with the commit that made it (config.json's git_commit)")
    wanted = {k: v for k, v in dataclasses.asdict(args).items() if k not in RUNTIME_FIELDS}
    if {k: v for k, v in ckpt["args"].items() if k in wanted} != wanted:
        fail(f"{path} was made with other arguments than {path.with_name('config.json')}; the "
             "run folder is inconsistent")


def load_checkpoint(ckpt: dict, agent: dict, buffer, action_space: gym.Space,
                    envs: gym.vector.VectorEnv,
                    device: torch.device) -> tuple[int, np.ndarray, float, dict]:
    """checkpoint_state's, in place into `agent`, the buffer, the random streams and the episode
    under way (replayed); returns the step, its observation, the time trained and the progress."""
    for name, obj in agent.items():
        if torch.is_tensor(obj):
            with torch.no_grad():
                obj.copy_(ckpt[name])
        else:  # a module or an optimizer
            obj.load_state_dict(ckpt[name])
        if isinstance(obj, torch.optim.Optimizer):
            for group in obj.param_groups:
                group["capturable"] = device.type == "cuda"  # the checkpoint's is its device's
    load_buffer_state(buffer, ckpt["buffer"])
    action_space.np_random.bit_generator.state = ckpt["rng"]["action_space"]
    set_rng_states(ckpt["rng"], device)
    envs.reset(seed=ckpt["args"]["seed"])
    envs.set_attr("record", [ckpt["rng"]["episode"]])
    return ckpt["global_step"], np.stack(envs.call("replay")), ckpt["elapsed"], ckpt["progress"]


def policy_weights(actor: dict, qf: dict, args: dict,
                   log_alpha: torch.Tensor | None = None) -> dict:
    """final_model.pt: the actor's and critic's state dicts and the arguments that rebuild them;
    with log alpha, a snapshot (all that restart_from_snapshot needs)."""
    weights = {"actor": actor, "qf": qf, "config": {f: args[f] for f in MODEL_FIELDS}}
    return weights if log_alpha is None else weights | {"log_alpha": log_alpha.detach().clone()}
