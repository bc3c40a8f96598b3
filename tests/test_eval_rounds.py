"""sac_utils/eval_rounds.py: lockstep rounds, the worker pool, q_best, and their failures."""

import copy
import signal
import subprocess
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

import tests.toy_envs  # noqa: F401  (registers Countdown-v0 here; workers import it by id)
from mode_search import mean_action, mode_action
from sac_utils import eval_rounds
from sac_utils.eval_rounds import (
    Q_BEST_CANDIDATES,
    EvalPool,
    Round,
    eval_columns,
    eval_seeds,
    q_best_choice,
    round_row,
    round_statistics,
    run_round,
)
from tests.toy_envs import ToyActor, ToyCritic, episode_of

COUNTDOWN = "tests.toy_envs:Countdown-v0"
ROOT = Path(__file__).resolve().parent.parent


def collect(workers: int, rounds: list[Round]) -> list[tuple[str, dict]]:
    """Every round's (label, result), in the order the pool hands them back."""
    results = []
    pool = EvalPool(workers, lambda round_, result: results.append((round_.label, result)))
    for round_ in rounds:
        pool.submit(round_)
    pool.drain()
    pool.close()
    return results


def test_episodes_of_different_lengths_in_one_batch_keep_their_own_return_and_length():
    seeds = [3, 12, 0, 7, 25, 4]  # lengths 4, 13, 1, 8, 13, 5
    actions = {"": "mode", "tanh_mu_": "tanh_mu", "mean_": "mean", "sample_": "sample"}
    result = run_round(Round(COUNTDOWN, seeds, actions, ToyActor()))
    for prefix in actions:
        for k, seed in enumerate(seeds):
            length, reward, success = episode_of(seed)
            assert result[prefix]["lengths"][k] == length
            assert result[prefix]["returns"][k] == pytest.approx(length * reward)
            assert result[prefix]["successes"][k] is success
    row = round_statistics(result, "tanh_mu_")
    returns = [episode_of(s)[0] * episode_of(s)[1] for s in seeds]
    assert row["tanh_mu_return_mean"] == pytest.approx(np.mean(returns))
    assert row["tanh_mu_return_min"] == pytest.approx(min(returns))
    assert row["tanh_mu_success_rate"] == pytest.approx(np.mean([episode_of(s)[2] for s in seeds]))


def test_an_episode_a_physics_blow_up_ended_is_marked_unstable_and_only_it():
    # Odd seeds blow up at their last step, even ones end normally; seed 5 again at the end is
    # its first episode again (same start), not stepped: it must carry the first one's mark.
    seeds = [5, 2, 7, 12, 5]  # lengths 6, 3, 8, 13, 6
    actions = {"": "mode", "tanh_mu_": "tanh_mu", "sample_": "sample"}
    result = run_round(Round("tests.toy_envs:OddBlowUp-v0", seeds, actions, ToyActor()))
    assert result["distinct_episodes"] == 4
    for prefix in actions:
        assert result[prefix]["unstable"] == [True, False, True, False, True], prefix
        assert result[prefix]["lengths"] == [episode_of(s)[0] for s in seeds]
        # The blow-up's step pays nothing, as H1HandEnv's; an ordinary end, the seed's success.
        assert result[prefix]["returns"][0] == pytest.approx(5 * episode_of(5)[1])
        assert result[prefix]["successes"] == [None, True, None, True, None]
    ordinary = run_round(Round(COUNTDOWN, seeds, {"": "mode"}, ToyActor()))
    assert ordinary[""]["unstable"] == [False] * len(seeds)
    # eval.csv's columns (training's) are what they were: no column for the blow-ups.
    assert set(round_row(result, {"": "mode"})) == set(eval_columns({"": "mode"}, False))


@pytest.mark.slow
def test_a_round_is_the_same_in_process_and_in_any_number_of_workers():
    from sac_standard import Actor, TwinQ

    torch.manual_seed(0)
    env = gym.make("Pendulum-v1")
    actor = Actor(3, (32, 32), env.action_space, -10.0, 2.0)
    critic = TwinQ(3, 1, (32, 32))
    with torch.no_grad():  # a wide policy, so that the mode, tanh(mu) and the mean differ
        actor.fc_logstd.bias.fill_(0.5)
    actions = {"": "mode", "tanh_mu_": "tanh_mu", "mean_": "mean", "q_best_": "q_best"}
    rounds = [Round("Pendulum-v1", eval_seeds(1, r, 3), actions, actor, critic, shift_of="",
                    label=f"round {r}") for r in (1, 2, 3)]
    in_process = collect(0, copy.deepcopy(rounds))
    assert collect(1, copy.deepcopy(rounds)) == in_process
    assert collect(2, copy.deepcopy(rounds)) == in_process
    first = in_process[0][1]
    assert first[""]["returns"] != first["tanh_mu_"]["returns"]
    assert sum(first["q_best_"]["shares"].values()) == pytest.approx(1.0)
    assert set(first["shift"]) == {"mode_shift_abs_mean", "mode_shift_abs_sum", "sigma_mean",
                                   "bimodal_fraction"}
    assert first["shift"]["mode_shift_abs_mean"] > 0


