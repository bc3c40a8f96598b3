"""What evaluate.py evaluates: a policy (an actor, and the critic q_best needs) from one of our
run folders or weight files (final_model.pt, checkpoint.pt, a snapshot; loaded with
weights_only=True: they cannot run code) or from a Stable-Baselines3 SAC .zip (unpickled by SB3:
only from a source you trust), as our Actor and TwinQ. Anything else stops with one line saying
what to give instead."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn

import sac_corrected as sac
from sac_utils.cli import fail, read_config_json


class SB3Actor(nn.Module):
    """SB3's SAC actor as our Actor: mu and log sigma, and SB3's `unscale_action` as scale."""

    def __init__(self, model) -> None:
        super().__init__()
        self.policy = model.policy

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        actor = self.policy.actor
        mu, log_std, latent = actor.get_action_dist_params(obs)
        if latent:  # gSDE: log_std is a parameter matrix; sigma at this state comes from both
            normal = actor.action_dist.proba_distribution(mu, log_std, **latent).distribution
            log_std = normal.stddev.log()
        return mu, log_std

    def scale(self, y: torch.Tensor) -> torch.Tensor:
        low, high = (torch.as_tensor(b, dtype=y.dtype, device=y.device)
                     for b in (self.policy.action_space.low, self.policy.action_space.high))
        return low + 0.5 * (y + 1.0) * (high - low)


class SB3Critic(nn.Module):
    """SB3's SAC critic as our TwinQ: env actions in (scaled as SB3's `scale_action` does),
    (n_critics, batch) out."""

    def __init__(self, policy) -> None:
        super().__init__()
        self.policy = policy

    def forward(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        low, high = (torch.as_tensor(b, dtype=action.dtype, device=action.device)
                     for b in (self.policy.action_space.low, self.policy.action_space.high))
        scaled = 2.0 * ((action - low) / (high - low)) - 1.0
        return torch.cat(self.policy.critic(obs, scaled), 1).T


def load_policy(source: Path, env_id: str | None, need_critic: bool
                ) -> tuple[nn.Module, nn.Module | None, str, dict]:
    """The actor, the critic (None unless `need_critic`), the env id (`env_id` where given,
    else the one the source names) and where they came from."""
    if source.suffix == ".zip":
        actor, env_id, info = load_sb3(source, env_id)
        return actor, SB3Critic(actor.policy) if need_critic else None, env_id, info
    if source.is_dir():
        config = read_config(source)
        path = next((source / n for n in ("final_model.pt", "checkpoint.pt")
                     if (source / n).is_file()), None)
        if path is None:
            fail(f"{source} holds no final_model.pt or checkpoint.pt yet: nothing to evaluate")
        state, env_id = load_weights(path), env_id or config.get("env_id")
        if not isinstance(env_id, str):
            fail(f"{source / 'config.json'} names no env_id; restore it, or pass --env-id")
        info = {"source": str(path), "kind": "run", "run_seed": config.get("seed")}
    else:
        path, state = source, load_weights(source)
        # final_model.pt keeps the fields that rebuild the actor; checkpoint.pt keeps all arguments.
        config = state.get("config") or state.get("args") or {}
        env_id = env_id or (config.get("env_id") if isinstance(config, dict) else None)
        if not isinstance(env_id, str):
            fail(f"{source} does not say which env it was trained on; pass --env-id")
        info = {"source": str(path), "kind": "weights"}
    actor = build_actor(state["actor"], env_id, config, path)
    return actor, build_critic(state, actor, path) if need_critic else None, env_id, info


def read_config(run_dir: Path) -> dict:
    return read_config_json(run_dir, "give a folder made by sac_standard.py or "
                            "sac_corrected.py, a final_model.pt or an SB3 .zip",
                            "restore it from a copy")


def load_weights(path: Path) -> dict:
    """weights_only: a file cannot run code; mmap: a checkpoint.pt's replay buffer stays on
    disk."""
    try:
        state = torch.load(path, map_location="cpu", weights_only=True, mmap=True)
    except Exception as error:  # not a torch file, truncated, or holding more than weights
        fail(f"{path} is not a weights file of ours ({type(error).__name__}: "
             f"{str(error).splitlines()[0][:120]}); give a final_model.pt or a run folder")
    if not isinstance(state, dict) or not tensors(state.get("actor")):
        fail(f"{path} holds no 'actor' weights; give a final_model.pt or a run folder")
    if broken := non_finite(state["actor"]):
        fail(f"{path}: the actor's {broken} holds NaN/inf (training diverged); evaluate "
             "an earlier model")
    # Files written with --num-seeds (results/*-1M's) hold the actor and critic with a leading
    # seed axis of 1: (1, in, out) weights and (1, 1, out) biases, not (in, out) and (out,); and
    # every file written before issue 87 holds (in, out) weights, not nn.Linear's (out, in).
    def fit(key: str, value: torch.Tensor) -> torch.Tensor:
        if value.dim() != 3:
            return value
        return value[0] if key.endswith(".weight") else value[0, 0]

    return state | {part: to_linear_layout({k: fit(k, v) for k, v in state[part].items()})
                    for part in ("actor", "qf") if tensors(state.get(part))}


def to_linear_layout(weights: dict) -> dict:
    """A state dict of our networks in nn.Linear's layout, whichever it was written in."""
    if not old_layout(weights):
        return weights
    return {k: v.T.contiguous() if k.endswith(".weight") and v.dim() == 2 else v
            for k, v in weights.items()}


