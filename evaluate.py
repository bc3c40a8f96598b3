"""Does the correction help my policy? A trained SAC policy evaluated with several evaluation
actions, paired: every action starts its episode k from the same state.

    python evaluate.py runs/h1hand-cube-v0__corrected__seed0__20261122-120000
    python evaluate.py final_model.pt --env-id Hopper-v5 --episodes 100 --selectors mode mean
    python evaluate.py sb3_sac_hopper.zip --env-id Hopper-v5 --selectors mode tanh_mu q_best sample
    python evaluate.py campaign/ --out robust/ --reset-noise 0.01 --episodes 100 \
        --selectors mode tanh_mu mean q_best          # every run of a campaign, every snapshot

SOURCE: a run folder of ours (its final_model.pt, else checkpoint.pt), one of our weight files
(loaded with weights_only=True: they cannot run code), or a Stable-Baselines3 SAC .zip (unpickled
by SB3: only from a source you trust). A folder of run folders is a campaign: every run's final
weights and snapshots into --out, resumable after a kill; that --out as SOURCE rewrites its
summary. The episodes run through sac_utils/eval_rounds.py, the training runs' own evaluation.
docs/evaluate.md has the details.
"""

from __future__ import annotations

import collections
import contextlib
import csv
import io
import itertools
import json
import os
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import torch.nn as nn
import tyro

import sac_corrected as sac
from analysis import estimators, report
from sac_utils.cli import broken_rule, check_reset_noise, fail, json_object_or_fail
from sac_utils.eval_rounds import (
    ACTIONS,
    Q_BEST_CANDIDATES,
    SHIFT_COLUMNS,
    EvalPool,
    Round,
    eval_seeds,
    start_key,
)
from sac_utils.files import complete_lines, write_json, write_text_atomically
from sac_utils.policies import build_actor, build_critic, load_policy, load_weights, read_config
from sac_utils.run_folder import machine

# Episodes per job. Fixed, not derived from --workers: a job's episodes share one batch per
# actor call, and the numbers must not depend on how many processes ran the jobs.
JOB_EPISODES = 10


@dataclass
class Args:
    source: tyro.conf.Positional[Path]
    """a run folder, a final_model.pt or checkpoint.pt, or a Stable-Baselines3 SAC .zip"""
    env_id: str | None = None
    """the env to evaluate in (default: the run's; required for an SB3 .zip)"""
    episodes: int = 50
    """episodes per evaluation action"""
    seed: int = 0
    """episode k of every action resets with a seed derived from (--seed, --eval-round, k); for a
    folder of runs, from (the run's own seed, --eval-round, k), and --seed seeds only the
    bootstrap intervals"""
    eval_round: int = 0
    """with a run's seed, its evaluation round N gives the same start states as the run's
    N-th evaluation (0, the default, is a round no training run evaluates; so is any N above the
    run's number of rounds, for other starts)"""
    solver: Literal["exact", "grid"] = "exact"
    """how to find the mode (mode_search.py)"""
    reset_noise: float | None = None
    """half-width of the uniform noise on every qpos entry at each reset (h1hand tasks; default:
    the task's own). bookshelf and cube reset without noise, so their episodes from one policy
    are one episode: 0.01 (HumanoidBench's own elsewhere) gives distinct starts"""
    steps: tuple[int, ...] = ()
    """with a folder of runs: evaluate the snapshots (or final weights) at these steps only
    (default: every snapshot and the final weights); --out stays unfinished while some are not
    there yet, and the same command later evaluates them"""
    selectors: tuple[Literal["mode", "tanh_mu", "mean", "q_best", "sample"], ...] = (
        "mode", "tanh_mu")
    """evaluation actions: the mode, tanh(mu), the mean E[tanh(u)], the critic's pick of those
    three at each state (q_best), a sampled action (stochastic, seeded)"""
    video: Path | None = None
    """write the first episode of each action as an MP4 into this folder"""
    out: Path | None = None
    """write episodes.csv (one row per episode and action) and summary.json here"""
    reps: int = 10_000
    """bootstrap replications of the confidence intervals"""
    workers: int | None = None
    """worker processes that run the jobs (default: every core this process may use; 0: in
    this process). The results do not depend on it."""


def parse_args(argv: list[str] | None = None) -> Args:
    """The flags; tyro's parse errors on one line."""
    captured = io.StringIO()
    try:
        with contextlib.redirect_stderr(captured):
            return tyro.cli(Args, args=argv, prog="evaluate.py")
    except SystemExit as exit_:
        if exit_.code in (0, None):  # --help
            raise
        fail(f"{one_line(captured.getvalue())} (see evaluate.py --help)")


def one_line(box: str) -> str:
    """The message of tyro's error box, borders dropped."""
    lines = []
    for line in box.splitlines()[1:]:
        text = line.strip().strip("│").strip()
        if text.startswith("─") or line.lstrip().startswith("╰"):
            break
        lines.append(text)
    return " ".join(" ".join(lines).split()) or "could not parse the flags"


