"""The data model analyze.py reports on: scores by task, (algorithm, action), seed and step,
from the runs' eval.csv (`load_runs`) and evaluate.py's per_seed.csv (`load_robust`). Nothing
here writes a report; the notes each step returns (runs skipped, cut, left out) go to summary.md.
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from analysis import estimators
from analysis.report import format_step
from sac_utils import files


class AnalysisError(Exception):
    """A problem with the input that the user can fix: reported as one message, no traceback."""


# ============================================================================== what to edit
# HumanoidBench's success bars, the return at which a task counts as solved (a score of 1.0 under
# the default normalisation). A task without one is scored min-max (analyze.py --normalize).
SUCCESS_BARS = {
    "h1hand-stand-v0": 800.0,
    "h1hand-powerlift-v0": 800.0,
    "h1hand-cube-v0": 370.0,
    "h1hand-bookshelf_simple-v0": 2000.0,
    "h1hand-bookshelf_hard-v0": 2000.0,
}

STANDARD, CORRECTED = "standard", "corrected"
# The action each script evaluates with on its own (eval.csv's unprefixed columns).
OWN_ACTIONS = {CORRECTED: "mode", STANDARD: "tanh_mu"}
# An evaluation action: a block of eval.csv columns NAME_return_mean, ... of the same actor
# from the same start states (sac_corrected.py always logs tanh_mu_; --eval-selectors adds
# mean_, q_best_ and, for sac_standard.py, mode_) -> its name in figures and tables.
ACTIONS = {"tanh_mu": "tanh(mu)", "mode": "mode", "mean": "mean", "q_best": "q_best"}
BASELINE = estimators.BASELINE
# Optional: how often an action's critic picked each candidate (shares summing to 1).
CHOICE_SHARES = {"q_best": ("q_best_share_mode", "q_best_share_tanh_mu", "q_best_share_mean")}
Key = tuple[str, str]  # a group of evaluations: (algorithm, action)


def own_action(algorithm: str) -> str:
    """The action an algorithm's runs evaluate with on their own; an unknown one's, its name."""
    return OWN_ACTIONS.get(algorithm, algorithm)


def is_own(key: Key) -> bool:
    """The runs' own evaluation, not a paired evaluation with another action."""
    return key[1] == own_action(key[0])


def eval_suffix(key: Key) -> str:
    """"" for its own action, " (mean eval)"."""
    return "" if is_own(key) else f" ({ACTIONS.get(key[1], key[1])} eval)"


def group_name(key: Key) -> str:
    """summary.csv's group: "corrected", "corrected (mean eval)"."""
    return key[0] + eval_suffix(key)


# ------------------------------------------------------------------------- the run-folder format
# docs/scripts.md, "The run folder", documents it. Everything else in a run folder is ignored.
CONFIG_FILE = "config.json"
EVAL_FILE = "eval.csv"
REQUIRED_CONFIG_KEYS = ("env_id", "seed", "algorithm")
STEP_COLUMN = "global_step"
RETURN_COLUMN = "return_mean"  # mean return of the script's own evaluation action
REQUIRED_EVAL_COLUMNS = (STEP_COLUMN, RETURN_COLUMN)
PAIRED_RETURN_COLUMN = f"{BASELINE}_{RETURN_COLUMN}"
# Optional: the shift sac_corrected.py measures at the states its mode policy visited.
SHIFT_COLUMNS = ("mode_shift_abs_mean", "mode_shift_abs_sum", "sigma_mean", "bimodal_fraction")
# Over training: the shift per action dimension, which tasks of any dimension share an axis on.
OVER_TRAINING_SHIFT_COLUMNS = ("mode_shift_abs_mean", "sigma_mean", "bimodal_fraction")
# Optional: distinct episodes per evaluation round (one where the task resets without noise).
EPISODES_COLUMN = "distinct_episodes"

# A standard run and the paired evaluation of the corrected run of the same seed agree when
# their returns at a shared step differ by at most this (relative): the CSVs hold the same
# floats, so any real difference (other flags, code, or device) is far larger.
AGREEMENT_RTOL = 1e-9

# ============================================================================== the data
# ------------------------------------------------------------------------------------- load
@dataclasses.dataclass
class Curve:
    """One run's evaluation returns, at the steps it logged, for one group."""

    run_dir: Path
    seed: int
    steps: np.ndarray
    returns: np.ndarray
    action_dim: int | None = None  # config.json's, where it has one
    # eval.csv's SHIFT_COLUMNS (the run's own curve), its action's CHOICE_SHARES (a paired one)
    logged: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    budget: int | None = None  # config.json's total_timesteps, where it has one
    episodes: np.ndarray | None = None  # EPISODES_COLUMN per step, where the run logged it
    restarts: tuple[int, ...] = ()  # steps where the run restarted from a snapshot


# task -> (algorithm, action) -> curves sorted by seed
Runs = dict[str, dict[Key, list[Curve]]]


def read_config(path: Path) -> dict:
    """The run's config.json, checked for the keys analyze.py needs."""
    config = files.read_json_object(path, f"fix or remove that run (it needs keys "
                                          f"{list(REQUIRED_CONFIG_KEYS)})", AnalysisError)
    missing = [key for key in REQUIRED_CONFIG_KEYS if key not in config]
    if missing:
        raise AnalysisError(
            f"{path} lacks key(s) {missing}; every config.json needs {list(REQUIRED_CONFIG_KEYS)}")
    if not isinstance(config["seed"], int) or isinstance(config["seed"], bool):
        raise AnalysisError(f"{path}: seed must be an integer, got {config['seed']!r}")
    for key in ("env_id", "algorithm"):
        if not isinstance(config[key], str) or not config[key]:
            raise AnalysisError(f"{path}: {key} must be a non-empty string, got {config[key]!r}")
    return config