def old_layout(weights: dict) -> bool:
    """Whether our networks' weights are stored (in, out), as before issue 87 (results/), not
    nn.Linear's (out, in): told by the first non-square layer's bias length."""
    for key, weight in weights.items():
        bias = weights.get(key.removesuffix("weight") + "bias")
        if key.endswith(".weight") and weight.dim() == 2 and bias is not None \
                and weight.shape[0] != weight.shape[1]:
            return weight.shape[1] == bias.shape[-1]
    return False


def tensors(weights: object) -> bool:
    return isinstance(weights, dict) and all(torch.is_tensor(v) for v in weights.values())


def non_finite(weights: dict) -> str | None:
    return next((k for k, v in weights.items()
                 if v.is_floating_point() and not v.isfinite().all()), None)


def layers(weights: dict, prefix: str) -> list[torch.Tensor]:
    keys = [k for k in weights if k.startswith(prefix) and k.endswith(".weight")]
    return [weights[k] for k in sorted(keys, key=lambda k: int(k.split(".")[1]))]


def load_into(module: nn.Module, weights: dict, path: Path, what: str, fix: str = "") -> None:
    try:
        module.load_state_dict(weights)
    except RuntimeError as error:  # layers missing, extra or of the wrong shape
        fail(f"{path}: its {what} ({' '.join(str(error).split())[:200]}); give a final_model.pt "
             f"of sac_standard.py or sac_corrected.py{fix}")


def build_actor(weights: dict, env_id: str, config: dict, path: Path) -> sac.Actor:
    env = sac.make_env(env_id)
    obs_dim, action_dim = env.observation_space.shape[0], int(np.prod(env.action_space.shape))
    trunk = layers(weights, "trunk.")
    if not trunk or trunk[0].dim() != 2 or "fc_mean.weight" not in weights:
        fail(f"{path} holds no actor of sac_standard.py or sac_corrected.py (no trunk or "
             "fc_mean layers); give a final_model.pt or a run folder")
    shapes = (trunk[0].shape[1], weights["fc_mean.weight"].shape[0])
    if shapes != (obs_dim, action_dim):
        fail(f"{path} was trained on {shapes[0]}-dim observations and {shapes[1]}-dim "
             f"actions; {env_id} has {obs_dim} and {action_dim}: pass the --env-id it was "
             "trained on")
    actor = sac.Actor(obs_dim, tuple(w.shape[0] for w in trunk), env.action_space,
                      config.get("log_std_min", sac.Args.log_std_min),
                      config.get("log_std_max", sac.Args.log_std_max))
    load_into(actor, weights, path, "actor does not fit our Actor")
    return actor


def build_critic(state: dict, actor: sac.Actor, path: Path) -> sac.TwinQ:
    weights, drop = state.get("qf"), ", or drop q_best from --selectors"
    if not tensors(weights) or not weights:
        fail(f"{path} holds no critic weights ('qf'), which q_best needs; give a "
             f"final_model.pt or checkpoint.pt that holds them{drop}")
    qf1 = layers(weights, "qf1.")
    obs_dim, action_dim = actor.trunk[0].weight.shape[1], actor.fc_mean.weight.shape[0]
    if not qf1 or any(w.dim() != 2 for w in qf1) or qf1[-1].shape[0] != 1 \
            or qf1[0].shape[1] != obs_dim + action_dim:
        fail(f"{path}: its 'qf' is not a critic of sac_standard.py or sac_corrected.py for "
             f"{obs_dim}-dim observations and {action_dim}-dim actions; give the run's own "
             f"final_model.pt{drop}")
    critic = sac.TwinQ(obs_dim, action_dim, tuple(w.shape[0] for w in qf1[:-1]))
    load_into(critic, weights, path, "critic does not fit our TwinQ", drop)
    if broken := non_finite(weights):
        fail(f"{path}: the critic's {broken} holds NaN/inf (training diverged); evaluate "
             f"an earlier model{drop}")
    return critic.eval()


def load_sb3(path: Path, env_id: str | None) -> tuple[nn.Module, str, dict]:
    if env_id is None:
        fail(f"{path} is a Stable-Baselines3 file: pass --env-id, the env it was trained on")
    try:
        data = json.loads(zipfile.ZipFile(path).read("data"))
    except (zipfile.BadZipFile, KeyError, json.JSONDecodeError) as error:
        fail(f"{path} is not a Stable-Baselines3 model ({error}); give an SB3 SAC .zip")
    policy = data.get("policy_class", {})
    module = policy.get("__module__", "") if isinstance(policy, dict) else ""
    if not module.startswith("stable_baselines3.sac"):
        fail(f"{path} is not a Stable-Baselines3 SAC model (its policy comes from "
             f"{module or 'an unknown module'}): the mode of a tanh-squashed Gaussian needs "
             "a SAC policy")
    try:
        from stable_baselines3 import SAC
    except ImportError:
        fail("an SB3 .zip needs stable-baselines3: pip install stable-baselines3==2.9.2")
    env = sac.make_env(env_id)
    try:
        model = SAC.load(path, device="cpu")
    except Exception as error:  # a damaged archive or one from an incompatible SB3 version
        fail(f"{path} cannot be loaded by stable-baselines3 ({type(error).__name__}: "
             f"{' '.join(str(error).split())[:160]}); give an SB3 SAC .zip it can load")
    spaces = (model.observation_space.shape, model.action_space.shape)
    if spaces != (env.observation_space.shape, env.action_space.shape):
        fail(f"{path} was trained on observations {spaces[0]} and actions {spaces[1]}; "
             f"{env_id} has {env.observation_space.shape} and {env.action_space.shape}: "
             "pass the --env-id it was trained on")
    return SB3Actor(model), env_id, {"source": str(path), "kind": "stable-baselines3"}