def check_args(args: Args) -> None:
    """Before anything is loaded, run or written."""
    rules = (
        ("episodes", args.episodes >= 1, "at least 1"),
        ("seed", args.seed >= 0, "a non-negative integer"),
        ("eval_round", args.eval_round >= 0, "0 or more"),
        ("selectors", len(args.selectors) >= 1, f"one or more of {', '.join(ACTIONS)}"),
        ("reps", args.reps >= 1, "at least 1"),
        ("reset_noise", args.reset_noise is None
         or (np.isfinite(args.reset_noise) and args.reset_noise >= 0),
         "a finite number >= 0 (HumanoidBench's is 0.01); leave it out for the task's own"),
        ("steps", all(s >= 0 for s in args.steps), "steps of the runs' snapshots (>= 0)"),
        ("workers", args.workers is None or args.workers >= 0, "0 (in-process) or more"),
    )
    if message := broken_rule(args, rules):
        fail(message)
    if not args.source.exists():
        fail(f"{args.source} does not exist; give a run folder, a final_model.pt or an SB3 "
             "SAC .zip")
    for flag, folder in (("--out", args.out), ("--video", args.video)):
        if folder is not None and folder.exists() and not folder.is_dir():
            fail(f"{flag} {folder}: a file of that name exists; give a folder")


# ----------------------------------------------------------------------------- evaluate
def make_jobs(actor: nn.Module, critic: nn.Module | None, env_id: str, seeds: list[int],
              actions: list[str], args: Args, label: str = "") -> list[Round]:
    shift_of = shift_action(actions)
    jobs = []
    for start in range(0, len(seeds), JOB_EPISODES):
        part = seeds[start:start + JOB_EPISODES]
        videos = {s: args.video / f"{s}.mp4" for s in actions} if args.video and start == 0 else {}
        jobs.append(Round(env_id, part, {s: s for s in actions}, actor, critic,
                          mode_solver=args.solver, reset_noise=args.reset_noise,
                          shift_of=shift_of, videos=videos,
                          label=f"{label}episodes {start}-{start + len(part) - 1}"))
    return jobs


def run_jobs(jobs: list[Round], workers: int | None, label: str,
             keep: Callable[[dict], None] | None = None) -> list[dict]:
    """Every job's result, in job order, each also handed to `keep` as it comes back."""
    results: list[dict] = []
    progress = progress_bar(label, sum(len(j.seeds) for j in jobs))

    def done(job: Round, result: dict) -> None:
        results.append(result)
        if keep is not None:
            keep(result)
        progress(sum(len(j.seeds) for j in jobs[:len(results)]))

    workers = len(os.sched_getaffinity(0)) if workers is None else workers
    # More processes than jobs would only cost their start-up.
    pool = EvalPool(min(workers, len(jobs)), done)
    try:
        for job in jobs:
            pool.submit(job)
        pool.drain()
    except SystemExit as exit_:
        if isinstance(exit_.code, str):  # the runner's one line; its advice is for training
            fact = exit_.code.split("; ")[0]
            fail(f"{fact}; the model is damaged or does not belong to this env" if
                 "NaN/inf" in fact else f"{fact}; run again, with --workers 0 to see why")
        raise
    finally:
        pool.close()
    return results


def merge(results: list[dict], actions: list[str]) -> tuple[dict, dict]:
    """The jobs' episodes per action, and their shares and shift statistics pooled: each is a
    mean over states, so a job weighs as many states as it visited."""
    merged = {s: {k: [x for r in results for x in r[s][k]]
                  for k in ("returns", "lengths", "successes", "unstable", "ends")}
              for s in actions}
    for s in (s for s in actions if "shares" in results[0][s]):
        weights = np.array([sum(r[s]["lengths"]) for r in results], float)
        merged[s]["shares"] = {c: float(np.average([r[s]["shares"][c] for r in results],
                                                   weights=weights)) for c in Q_BEST_CANDIDATES}
    states = np.array([r["shift_states"] for r in results], float)
    shift = {k: float(np.average([r["shift"][k] for r in results], weights=states))
             for k in SHIFT_COLUMNS}
    return merged, shift


def progress_bar(label: str, total: int) -> Callable[[int], None]:
    """Redrawn in place on a terminal, else a line at every tenth (not one per job in a log)."""
    start, shown, tty = time.perf_counter(), [0], sys.stderr.isatty()

    def update(done: int) -> None:
        elapsed = time.perf_counter() - start
        filled = 24 * done // total
        line = (f"{label} [{'#' * filled}{'.' * (24 - filled)}] {done}/{total} episodes, "
                f"{elapsed:.0f} s, ~{elapsed / done * (total - done):.0f} s left")
        if tty:
            # \r back to the line's start, ESC[K clears what a longer earlier line left.
            print(f"\r{line}\033[K", end="\n" if done == total else "", file=sys.stderr, flush=True)
        elif 10 * done // total > shown[0]:
            shown[0] = 10 * done // total
            print(line, file=sys.stderr, flush=True)

    return update


def mean_with_ci(values: np.ndarray, reps: int, seed: int) -> tuple[float, float, float]:
    """The percentile bootstrap; NumPy's legacy generator takes seeds below 2**32."""
    point, low, high = estimators.bootstrap_mean(values, reps, np.random.RandomState(seed % 2**32))
    return float(point), float(low), float(high)


def distinct_starts(env_id: str, seeds: list[int], reset_noise: float | None) -> int | None:
    """None where the env cannot tell."""
    env = sac.make_env(env_id)
    options = None if reset_noise is None else {"qpos_noise": reset_noise}
    keys = set()
    for seed in seeds:
        env.reset(seed=seed, options=options)
        key = start_key(env)
        if key is None:
            return None
        keys.add(key)
    return len(keys)