def read_eval_csv(path: Path) -> tuple[dict[str, np.ndarray], bool]:
    """The columns analyze.py uses, as arrays, and whether an incomplete last line (a run
    killed mid-write) was dropped."""
    lines = path.read_text(encoding="utf-8", errors="replace").splitlines(keepends=True)
    partial = bool(lines) and not lines[-1].endswith(("\n", "\r"))
    rows = [row for row in csv.reader(lines[:-1] if partial else lines) if row]
    if not rows:
        return {name: np.empty(0) for name in REQUIRED_EVAL_COLUMNS}, partial
    header, body = [name.strip() for name in rows[0]], rows[1:]
    missing = [name for name in REQUIRED_EVAL_COLUMNS if name not in header]
    if missing:
        raise AnalysisError(
            f"{path} lacks column(s) {missing}; eval.csv needs a header row with at least "
            f"{list(REQUIRED_EVAL_COLUMNS)} (see docs/analyze.md)")
    optional = (*(f"{action}_{RETURN_COLUMN}" for action in ACTIONS),
                *(column for columns in CHOICE_SHARES.values() for column in columns),
                *SHIFT_COLUMNS, EPISODES_COLUMN)
    wanted = [*REQUIRED_EVAL_COLUMNS, *(c for c in optional if c in header)]
    columns = {name: np.empty(len(body)) for name in wanted}
    for i, row in enumerate(body):
        if len(row) != len(header):
            raise AnalysisError(
                f"{path}, row {i + 2}: {len(row)} fields where the header has {len(header)}; "
                "fix or delete that row")
        for name in wanted:
            columns[name][i] = _parse_number(row[header.index(name)], path, i + 2, name,
                                             name in optional)
    _check_columns(columns, path)
    return columns, partial


def _parse_number(text: str, path: Path, row: int, column: str, optional: bool) -> float:
    if not text.strip() and optional:
        return math.nan  # optional column: an empty cell means "not measured"
    try:
        value = float(text)
    except ValueError:
        raise AnalysisError(f"{path}, row {row}: {column} = {text!r} is not a number") from None
    if not math.isfinite(value) and not optional:
        raise AnalysisError(f"{path}, row {row}: {column} = {text!r} is not a finite number")
    return value


def _check_columns(columns: dict[str, np.ndarray], path: Path) -> None:
    steps = columns[STEP_COLUMN]
    if np.any(steps != np.round(steps)):
        raise AnalysisError(f"{path}: {STEP_COLUMN} must hold whole environment steps")
    if np.any(np.diff(steps) <= 0):
        row = int(np.argmax(np.diff(steps) <= 0)) + 3
        raise AnalysisError(
            f"{path}, row {row}: {STEP_COLUMN} does not increase (a resumed run whose log "
            "was not truncated?); keep one row per evaluation step")


def load_runs(roots: Sequence[Path]) -> tuple[Runs, list[str]]:
    """Every run under the `roots`, grouped by task and group, and notes on what was skipped."""
    for root in roots:
        if not root.is_dir():
            raise AnalysisError(
                f"{root} is not a folder; pass the folder(s) that hold the run folders")
    runs: Runs = {}
    notes: list[str] = []
    # A folder named twice (or inside another one named) is read once.
    configs = {path.resolve(): path for root in roots for path in sorted(root.rglob(CONFIG_FILE))}
    for config_path in configs.values():
        run_dir = config_path.parent
        if not (run_dir / EVAL_FILE).is_file():
            notes.append(f"{run_dir}: no {EVAL_FILE} yet; skipped")
            continue
        config = read_config(config_path)
        # config.json's "restarts" (`sweep.py restart`): where the run's curve stops being its own
        restarts = config.get("restarts")
        restarts = [r for r in restarts if isinstance(r, dict)] if isinstance(restarts, list) \
            else []
        notes += [f"{run_dir}: restarted from {r.get('snapshot')} at step {r.get('step')} (its "
                  f"checkpoint lost; the replay buffer refilled for {r.get('refill')} steps): "
                  "from there a new sample, not the lost run's future" for r in restarts]
        columns, partial = read_eval_csv(run_dir / EVAL_FILE)
        if partial:
            notes.append(
                f"{run_dir / EVAL_FILE}: incomplete last line (killed mid-write?); "
                "read up to the last complete row")
        if columns[STEP_COLUMN].size == 0:
            notes.append(f"{run_dir}: no complete evaluation row yet; skipped")
            continue
        task, algorithm, seed = config["env_id"], config["algorithm"], config["seed"]
        steps = columns[STEP_COLUMN].astype(np.int64)
        action_dim = config.get("action_dim") if isinstance(config.get("action_dim"), int) \
            else None
        budget = config.get("total_timesteps")
        budget = budget if isinstance(budget, int) and budget > 0 else None
        curve = functools.partial(
            Curve, run_dir, seed, steps, action_dim=action_dim, budget=budget,
            episodes=columns.get(EPISODES_COLUMN),
            restarts=tuple(r["step"] for r in restarts if isinstance(r.get("step"), int)))
        own = (algorithm, own_action(algorithm))
        _add_curve(runs, task, own, curve(columns[RETURN_COLUMN], logged={
            c: columns[c] for c in SHIFT_COLUMNS if c in columns}))
        for action in ACTIONS:
            paired = columns.get(f"{action}_{RETURN_COLUMN}")
            if paired is None or action == own[1]:
                continue
            if np.isfinite(paired).all():
                _add_curve(runs, task, (algorithm, action), curve(paired, logged={
                    c: columns[c] for c in CHOICE_SHARES.get(action, ()) if c in columns}))
            else:
                notes.append(f"{run_dir}: {action}_{RETURN_COLUMN} has empty cells; "
                             f"its paired {action} eval left out")
    if not runs:
        raise AnalysisError(
            f"no runs found under {', '.join(map(str, roots))}: a run is a folder holding "
            f"{CONFIG_FILE} (keys "
            f"{list(REQUIRED_CONFIG_KEYS)}) and {EVAL_FILE} (columns "
            f"{list(REQUIRED_EVAL_COLUMNS)}); see docs/analyze.md")
    for groups in runs.values():
        for curves in groups.values():
            curves.sort(key=lambda curve: curve.seed)
    return runs, notes