@pytest.mark.slow
def test_rounds_are_handed_back_in_submission_order_when_a_later_one_finishes_first(
        tmp_path, monkeypatch):
    gate = tmp_path / "gate"
    monkeypatch.setenv("TOY_ENVS_GATE", str(gate))  # the workers inherit it
    gated = "tests.toy_envs:GatedCountdown-v0"  # an episode's second step waits for the gate
    long_round = Round(gated, [12, 25], {"": "tanh_mu"}, ToyActor(), label="long")  # 13 steps
    short_round = Round(gated, [0, 13], {"": "tanh_mu"}, ToyActor(), label="short")  # 1 step
    finished = []
    pool = EvalPool(2, lambda round_, result: finished.append(round_.label))
    pool.submit(long_round)
    pool.submit(short_round)
    pool.pending[1][0].result()  # the short round is done...
    assert not pool.pending[0][0].done()  # ...while the long one waits at the gate
    pool.poll()
    assert finished == []  # not handed back before the round submitted earlier
    gate.touch()
    pool.drain()
    pool.close()
    assert finished == ["long", "short"]


@pytest.mark.parametrize("workers", [0, 1])
def test_a_nan_action_names_the_round_the_action_and_the_episode(workers):
    seeds = [5, 9, 2]  # rewards 0.5, 4.5, 2.5: episode 1's mu is NaN
    round_ = Round(COUNTDOWN, seeds, {"": "tanh_mu", "mode_": "mode"}, ToyActor(nan_reward=4.5),
                   label="evaluation at step 3000")
    handed_back = []
    pool = EvalPool(workers, lambda r, result: handed_back.append(result))
    with pytest.raises(SystemExit) as error:
        pool.submit(round_)
        pool.drain()
    message = str(error.value)
    assert "evaluation at step 3000" in message and "'tanh_mu'" in message
    assert "episode 1 (reset seed 9)" in message and "\n" not in message
    assert handed_back == []


def test_q_best_picks_the_candidate_its_critic_scores_highest_and_ties_go_to_tanh_mu():
    obs = torch.zeros(4, 3)
    candidates = {"tanh_mu": torch.tensor([[0.0], [0.0], [0.3], [0.5]]),
                  "mode": torch.tensor([[0.9], [-0.5], [0.3], [0.1]]),
                  "mean": torch.tensor([[0.4], [0.2], [0.3], [0.5]])}
    critic = ToyCritic(torch.tensor([0.8]))
    choice = q_best_choice(obs, candidates, ToyActor(), critic)
    # Row 0: the mode is nearest 0.8; row 1: the mean; row 2: all tie; row 3: tanh_mu ties mean.
    names = [Q_BEST_CANDIDATES[i] for i in choice]
    assert names == ["mode", "mean", "tanh_mu", "tanh_mu"]


def test_q_best_acts_with_the_chosen_candidate_and_logs_shares():
    seeds = [3, 7, 12]
    mu_of = lambda obs: ToyActor()(obs)  # noqa: E731
    obs = torch.tensor([[4.0, 3.5, 1.0]])
    mu, log_std = mu_of(obs)
    target = mean_action(mu, log_std)[0]  # the critic wants the mean of the first state
    round_ = Round(COUNTDOWN, seeds, {"": "q_best"}, ToyActor(), ToyCritic(target))
    result = run_round(round_)
    shares = result[""]["shares"]
    assert set(shares) == set(Q_BEST_CANDIDATES)
    assert sum(shares.values()) == pytest.approx(1.0)
    assert shares["mean"] > 0
    row = round_row(result, {"": "q_best"})
    assert [k for k in row if "share" in k] == [f"share_{c}" for c in Q_BEST_CANDIDATES]
    assert list(row) == eval_columns({"": "q_best"}, shift=False)
    assert not torch.equal(mode_action(mu, log_std), mean_action(mu, log_std))


