"""Bad input, for the SAC scripts and evaluate.py: the one-line error (`fail`), each flag's range
(`broken_rule`, for sweep.py too), --resume's rules (a flag may change where and how fast, never
what is computed), --env-id, a run's config.json, a non-finite action or loss.
"""

import dataclasses
import difflib
import importlib
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

import gymnasium as gym
import numpy as np
import tyro

from sac_utils.files import read_json_object

INTERRUPTED_EXIT_CODE = 3  # a graceful stop on a signal: "resume with --resume"
# Flags that may differ when resuming: they change where and how fast, not what is computed.
TRACKING_FIELDS = ("track", "wandb_project_name", "wandb_entity", "wandb_group")
RUNTIME_FIELDS = ("output_dir", "run_name", "resume", "checkpoint_interval", "snapshot_interval",
                  "print_interval", "cuda", "compile", "cudagraphs", "gpu_buffer", "torch_threads",
                  "capture_video", "eval_workers", *TRACKING_FIELDS)
# What a resume keeps unless told otherwise (sweep.py gives --resume alone); compiled and eager
# round apart.
KEPT_FIELDS = (*TRACKING_FIELDS, "compile", "checkpoint_interval", "snapshot_interval")


def fail(message: str) -> NoReturn:
    """Bad input: one line naming the problem and the fix on stderr, exit code 2."""
    print(f"{Path(sys.argv[0]).name}: error: {message}", file=sys.stderr, flush=True)
    sys.exit(2)


def check_finite(x: np.ndarray, what: str) -> None:
    """A NaN or infinite action or loss ends the run with one line (exit code 1)."""
    if not np.isfinite(x).all():
        raise SystemExit(f"non-finite {what} (NaN/inf): training diverged; try lower learning "
                         "rates or resume from an earlier checkpoint")


def json_object_or_fail(path: Path, fix: str) -> dict:
    """A JSON file's object, or one line naming what is wrong with it and `fix`."""
    try:
        return read_json_object(path, fix)
    except ValueError as error:
        fail(str(error))


def read_config_json(run_dir: Path, give_instead: str, restore: str) -> dict:
    """A run folder's config.json, or one line: `give_instead` where the folder is not a run,
    `restore` where the file is damaged."""
    path = run_dir / "config.json"
    if not path.is_file():
        fail(f"{run_dir} is not a run folder (no config.json); {give_instead}")
    return json_object_or_fail(path, restore)


def parse_args(args_class: type, algorithm: str, eval_actions: Callable) -> object:
    """A script's Args, checked; with --resume, the run's stored arguments are the defaults and a
    flag that contradicts them is an error."""
    args = tyro.cli(args_class)
    if args.resume is not None:
        run_dir = Path(args.resume)
        path = run_dir / "config.json"
        config = read_config_json(run_dir, "give --resume a folder made by sac_standard.py or "
                                  "sac_corrected.py", "restore it from a copy, or start a new run")
        if config.get("algorithm") != algorithm:
            fail(f"{run_dir} is a run of {config.get('script')}; resume it with that script")
        stored = stored_args(args_class, config, skip=RUNTIME_FIELDS)
        kept = {k: config[k] for k in KEPT_FIELDS if k in config}
        wrong = [k for k, v in (stored | kept).items() if not same_type(v, getattr(args, k))]
        if wrong:
            fail(f"{path} holds values of the wrong type for {wrong}; it was edited or damaged: "
                 "restore it, or start a new run")
        args = tyro.cli(args_class, default=dataclasses.replace(args, **stored, **kept))
        changed = [k for k, v in stored.items() if getattr(args, k) != v]
        if changed:
            fail(f"--resume {args.resume}: flags {changed} contradict the run's stored arguments; "
                 "drop them or start a new run")
    check_args(args, eval_actions)
    return args


def stored_args(args_class: type, config: dict, skip: tuple[str, ...] = ()) -> dict:
    """The arguments of a config.json that args_class has (but `skip`), lists back to tuples."""
    names = [f.name for f in dataclasses.fields(args_class) if f.name not in skip]
    return {k: tuple(config[k]) if isinstance(config[k], list) else config[k]
            for k in names if k in config}


def same_type(value: object, default: object) -> bool:
    """Whether a config.json value can stand for a flag with this default (None: any)."""
    if default is None or value is None:
        return True
    if isinstance(default, float):
        return isinstance(value, int | float) and not isinstance(value, bool)
    if isinstance(default, tuple):  # hidden_sizes holds ints, eval_selectors names
        return isinstance(value, tuple) and all(type(v) is type(default[0]) if default
                                                else type(v) is str for v in value)
    return type(value) is type(default)