def restart_marks(runs: Runs) -> dict[str, list[tuple[int, int]]]:
    """task -> (seed, step) of every restart from a snapshot among its runs, for the figures
    over training to mark."""
    return {task: sorted({(curve.seed, step) for curves in groups.values() for curve in curves
                          for step in curve.restarts})
            for task, groups in runs.items()}


def _add_curve(runs: Runs, task: str, key: Key, curve: Curve) -> None:
    curves = runs.setdefault(task, {}).setdefault(key, [])
    twin = next((other for other in curves if other.seed == curve.seed), None)
    if twin is not None:
        raise AnalysisError(
            f"two runs of {task}, {group_name(key)}, seed {curve.seed}: {twin.run_dir} and "
            f"{curve.run_dir}; move one out of the folder")
    curves.append(curve)


def group_order() -> list[Key]:
    """The paper's groups in a fixed order (so that tables and colours stay put): the two
    algorithms, corrected's tanh(mu), then each algorithm's other evaluation actions."""
    others = [(algorithm, action) for algorithm in (CORRECTED, STANDARD) for action in ACTIONS
              if action not in (BASELINE, own_action(algorithm))]
    return [(STANDARD, BASELINE), (CORRECTED, "mode"), (CORRECTED, BASELINE), *others]


def group_rank(key: Key) -> tuple[int, str]:
    """Sort key: the paper's groups first, in a fixed order, then the others by name."""
    order = group_order()
    return (order.index(key) if key in order else len(order), group_name(key))


def ordered_groups(runs: Runs) -> list[Key]:
    """Every group in the folder: the paper's first, in a fixed order (so colours stay put)."""
    return sorted({key for groups in runs.values() for key in groups}, key=group_rank)


# ------------------------------------------------------------------------------------- pair
@dataclasses.dataclass
class Pairing:
    """How the corrected runs' paired tanh(mu) evaluation relates to the standard runs."""

    derived: list[str]  # tasks whose standard group is the corrected runs' paired evaluation
    agreeing: dict[str, int]  # task -> (seed, step) points where standard and paired agree
    disagreeing: list[str]  # one line per standard run that disagrees with its paired twin


def standard_from_paired(runs: Runs) -> Pairing:
    """A corrected run's tanh(mu) evaluation is the standard run of its seed (same training
    decisions, same start states, same actor). A task without sac_standard.py runs gets them
    from it; a task with both is checked point by point (same seed, same step)."""
    pairing = Pairing([], {}, [])
    paired_key, standard_key = (CORRECTED, BASELINE), (STANDARD, BASELINE)
    for task, groups in sorted(runs.items()):
        if paired_key not in groups:
            continue
        if standard_key not in groups:
            groups[standard_key] = groups.pop(paired_key)
            pairing.derived.append(task)
            continue
        paired = {curve.seed: curve for curve in groups[paired_key]}
        for standard in groups[standard_key]:
            twin = paired.get(standard.seed)
            if twin is None:
                continue
            steps, i, j = np.intersect1d(standard.steps, twin.steps, return_indices=True)
            a, b = standard.returns[i], twin.returns[j]
            differ = ~np.isclose(a, b, rtol=AGREEMENT_RTOL, atol=0.0)
            if differ.any():
                k = int(np.argmax(differ))
                pairing.disagreeing.append(
                    f"{task}, seed {standard.seed}: {standard.run_dir} and the paired evaluation "
                    f"of {twin.run_dir} differ at {int(differ.sum())} of {steps.size} shared "
                    f"steps (step {format_step(steps[k])}: {a[k]:.6g} vs {b[k]:.6g}); made with "
                    "other flags or code? Kept apart")
            else:
                pairing.agreeing[task] = pairing.agreeing.get(task, 0) + steps.size
    return pairing