def summarise(results: dict, shift: dict, args: Args, info: dict, env_id: str,
              starts: int | None) -> dict:
    summary = {**info, "env_id": env_id, "episodes": args.episodes, "seed": args.seed,
               "eval_round": args.eval_round, "reset_noise": args.reset_noise,
               "distinct_starts": starts, "solver": args.solver,
               "episodes_per_job": JOB_EPISODES, "selectors": {}}
    for action, episodes in results.items():
        mean, low, high = mean_with_ci(np.array(episodes["returns"]), args.reps, args.seed)
        summary["selectors"][action] = {
            "return_mean": mean, "ci_low": low, "ci_high": high,
            "return_std": float(np.std(episodes["returns"])),
            "length_mean": float(np.mean(episodes["lengths"])),
            "unstable_ends": int(np.sum(episodes["unstable"])),
            "ends": dict(collections.Counter(episodes["ends"]))}
        if "shares" in episodes:
            summary["selectors"][action]["choice_shares"] = episodes["shares"]
    if "tanh_mu" in results:  # episode by episode: from the same start state
        paired = summary["paired_difference_minus_tanh_mu"] = {}
        for s in (s for s in results if s != "tanh_mu"):
            diffs = estimators.paired_difference(results[s]["returns"],
                                                 results["tanh_mu"]["returns"])
            mean, low, high = mean_with_ci(diffs, args.reps, args.seed)
            paired[s] = {"mean": mean, "ci_low": low, "ci_high": high,
                         "share_better": float(np.mean(diffs > 0)),
                         "share_equal": float(np.mean(diffs == 0))}
    summary["shift_at_visited_states"] = shift
    return summary


def print_summary(summary: dict) -> None:
    print(f"\n{summary['source']} on {summary['env_id']}: {summary['episodes']} episodes per "
          f"action, the same start states for each (seed {summary['seed']}, round "
          f"{summary['eval_round']})\n")
    # A task that resets without noise gives every episode one start: the "episodes" of a
    # deterministic action are one episode repeated, and a CI over them means nothing.
    one = summary["distinct_starts"] == 1 and summary["episodes"] > 1
    if one:
        print(f"All {summary['episodes']} episodes start from the same state ({summary['env_id']} "
              "resets without noise): each deterministic action ran one episode, so there is "
              "no CI. For distinct starts, evaluate with --reset-noise 0.01 (HumanoidBench's "
              "reset noise on its other tasks).\n")
    print(f"{'action':<10} {'mean return':>12}  {'95% CI':>23}  {'std':>9}  {'length':>7}")
    for name, s in summary["selectors"].items():
        ci = f"[{s['ci_low']:10.2f}, {s['ci_high']:10.2f}]" if not one or name == "sample" \
            else f"{'(one episode)':>24}"
        print(f"{name:<10} {s['return_mean']:12.2f}  {ci}  {s['return_std']:9.2f}  "
              f"{s['length_mean']:7.1f}")
    ends = {name: s["unstable_ends"] for name, s in summary["selectors"].items()
            if s["unstable_ends"]}
    if ends:
        print("physics blow-ups ended " + ", ".join(
            f"{n} of {name}'s episodes" for name, n in ends.items()) + " (the return is what "
            "was earned until then)")
    for name, s in summary["selectors"].items():
        if "choice_shares" in s:
            shares = ", ".join(f"{c} {100 * v:.1f}%" for c, v in s["choice_shares"].items())
            print(f"{name} chose, over its visited states: {shares}")
    print()
    for name, paired in summary.get("paired_difference_minus_tanh_mu", {}).items():
        if one and name != "sample":
            print(f"{name} - tanh_mu, one paired episode: {paired['mean']:.2f}")
            continue
        print(f"{name} - tanh_mu, paired: {paired['mean']:.2f} [{paired['ci_low']:.2f}, "
              f"{paired['ci_high']:.2f}]; {name} did better in "
              f"{100 * paired['share_better']:.0f}% of episodes "
              f"(equal in {100 * paired['share_equal']:.0f}%)")
    shift = summary["shift_at_visited_states"]
    print(f"distribution shift at the visited states: mean |mode - tanh(mu)| "
          f"{shift['mode_shift_abs_mean']:.4f} per dimension, {shift['mode_shift_abs_sum']:.3f} "
          f"summed over dimensions; sigma {shift['sigma_mean']:.3f}; bimodal dimensions "
          f"{100 * shift['bimodal_fraction']:.1f}%")


# physics_unstable, then end, were added last: a reader by name reads older files alike.
EPISODE_COLUMNS = ["selector", "episode", "reset_seed", "return", "length", "success",
                   "physics_unstable", "end"]


def episode_rows(results: dict, seeds: list[int]) -> Iterator[list]:
    for action, episodes in results.items():
        for k, seed in enumerate(seeds):
            success = episodes["successes"][k]
            yield [action, k, seed, repr(episodes["returns"][k]), episodes["lengths"][k],
                   "" if success is None else success, int(episodes["unstable"][k]),
                   episodes["ends"][k]]


# ----------------------------------------------------------------------------- a campaign
CAMPAIGN_FILE = "evaluation.json"
# Asked of each seed: the paired difference's standard error below this share of tanh(mu)'s.
PRECISION = 0.10


@dataclass
class Policy:
    run: str
    seed: int
    env_id: str
    step: int
    path: Path | None  # None: evaluated in --out, its weights since gone from the runs' folder
    config: dict


def is_campaign(source: Path) -> bool:
    return source.is_dir() and not (source / "config.json").exists() \
        and next(source.rglob("config.json"), None) is not None