def check_args(args, eval_actions: Callable) -> None:
    """Every flag's range, before anything is written; eval_actions: the script's own."""
    from sac_utils.eval_rounds import action_name  # torch: not for sweep.py, which imports cli

    finite = math.isfinite
    at_least_one = [(k, getattr(args, k) >= 1, "at least 1") for k in (
        "total_timesteps", "buffer_size", "log_interval", "print_interval", "torch_threads")]
    positive = [(k, finite(getattr(args, k)) and getattr(args, k) > 0, "a positive number")
                for k in ("policy_lr", "q_lr", "alpha_lr", "alpha_init")]
    own_actions = [action_name(a) for a in
                   eval_actions(dataclasses.replace(args, eval_selectors=())).values()]
    actions = [action_name(a) for a in eval_actions(args).values()]
    rules = (
        ("seed", args.seed >= 0, "a non-negative integer"),
        *at_least_one,
        ("batch_size", 1 <= args.batch_size <= args.buffer_size,
         f"between 1 and --buffer-size ({args.buffer_size})"),
        ("gamma", 0 <= args.gamma <= 1, "in [0, 1]"),
        ("tau", 0 < args.tau <= 1, "in (0, 1]"),
        ("learning_starts", 0 <= args.learning_starts < args.total_timesteps,
         f"in [0, --total-timesteps ({args.total_timesteps})), or no gradient update would run"),
        *positive,
        ("target_entropy_scale", finite(args.target_entropy_scale), "a finite number"),
        ("hidden_sizes", len(args.hidden_sizes) > 0 and min(args.hidden_sizes) >= 1,
         "one or more positive layer widths, e.g. --hidden-sizes 256 256"),
        ("log_std_max", finite(args.log_std_max), "a finite number"),
        ("log_std_min", finite(args.log_std_min) and args.log_std_min < args.log_std_max,
         f"a finite number below --log-std-max ({args.log_std_max})"),
        ("eval_interval", args.eval_interval >= 1, "at least 1 (above --total-timesteps: no "
         "evaluation)"),
        ("eval_episodes", args.eval_episodes >= 1, "at least 1 (to skip evaluation, set "
         "--eval-interval above --total-timesteps)"),
        ("eval_reset_noise", args.eval_reset_noise is None
         or (finite(args.eval_reset_noise) and args.eval_reset_noise >= 0),
         "a finite number >= 0 (HumanoidBench's is 0.01); leave it out for the task's own"),
        ("eval_selectors", len(set(actions)) == len(actions),
         f"evaluation actions other than this script's own ({', '.join(own_actions)}), each once"),
        ("eval_workers", args.eval_workers is None or args.eval_workers >= 0,
         "0 (in-process) or more"),
        ("checkpoint_interval", args.checkpoint_interval >= 0, "0 (off) or more"),
        ("snapshot_interval", args.snapshot_interval >= 0, "0 (off) or more"),
        ("run_name", args.run_name is None or (args.run_name not in ("", ".", "..")
                                               and "/" not in args.run_name),
         "a folder name without '/'"),
        ("wandb_project_name", bool(args.wandb_project_name), "a non-empty name"),
    )
    if message := broken_rule(args, rules):
        fail(message)


def broken_rule(args, rules: tuple[tuple[str, bool, str], ...]) -> str | None:
    """The first rule (field, whether its value is allowed, what is) that args break, as one line
    (`--flag VALUE: must be ...`); None if they keep them all. Shared with sweep.py."""
    for name, ok, allowed in rules:
        if not ok:
            value = getattr(args, name)
            shown = " ".join(map(str, value)) if isinstance(value, list | tuple) else repr(value)
            return f"--{name.replace('_', '-')} {shown}: must be {allowed}"
    return None


def registered_env_id(env_id: str) -> str:
    """The gymnasium id of --env-id, or one line naming close matches ("module:EnvId" imports
    the module first, which registers the env)."""
    module, _, name = env_id.rpartition(":")
    if module:
        try:
            importlib.import_module(module)
        except ImportError as error:
            fail(f"--env-id {env_id}: cannot import {module!r} ({error}); check the module path "
                 "(run from the folder that holds it)")
    if name not in gym.registry:
        close = difflib.get_close_matches(name, list(gym.registry), n=5, cutoff=0.5)
        ours = sorted(k for k in gym.registry if k.startswith("h1hand-"))
        fail(f"unknown env id {env_id!r}; close matches: {close}; our tasks: {ours}")
    return env_id


def check_reset_noise(env: gym.Env, env_id: str, reset_noise: float | None,
                      flag: str = "--eval-reset-noise") -> None:
    """A reset noise is an option of our h1hand tasks only; other envs would ignore it."""
    from humanoid_envs.base import H1HandEnv

    if reset_noise is not None and not isinstance(env.unwrapped, H1HandEnv):
        fail(f"{flag} {reset_noise}: {env_id} is not an h1hand task, which alone take it "
             "(gymnasium's MuJoCo envs set theirs with reset_noise_scale); leave it out")


def check_spaces(env: gym.Env, env_id: str) -> gym.Env:
    """The env, if SAC can act in it: a bounded Box of actions, a flat Box of observations."""
    space = env.action_space
    if not isinstance(space, gym.spaces.Box):
        fail(f"{env_id} has a {type(space).__name__} action space; SAC needs a Box")
    if not (np.isfinite(space.low).all() and np.isfinite(space.high).all()):
        fail(f"{env_id} has unbounded actions; SAC squashes into finite bounds")
    obs_space = env.observation_space
    if not isinstance(obs_space, gym.spaces.Box) or len(obs_space.shape) != 1:
        fail(f"{env_id} observations are not a flat Box; flatten them first")
    return env