# ------------------------------------------------------------------------------------- align
@dataclasses.dataclass
class Task:
    """A task's runs aligned on the evaluation steps all of them share."""

    steps: np.ndarray  # (steps,) shared by every run of the task
    returns: dict[Key, np.ndarray]  # (seeds, steps)
    seeds: dict[Key, list[int]]
    scored_step: int  # the step final scores are taken at
    budget: int  # the runs' total_timesteps where they agree, else the last shared step

    def at(self, group: Key, steps: np.ndarray) -> np.ndarray:
        """The group's returns at some of the shared steps, (seeds, steps)."""
        return self.returns[group][:, np.searchsorted(self.steps, steps)]

    def scored(self, group: Key) -> np.ndarray:
        """The group's returns at the scored step, one per seed."""
        return self.at(group, np.array([self.scored_step]))[:, 0]


def align(runs: Runs, at_step: int | None) -> tuple[dict[str, Task], list[str]]:
    """Each task's runs on their shared steps, and notes on the runs that were cut."""
    tasks, notes = {}, []
    for task, groups in sorted(runs.items()):
        curves = [curve for group in groups.values() for curve in group]
        steps = functools.reduce(np.intersect1d, [curve.steps for curve in curves])
        if steps.size == 0:
            raise AnalysisError(
                f"the runs of {task} share no evaluation step (different eval intervals or "
                "step ranges); analyse runs logged on a common step grid")
        scored_step = _scored_step(task, curves, steps, at_step)
        notes += _alignment_notes(task, curves, steps, scored_step)
        tasks[task] = Task(
            steps=steps,
            returns={g: np.stack([c.returns[np.searchsorted(c.steps, steps)] for c in cs])
                     for g, cs in groups.items()},
            seeds={g: [c.seed for c in cs] for g, cs in groups.items()},
            scored_step=scored_step,
            budget=task_budget(curves, steps),
        )
    return tasks, notes


def task_budget(curves: list[Curve], steps: np.ndarray) -> int:
    """The task's training budget: its runs' total_timesteps where all give the same one,
    else the last step its runs share."""
    budgets = {curve.budget for curve in curves}
    return budgets.pop() if len(budgets) == 1 and None not in budgets else int(steps[-1])


def _scored_step(task: str, curves: list[Curve], steps: np.ndarray, at_step: int | None) -> int:
    if at_step is None:
        return int(steps[-1])
    if at_step not in steps:
        lacking = [c for c in curves if at_step not in c.steps]
        example = f" (e.g. {lacking[0].run_dir}, which stops at {lacking[0].steps[-1]})"
        raise AnalysisError(
            f"--at-step {at_step}: not every run of {task} was evaluated at that step"
            f"{example if lacking else ''}; steps all its runs share: "
            f"{format_step(steps[0])} .. {format_step(steps[-1])}, {steps.size} in all")
    return at_step


def _alignment_notes(
    task: str, curves: list[Curve], steps: np.ndarray, scored_step: int
) -> list[str]:
    notes = []
    # A paired evaluation shares its run with its algorithm's curve: name each run once.
    cut = {c.run_dir: c.steps[-1] for c in curves if c.steps[-1] > steps[-1]}
    if cut:
        shortest = min(curves, key=lambda c: c.steps[-1])
        notes.append(
            f"{task}: its runs share steps up to {format_step(steps[-1])} (shortest run: "
            f"{shortest.run_dir}, to {format_step(shortest.steps[-1])}); curves and scores stop "
            "there. Cut: "
            + ", ".join(f"{d} (reached {format_step(last)})" for d, last in cut.items()))
    unshared = {c.run_dir for c in curves
                if np.setdiff1d(c.steps[c.steps <= steps[-1]], steps).size}
    if unshared:
        notes.append(
            f"{task}: evaluation steps differ between runs ({len(unshared)} run(s) have steps "
            f"others lack); curves and scores use the {steps.size} steps all runs share")
    if scored_step != steps[-1]:
        notes.append(f"{task}: final scores taken at --at-step {format_step(scored_step)}")
    return notes


# ----------------------------------------------------------------------- paired differences
def paired_groups(data: Task, derived: bool) -> list[tuple[Key, Key]]:
    """(group of some evaluation action, group of tanh(mu) of the same actors) pairs present in
    a task; `derived`: its standard group is the corrected runs' paired evaluation."""
    pairs = []
    for key in sorted(data.returns, key=group_rank):
        baseline = (key[0], BASELINE)
        if key[0] == CORRECTED and derived and baseline not in data.returns:
            baseline = (STANDARD, BASELINE)
        if baseline in data.returns and key[1] != BASELINE:
            pairs.append((key, baseline))
    return pairs


def paired_difference_curves(tasks: dict[str, Task], derived: Sequence[str] = ()
                             ) -> dict[str, dict[Key, np.ndarray]]:
    """task -> group -> per-seed difference (group minus tanh(mu) of the same actors) at every
    shared step, (seeds, steps), on the seeds both have (a run made without some evaluation
    action has no partner there)."""
    curves: dict[str, dict[Key, np.ndarray]] = {}
    for task, data in tasks.items():
        for group, baseline in paired_groups(data, task in derived):
            seeds = sorted(set(data.seeds[group]) & set(data.seeds[baseline]))
            own, paired = ([data.seeds[g].index(seed) for seed in seeds] for g in (group, baseline))
            curves.setdefault(task, {})[group] = estimators.paired_difference(
                data.returns[group][own], data.returns[baseline][paired])
    return curves