def campaign_policies(root: Path, steps: tuple[int, ...], out: Path | None = None
                      ) -> tuple[list[Policy], list[str]]:
    """The policies there, and those at --steps not there yet ("run step N"). The final weights
    stand for a snapshot at their step. A sweep's run not started yet (sweep_run.json without
    config.json) has none of its steps there: the campaign is not complete without it. A step
    with rows in `out` stays a policy when its weights have left the run folder (a long
    campaign's evaluated snapshots may leave the repository to keep it small): its rows are
    kept, and the campaign can still be completed."""
    run_dirs = sorted(p.parent for p in root.rglob("config.json"))
    planned = sorted(p.parent.name for p in root.rglob("sweep_run.json")
                     if not (p.parent / "config.json").is_file())
    if len({d.name for d in run_dirs}) < len(run_dirs):  # the output is one folder per name
        fail(f"{root}: two run folders share a name; evaluate them separately")
    policies, missing = [], [f"{name} (not started)" for name in planned]
    for run_dir in run_dirs:
        config = read_config(run_dir)
        files: dict[int, Path | None] = {int(p.stem.removeprefix("step")): p
                 for p in (run_dir / "snapshots").glob("step*.pt")
                 if p.stem.removeprefix("step").isdigit()}
        if (run_dir / "final_model.pt").is_file():
            done = run_dir / "done.json"
            final = json.loads(done.read_text())["global_step"] if done.is_file() \
                else config.get("total_timesteps")
            files[int(final)] = run_dir / "final_model.pt"
        evaluated = rows_by_step(out / run_dir.name / "episodes.csv", EPISODES_HEADER,
                                 OLD_EPISODES_HEADERS) if out is not None else None
        files |= {s: None for s in evaluated or {} if s not in files and (not steps or s in steps)}
        missing += [f"{run_dir.name} step {s}" for s in steps if s not in files]
        policies += [Policy(run_dir.name, int(config["seed"]), config["env_id"], step, path, config)
                     for step, path in sorted(files.items()) if not steps or step in steps]
    if not policies:
        fail(f"{root}: no run under it holds final_model.pt or snapshots"
             f"{' at --steps ' + ' '.join(map(str, steps)) if steps else ''}; train with "
             "--snapshot-interval, or give a run folder")
    return policies, missing


def evaluate_campaign(args: Args) -> None:
    """All jobs in one pool; each policy's rows are written as soon as its last job is back,
    so the same command again, after a kill, evaluates only the others."""
    if args.out is None or args.video is not None:
        fail(f"{args.source} is a folder of runs: give --out (where each run's episodes.csv and "
             "the summary go), and no --video")
    policies, missing = campaign_policies(args.source, args.steps, args.out)
    for env_id in sorted({p.env_id for p in policies}):
        check_reset_noise(sac.make_env(env_id), env_id, args.reset_noise, "--reset-noise")
    actions = list(dict.fromkeys(args.selectors))
    settings = {"command": ["evaluate.py", *sys.argv[1:]], "source": str(args.source),
                "episodes": args.episodes, "eval_round": args.eval_round,
                "reset_noise": args.reset_noise, "selectors": actions, "solver": args.solver,
                "steps": list(args.steps)}
    recorded = recorded_settings(args.out)
    if recorded is not None:
        check_same_settings(args.out, recorded, settings)
    # Rows in --out count only under a record of the settings they were evaluated with.
    finished = {} if recorded is None else finished_policies(args.out, policies, actions, args)
    left = [p for p in policies if (p.run, p.step) not in finished]
    if (gone := next((p for p in left if p.path is None), None)) is not None:
        fail(f"{gone.run} step {gone.step}: its rows in {args.out} are incomplete and its weights "
             f"are gone from {args.source}; put its snapshot back (from git: git checkout COMMIT "
             "-- PATH) and run the command again")
    if (args.out / CAMPAIGN_FILE).is_file():
        # evaluation.json marks --out complete: nothing is evaluated again, nor added to it.
        print(f"{args.out} is complete ({CAMPAIGN_FILE}): nothing evaluated, its summary again"
              + (f"; {len(left)} policies under {args.source} are not in it: evaluate them "
                 "into another --out" if left else ""), file=sys.stderr)
        (args.out / PARTIAL_FILE).unlink(missing_ok=True)  # a kill just after the end leaves it
        summarize_campaign(args.out)
        return
    print(f"{args.out}: {len(finished)} of {len(policies)} policies already evaluated, "
          f"{len(left)} left" + (f", {len(missing)} not there yet" if missing else ""),
          file=sys.stderr)
    planned = [plan_policy(policy, actions, args) for policy in left]  # fails before writing
    try:
        args.out.mkdir(parents=True, exist_ok=True)
        seconds = evaluate_policies(args, settings, planned, finished,
                                    recorded.get("seconds", 0.0) if recorded else 0.0)
        for run in dict.fromkeys(p.run for p in policies):  # as one attempt would leave them:
            write_run_files(args.out, run, finished)  # rows of policies now gone, dropped
        done = {"seconds": round(seconds, 1),
                "runs": {p.run: {"env_id": p.env_id, "seed": p.seed} for p in policies}}
        if missing:  # a campaign still training: --out stays open for them, to be resumed
            summarize_unfinished(args.out, settings | done, missing)
            print(f"{args.out} is not finished ({PARTIAL_FILE}): not there yet at --steps: "
                  f"{', '.join(missing)}; once they are, the same command evaluates them and "
                  f"writes the summary ({PARTIAL_SUMMARY}: the policies so far)", file=sys.stderr)
            return
        # evaluation.json marks --out complete: written last, in one step. The machine too: on
        # another kind of CPU the same command's episodes are other draws (docs/evaluate.md).
        complete = {k: v for k, v in settings.items() if k != "steps"} | {
            "seconds": done["seconds"], "workers": args.workers, "machine": machine(),
            "runs": done["runs"]}
        write_json(args.out / CAMPAIGN_FILE, complete)
        (args.out / PARTIAL_FILE).unlink(missing_ok=True)
        (args.out / PARTIAL_SUMMARY).unlink(missing_ok=True)
    except OSError as error:
        fail(f"--out {args.out}: cannot write there ({error.strerror}); give a writable folder")
    summarize_campaign(args.out)