@pytest.mark.slow
def test_video_of_the_first_episode(tmp_path):
    from sac_standard import Actor

    env = gym.make("Hopper-v5")
    video = tmp_path / "round.mp4"
    result = run_round(Round("Hopper-v5", [1, 2], {"": "tanh_mu", "mode_": "mode"},
                             Actor(11, (8,), env.action_space, -10.0, 2.0),
                             videos={"mode_": video}))
    assert video.stat().st_size > 1000
    import imageio

    assert len(imageio.mimread(video)) == result["mode_"]["lengths"][0]


# --- in the training scripts ------------------------------------------------------------------
TOY = ["--total-timesteps", "1200", "--learning-starts", "100", "--eval-interval", "300",
       "--eval-episodes", "3", "--hidden-sizes", "8", "--batch-size", "16", "--log-interval",
       "100", "--checkpoint-interval", "200"]


@pytest.mark.slow
def test_sigkill_with_a_round_in_flight_then_resume_gives_the_uninterrupted_eval_csv(tmp_path):
    from tests.test_sac import command, read_csv, run, wait_for

    env = ["--env-id", "tests.toy_envs:SlowEval-v0", "--output-dir", str(tmp_path)]
    run("sac_standard.py", *TOY, *env, "--run-name", "whole", "--eval-workers", "0")
    killed = tmp_path / "killed"
    process = subprocess.Popen(command("sac_standard.py", *TOY, *env, "--run-name", "killed",
                                       "--eval-workers", "1"), cwd=ROOT,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    # Training has passed step 900 while the slow rounds are still being evaluated.
    wait_for(lambda: (killed / "train.csv").exists()
             and "\n900," in (killed / "train.csv").read_text())
    in_flight = len(read_csv(killed / "eval.csv")) < 3
    process.send_signal(signal.SIGKILL)
    process.wait()
    assert in_flight and not (killed / "done.json").exists()
    run("sac_standard.py", "--resume", str(killed), "--eval-workers", "2")
    for name in ("eval.csv", "train.csv"):
        assert read_csv(killed / name) == read_csv(tmp_path / "whole" / name)
    assert [row["global_step"] for row in read_csv(killed / "eval.csv")] == ["300", "600", "900",
                                                                            "1200"]


@pytest.mark.slow
def test_a_nan_in_one_evaluation_episode_stops_the_run_in_one_line(tmp_path):
    from tests.test_sac import run

    result = run("sac_corrected.py", *TOY, "--env-id", "tests.toy_envs:NanEval-v0",
                 "--output-dir", str(tmp_path), "--run-name", "nan", check=False)
    assert result.returncode == 1 and "Traceback" not in result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("evaluation of seed 0 at step 300: the evaluation action 'mode' is "
                           "NaN/inf in episode 0 (reset seed ")
    checkpoint = torch.load(tmp_path / "nan" / "checkpoint.pt", weights_only=False)
    assert checkpoint["global_step"] >= 200
    assert not (tmp_path / "nan" / "eval.csv").read_text().count("\n") > 1  # no row written


# --- one episode per distinct start -----------------------------------------------------------
def _stepped_round(monkeypatch, round_: Round, dedupe: bool) -> tuple[dict, int]:
    """run_round's result and how many env steps it took (with dedupe False: every episode of
    every action stepped, as before episodes were deduplicated)."""
    from humanoid_envs.base import H1HandEnv

    steps = [0]
    step = H1HandEnv.step

    def counted(self, action):
        steps[0] += 1
        return step(self, action)

    monkeypatch.setattr(H1HandEnv, "step", counted)
    if not dedupe:
        monkeypatch.setattr(eval_rounds, "start_key", lambda env: None)
    result = run_round(copy.deepcopy(round_))
    monkeypatch.undo()
    return result, steps[0]


class RowByRow(torch.nn.Module):
    """A network called one row at a time. BLAS may round the rows of one batch differently by
    their position (seen here for batches of 2 and 3 equal rows, not 10), which would make
    episodes from equal starts differ in the last bits; row by row, equal starts are equal
    episodes, so stepping them all is the exact reference for stepping one."""

    def __init__(self, net: torch.nn.Module):
        super().__init__()
        self.net = net

    def forward(self, *inputs: torch.Tensor):
        rows = [self.net(*(x[i:i + 1] for x in inputs)) for i in range(len(inputs[0]))]
        if isinstance(rows[0], tuple):
            return tuple(torch.cat(parts) for parts in zip(*rows, strict=True))
        return torch.cat(rows, dim=-1)  # the critic's (2, batch)

    def scale(self, y: torch.Tensor) -> torch.Tensor:
        return self.net.scale(y)


def _h1hand_round(env_id: str, seeds: list[int]) -> Round:
    from sac_standard import Actor, TwinQ

    env = gym.make(env_id)
    obs_dim, action_dim = env.observation_space.shape[0], env.action_space.shape[0]
    torch.manual_seed(0)
    actor = Actor(obs_dim, (16,), env.action_space, -10.0, 2.0)
    with torch.no_grad():  # a wide policy: the mode, tanh(mu) and the mean differ
        actor.fc_logstd.bias.fill_(0.5)
    actions = {"": "mode", "tanh_mu_": "tanh_mu", "q_best_": "q_best", "sample_": "sample"}
    return Round(env_id, seeds, actions, RowByRow(actor),
                 RowByRow(TwinQ(obs_dim, action_dim, (16,))), shift_of="")


def test_a_start_without_reset_noise_is_stepped_once_and_gives_the_rows_of_stepping_all(
        monkeypatch):
    round_ = _h1hand_round("h1hand-bookshelf_simple-v0", eval_seeds(0, 1, 3))
    deduped, steps = _stepped_round(monkeypatch, round_, dedupe=True)
    everything, all_steps = _stepped_round(monkeypatch, round_, dedupe=False)
    assert deduped == everything | {"distinct_episodes": 1}
    assert everything["distinct_episodes"] == 3  # unknown starts count as distinct
    lengths = {p: deduped[p]["lengths"] for p in round_.actions}
    assert all(len(set(lengths[p])) == 1 for p in ("", "tanh_mu_", "q_best_"))
    # Deterministic actions: one episode each; "sample" draws other noise per episode: all run.
    assert steps == sum(lengths[p][0] for p in ("", "tanh_mu_", "q_best_")) + sum(
        lengths["sample_"])
    assert all_steps == sum(sum(v) for v in lengths.values())
    assert round_row(deduped, round_.actions)["distinct_episodes"] == 1


def test_starts_with_reset_noise_are_all_stepped(monkeypatch):
    round_ = _h1hand_round("h1hand-stand-v0", eval_seeds(0, 1, 3))
    deduped, steps = _stepped_round(monkeypatch, round_, dedupe=True)
    everything, all_steps = _stepped_round(monkeypatch, round_, dedupe=False)
    assert deduped == everything and deduped["distinct_episodes"] == 3
    assert steps == all_steps == sum(sum(deduped[p]["lengths"]) for p in round_.actions)


def test_reset_noise_makes_every_start_distinct_and_keeps_the_actions_paired(monkeypatch):
    round_ = _h1hand_round("h1hand-bookshelf_simple-v0", eval_seeds(0, 1, 3))
    round_.reset_noise = 0.01
    result, steps = _stepped_round(monkeypatch, round_, dedupe=True)
    assert result["distinct_episodes"] == 3
    assert steps == sum(sum(result[p]["lengths"]) for p in round_.actions)
    assert len(set(result["tanh_mu_"]["returns"])) == 3
    # Paired: episode k of every action starts from the same state (an action's first step is
    # taken from it), so tanh(mu) run alone from these seeds gives its rows again.
    alone = copy.deepcopy(round_)
    alone.actions, alone.shift_of = {"tanh_mu_": "tanh_mu"}, None
    assert run_round(alone)["tanh_mu_"] == result["tanh_mu_"]
    # The same command, the same rows.
    assert _stepped_round(monkeypatch, round_, dedupe=True)[0] == result


def test_repeated_reset_seeds_are_stepped_once_on_any_env_that_can_tell(monkeypatch):
    # Hopper's starts draw noise, so equal seeds give equal starts; it cannot tell its start
    # state (no start_state), so each episode runs.
    result = run_round(Round("Hopper-v5", [5, 5], {"": "tanh_mu"}, _hopper_actor()))
    assert result["distinct_episodes"] == 2
    round_ = _h1hand_round("h1hand-stand-v0", [5, 7, 5])
    deduped, _ = _stepped_round(monkeypatch, round_, dedupe=True)
    assert deduped["distinct_episodes"] == 2
    assert deduped["tanh_mu_"]["returns"][0] == deduped["tanh_mu_"]["returns"][2]


def _hopper_actor():
    from sac_standard import Actor

    return Actor(11, (8,), gym.make("Hopper-v5").action_space, -10.0, 2.0)