def paired_differences(tasks: dict[str, Task], derived: Sequence[str] = ()
                       ) -> dict[str, dict[Key, np.ndarray]]:
    """paired_difference_curves at each task's scored step: task -> group -> one per seed."""
    return {task: {g: diffs[:, np.searchsorted(tasks[task].steps, tasks[task].scored_step)]
                   for g, diffs in by_group.items()}
            for task, by_group in paired_difference_curves(tasks, derived).items()}


# Each seed's paired difference averaged over its last evaluation rounds, since one round of a
# noisy task is one draw of that noise.
LAST_ROUNDS = (20, 50)


def last_rounds_averages(tasks: dict[str, Task], curves: dict[str, dict[str, np.ndarray]]
                         ) -> tuple[dict[tuple[str, str, int], np.ndarray],
                                    dict[tuple[str, int], np.ndarray], list[str]]:
    """Per seed, each paired difference averaged over the last k shared evaluation steps up to
    the scored step, for each k of LAST_ROUNDS: (task, group, k) -> per-seed averages, (task, k)
    -> the window's steps, and notes on the tasks with fewer steps than k."""
    averages, windows, short = {}, {}, {}
    for task, by_group in curves.items():
        data = tasks[task]
        rounds = int(np.searchsorted(data.steps, data.scored_step, side="right"))
        if rounds < max(LAST_ROUNDS):
            short[task] = rounds
        for k in LAST_ROUNDS:
            if k > rounds:
                continue
            windows[task, k] = data.steps[rounds - k:rounds]
            for group, diffs in by_group.items():
                averages[task, group, k] = diffs[:, rounds - k:rounds].mean(axis=1)
    notes = [f"averages over the last {' / '.join(map(str, LAST_ROUNDS))} evaluation rounds left "
             "out where a task has fewer shared rounds up to its scored step: "
             + ", ".join(f"{task} ({rounds} rounds)" for task, rounds in short.items())
             ] if short else []
    return averages, windows, notes


def one_episode_per_seed(curves: Sequence[Curve], steps: np.ndarray) -> bool:
    """Whether every run logged one distinct episode (eval.csv's distinct_episodes) at each of
    `steps`, which all of them share: its return there is one draw of the episode's noise."""
    return bool(curves) and all(
        c.episodes is not None and np.all(c.episodes[np.searchsorted(c.steps, steps)] == 1)
        for c in curves)


def shift_curves(runs: Runs, tasks: dict[str, Task]) -> dict[str, dict[str, np.ndarray]]:
    """task -> shift column -> (runs, steps) at the task's shared steps, from the corrected runs
    that logged it with no empty cell there."""
    shifts: dict[str, dict[str, np.ndarray]] = {}
    for task, data in tasks.items():
        curves = runs[task].get((CORRECTED, own_action(CORRECTED)), [])
        for column in OVER_TRAINING_SHIFT_COLUMNS:
            rows = [c.logged[column][np.searchsorted(c.steps, data.steps)] for c in curves
                    if column in c.logged]
            rows = [row for row in rows if np.isfinite(row).all()]
            if rows:
                shifts.setdefault(task, {})[column] = np.stack(rows)
    return shifts


# ---------------------------------------------------------------------- the dimension study
DIMENSION_SHIFT_COLUMNS = ("mode_shift_abs_sum", "sigma_mean", "bimodal_fraction")
TRAINING_FRACTIONS = (0.25, 0.5, 0.75, 1.0)  # of each task's scored step


@dataclasses.dataclass
class Dimension:
    """One task of the dimension study (beyond the paper)."""

    action_dim: int
    scale: float  # the range of the task's tanh(mu) returns in the folder
    steps: dict[float, int]  # training fraction -> step
    # group -> fraction -> per-seed raw difference, groups in the report's order
    differences: dict[tuple[str, str], dict[float, np.ndarray]]
    shift: dict[str, np.ndarray]  # DIMENSION_SHIFT_COLUMN -> per-seed value at the final step

def training_fraction_steps(steps: np.ndarray, scored_step: int) -> dict[float, int]:
    """The shared step at each of TRAINING_FRACTIONS: the last one at or before that share of
    the scored step (the first shared step if none is), the scored step at 1.0."""
    picks = {f: int(steps[max(0, np.searchsorted(steps, f * scored_step, side="right") - 1)])
             for f in TRAINING_FRACTIONS}
    return {**picks, 1.0: scored_step}

def logged_at(curves: list[Curve], columns: Sequence[str], step: int) -> dict[str, np.ndarray]:
    """Each of `columns` (Curve.logged) at `step`, one value per run that logged it (empty cells
    left out)."""
    logged = {}
    for column in columns:
        values = np.array([c.logged[column][c.steps == step][0]
                           for c in curves if column in c.logged])
        if np.isfinite(values).any():
            logged[column] = values[np.isfinite(values)]
    return logged

def single_action_dim(task: str, curves: Sequence[Curve], study: str
                      ) -> tuple[int | None, str | None]:
    """The one action_dim the runs' config.json give, else None and the note that leaves the
    task out of `study`."""
    dims = {c.action_dim for c in curves}
    if None in dims or len(dims) != 1:
        return None, (f"{task}: its runs' config.json give no single action_dim "
                      f"({sorted(dims, key=str)}); left out of {study}")
    return dims.pop(), None