def plan_policy(policy: Policy, actions: list[str], args: Args) -> tuple[Policy, list[int],
                                                                           list[Round]]:
    """Reset seeds from the run's seed: a run's steps start from the same states."""
    state = load_weights(policy.path)
    actor = build_actor(state["actor"], policy.env_id, policy.config, policy.path).eval()
    critic = build_critic(state, actor, policy.path) if "q_best" in actions else None
    seeds = eval_seeds(policy.seed, args.eval_round, args.episodes)
    return policy, seeds, make_jobs(actor, critic, policy.env_id, seeds, actions, args,
                                    label=f"{policy.run} step {policy.step}: ")


def evaluate_policies(args: Args, settings: dict,
                      planned: list[tuple[Policy, list[int], list[Round]]],
                      finished: dict[tuple[str, int], PolicyRows], seconds: float) -> float:
    """The seconds of all attempts at the end (`seconds`: of the earlier ones)."""
    write_json(args.out / PARTIAL_FILE, settings | {"seconds": seconds})
    if not planned:  # all finished by an attempt killed before it wrote evaluation.json
        return seconds
    actions = settings["selectors"]
    start, waiting, results = time.perf_counter(), list(planned), []

    def keep(result: dict) -> None:
        # in job order: the first waiting policy's come first
        results.append(result)
        policy, seeds, jobs = waiting[0]
        if len(results) < len(jobs):
            return
        merged, shift = merge(results, actions)
        shares = merged.get("q_best", {}).get("shares", {})
        finished[policy.run, policy.step] = (
            [[policy.step, *row] for row in episode_rows(merged, seeds)],
            [policy.step, *(repr(shift[c]) for c in SHIFT_COLUMNS),
             *(repr(shares[c]) if shares else "" for c in Q_BEST_CANDIDATES)])
        waiting.pop(0)
        results.clear()
        write_run_files(args.out, policy.run, finished)
        write_json(args.out / PARTIAL_FILE,
                   settings | {"seconds": seconds + time.perf_counter() - start})

    run_jobs([job for *_, jobs in planned for job in jobs], args.workers,
             f"{len(planned)} policies x {' '.join(actions)}", keep)
    return seconds + time.perf_counter() - start


# ----------------------------------------------------------------------- resuming a campaign
# While a campaign is evaluated, --out holds PARTIAL_FILE (the settings, the command and the
# seconds so far) and every finished policy's rows.
PARTIAL_FILE = "evaluation.partial.json"
# An unfinished campaign's per-policy tables so far: no across-seed figure is read from them.
PARTIAL_SUMMARY = "summary.partial.md"
# The settings that decide a policy's rows: a resumed evaluation must be given the same.
RESUME_SETTINGS = ("source", "episodes", "eval_round", "reset_noise", "selectors", "solver",
                   "steps")
EPISODES_HEADER = ["step", *EPISODE_COLUMNS]
# Before physics_unstable or end (results/*/robust*/): resumed with those cells empty ("not
# recorded"; the episodes are not run again), so that the rewritten file has one header.
OLD_EPISODES_HEADERS = (EPISODES_HEADER[:-2], EPISODES_HEADER[:-1])
SHIFT_HEADER = ["step", *SHIFT_COLUMNS, *(f"q_best_share_{c}" for c in Q_BEST_CANDIDATES)]
# One policy's episodes.csv rows and shift.csv row, each starting with its step.
PolicyRows = tuple[list[list], list]


# What a damaged evaluation.json or marker's one-line error ends with.
DAMAGED_RECORD = "the evaluation's record is damaged; give another --out"


def recorded_settings(out: Path) -> dict | None:
    """evaluation.json, else the marker, else None (a new evaluation)."""
    for path in (out / CAMPAIGN_FILE, out / PARTIAL_FILE):
        if path.is_file():
            return json_object_or_fail(path, DAMAGED_RECORD)
    return None


def check_same_settings(out: Path, recorded: dict, settings: dict) -> None:
    """evaluation.json has no steps: those go unchecked against a complete out."""
    def shown(value: object) -> str:
        if isinstance(value, list):
            return " ".join(map(str, value)) or "(not given)"
        return "(not given)" if value is None else str(value)

    differing = [k for k in RESUME_SETTINGS if k in recorded and (  # source: the same folder
        Path(recorded[k]).resolve() != Path(settings[k]).resolve() if k == "source"
        else recorded[k] != settings[k])]
    if differing:
        fail(f"--out {out} holds an evaluation with other settings ("
             + "; ".join(f"{'source' if k == 'source' else '--' + k.replace('_', '-')} "
                         f"{shown(recorded[k])} there, {shown(settings[k])} here"
                         for k in differing)
             + "): give the same source and flags to resume it, or another --out")


