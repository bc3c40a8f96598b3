"""evaluate.py on a real Stable-Baselines3 SAC and on a run of ours: paired, deterministic,
agreeing with the training run's own evaluation, and clear about bad input."""

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def evaluate(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "evaluate.py"), *args],
                          capture_output=True, text=True, cwd=ROOT, timeout=300)


def refused(result: subprocess.CompletedProcess, fragment: str) -> None:
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and fragment in lines[0] and "Traceback" not in result.stderr, lines


def read_rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def sb3_models(tmp_path_factory) -> dict[str, Path]:
    """A real SB3 SAC (a few hundred steps on Pendulum-v1) and, for the refusal, a PPO."""
    import gymnasium as gym
    from stable_baselines3 import PPO, SAC

    out = tmp_path_factory.mktemp("sb3")
    sac = SAC("MlpPolicy", gym.make("Pendulum-v1"), learning_starts=100, batch_size=32,
              policy_kwargs={"net_arch": [32, 32]}, seed=0, device="cpu")
    sac.learn(300)
    sac.save(out / "sac_pendulum.zip")
    ppo = PPO("MlpPolicy", gym.make("Pendulum-v1"), n_steps=64, batch_size=32, seed=0,
              device="cpu")
    ppo.learn(64)
    ppo.save(out / "ppo_pendulum.zip")
    return {"sac": out / "sac_pendulum.zip", "ppo": out / "ppo_pendulum.zip"}


@pytest.fixture(scope="module")
def our_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs")
    result = subprocess.run(
        [sys.executable, str(ROOT / "sac_corrected.py"), "--env-id", "Pendulum-v1",
         "--total-timesteps", "1500", "--learning-starts", "500", "--eval-interval", "500",
         "--eval-episodes", "2", "--hidden-sizes", "32", "32", "--checkpoint-interval", "0",
         "--output-dir", str(out), "--run-name", "ours"], capture_output=True, text=True, cwd=ROOT)
    assert result.returncode == 0, result.stderr
    return out / "ours"


def test_sb3_sac_paired_and_deterministic(sb3_models, tmp_path):
    args = [str(sb3_models["sac"]), "--env-id", "Pendulum-v1", "--episodes", "3", "--selectors",
            "mode", "tanh_mu", "sample", "--reps", "200"]
    first = evaluate(*args, "--out", str(tmp_path / "a"))
    assert first.returncode == 0, first.stderr
    assert "mode - tanh_mu, paired:" in first.stdout and "distribution shift" in first.stdout
    rows = read_rows(tmp_path / "a" / "episodes.csv")
    assert [r["selector"] for r in rows] == ["mode"] * 3 + ["tanh_mu"] * 3 + ["sample"] * 3
    # Paired: episode k of every selector starts from the same reset seed.
    seeds = {s: [r["reset_seed"] for r in rows if r["selector"] == s] for s in
             ("mode", "tanh_mu", "sample")}
    assert seeds["mode"] == seeds["tanh_mu"] == seeds["sample"] and len(set(seeds["mode"])) == 3
    returns = {s: [float(r["return"]) for r in rows if r["selector"] == s] for s in seeds}
    assert returns["mode"] != returns["tanh_mu"]  # a trained SB3 SAC: the two actions differ
    summary = json.loads((tmp_path / "a" / "summary.json").read_text())
    assert summary["kind"] == "stable-baselines3"
    paired = summary["paired_difference_mode_minus_tanh_mu"]
    diffs = [m - t for m, t in zip(returns["mode"], returns["tanh_mu"], strict=True)]
    assert paired["mean"] == pytest.approx(sum(diffs) / 3)
    assert paired["ci_low"] <= paired["mean"] <= paired["ci_high"]
    # Deterministic for a seed, sampled episodes included.
    second = evaluate(*args, "--out", str(tmp_path / "b"))
    assert second.returncode == 0, second.stderr
    assert (tmp_path / "a" / "episodes.csv").read_text() == \
        (tmp_path / "b" / "episodes.csv").read_text()


def test_our_run_agrees_with_its_own_last_evaluation(our_run, tmp_path):
    last = read_rows(our_run / "eval.csv")[-1]
    result = evaluate(str(our_run), "--seed", "0", "--eval-round", last["eval_round"],
                      "--episodes", "2", "--reps", "100", "--out", str(tmp_path / "out"))
    assert result.returncode == 0, result.stderr
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["source"].endswith("final_model.pt") and summary["env_id"] == "Pendulum-v1"
    selectors = summary["selectors"]
    assert selectors["tanh_mu"]["return_mean"] == pytest.approx(
        float(last["tanh_mu_return_mean"]), rel=1e-9)
    assert selectors["mode"]["return_mean"] == pytest.approx(float(last["return_mean"]),
                                                             rel=1e-9)
    shift = summary["shift_at_visited_states"]
    assert shift["mode_shift_abs_mean"] > 0  # the mode is not tanh(mu)


def test_a_bare_weights_file_carries_its_env(our_run):
    result = evaluate(str(our_run / "final_model.pt"), "--episodes", "1", "--reps", "50")
    assert result.returncode == 0, result.stderr
    assert "on Pendulum-v1" in result.stdout


def test_bad_sources_fail_clearly(sb3_models, our_run, tmp_path):
    refused(evaluate(str(ROOT / "tests")), "is not a run folder (no config.json)")
    refused(evaluate(str(our_run), "--env-id", "InvertedPendulum-v5"),
            "was trained on 3-dim observations and 1-dim actions; InvertedPendulum-v5 has 4 and 1")
    refused(evaluate(str(sb3_models["ppo"]), "--env-id", "Pendulum-v1"),
            "is not a Stable-Baselines3 SAC model (its policy comes from "
            "stable_baselines3.common.policies)")
    refused(evaluate(str(sb3_models["sac"])), "pass --env-id")
    refused(evaluate(str(sb3_models["sac"]), "--env-id", "Hopper-v5"),
            "was trained on observations (3,) and actions (1,)")
    text = tmp_path / "model.pt"
    text.write_text("not weights")
    refused(evaluate(str(text), "--env-id", "Pendulum-v1"), "is not a weights file of ours")
    refused(evaluate(str(our_run), "--episodes", "0"), "--episodes 0: must be at least 1")
    refused(evaluate(str(tmp_path / "missing")), "does not exist")