def build_study(runs: Runs, tasks: dict[str, Task], derived: Sequence[str]
                ) -> tuple[dict[str, Dimension], list[str]]:
    """Each task's Dimension, and notes on the tasks left out."""
    study, notes, curves = {}, [], paired_difference_curves(tasks, derived)
    for task, data in tasks.items():
        pairs = paired_groups(data, task in derived)
        if not pairs:
            continue
        algorithms = {group[0] for group, _ in pairs}
        dim, note = single_action_dim(task, [c for a in algorithms
                                             for c in runs[task].get((a, own_action(a)), [])],
                                      "the dimension study")
        if note:
            notes.append(note)
            continue
        baselines = np.concatenate([data.returns[b].ravel() for b in {b for _, b in pairs}])
        scale = float(baselines.max() - baselines.min()) or 1.0
        steps = training_fraction_steps(data.steps, data.scored_step)
        differences = {group: {f: curves[task][group][:, np.searchsorted(data.steps, step)]
                               for f, step in steps.items()} for group, _ in pairs}
        shift = {}
        for key in sorted(((a, own_action(a)) for a in algorithms), key=group_rank):
            shift = shift or logged_at(runs[task][key], DIMENSION_SHIFT_COLUMNS,
                                       data.scored_step)
        study[task] = Dimension(dim, scale, steps, differences, shift)
    return study, notes

# ------------------------------------------------------------- robust evaluation (evaluate.py)
# evaluate.py's campaign folders (--robust): per_seed.csv holds, per policy and action, the mean
# return and the mean and standard error of the paired difference against tanh(mu) from the
# same starts. Everything across seeds is analyze.py's.
ROBUST_SETTINGS_FILE = "evaluation.json"
ROBUST_PER_SEED_FILE = "per_seed.csv"
ROBUST_COLUMNS = ("env_id", "seed", "step", "selector", "episodes", "return_mean",
                  "difference_mean", "difference_se")
ROBUST_UNSTABLE_COLUMN = "unstable_ends"  # episodes a physics blow-up ended; empty: not recorded


@dataclasses.dataclass
class Robust:
    """The --robust folders: every per_seed.csv row, one per (task, seed, step, action), sorted
    by task, step, action and seed; each folder's evaluation.json; the actions in the order the
    evaluation.json files list them."""

    rows: pd.DataFrame
    settings: dict[Path, dict]
    actions: list[str]


def read_robust_folder(folder: Path) -> tuple[dict, pd.DataFrame]:
    """A --robust folder's evaluation.json and per_seed.csv, checked for what analyze.py reads."""
    path = folder / ROBUST_SETTINGS_FILE
    if not path.is_file():
        raise AnalysisError(
            f"--robust {folder}: no {ROBUST_SETTINGS_FILE} there; pass a folder that "
            "`evaluate.py RUNS_DIR --out FOLDER` wrote over a campaign of runs")
    settings = files.read_json_object(path, "evaluate again", AnalysisError)
    path, again = folder / ROBUST_PER_SEED_FILE, f"`evaluate.py {folder}` writes it again"
    if not path.is_file():
        raise AnalysisError(f"{path} is missing: {again} from the runs' episodes.csv")
    try:  # round_trip: the floats evaluate.py wrote, to the last bit
        rows = pd.read_csv(path, float_precision="round_trip")
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as error:
        raise AnalysisError(f"{path} is not a CSV ({str(error).splitlines()[0]}); "
                            f"{again}") from None
    missing = [name for name in ROBUST_COLUMNS if name not in rows.columns]
    if missing:
        raise AnalysisError(f"{path}: its header {list(rows.columns)} lacks {missing}; {again}")
    for name in ("seed", "step", "episodes", "return_mean"):
        if not pd.api.types.is_numeric_dtype(rows[name]) or rows[name].isna().any():
            raise AnalysisError(f"{path}: column {name} holds something that is not a number; "
                                f"{again}")
    for (task, seed, step), policy in rows.groupby(["env_id", "seed", "step"]):
        if BASELINE not in set(policy.selector):
            raise AnalysisError(
                f"{path}: no {BASELINE} episodes at step {format_step(step)} ({task}, seed "
                f"{seed}); every action is compared with tanh(mu) of the same actor, so "
                f"evaluate with --selectors ... {BASELINE}")
    return settings, rows.assign(source=str(path))


def load_robust(folders: Sequence[Path]) -> Robust:
    """Every --robust folder's per-seed rows; a (task, seed, step) may come from one folder."""
    settings, frames = {}, []
    for folder in folders:
        settings[folder], rows = read_robust_folder(folder)
        frames.append(rows.assign(machine=cpu_name(settings[folder])))
    rows = pd.concat(frames, ignore_index=True)
    twice = rows[rows.duplicated(["env_id", "seed", "step", "selector"], keep=False)]
    if len(twice):
        task, seed, step = twice.iloc[0][["env_id", "seed", "step"]]
        sources = " and ".join(twice[(twice.env_id == task) & (twice.seed == seed)
                                     & (twice.step == step)].source.unique())
        raise AnalysisError(f"{task}, seed {seed}, step {format_step(step)} is in two --robust "
                            f"folders ({sources}); pass each evaluation once")
    listed = [a for s in settings.values() if isinstance(s.get("selectors"), list)
              for a in s["selectors"]]
    actions = list(dict.fromkeys([*listed, *rows.selector]))
    rows = rows.assign(order=rows.selector.map(actions.index)).sort_values(
        ["env_id", "step", "order", "seed"], ignore_index=True)
    return Robust(rows, settings, actions)