def finished_policies(out: Path, policies: list[Policy], actions: list[str],
                      args: Args) -> dict[tuple[str, int], PolicyRows]:
    """By (run, step), the policies whose rows in out are all there, from these reset seeds."""
    finished = {}
    for run, group in itertools.groupby(policies, key=lambda p: p.run):
        episodes = rows_by_step(out / run / "episodes.csv", EPISODES_HEADER,
                                OLD_EPISODES_HEADERS) or {}
        shifts = rows_by_step(out / run / "shift.csv", SHIFT_HEADER) or {}
        for policy in group:
            seeds = eval_seeds(policy.seed, args.eval_round, args.episodes)
            expected = [[s, str(k), str(seed)] for s in actions for k, seed in enumerate(seeds)]
            rows, shift = episodes.get(policy.step, []), shifts.get(policy.step, [])
            if [row[1:4] for row in rows] == expected and len(shift) == 1:
                finished[run, policy.step] = (rows, shift[0])
    return finished


def rows_by_step(path: Path, header: list[str], older: tuple[list[str], ...] = ()
                 ) -> dict[int, list[list[str]]] | None:
    """As text (rewritten, they are the same bytes); rows under an `older` header (header's
    first columns) padded with empty cells. None: no file, or another header."""
    rows = list(csv.reader(complete_lines(path))) if path.is_file() else []
    if not rows or (rows[0] != header and rows[0] not in older):
        return None
    grouped: dict[int, list[list[str]]] = {}
    for row in rows[1:]:
        grouped.setdefault(int(row[0]), []).append(row + [""] * (len(header) - len(rows[0])))
    return grouped


def write_run_files(out: Path, run: str, finished: dict[tuple[str, int], PolicyRows]) -> None:
    steps = sorted(step for name, step in finished if name == run)
    (out / run).mkdir(exist_ok=True)
    write_text_atomically(out / run / "episodes.csv", csv_text(
        [EPISODES_HEADER, *(row for step in steps for row in finished[run, step][0])]))
    write_text_atomically(out / run / "shift.csv", csv_text(
        [SHIFT_HEADER, *(finished[run, step][1] for step in steps)]))


def csv_text(rows: list[list]) -> str:
    text = io.StringIO()
    csv.writer(text).writerows(rows)
    return text.getvalue()


def read_campaign(out: Path) -> tuple[dict, dict[tuple[str, int, str], list[list[str]]]]:
    """evaluation.json, and episodes.csv's rows by (run, step, action)."""
    settings = json_object_or_fail(out / CAMPAIGN_FILE, DAMAGED_RECORD)
    return settings, campaign_episodes(out, settings["runs"])


def campaign_episodes(out: Path, runs: Iterable[str]
                      ) -> dict[tuple[str, int, str], list[list[str]]]:
    """episodes.csv's rows of these runs by (run, step, action)."""
    episodes: dict[tuple[str, int, str], list[list[str]]] = {}
    for run in runs:
        path = out / run / "episodes.csv"
        if not path.is_file():
            fail(f"{path} is missing: {out} is incomplete; evaluate the campaign again")
        by_step = rows_by_step(path, EPISODES_HEADER, OLD_EPISODES_HEADERS)
        if by_step is None:
            fail(f"{path} does not start with a header evaluate.py writes; restore it")
        selector = EPISODES_HEADER.index("selector")
        for step, rows in by_step.items():
            for row in rows:
                episodes.setdefault((run, step, row[selector]), []).append(row)
    return episodes


def read_shifts(out: Path, settings: dict) -> dict[tuple[str, int], list[str]]:
    """shift.csv's row by (run, step), where a run has the file (older campaigns may not)."""
    shifts = {}
    for run in settings["runs"]:
        for step, rows in (rows_by_step(out / run / "shift.csv", SHIFT_HEADER) or {}).items():
            shifts[run, step] = rows[0]
    return shifts


def per_seed_rows(settings: dict, episodes: dict[tuple[str, int, str], list[list[str]]]
                  ) -> list[dict]:
    """unstable_ends and end_<why> only where some episode records them: a folder of older
    files keeps its summary as it was."""
    column = {c: EPISODES_HEADER.index(c) for c in ("return", "physics_unstable", "end")}

    def recorded(rows: list[list[str]], name: str) -> list[str] | None:
        cells = [row[column[name]] for row in rows]
        return cells if all(cells) else None  # an empty cell: not recorded

    returns = {key: np.array([float(row[column["return"]]) for row in rows])
               for key, rows in episodes.items()}
    flags = {key: recorded(rows, "physics_unstable") for key, rows in episodes.items()}
    ends = {key: recorded(rows, "end") for key, rows in episodes.items()}
    any_unstable = any(cells is not None for cells in flags.values())
    reasons = sorted({why for cells in ends.values() for why in cells or ()})
    rows, order = [], {s: i for i, s in enumerate(settings["selectors"])}
    for (run, step, action), values in sorted(returns.items(),
                                                key=lambda kv: (*kv[0][:2], order[kv[0][2]])):
        row = {"env_id": settings["runs"][run]["env_id"], "run": run,
               "seed": settings["runs"][run]["seed"], "step": step, "selector": action,
               "episodes": len(values), "return_mean": values.mean(),
               "return_se": estimators.standard_error(values)}
        baseline = returns.get((run, step, "tanh_mu"))
        if action != "tanh_mu" and baseline is not None:
            diffs = estimators.paired_difference(values, baseline)
            row |= {"tanh_mu_return_mean": float(np.mean(baseline)),
                    "difference_mean": diffs.mean(),
                    "difference_se": estimators.standard_error(diffs),
                    "share_better": float(np.mean(diffs > 0))}
        key, pair = (run, step, action), ends.get((run, step, "tanh_mu"))
        for why in report.SHARE_ENDS:
            if action == "tanh_mu" or why not in reasons or ends[key] is None or pair is None:
                continue
            # "The mode's episodes end with the robot down more often", tested as the returns are:
            # per start, 1 where the action's episode ended so minus 1 where tanh(mu)'s did.
            share = estimators.paired_difference(np.array(ends[key]) == why,
                                                 np.array(pair) == why)
            row |= {f"{why}_difference_mean": share.mean(),
                    f"{why}_difference_se": estimators.standard_error(share)}
        if any_unstable:
            row["unstable_ends"] = None if flags[key] is None else sum(map(int, flags[key]))
        counts = None if ends[key] is None else collections.Counter(ends[key])
        row |= {f"end_{why}": None if counts is None else counts[why] for why in reasons}
        rows.append(row)
    return rows