def cpu_name(settings: dict) -> str | None:
    """The CPU an evaluation.json records, without trademarks and clock ("Intel Xeon"): on
    another kind of CPU the same evaluation plays other draws of its episodes."""
    machine = settings.get("machine")
    cpu = machine.get("cpu") if isinstance(machine, dict) else None
    if not isinstance(cpu, str) or not cpu.strip():
        return None
    words = cpu.replace("(R)", "").replace("(TM)", "").split("@")[0].split()
    return " ".join(w for w in words if w not in ("Processor", "CPU")) or cpu.strip()


@dataclasses.dataclass
class RobustStep:
    """One task's robust evaluation at one step: per action, one value per seed (seed order)."""

    returns: dict[str, np.ndarray]  # mean return over each seed's episodes
    differences: dict[str, np.ndarray]  # all but tanh_mu: mean of (it - tanh_mu) per episode
    errors: dict[str, np.ndarray]  # the standard errors of those paired episodes
    episodes: np.ndarray  # episodes per seed (of tanh_mu, which every seed played)
    seeds: np.ndarray  # the seeds, in the order of every array above
    played: dict[str, int]  # each action's episodes over its seeds
    unstable: dict[str, int | None]  # of those, ended by a physics blow-up (None: not recorded)
    machine: str | None = None  # the CPU its evaluation.json records (None: not recorded)


def robust_paired_differences(robust: Robust) -> dict[str, dict[int, RobustStep]]:
    """task -> step -> RobustStep, from the per-seed rows."""
    by_task: dict[str, dict[int, RobustStep]] = {}
    for (task, step), rows in robust.rows.groupby(["env_id", "step"], sort=False):
        baseline = rows[rows.selector == BASELINE]
        machines = sorted(set(rows.machine.dropna()))
        at = RobustStep({}, {}, {}, baseline.episodes.to_numpy(), baseline.seed.to_numpy(), {},
                        {}, " + ".join(machines) if machines else None)
        for action, seeds in rows.groupby("selector", sort=False):
            at.returns[action] = seeds.return_mean.to_numpy()
            at.played[action] = int(seeds.episodes.sum())
            unstable = seeds.get(ROBUST_UNSTABLE_COLUMN)
            at.unstable[action] = None if unstable is None or unstable.isna().any() \
                else int(unstable.sum())
            if action != BASELINE:
                at.differences[action] = seeds.difference_mean.to_numpy()
                at.errors[action] = seeds.difference_se.to_numpy()
        by_task.setdefault(task, {})[int(step)] = at
    return by_task


def robust_shared_steps(by_task: dict[str, dict[int, RobustStep]]) -> list[int]:
    """The steps every task's robust evaluation has, in order; none for no task."""
    return sorted(functools.reduce(set.intersection, map(set, by_task.values()))) if by_task \
        else []


def blowups_recorded(by_task: dict[str, dict[int, RobustStep]]) -> bool:
    """Whether any policy's episodes record physics blow-ups."""
    return any(ends is not None for steps in by_task.values() for at in steps.values()
               for ends in at.unstable.values())


# ------------------------------------------------------------------------------------- normalise
@dataclasses.dataclass
class RobustDimension:
    """One task of the dimension study from the robust evaluations: at its last robust step,
    each action's paired difference per seed as a share of that seed's tanh(mu) return."""

    action_dim: int
    step: int
    relative: dict[str, np.ndarray]  # action -> per seed: difference / tanh(mu)'s mean return


def robust_dimension_study(by_task: dict[str, dict[int, RobustStep]], runs: Runs
                           ) -> tuple[dict[str, RobustDimension], list[str]]:
    """Each task's RobustDimension (the action dimension from its runs' config.json), and notes
    on the tasks left out. Relative, not range-normalised as build_study's: the robust
    evaluation has one or a few steps, and "the mode costs 5% of the return" reads alike on
    every task; a seed whose tanh(mu) return is not positive leaves its task out."""
    study, notes = {}, []
    for task, steps in by_task.items():
        dim, note = single_action_dim(task, [c for curves in runs.get(task, {}).values()
                                             for c in curves], "the robust dimension study")
        if note:
            notes.append(note)
            continue
        step = max(steps)
        at = steps[step]
        tanh_mu = at.returns[BASELINE]
        if (tanh_mu <= 0).any():
            notes.append(f"{task}: a seed's tanh(mu) return at {format_step(step)} is not "
                         "positive; left out of the robust dimension study (its differences "
                         "are relative to it)")
            continue
        study[task] = RobustDimension(dim, step,
                                      {a: d / tanh_mu for a, d in at.differences.items()})
    return study, notes


def resolve_normalization(mode: str, tasks: Sequence[str]) -> tuple[str, str]:
    """`auto` made concrete, and a sentence for summary.md saying what was chosen and why."""
    if mode != "auto":
        return mode, ""
    lacking = [task for task in tasks if task not in SUCCESS_BARS]
    if not lacking:
        return "success-bar", "`auto` chose `success-bar`: every task has a HumanoidBench bar. "
    return "min-max", (f"`auto` chose `min-max`: no HumanoidBench success bar for "
                       f"{', '.join(lacking)}. ")