def write_rows(path: Path, rows: list[dict]) -> None:
    columns = list(dict.fromkeys(k for row in rows for k in row))
    write_text_atomically(path, csv_text([columns, *(
        [repr(float(v)) if isinstance(v, float) else v for v in map(row.get, columns)]
        for row in rows)]))


def summarize_campaign(out: Path) -> None:
    """per_seed.csv and summary.md from the CSVs; across seeds is analyze.py's (--robust)."""
    settings, episodes = read_campaign(out)
    per_seed, text = campaign_summary(out, settings, episodes)
    write_rows(out / "per_seed.csv", per_seed)
    write_text_atomically(out / "summary.md", text)
    print(text, end="")
    print(f"wrote {out / 'summary.md'} and per_seed.csv; across seeds: analyze.py RUNS "
          f"--robust {out}")


def summarize_unfinished(out: Path, settings: dict, missing: list[str]) -> None:
    """summary.partial.md: summary.md's per-policy tables for the policies evaluated so far
    (settings' runs), headed by those not there yet."""
    _, text = campaign_summary(out, settings, campaign_episodes(out, settings["runs"]), missing)
    write_text_atomically(out / PARTIAL_SUMMARY, text)


def campaign_summary(out: Path, settings: dict,
                     episodes: dict[tuple[str, int, str], list[list[str]]],
                     missing: Sequence[str] = ()) -> tuple[list[dict], str]:
    """per_seed.csv's rows and the summary's text (an unfinished one's with `missing`)."""
    per_seed = per_seed_rows(settings, episodes)
    return per_seed, campaign_markdown(settings, per_seed, episodes, read_shifts(out, settings),
                                       missing)


def fall_split(settings: dict, episodes: dict[tuple[str, int, str], list[list[str]]]
               ) -> list[str]:
    """Per policy, the first action's paired return differences against tanh(mu) split by how
    the two episodes from each start ended: is its difference in the starts where one episode
    ended early (an h1hand robot fell; a gymnasium body left its healthy range, "terminated"),
    or spread over all of them? A part is chosen by the episodes' own outcomes, so "only the
    action's fell" is a loss by construction."""
    action = next((a for a in settings["selectors"] if a != estimators.BASELINE), None)
    column = {c: EPISODES_HEADER.index(c) for c in ("return", "end")}
    ends = {r[column["end"]] for group in episodes.values() for r in group}
    early = next((why for why in report.SHARE_ENDS if why in ends), None)
    if early is None:
        return []
    # a task column where the runs span several (a campaign's rows are otherwise one task's)
    several = len({about["env_id"] for about in settings["runs"].values()}) > 1
    rows = []
    for run, about in sorted(settings["runs"].items(),
                             key=lambda kv: (kv[1]["env_id"] if several else "", kv[1]["seed"])):
        for step in sorted({s for r, s, _ in episodes if r == run}):
            pairs = list(zip(episodes.get((run, step, action), []),
                             episodes.get((run, step, estimators.BASELINE), []), strict=False))
            if not pairs or not all(it[column["end"]] and base[column["end"]]
                                    for it, base in pairs):
                continue
            parts: dict[tuple[bool, bool], list[float]] = {
                (False, False): [], (True, False): [], (False, True): [], (True, True): []}
            for it, base in pairs:
                parts[it[column["end"]] == early, base[column["end"]] == early].append(
                    float(it[column["return"]]) - float(base[column["return"]]))
            rows.append([*([about["env_id"]] if several else []), about["seed"],
                         report.format_step(step), *(
                f"{len(v)}" + (f", {v[0]:+.2f}" if v else "") if len(v) < 2 else
                f"{len(v)}, {np.mean(v):+.2f} +- {estimators.standard_error(v):.2f}"
                for v in parts.values())])
    return ["## Where the differences are", "",
            f"Per policy, {action} minus tanh(mu) split by how the two episodes from each start "
            "ended; each cell: starts, and the mean difference over them +- the standard error "
            "of those differences.", "",
            report.markdown_table([*(["task"] if several else []), "seed", "step",
                                   f"neither {early}",
                                   f"only the {action}'s {early}", f"only tanh(mu)'s {early}",
                                   f"both {early}"], rows), ""]


def shift_action(actions: list[str]) -> str:
    """The action whose visited states the shift statistics are taken at."""
    return "mode" if "mode" in actions else actions[0]


def shift_table(settings: dict, shifts: dict[tuple[str, int], list[str]]) -> list[str]:
    """Per policy (shift.csv): the shift the mode makes at the states the mode's episodes (else
    the first action's) visited, per dimension and summed, the policy's sigma and its share of
    two-mode dimensions there; and which action q_best picked in its own episodes."""
    if not shifts:
        return []
    rows = []
    about = settings["runs"]
    for (run, step), row in sorted(shifts.items(), key=lambda kv: (
            about[kv[0][0]]["env_id"], about[kv[0][0]]["seed"], kv[0][1])):
        cells = {c: float(v) for c, v in zip(SHIFT_HEADER[1:], row[1:], strict=True) if v}
        picks = " / ".join(f"{100 * cells[f'q_best_share_{c}']:.0f}%" if
                           f"q_best_share_{c}" in cells else "-" for c in Q_BEST_CANDIDATES)
        number = {c: f"{cells[c]:.4g}" if c in cells else "-" for c in SHIFT_COLUMNS}
        if "bimodal_fraction" in cells:
            number["bimodal_fraction"] = f"{100 * cells['bimodal_fraction']:.1f}%"
        rows.append([about[run]["env_id"], about[run]["seed"], report.format_step(step),
                     *number.values(), picks])
    visited = shift_action(settings["selectors"])
    return ["## The shift at the visited states", "",
            f"Per policy, over the states its {visited} episodes visited: |mode - tanh(mu)| "
            "per action dimension (mean) and summed over dimensions, the policy's sigma (mean "
            "over dimensions) and the share of dimensions whose tanh-Gaussian has two modes; and, "
            "over q_best's own episodes, the share of its states where it picked tanh(mu) / the "
            "mode / the mean.", "",
            report.markdown_table(["task", "seed", "step", "mean abs(mode - tanh(mu))",
                                   "summed over dimensions", "sigma", "two-mode dimensions",
                                   "q_best's picks (tanh(mu) / mode / mean)"], rows), ""]


def campaign_markdown(settings: dict, per_seed: list[dict],
                      episodes: dict[tuple[str, int, str], list[list[str]]] | None = None,
                      shifts: dict[tuple[str, int], list[str]] | None = None,
                      missing: Sequence[str] = ()) -> str:
    """missing: an unfinished campaign's policies not there yet (summary.partial.md)."""
    noise = settings["reset_noise"]
    lines = [f"# {'Unfinished evaluation' if missing else 'Evaluation'} of "
             f"{len(settings['runs'])} runs from `{settings['source']}`", "",
             f"`{' '.join(settings['command'])}`", "",
             *([f"**Not finished**: the policies evaluated so far; not there yet: "
                f"{', '.join(missing)}. The same command evaluates them once they are, and "
                "writes summary.md.", ""] if missing else []),
             f"Each policy (a run's snapshot or final weights) acted with "
             f"{', '.join(settings['selectors'])} for {settings['episodes']} episodes; episode k "
             f"of every action and every step of a run starts from the same state (reset seeds "
             f"from the run's seed, round {settings['eval_round']}; reset noise on qpos: "
             f"{'the task' + chr(39) + 's own' if noise is None else f'+-{noise}'}). "
             f"{settings['seconds']:.0f} s of evaluation. Across seeds: analyze.py --robust.", "",
             "## Per seed", "", *report.per_seed_tables(per_seed, settings["selectors"])]
    failed = [f"seed {r['seed']} step {r['step']} {r['selector']}" for r in per_seed
              if "difference_se" in r and not (r["tanh_mu_return_mean"] and r["difference_se"]
                                               / abs(r["tanh_mu_return_mean"]) < PRECISION)]
    lines += [f"Precision check: {'every' if not failed else 'not every'} seed's paired "
              f"difference has a standard error below {PRECISION:.0%} of tanh(mu)'s mean return"
              + (f"; above it: {', '.join(failed)} (more --episodes would narrow it)."
                 if failed else "."), "", *fall_split(settings, episodes or {}),
              *shift_table(settings, shifts or {})]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    check_args(args)
    if (args.source / CAMPAIGN_FILE).is_file():
        summarize_campaign(args.source)
        return
    if (args.source / PARTIAL_FILE).is_file():
        command = " ".join((recorded_settings(args.source) or {}).get("command", []))
        fail(f"{args.source} holds a campaign evaluation not finished yet ({PARTIAL_FILE}): run "
             f"its command again to finish it ({command})")
    if is_campaign(args.source):
        evaluate_campaign(args)
        return
    actor, critic, env_id, info = load_policy(args.source, args.env_id, "q_best" in args.selectors)
    actor = actor.eval()
    if args.video:
        try:
            args.video.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            fail(f"--video {args.video}: cannot create it ({error.strerror}); give a "
                 "writable folder")
    seeds = eval_seeds(args.seed, args.eval_round, args.episodes)
    check_reset_noise(sac.make_env(env_id), env_id, args.reset_noise, "--reset-noise")
    actions = list(dict.fromkeys(args.selectors))
    jobs = make_jobs(actor, critic, env_id, seeds, actions, args)
    results, shift = merge(run_jobs(jobs, args.workers, " ".join(actions)), actions)
    summary = summarise(results, shift, args, info, env_id,
                        distinct_starts(env_id, seeds, args.reset_noise))
    print_summary(summary)
    if args.out:
        try:
            args.out.mkdir(parents=True, exist_ok=True)
            write_text_atomically(args.out / "episodes.csv", csv_text(
                [EPISODE_COLUMNS, *episode_rows(results, seeds)]))
            write_json(args.out / "summary.json", summary)
        except OSError as error:
            fail(f"--out {args.out}: cannot write there ({error.strerror}); give a writable "
                 "folder")
        print(f"\nwrote {args.out / 'episodes.csv'} and {args.out / 'summary.json'}")


if __name__ == "__main__":
    main()