def normalizers(tasks: dict[str, Task], mode: str) -> dict[str, tuple[float, float]]:
    """Per task (offset, scale): score = (return - offset) / scale."""
    if mode == "none":
        if len(tasks) > 1:
            raise AnalysisError(
                f"{len(tasks)} tasks found ({', '.join(tasks)}) but --normalize none: raw "
                "returns of different tasks cannot be aggregated. Use --normalize success-bar "
                "or --normalize min-max, or point analyze.py at a folder with one task")
        return {task: (0.0, 1.0) for task in tasks}
    if mode == "success-bar":
        unknown = [task for task in tasks if task not in SUCCESS_BARS]
        if unknown:
            raise AnalysisError(
                f"no success bar known for {', '.join(unknown)} (known: "
                f"{', '.join(SUCCESS_BARS)}); use --normalize min-max"
                + (" or --normalize none" if len(tasks) == 1 else ""))
        return {task: (0.0, SUCCESS_BARS[task]) for task in tasks}
    bounds = {}
    for task, data in tasks.items():
        everything = np.concatenate([returns.ravel() for returns in data.returns.values()])
        low, high = float(everything.min()), float(everything.max())
        bounds[task] = (low, high - low if high > low else 1.0)
    return bounds


def normalize(returns: np.ndarray, norm: tuple[float, float]) -> np.ndarray:
    return (returns - norm[0]) / norm[1]


@dataclasses.dataclass
class Aggregate:
    """Normalised scores of the groups compared across tasks, as rliable wants them."""

    tasks: list[str]
    groups: list[Key]
    final: dict[Key, np.ndarray]  # group -> (runs, tasks) at each task's scored step
    frames: np.ndarray  # x of the sample-efficiency curve: steps, or fractions of the budgets
    curves: dict[str, np.ndarray]  # group -> (runs, tasks, frames)
    by_fraction: bool = False  # frames are fractions of each task's budget


def build_aggregate(
    tasks: dict[str, Task], norms: dict, groups: list[Key], curve_points: int
) -> tuple[Aggregate | None, list[str]]:
    """Score matrices over the tasks that every algorithm ran, and notes on what was left out."""
    notes = []
    algorithms = [g for g in groups if is_own(g)]
    common = [t for t, data in tasks.items() if all(a in data.returns for a in algorithms)]
    for task in sorted(set(tasks) - set(common)):
        lacking = [a for a in algorithms if a not in tasks[task].returns]
        notes.append(f"{task}: left out of the aggregate metrics (no "
                     f"{', '.join(map(group_name, lacking))} runs)")
    if not common:
        notes.append("no task was run by every algorithm: aggregate metrics skipped")
        return None, notes
    members = [g for g in groups if all(g in tasks[t].returns for t in common)]
    for group in sorted(set(groups) - set(members), key=groups.index):
        notes.append(f"{group_name(group)}: left out of the aggregate metrics (missing on some "
                     "tasks)")
    runs = {g: min(tasks[t].returns[g].shape[0] for t in common) for g in members}
    for g in members:
        if any(tasks[t].returns[g].shape[0] > runs[g] for t in common):
            notes.append(
                f"{group_name(g)}: tasks have different numbers of seeds; the aggregate uses the "
                f"{runs[g]} lowest seeds of each task")
    final = {
        g: np.stack([normalize(tasks[t].scored(g)[: runs[g]], norms[t]) for t in common], axis=1)
        for g in members
    }
    shared = functools.reduce(np.intersect1d, [tasks[t].steps for t in common])
    by_fraction = shared.size == 0 or len({tasks[t].budget for t in common}) > 1
    if by_fraction:
        frames, steps, note = fraction_frames({t: tasks[t] for t in common}, curve_points)
        notes.append(note)
    else:
        picks = np.linspace(0, shared.size - 1, curve_points).round().astype(int)
        frames = shared[np.unique(picks)]
        steps = dict.fromkeys(common, frames)
    curves = {
        g: np.stack([normalize(tasks[t].at(g, steps[t])[: runs[g]], norms[t]) for t in common],
                    1) if frames.size else np.empty((runs[g], len(common), 0))
        for g in members
    }
    return Aggregate(common, members, final, frames, curves, by_fraction), notes


def fraction_frames(tasks: dict[str, Task], curve_points: int
                    ) -> tuple[np.ndarray, dict[str, np.ndarray], str]:
    """The sample-efficiency curve's x where tasks have different budgets or share no step:
    fractions of each budget, each task's steps at them, and summary.md's note saying so."""
    first = max(data.steps[0] / data.budget for data in tasks.values())
    last = min(data.steps[-1] / data.budget for data in tasks.values())
    budgets = ", ".join(f"{t} {format_step(data.budget)}" for t, data in tasks.items())
    if first > last:
        return np.empty(0), {}, (
            f"the aggregated tasks' evaluations cover no common fraction of their budgets "
            f"({budgets}): sample-efficiency curve skipped")
    frames = np.unique(np.linspace(first, last, curve_points))
    # A step's fraction is rounded so that an evaluation exactly at a frame counts as reached.
    steps = {t: data.steps[np.searchsorted(np.round(data.steps / data.budget, 12),
                                           np.round(frames, 12), side="right") - 1]
             for t, data in tasks.items()}
    return frames, steps, (
        "the aggregated tasks have different budgets or share no evaluation step, so the "
        "sample-efficiency curve's x axis is the fraction of each task's budget (config.json's "
        "total_timesteps where a task's runs agree on it, else its last shared step: "
        f"{budgets}); at each fraction a task contributes its last evaluation at or before it")
