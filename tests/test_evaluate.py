"""evaluate.py on a real Stable-Baselines3 SAC and on a run of ours: paired, deterministic,
agreeing with the training run's own evaluation and with SB3's own action distribution, and
clear about bad input. Most calls run evaluate.main in this process (an import of torch, gym
and rliable per call would cost seconds) with --workers 0; one of each kind runs the real
command line, and some the worker processes."""

import csv
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

import evaluate
from mode_search import tanh_normal_log_prob
from sac_utils import policies
from sac_utils.eval_rounds import Q_BEST_CANDIDATES, Round, eval_seeds, run_round
from sac_utils.run_folder import machine
from tests.test_sac import EAGER

ROOT = Path(__file__).resolve().parent.parent


def cli(*args: str, code: str = "") -> subprocess.CompletedProcess:
    """evaluate.py as a user runs it (with `code` run first, inside the same interpreter)."""
    command = [sys.executable, str(ROOT / "evaluate.py"), *args] if not code else [
        sys.executable, "-c", f"import runpy, sys; {code}; sys.argv = {['evaluate.py', *args]!r}"
        "; runpy.run_path('evaluate.py', run_name='__main__')"]
    return subprocess.run(command, capture_output=True, text=True, cwd=ROOT, timeout=300)


def run(capsys, *args: str) -> tuple[int, str, str]:
    """evaluate.main in this process, and its episodes too unless --workers is given: exit code,
    stdout, stderr."""
    if "--workers" not in args:
        args = (*args, "--workers", "0")
    try:
        evaluate.main(list(args))
        code = 0
    except SystemExit as exit_:
        code = exit_.code
    out, err = capsys.readouterr()
    return code, out, err


def refused(capsys, fragment: str, *args: str) -> None:
    code, out, err = run(capsys, *args)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and fragment in lines[0], (code, err)
    assert "error: " in lines[0] and out == ""


def read_rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def sb3_models(tmp_path_factory) -> dict[str, Path]:
    """Real SB3 SACs (a few hundred steps on Pendulum-v1; one with gSDE, whose sigma is not a
    network output) and, for the refusal, a PPO."""
    from stable_baselines3 import PPO, SAC

    out = tmp_path_factory.mktemp("sb3")
    for name, sde in (("sac", False), ("sac_gsde", True)):
        model = SAC("MlpPolicy", gym.make("Pendulum-v1"), learning_starts=100, batch_size=32,
                    use_sde=sde, policy_kwargs={"net_arch": [32, 32]}, seed=0, device="cpu")
        model.learn(300)
        model.save(out / f"{name}.zip")
    ppo = PPO("MlpPolicy", gym.make("Pendulum-v1"), n_steps=64, batch_size=32, seed=0,
              device="cpu")
    ppo.learn(64)
    ppo.save(out / "ppo.zip")
    return {name: out / f"{name}.zip" for name in ("sac", "sac_gsde", "ppo")}


@pytest.fixture(scope="module")
def our_run(tmp_path_factory) -> Path:
    """A tiny run whose checkpoint (step 1600, an episode's end) and last evaluation (round 2)
    both hold the final model (the critic too: it evaluates q_best)."""
    out = tmp_path_factory.mktemp("runs")
    result = subprocess.run(
        [sys.executable, str(ROOT / "sac_corrected.py"), "--env-id", "Pendulum-v1",
         "--total-timesteps", "1600", "--learning-starts", "500", "--eval-interval", "800",
         "--eval-episodes", "2", "--eval-selectors", "mean", "q_best", "--hidden-sizes", "32",
         "32", "--checkpoint-interval", "1600", *EAGER,
         "--output-dir", str(out), "--run-name", "ours"], capture_output=True, text=True, cwd=ROOT)
    assert result.returncode == 0, result.stderr
    return out / "ours"


@pytest.mark.slow
def test_sb3_sac_paired_and_deterministic(sb3_models, tmp_path, capsys):
    args = [str(sb3_models["sac"]), "--env-id", "Pendulum-v1", "--episodes", "3", "--selectors",
            "mode", "tanh_mu", "sample", "--reps", "200"]
    first = cli(*args, "--out", str(tmp_path / "a"))
    assert first.returncode == 0, first.stderr
    assert "mode - tanh_mu, paired:" in first.stdout and "distribution shift" in first.stdout
    # The progress bar, and a job of 3 episodes run by one worker process (the default: one
    # per core, no more than there are jobs).
    assert "mode tanh_mu sample [########################] 3/3 episodes" in first.stderr
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
    paired = summary["paired_difference_minus_tanh_mu"]["mode"]
    diffs = [m - t for m, t in zip(returns["mode"], returns["tanh_mu"], strict=True)]
    assert paired["mean"] == pytest.approx(sum(diffs) / 3)
    assert paired["ci_low"] <= paired["mean"] <= paired["ci_high"]
    # Deterministic for a seed, sampled episodes and CIs included: another process gives the
    # same files.
    code, _, err = run(capsys, *args, "--out", str(tmp_path / "b"))
    assert code == 0, err
    for name in ("episodes.csv", "summary.json"):
        assert (tmp_path / "a" / name).read_text() == (tmp_path / "b" / name).read_text()


@pytest.mark.parametrize("name", ["sac", "sac_gsde"])
@pytest.mark.slow
def test_sb3_actor_is_sb3s_own_distribution(sb3_models, name):
    """mu and sigma as evaluate.py reads them are the distribution SB3 samples from: SB3's own
    sampled actions have the log-density SB3 reports, and tanh(mu), rescaled, is SB3's
    deterministic action."""
    actor, env_id, _ = policies.load_sb3(sb3_models[name], "Pendulum-v1")
    policy = actor.policy
    obs = torch.as_tensor(np.stack([gym.make(env_id).reset(seed=s)[0] for s in range(8)]))
    with torch.no_grad():
        mu, log_std = actor(obs)
        if policy.actor.use_sde:
            policy.actor.reset_noise(batch_size=8)
        squashed, sb3_log_prob = policy.actor.action_log_prob(obs)
        ours = tanh_normal_log_prob(squashed.double(), mu.double(), log_std.double()).sum(1)
        deterministic = policy.predict(obs.numpy(), deterministic=True)[0]
    # SB3 adds 1e-6 inside log(1 - tanh(u)^2), and gSDE 1e-6 to the variance.
    assert ours.numpy() == pytest.approx(sb3_log_prob.double().numpy(), abs=1e-3)
    assert actor.scale(torch.tanh(mu)).numpy() == pytest.approx(deterministic, abs=1e-6)
    assert policy.actor.use_sde == (name == "sac_gsde")


@pytest.mark.slow
def test_sb3_gsde_policy_evaluates(sb3_models, capsys, tmp_path):
    code, out, err = run(capsys, str(sb3_models["sac_gsde"]), "--env-id", "Pendulum-v1",
                         "--episodes", "2", "--reps", "50", "--out", str(tmp_path))
    assert code == 0, err
    summary = json.loads((tmp_path / "summary.json").read_text())
    shift = summary["shift_at_visited_states"]
    # gSDE's sigma at a state comes from the latent features: wide enough that the mode is not
    # tanh(mu), and the two actions' episodes differ.
    assert 0 < shift["sigma_mean"] < 10 and shift["mode_shift_abs_mean"] > 1e-4
    assert shift["mode_shift_abs_sum"] == pytest.approx(shift["mode_shift_abs_mean"])  # 1 dim
    returns = {s: [float(r["return"]) for r in read_rows(tmp_path / "episodes.csv")
                   if r["selector"] == s] for s in ("mode", "tanh_mu")}
    assert len(returns["mode"]) == 2 and returns["mode"] != returns["tanh_mu"]


@pytest.mark.slow
def test_our_run_agrees_with_its_own_last_evaluation(our_run, tmp_path, capsys):
    """Every selector, q_best (with the critic read back from final_model.pt) and its choice
    shares included, gives the numbers the run logged in its last evaluation."""
    last = read_rows(our_run / "eval.csv")[-1]
    code, out, err = run(capsys, str(our_run), "--seed", "0", "--eval-round",
                         last["eval_round"], "--episodes", "2", "--reps", "100", "--selectors",
                         "mode", "tanh_mu", "mean", "q_best", "--out", str(tmp_path / "out"))
    assert code == 0, err
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["source"].endswith("final_model.pt") and summary["env_id"] == "Pendulum-v1"
    selectors = summary["selectors"]
    for selector, prefix in (("mode", ""), ("tanh_mu", "tanh_mu_"), ("mean", "mean_"),
                             ("q_best", "q_best_")):
        assert selectors[selector]["return_mean"] == pytest.approx(
            float(last[f"{prefix}return_mean"]), rel=1e-9), selector
    shares = selectors["q_best"]["choice_shares"]
    assert list(shares) == list(Q_BEST_CANDIDATES) and sum(shares.values()) == pytest.approx(1)
    assert sum(share > 0 for share in shares.values()) >= 2  # a real choice, so its critic matters
    for name, share in shares.items():
        assert share == pytest.approx(float(last[f"q_best_share_{name}"]), abs=1e-12)
    assert "q_best chose, over its visited states: tanh_mu" in out
    shift = summary["shift_at_visited_states"]
    assert shift["mode_shift_abs_mean"] > 0  # the mode is not tanh(mu)
    assert shift["mode_shift_abs_mean"] == pytest.approx(float(last["mode_shift_abs_mean"]),
                                                         rel=1e-6)
    # Every selector's paired difference against tanh_mu.
    paired = summary["paired_difference_minus_tanh_mu"]
    assert set(paired) == {"mode", "mean", "q_best"}
    for selector in paired:
        assert f"{selector} - tanh_mu, paired:" in out
        assert paired[selector]["mean"] == pytest.approx(
            selectors[selector]["return_mean"] - selectors["tanh_mu"]["return_mean"])


@pytest.mark.slow
def test_results_do_not_depend_on_workers_and_stay_paired(our_run, tmp_path, capsys):
    """12 episodes (a job of 10 and one of 2) of every selector: the same files in-process and
    with 1 or 2 worker processes, the episodes in order, each starting state shared."""
    args = [str(our_run), "--episodes", "12", "--reps", "50", "--selectors", *evaluate.ACTIONS]
    for workers in ("0", "1", "2"):
        code, _, err = run(capsys, *args, "--workers", workers, "--out", str(tmp_path / workers))
        assert code == 0, err
    for name in ("episodes.csv", "summary.json"):
        assert (tmp_path / "1" / name).read_text() == (tmp_path / "0" / name).read_text()
        assert (tmp_path / "2" / name).read_text() == (tmp_path / "0" / name).read_text()
    rows = read_rows(tmp_path / "0" / "episodes.csv")
    seeds = eval_seeds(0, 0, 12)
    for selector in evaluate.ACTIONS:
        mine = [r for r in rows if r["selector"] == selector]
        assert [int(r["reset_seed"]) for r in mine] == seeds
        assert [int(r["episode"]) for r in mine] == list(range(12))
    # The second job's episodes are episodes 10 and 11, in that order.
    actor, _, env_id, _ = policies.load_policy(our_run, None, False)
    second = run_round(Round(env_id, seeds[10:], {"tanh_mu": "tanh_mu"}, actor))
    assert [float(r["return"]) for r in rows if r["selector"] == "tanh_mu"][10:] == \
        second["tanh_mu"]["returns"]
    summary = json.loads((tmp_path / "0" / "summary.json").read_text())
    shares = summary["selectors"]["q_best"]["choice_shares"]
    assert sum(shares.values()) == pytest.approx(1.0)
    returns = {s: [float(r["return"]) for r in rows if r["selector"] == s]
               for s in evaluate.ACTIONS}
    for a, b in (("mean", "tanh_mu"), ("tanh_mu", "mode"), ("mean", "mode")):
        assert returns[a] != returns[b], (a, b)  # three actions, three sets of episodes


@pytest.mark.slow
def test_sb3_critic_is_sb3s_own(sb3_models, tmp_path, capsys):
    """q_best on an SB3 SAC scores with SB3's critic, fed actions as SB3 scales them; the
    evaluation runs and reports its choice shares."""
    actor, critic, _, _ = policies.load_policy(sb3_models["sac"], "Pendulum-v1", True)
    policy = actor.policy
    obs = torch.as_tensor(np.stack([gym.make("Pendulum-v1").reset(seed=s)[0] for s in range(8)]))
    env_actions = torch.linspace(-2.0, 2.0, 8)[:, None]
    with torch.no_grad():
        ours = critic(obs, env_actions)
        sb3 = policy.critic(obs, torch.as_tensor(policy.scale_action(env_actions.numpy())))
    assert ours.shape == (2, 8)
    assert ours.numpy() == pytest.approx(torch.cat(sb3, 1).T.numpy(), abs=1e-5)
    assert not torch.equal(ours[:, 0], ours[:, -1])  # the action matters to a trained critic
    code, out, err = run(capsys, str(sb3_models["sac"]), "--env-id", "Pendulum-v1",
                         "--episodes", "3", "--reps", "50", "--selectors", "tanh_mu", "mean",
                         "q_best", "--out", str(tmp_path))
    assert code == 0, err
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert sum(summary["selectors"]["q_best"]["choice_shares"].values()) == pytest.approx(1.0)
    assert set(summary["paired_difference_minus_tanh_mu"]) == {"mean", "q_best"}
    assert "paired_difference_mode_minus_tanh_mu" not in summary
    assert "q_best - tanh_mu, paired:" in out and "mean - tanh_mu, paired:" in out


@pytest.mark.slow
def test_q_best_needs_a_critic(our_run, tmp_path, capsys):
    state = torch.load(our_run / "final_model.pt", weights_only=True)
    del state["qf"]
    torch.save(state, tmp_path / "actor_only.pt")
    refused(capsys, "holds no critic weights ('qf'), which q_best needs",
            str(tmp_path / "actor_only.pt"), "--selectors", "mode", "q_best")
    code, _, err = run(capsys, str(tmp_path / "actor_only.pt"), "--episodes", "1", "--reps",
                       "10", "--selectors", "mode", "mean")  # no q_best: no critic needed
    assert code == 0, err
    state = torch.load(our_run / "final_model.pt", weights_only=True)
    state["qf"] = {k: v for k, v in state["qf"].items() if k.startswith("qf1.")}
    torch.save(state, tmp_path / "half.pt")
    refused(capsys, "its critic does not fit our TwinQ", str(tmp_path / "half.pt"),
            "--selectors", "q_best")
    state = torch.load(our_run / "final_model.pt", weights_only=True)
    state["qf"]["qf2.0.bias"][0] = float("inf")
    torch.save(state, tmp_path / "inf.pt")
    refused(capsys, "the critic's qf2.0.bias holds NaN/inf", str(tmp_path / "inf.pt"),
            "--selectors", "q_best")


@pytest.mark.slow
def test_a_nan_action_stops_with_one_line(our_run, capsys, monkeypatch):
    build = policies.build_actor

    def damaged(*args, **kwargs):
        actor = build(*args, **kwargs)
        with torch.no_grad():
            actor.fc_mean.bias.fill_(float("nan"))
        return actor

    monkeypatch.setattr(policies, "build_actor", damaged)
    refused(capsys, "episodes 0-1: the evaluation action 'tanh_mu' is NaN/inf in episode 0",
            str(our_run), "--episodes", "2", "--selectors", "tanh_mu")
    code, _, err = run(capsys, str(our_run), "--episodes", "2", "--selectors", "tanh_mu")
    assert err.strip().endswith("the model is damaged or does not belong to this env"), err


@pytest.mark.slow
def test_weights_files_alone(our_run, tmp_path, capsys):
    """final_model.pt names its env; checkpoint.pt (loaded with weights_only=True) too, and a
    run folder without final_model.pt falls back to it: here both hold the same actor."""
    args = ("--episodes", "1", "--reps", "20")
    tables = {}
    for name, source in (("final", our_run / "final_model.pt"),
                         ("checkpoint", our_run / "checkpoint.pt")):
        code, out, err = run(capsys, str(source), *args)
        assert code == 0 and "on Pendulum-v1" in out, err
        tables[name] = out.split("\n", 2)[2]  # the table, after the line naming the source
    assert tables["final"] == tables["checkpoint"]
    partial = tmp_path / "partial"
    shutil.copytree(our_run, partial, ignore=shutil.ignore_patterns("final_model.pt"))
    code, out, err = run(capsys, str(partial), *args)
    assert code == 0 and "checkpoint.pt on Pendulum-v1" in out, err


@pytest.mark.slow
def test_files_in_older_layouts_give_the_same_numbers(our_run, tmp_path, capsys):
    """Weights (in, out), as every file written before issue 87 holds them, and with a leading
    seed axis of 1 too (written with --num-seeds, as every committed results/*-1M weight file
    is) evaluate exactly as the same networks in today's layout (nn.Linear's (out, in))."""
    state = torch.load(our_run / "final_model.pt", weights_only=True)
    assert state["actor"]["trunk.0.weight"].shape == (32, 3)  # (out, in)
    layouts = {"in_out": {".weight": lambda v: v.T},
               "seed_axis": {".weight": lambda v: v.T[None], ".bias": lambda v: v[None, None]}}
    for name, layout in layouts.items():  # the action scale and bias buffers stay as they are
        def old(weights: dict, layout: dict = layout) -> dict:
            return {k: next((f(v) for end, f in layout.items() if k.endswith(end)), v)
                    for k, v in weights.items()}

        torch.save({**state, "actor": old(state["actor"]), "qf": old(state["qf"])},
                   tmp_path / f"{name}.pt")
    outputs = []
    for source in (our_run / "final_model.pt", *(tmp_path / f"{n}.pt" for n in layouts)):
        code, _, err = run(capsys, str(source), "--episodes", "2", "--reps", "20", "--selectors",
                           "mode", "tanh_mu", "q_best", "--out", str(tmp_path / source.stem))
        assert code == 0, err
        outputs.append(read_rows(tmp_path / source.stem / "episodes.csv"))
    assert outputs[0] == outputs[1] == outputs[2]


@pytest.mark.parametrize("path", [
    "results/powerlift-10M/runs/h1hand-powerlift-v0__corrected__seed6__ffb396c1/snapshots/"
    "step1000000.pt",
    "results/bookshelf_simple-1M/runs/h1hand-bookshelf_simple-v0__corrected__seed0__007b8ea9/"
    "final_model.pt"])
def test_committed_weights_files_load_and_act_as_their_scripts_did(path):
    """A committed snapshot (weights (in, out)) and a --num-seeds final_model.pt ((1, in, out))
    load as nn.Linear networks and give the actions and Q values that their scripts' own
    layers (x @ W + b) give from the raw tensors."""
    actor, critic, env_id, _ = policies.load_policy(ROOT / path, None, need_critic=True)
    raw = torch.load(ROOT / path, map_location="cpu", weights_only=True)
    squeeze = {k: v.reshape(v.shape[-2:]) if k.endswith(".weight") else v.reshape(-1)
               for part in ("actor", "qf") for k, v in
               ((f"{part}.{k}", v) for k, v in raw[part].items())}

    def layer(name: str, x: torch.Tensor) -> torch.Tensor:
        return x @ squeeze[f"{name}.weight"] + squeeze[f"{name}.bias"]

    obs = torch.randn(16, actor.trunk[0].in_features, generator=torch.Generator().manual_seed(0))
    h = layer("actor.trunk.2", layer("actor.trunk.0", obs).relu()).relu()
    mu, log_std = actor(obs)
    torch.testing.assert_close(mu, layer("actor.fc_mean", h), rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(log_std, layer("actor.fc_logstd", h).clamp(-10, 2), rtol=1e-5,
                               atol=1e-5)
    x = torch.cat([obs, actor.scale(torch.tanh(mu))], -1)
    q1 = layer("qf.qf1.4", layer("qf.qf1.2", layer("qf.qf1.0", x).relu()).relu())[:, 0]
    torch.testing.assert_close(critic(obs, actor.scale(torch.tanh(mu)))[0], q1, rtol=1e-5,
                               atol=1e-4)
    assert env_id.startswith("h1hand-")


@pytest.mark.slow
def test_bad_sources_fail_clearly(sb3_models, our_run, tmp_path, capsys):
    refused(capsys, "is not a run folder (no config.json)", str(ROOT / "tests"))
    refused(capsys, "was trained on 3-dim observations and 1-dim actions; InvertedPendulum-v5 "
            "has 4 and 1", str(our_run), "--env-id", "InvertedPendulum-v5")
    refused(capsys, "is not a Stable-Baselines3 SAC model (its policy comes from "
            "stable_baselines3.common.policies)", str(sb3_models["ppo"]), "--env-id",
            "Pendulum-v1")
    refused(capsys, "pass --env-id", str(sb3_models["sac"]))
    refused(capsys, "was trained on observations (3,) and actions (1,)", str(sb3_models["sac"]),
            "--env-id", "Hopper-v5")
    refused(capsys, "unknown env id 'Pendulum-v9'", str(sb3_models["sac"]), "--env-id",
            "Pendulum-v9")
    text = tmp_path / "model.pt"
    text.write_text("not weights")
    refused(capsys, "is not a weights file of ours", str(text), "--env-id", "Pendulum-v1")
    not_zip = tmp_path / "model.zip"
    not_zip.write_text("not a zip")
    refused(capsys, "is not a Stable-Baselines3 model", str(not_zip), "--env-id", "Pendulum-v1")
    refused(capsys, "does not exist", str(tmp_path / "missing"))
    # Weights without a usable actor, or with NaN in it.
    torch.save({"actor": {"fc_mean.weight": torch.zeros(1, 32)}}, tmp_path / "headless.pt")
    refused(capsys, "holds no actor of sac_standard.py or sac_corrected.py",
            str(tmp_path / "headless.pt"), "--env-id", "Pendulum-v1")
    state = torch.load(our_run / "final_model.pt", weights_only=True)
    state["actor"]["fc_mean.bias"][0] = float("nan")
    torch.save(state, tmp_path / "nan.pt")
    refused(capsys, "fc_mean.bias holds NaN/inf", str(tmp_path / "nan.pt"))
    # A run folder whose config.json is damaged, or that holds no weights yet.
    damaged = tmp_path / "damaged"
    shutil.copytree(our_run, damaged)
    (damaged / "config.json").write_text("[1, 2]")
    refused(capsys, "does not hold a JSON object", str(damaged))
    (damaged / "config.json").write_text(json.dumps({"seed": 0}))
    refused(capsys, "names no env_id", str(damaged))
    for name in ("final_model.pt", "checkpoint.pt"):
        (damaged / name).unlink()
    refused(capsys, "holds no final_model.pt or checkpoint.pt", str(damaged), "--env-id",
            "Pendulum-v1")


@pytest.mark.slow
def test_a_damaged_evaluation_record_fails_clearly(tmp_path, capsys):
    """evaluation.json (an evaluation to summarise again) or its marker (one not finished) that
    is not a JSON object: one line naming the file, nothing written."""
    for name, content in (("evaluation.json", "{broken"), ("evaluation.json", "[1, 2]"),
                          (evaluate.PARTIAL_FILE, "[]"), (evaluate.PARTIAL_FILE, "\xff")):
        out = tmp_path / f"{name}-{len(content)}"
        out.mkdir()
        (out / name).write_text(content, encoding="latin-1")
        code, printed, err = run(capsys, str(out))
        assert code == 2 and printed == "" and len(err.strip().splitlines()) == 1, (code, err)
        assert str(out / name) in err, err
        assert err.strip().endswith("the evaluation's record is damaged; give another --out"), err
        assert sorted(p.name for p in out.iterdir()) == [name]


def test_bad_flags_fail_clearly_before_running(our_run, tmp_path, capsys):
    run_dir = str(our_run)
    refused(capsys, "--episodes 0: must be at least 1", run_dir, "--episodes", "0")
    refused(capsys, "--reps 0: must be at least 1", run_dir, "--reps", "0")
    refused(capsys, "--seed -1: must be a non-negative integer", run_dir, "--seed", "-1")
    refused(capsys, "--eval-round -1: must be 0 or more", run_dir, "--eval-round", "-1")
    refused(capsys, "--selectors : must be one or more", run_dir, "--selectors")
    # tyro's own parse errors, on one line.
    refused(capsys, "invalid choice 'bogus' for argument '--solver'", run_dir, "--solver",
            "bogus")
    refused(capsys, "Error parsing --episodes: invalid literal for int()", run_dir,
            "--episodes", "ten")
    refused(capsys, "invalid choice 'median' for argument '--selectors'", run_dir, "--selectors",
            "median")
    refused(capsys, "--workers -1: must be 0 (in-process) or more", run_dir, "--workers", "-1")
    refused(capsys, "Unrecognized options: --cuda", run_dir, "--cuda")  # the runner uses CPU
    refused(capsys, "Unrecognized options: --episode", run_dir, "--episode", "3")
    refused(capsys, "Missing from evaluate.py: PATH")
    # Output folders that are files, refused before a single episode runs.
    taken = tmp_path / "taken"
    taken.write_text("mine")
    refused(capsys, f"--out {taken}: a file of that name exists", run_dir, "--out", str(taken))
    refused(capsys, f"--video {taken}: a file of that name exists", run_dir, "--video",
            str(taken))
    assert taken.read_text() == "mine"
    # A seed above 2**32 (NumPy's legacy generator's limit) still evaluates, from its own start
    # state (not that of the seed modulo 2**32).
    out = tmp_path / "big_seed"
    code, stdout, err = run(capsys, run_dir, "--seed", str(2**40), "--episodes", "1", "--reps",
                            "10", "--out", str(out))
    assert code == 0, err
    assert f"the same start states for each (seed {2**40}, round 0)" in stdout
    rows = read_rows(out / "episodes.csv")
    assert [(r["selector"], int(r["reset_seed"])) for r in rows] == [
        ("mode", eval_seeds(2**40, 0, 1)[0]), ("tanh_mu", eval_seeds(2**40, 0, 1)[0])]
    assert eval_seeds(2**40, 0, 1) != eval_seeds(0, 0, 1)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["seed"] == 2**40
    for selector, row in zip(("mode", "tanh_mu"), rows, strict=True):
        assert summary["selectors"][selector]["return_mean"] == float(row["return"])


@pytest.mark.slow
def test_command_line_refusals_are_one_line(sb3_models):
    """The real command line: exit code 2, one line, no traceback; and without
    stable-baselines3 installed, a .zip asks for it."""
    for result, fragment in (
            (cli(str(sb3_models["ppo"]), "--env-id", "Pendulum-v1"),
             "is not a Stable-Baselines3 SAC model"),
            (cli(str(sb3_models["sac"]), "--env-id", "Pendulum-v1",
                 code="sys.modules['stable_baselines3'] = None"),
             "needs stable-baselines3: pip install stable-baselines3==2.9.2")):
        lines = result.stderr.strip().splitlines()
        assert result.returncode == 2 and len(lines) == 1, result.stderr
        assert lines[0].startswith("evaluate.py: error: ") and fragment in lines[0]


# --------------------------------------------------------------------------- a campaign
@pytest.fixture(scope="module")
def campaign(our_run, tmp_path_factory) -> Path:
    """Two runs of one task (seeds 0 and 1), each with a snapshot at step 800 (the final weights
    nudged, so that it acts otherwise) and its final weights at 1600."""
    root = tmp_path_factory.mktemp("campaign")
    final = torch.load(our_run / "final_model.pt", weights_only=True)
    config = json.loads((our_run / "config.json").read_text())
    for seed in (0, 1):
        run_dir = root / f"run{seed}"
        (run_dir / "snapshots").mkdir(parents=True)
        (run_dir / "config.json").write_text(json.dumps({**config, "seed": seed}))
        shutil.copy(our_run / "done.json", run_dir / "done.json")
        torch.save(final, run_dir / "final_model.pt")
        nudged = {**final, "actor": {k: v + 0.05 * (k == "fc_mean.bias")
                                     for k, v in final["actor"].items()}}
        torch.save(nudged, run_dir / "snapshots" / "step800.pt")
    return root


@pytest.mark.slow
def test_a_campaign_is_evaluated_per_seed_and_step_and_summarised(campaign, tmp_path, capsys):
    from scipy import stats

    out = tmp_path / "robust"
    code, printed, err = run(capsys, str(campaign), "--out", str(out), "--episodes", "6",
                             "--selectors", "mode", "tanh_mu", "mean", "--reps", "200")
    assert code == 0, err
    episodes = {}
    for seed in (0, 1):
        rows = read_rows(out / f"run{seed}" / "episodes.csv")
        assert len(rows) == 2 * 3 * 6  # steps x selectors x episodes
        for step in ("800", "1600"):
            for selector in ("mode", "tanh_mu", "mean"):
                mine = [r for r in rows if r["step"] == step and r["selector"] == selector]
                # Every step and action of a run from the same starts: its seed's.
                assert [int(r["reset_seed"]) for r in mine] == eval_seeds(seed, 0, 6)
                episodes[seed, int(step), selector] = np.array([float(r["return"])
                                                                for r in mine])
    assert not np.array_equal(episodes[0, 800, "mode"], episodes[0, 1600, "mode"])
    per_seed = read_rows(out / "per_seed.csv")
    differences = {}
    for row in per_seed:
        if row["selector"] == "tanh_mu":
            assert row["difference_mean"] == ""
            continue
        key = (int(row["seed"]), int(row["step"]), row["selector"])
        diffs = episodes[key] - episodes[key[:2] + ("tanh_mu",)]
        differences[key] = diffs.mean()
        assert float(row["difference_mean"]) == pytest.approx(diffs.mean())
        assert float(row["difference_se"]) == pytest.approx(stats.sem(diffs))
        assert float(row["return_se"]) == pytest.approx(stats.sem(episodes[key]))
    # Per seed only: across seeds is analyze.py's (--robust).
    assert sorted(p.name for p in out.iterdir() if p.is_file()) == [
        "evaluation.json", "per_seed.csv", "summary.md"]
    # Where it ran: another kind of CPU would give other episodes.
    assert json.loads((out / "evaluation.json").read_text())["machine"] == machine()
    summary = (out / "summary.md").read_text()
    assert "Precision check:" in summary and summary in printed
    for row in per_seed:
        if row["selector"] != "tanh_mu":
            mean, se = float(row["difference_mean"]), float(row["difference_se"])
            verdict = "level" if abs(mean) <= 3 * se else "ahead" if mean > 0 else "behind"
            word = verdict if verdict == "level" else f"**{verdict}**"
            assert f"| {mean:+.1f} +- {se:.1f} ({word}, " in summary
    # The --out folder as the source: the summary again from its CSVs, nothing run.
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    code, printed, err = run(capsys, str(out), "--reps", "200")
    assert code == 0, err
    for name, content in before.items():
        assert (out / name).read_bytes() == content, name


@pytest.mark.slow
def test_a_campaigns_episodes_do_not_depend_on_workers(campaign, tmp_path, capsys):
    for workers in ("0", "2"):
        code, _, err = run(capsys, str(campaign), "--out", str(tmp_path / workers), "--episodes",
                           "3", "--steps", "1600", "--reps", "50", "--workers", workers)
        assert code == 0, err
    for seed in (0, 1):
        name = f"run{seed}/episodes.csv"
        assert (tmp_path / "2" / name).read_text() == (tmp_path / "0" / name).read_text()
        assert {r["step"] for r in read_rows(tmp_path / "0" / name)} == {"1600"}


@pytest.mark.slow
def test_a_campaign_refuses_what_it_cannot_evaluate(campaign, tmp_path, capsys):
    refused(capsys, "is a folder of runs: give --out", str(campaign))
    refused(capsys, "no run under it holds final_model.pt or snapshots at --steps 5",
            str(campaign), "--out", str(tmp_path / "o"), "--steps", "5")
    refused(capsys, "Pendulum-v1 is not an h1hand task", str(campaign), "--out",
            str(tmp_path / "o"), "--reset-noise", "0.01")
    refused(capsys, "--reset-noise -1.0: must be a finite number >= 0", str(campaign),
            "--reset-noise", "-1")


def _h1hand_weights(tmp_path: Path) -> Path:
    """An untrained actor of ours for bookshelf_simple, as final_model.pt holds one."""
    import sac_corrected as sac

    env = gym.make("h1hand-bookshelf_simple-v0")
    torch.manual_seed(0)
    actor = sac.Actor(env.observation_space.shape[0], (16,), env.action_space, -10.0, 2.0)
    path = tmp_path / "final_model.pt"
    torch.save({"actor": actor.state_dict(), "config": {
        "env_id": "h1hand-bookshelf_simple-v0", "hidden_sizes": (16,), "log_std_min": -10.0,
        "log_std_max": 2.0}}, path)
    return path


def test_one_start_is_one_episode_and_reset_noise_gives_distinct_ones(tmp_path, capsys):
    weights = _h1hand_weights(tmp_path)
    code, out, err = run(capsys, str(weights), "--episodes", "3", "--reps", "50",
                         "--out", str(tmp_path / "same"))
    assert code == 0, err
    assert "All 3 episodes start from the same state" in out and "--reset-noise 0.01" in out
    assert "(one episode)" in out and "one paired episode" in out
    assert json.loads((tmp_path / "same" / "summary.json").read_text())["distinct_starts"] == 1
    code, out, err = run(capsys, str(weights), "--episodes", "3", "--reps", "50",
                         "--reset-noise", "0.01", "--out", str(tmp_path / "noisy"))
    assert code == 0, err
    assert "same state" not in out and "mode - tanh_mu, paired:" in out
    rows = read_rows(tmp_path / "noisy" / "episodes.csv")
    assert len({r["return"] for r in rows if r["selector"] == "tanh_mu"}) == 3


# --------------------------------------------------------------------------- resuming a campaign
CAMPAIGN_ARGS = ("--episodes", "3", "--selectors", "mode", "tanh_mu", "mean", "--reps", "50")


class Killed(BaseException):
    """The kill of a work session's end, as far as evaluate.py can tell: nothing runs after it."""


def interrupted(campaign: Path, out: Path, monkeypatch, capsys) -> None:
    """A campaign evaluation into out, killed just after its first policy (run0 at step 800)
    was written."""
    write_run_files = evaluate.write_run_files

    def then_killed(*args) -> None:
        write_run_files(*args)
        raise Killed

    with monkeypatch.context() as patch:
        patch.setattr(evaluate, "write_run_files", then_killed)
        with pytest.raises(Killed):
            evaluate.main([str(campaign), "--out", str(out), *CAMPAIGN_ARGS, "--workers", "0"])
    capsys.readouterr()


def files(out: Path) -> dict[str, bytes]:
    """out's files less evaluation.json's seconds and the summary's count of them (the time
    taken differs from one evaluation to the next)."""
    found = {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*"))
             if p.is_file()}
    settings = json.loads(found.pop("evaluation.json"))
    assert settings.pop("seconds") >= 0
    found["evaluation.json"] = json.dumps(settings).encode()
    found["summary.md"] = re.sub(rb"\d+ s of evaluation", b"N s of evaluation",
                                 found["summary.md"])
    return found


@pytest.mark.slow
def test_an_interrupted_campaign_resumes_to_the_same_files(campaign, tmp_path, monkeypatch,
                                                            capsys):
    code, _, err = run(capsys, str(campaign), "--out", str(tmp_path / "whole"), *CAMPAIGN_ARGS)
    assert code == 0 and "0 of 4 policies already evaluated, 4 left" in err, err
    out = tmp_path / "resumed"
    interrupted(campaign, out, monkeypatch, capsys)
    # What the kill left: the marker and the finished policy's rows, no evaluation.json.
    assert sorted(str(p.relative_to(out)) for p in out.rglob("*")) == [
        "evaluation.partial.json", "run0", "run0/episodes.csv", "run0/shift.csv"]
    assert {r["step"] for r in read_rows(out / "run0" / "episodes.csv")} == {"800"}
    assert len(read_rows(out / "run0" / "episodes.csv")) == 3 * 3
    marker = json.loads((out / evaluate.PARTIAL_FILE).read_text())
    assert (marker["episodes"], marker["selectors"]) == (3, ["mode", "tanh_mu", "mean"])
    refused(capsys, "not finished yet (evaluation.partial.json): run its command again", str(out))
    # The same command again evaluates only the three policies not written.
    evaluated = []
    run_jobs = evaluate.run_jobs

    def counted(jobs, *args):
        evaluated.extend(job.label.split(":")[0] for job in jobs)
        return run_jobs(jobs, *args)

    monkeypatch.setattr(evaluate, "run_jobs", counted)
    code, _, err = run(capsys, str(campaign), "--out", str(out), *CAMPAIGN_ARGS)
    assert code == 0 and "1 of 4 policies already evaluated, 3 left" in err, err
    assert evaluated == ["run0 step 1600", "run1 step 800", "run1 step 1600"]
    assert files(out) == files(tmp_path / "whole")
    # Complete now: the same command again evaluates nothing and rewrites the same summary.
    evaluated.clear()
    code, printed, err = run(capsys, str(campaign), "--out", str(out), *CAMPAIGN_ARGS)
    assert code == 0 and "is complete (evaluation.json): nothing evaluated" in err, err
    assert evaluated == [] and "Precision check" in printed
    assert files(out) == files(tmp_path / "whole")


@pytest.mark.slow
def test_a_resume_rewrites_a_policy_whose_rows_are_incomplete(campaign, tmp_path, capsys):
    out = tmp_path / "out"
    code, _, err = run(capsys, str(campaign), "--out", str(out), *CAMPAIGN_ARGS, "--steps",
                       "1600")
    assert code == 0, err
    whole = files(out)
    # As if killed mid-campaign, run1's rows cut short: run1 is evaluated again, run0 kept.
    settings = json.loads((out / "evaluation.json").read_text())
    (out / evaluate.PARTIAL_FILE).write_text(json.dumps(settings | {"steps": [1600]}))
    (out / "evaluation.json").unlink()
    episodes = (out / "run1" / "episodes.csv").read_text().splitlines(keepends=True)
    (out / "run1" / "episodes.csv").write_text("".join(episodes[:-1]), newline="")
    code, _, err = run(capsys, str(campaign), "--out", str(out), *CAMPAIGN_ARGS, "--steps",
                       "1600")
    assert code == 0 and "1 of 2 policies already evaluated, 1 left" in err, err
    assert files(out) == whole and not (out / evaluate.PARTIAL_FILE).exists()


@pytest.mark.slow
def test_a_campaign_still_training_stays_unfinished_until_its_steps_are_there(campaign, tmp_path,
                                                                              capsys):
    source, out = tmp_path / "runs", tmp_path / "out"
    shutil.copytree(campaign, source)
    (source / "run2").mkdir()  # a sweep's run not started yet: its plan, no config.json
    (source / "run2" / "sweep_run.json").write_text(json.dumps({"seed": 2}))
    asked = (*CAMPAIGN_ARGS, "--steps", "800", "2400")
    code, printed, err = run(capsys, str(source), "--out", str(out), *asked)
    assert code == 0 and "0 of 2 policies already evaluated, 2 left, 3 not there yet" in err, err
    assert ("not there yet at --steps: run2 (not started), run0 step 2400, run1 step 2400; once "
            "they are, the same command evaluates them") in err and printed == ""
    # Not sealed: the step-800 rows, the marker and the tables so far; no evaluation.json.
    assert sorted(p.name for p in out.iterdir() if p.is_file()) == [evaluate.PARTIAL_FILE,
                                                                    evaluate.PARTIAL_SUMMARY]
    assert {r["step"] for r in read_rows(out / "run1" / "episodes.csv")} == {"800"}
    so_far = (out / evaluate.PARTIAL_SUMMARY).read_text()
    assert so_far.startswith("# Unfinished evaluation of 2 runs") and (
        "not there yet: run2 (not started), run0 step 2400, run1 step 2400." in so_far)
    # summary.md's per-policy tables, of the two step-800 policies only
    assert "Precision check" in so_far and "2,400" not in so_far and "| 0 | 800 |" in so_far
    refused(capsys, "not finished yet (evaluation.partial.json): run its command again", str(out))
    for seed in (0, 1):  # the runs trained on to their next snapshot
        shutil.copy(source / f"run{seed}" / "snapshots" / "step800.pt",
                    source / f"run{seed}" / "snapshots" / "step2400.pt")
    code, printed, err = run(capsys, str(source), "--out", str(out), *asked)
    assert code == 0 and "2 of 4 policies already evaluated, 2 left, 1 not there yet" in err, err
    assert "run2 (not started)" in err and printed == "" and not (out / "evaluation.json").exists()
    shutil.rmtree(source / "run2")  # dropped from the sweep
    code, printed, err = run(capsys, str(source), "--out", str(out), *asked)
    assert code == 0 and "4 of 4 policies already evaluated, 0 left" in err, err
    assert "not there yet" not in err and "Precision check" in printed
    assert not (out / evaluate.PARTIAL_SUMMARY).exists()  # summary.md replaces it
    code, _, err = run(capsys, str(source), "--out", str(tmp_path / "whole"), *asked)
    assert code == 0, err
    assert files(out) == files(tmp_path / "whole")


@pytest.mark.slow
def test_an_evaluated_snapshot_may_leave_the_runs_folder(campaign, tmp_path, capsys):
    """A long campaign's evaluated snapshots may leave the repository (results/classic-1M):
    their rows stay and the campaign still completes as if they were there; weights gone with
    their rows cut short are refused, not dropped."""
    source, out = tmp_path / "runs", tmp_path / "out"
    shutil.copytree(campaign, source)
    asked = (*CAMPAIGN_ARGS, "--steps", "800", "2400")
    code, _, err = run(capsys, str(source), "--out", str(out), *asked)
    assert code == 0 and "2 not there yet" in err, err
    rows = {seed: (out / f"run{seed}" / "episodes.csv").read_bytes() for seed in (0, 1)}
    (source / "run0" / "snapshots" / "step800.pt").unlink()
    code, _, err = run(capsys, str(source), "--out", str(out), *asked)
    assert code == 0 and "2 of 2 policies already evaluated, 0 left, 2 not there yet" in err, err
    assert (out / "run0" / "episodes.csv").read_bytes() == rows[0]
    (source / "run1" / "snapshots" / "step800.pt").unlink()
    (out / "run1" / "episodes.csv").write_bytes(rows[1][:rows[1].rindex(b"\n", 0, -1) + 1])
    refused(capsys, "run1 step 800: its rows in", str(source), "--out", str(out), *asked)
    (out / "run1" / "episodes.csv").write_bytes(rows[1])
    for seed in (0, 1):  # the runs trained on to their next snapshot
        shutil.copy(campaign / "run1" / "snapshots" / "step800.pt",
                    source / f"run{seed}" / "snapshots" / "step2400.pt")
    code, _, err = run(capsys, str(source), "--out", str(out), *asked)
    assert code == 0 and "2 of 4 policies already evaluated, 2 left" in err, err
    assert "not there yet" not in err and (out / "evaluation.json").is_file()
    for seed in (0, 1):
        shutil.copy(campaign / f"run{seed}" / "snapshots" / "step800.pt",
                    source / f"run{seed}" / "snapshots" / "step800.pt")
    code, _, err = run(capsys, str(source), "--out", str(tmp_path / "whole"), *asked)
    assert code == 0, err
    assert files(out) == files(tmp_path / "whole")


@pytest.mark.slow
def test_a_resume_with_other_settings_is_refused(campaign, tmp_path, monkeypatch, capsys):
    out = tmp_path / "out"
    interrupted(campaign, out, monkeypatch, capsys)
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    refused(capsys, "holds an evaluation with other settings (--episodes 3 there, 4 here): give "
            "the same source and flags to resume it, or another --out", str(campaign), "--out",
            str(out), *CAMPAIGN_ARGS, "--episodes", "4")
    refused(capsys, "(--selectors mode tanh_mu mean there, mode tanh_mu here; --solver exact "
            "there, grid here)", str(campaign), "--out", str(out), *CAMPAIGN_ARGS,
            "--selectors", "mode", "tanh_mu", "--solver", "grid")
    refused(capsys, "(--steps (not given) there, 800 here)", str(campaign), "--out", str(out),
            *CAMPAIGN_ARGS, "--steps", "800")
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    # A complete --out too.
    code, _, err = run(capsys, str(campaign), "--out", str(out), *CAMPAIGN_ARGS)
    assert code == 0, err
    refused(capsys, "(--eval-round 0 there, 1 here)", str(campaign), "--out", str(out),
            *CAMPAIGN_ARGS, "--eval-round", "1")


def test_a_write_killed_midway_leaves_the_old_file(tmp_path, monkeypatch):
    """evaluate.py writes its files through sac_utils.files: a kill before the rename leaves
    the old file whole."""
    from sac_utils import files

    path = tmp_path / "episodes.csv"
    files.write_text_atomically(path, "old\r\n")

    def killed(*args) -> None:
        raise Killed

    monkeypatch.setattr(files.os, "replace", killed)
    with pytest.raises(Killed):
        files.write_text_atomically(path, "new\r\n")
    assert path.read_bytes() == b"old\r\n"


# --------------------------------------------------------------------------- physics blow-ups
BLOW_UP = "tests.toy_envs:OddBlowUp-v0"  # episodes from odd reset seeds end in a blow-up
BLOW_UP_ARGS = ("--episodes", "6", "--selectors", "mode", "tanh_mu", "--reps", "50")


def _toy_weights(path: Path, nudge: float = 0.0) -> Path:
    """An untrained actor of ours for the toy env, as final_model.pt holds one."""
    import sac_corrected as sac

    torch.manual_seed(0)
    actor = sac.Actor(3, (8,), gym.make(BLOW_UP).action_space, -10.0, 2.0)
    weights = {k: v + nudge * (k == "fc_mean.bias") for k, v in actor.state_dict().items()}
    torch.save({"actor": weights, "config": {"env_id": BLOW_UP, "hidden_sizes": (8,),
                                             "log_std_min": -10.0, "log_std_max": 2.0}}, path)
    return path


@pytest.fixture
def blow_up_campaign(tmp_path) -> Path:
    """Two toy runs (seeds 0 and 1), each with a snapshot at step 500 and its final weights at
    1000."""
    root = tmp_path / "campaign"
    for seed in (0, 1):
        run_dir = root / f"run{seed}"
        (run_dir / "snapshots").mkdir(parents=True)
        (run_dir / "config.json").write_text(json.dumps(
            {"env_id": BLOW_UP, "seed": seed, "total_timesteps": 1000, "hidden_sizes": [8]}))
        _toy_weights(run_dir / "final_model.pt")
        _toy_weights(run_dir / "snapshots" / "step500.pt", nudge=0.1)
    return root


def without_unstable_column(folder: Path) -> None:
    """Every run's episodes.csv under folder as evaluate.py wrote it before physics_unstable (and
    end, after it)."""
    for path in folder.glob("*/episodes.csv"):
        with open(path, newline="") as f:
            rows = list(csv.reader(f))
        assert rows[0][-2:] == ["physics_unstable", "end"]
        path.write_text(evaluate.csv_text([row[:-2] for row in rows]), newline="")


def test_episodes_csv_marks_the_episodes_a_physics_blow_up_ended(tmp_path, capsys):
    out = tmp_path / "out"
    code, printed, err = run(capsys, str(_toy_weights(tmp_path / "final_model.pt")),
                             *BLOW_UP_ARGS, "--out", str(out))
    assert code == 0, err
    with open(out / "episodes.csv", newline="") as f:
        assert next(csv.reader(f)) == evaluate.EPISODE_COLUMNS
    rows = read_rows(out / "episodes.csv")
    assert evaluate.EPISODE_COLUMNS[-2:] == ["physics_unstable", "end"] and len(rows) == 2 * 6
    marks = [r["physics_unstable"] for r in rows]
    assert marks == [str(int(r["reset_seed"]) % 2) for r in rows]
    # why each ended: the blow-ups, and the toy env's own end, which gives no reason
    assert [r["end"] for r in rows] == ["blow_up" if m == "1" else "terminated" for m in marks]
    assert {"0", "1"} <= set(marks)  # both kinds of end among these starts
    # summary.json and the printed summary count them per action
    summary = json.loads((out / "summary.json").read_text())
    for selector in ("mode", "tanh_mu"):
        ends = sum(r["physics_unstable"] == "1" for r in rows if r["selector"] == selector)
        assert summary["selectors"][selector]["unstable_ends"] == ends > 0
        assert summary["selectors"][selector]["ends"] == {"blow_up": ends,
                                                          "terminated": 6 - ends}
        assert f"{ends} of {selector}'s episodes" in printed


def test_a_campaign_counts_blow_ups_and_summarises_and_resumes_older_folders(
        blow_up_campaign, tmp_path, capsys):
    whole = tmp_path / "whole"
    code, _, err = run(capsys, str(blow_up_campaign), "--out", str(whole), *BLOW_UP_ARGS)
    assert code == 0, err
    blow_ups = {seed: sum(s % 2 for s in eval_seeds(seed, 0, 6)) for seed in (0, 1)}
    assert blow_ups[0] != blow_ups[1]  # the counts are told apart per run
    for seed in (0, 1):
        rows = read_rows(whole / f"run{seed}" / "episodes.csv")
        assert [r["physics_unstable"] for r in rows] == [str(int(r["reset_seed"]) % 2)
                                                         for r in rows]
    per_seed = read_rows(whole / "per_seed.csv")
    assert {(r["seed"], r["step"], r["selector"], r["unstable_ends"], r["end_blow_up"],
             r["end_terminated"]) for r in per_seed} == {
        (str(seed), step, selector, str(blow_ups[seed]), str(blow_ups[seed]),
         str(6 - blow_ups[seed])) for seed in (0, 1)
        for step in ("500", "1000") for selector in ("mode", "tanh_mu")}
    summary = (whole / "summary.md").read_text()
    assert "blow-ups" in summary
    # the toy task's early ends are gymnasium's "terminated", their paired share tested too
    assert f"| 1 | 1k | mode | {blow_ups[1]} | {6 - blow_ups[1]} | +0.00 +- 0.00: level, 0.0 SE " \
           f"| {blow_ups[1]} |" in summary

    # A complete folder from before the column: its summary as before, without the counts.
    old = tmp_path / "old"
    shutil.copytree(whole, old)
    without_unstable_column(old)
    code, _, err = run(capsys, str(old), "--reps", "50")
    assert code == 0, err
    old_per_seed = read_rows(old / "per_seed.csv")
    assert old_per_seed == [{k: v for k, v in r.items()
                             if k != "unstable_ends"
                             and not k.startswith(("end_", "terminated_difference"))}
                            for r in per_seed]
    assert "blow-ups" not in (old / "summary.md").read_text()

    # An unfinished folder from before the column, step 500 not evaluated yet: the resume keeps
    # the older rows (physics_unstable empty: not recorded), adds step 500's, one header.
    settings = json.loads((old / "evaluation.json").read_text())
    (old / evaluate.PARTIAL_FILE).write_text(json.dumps(settings | {"steps": []}))
    (old / "evaluation.json").unlink()
    for seed in (0, 1):
        for name in ("episodes.csv", "shift.csv"):
            path = old / f"run{seed}" / name
            lines = path.read_text().splitlines(keepends=True)
            path.write_text("".join(line for line in lines if not line.startswith("500,")),
                            newline="")
    code, _, err = run(capsys, str(blow_up_campaign), "--out", str(old), *BLOW_UP_ARGS)
    assert code == 0 and "2 of 4 policies already evaluated, 2 left" in err, err
    for seed in (0, 1):
        with open(whole / f"run{seed}" / "episodes.csv", newline="") as f:
            expected = [row[:-2] + ["", ""] if row[0] == "1000" else row
                        for row in csv.reader(f)]
        with open(old / f"run{seed}" / "episodes.csv", newline="") as f:
            assert list(csv.reader(f)) == expected
        name = f"run{seed}/shift.csv"
        assert (old / name).read_text() == (whole / name).read_text()
    assert {(r["seed"], r["step"], r["unstable_ends"]) for r in read_rows(old / "per_seed.csv")} \
        == {(str(seed), step, str(blow_ups[seed]) if step == "500" else "")
            for seed in (0, 1) for step in ("500", "1000")}
    summary = (old / "summary.md").read_text()
    assert "| 0 | 1k | mode | n/r | n/r |  | n/r |" in summary
    assert f"| 0 | 500 | mode | {blow_ups[0]} | {6 - blow_ups[0]} | +0.00 +- 0.00: level, 0.0 SE" \
           f" | {blow_ups[0]} |" in summary


def test_per_seed_tests_the_paired_share_of_falls_as_it_tests_the_returns():
    """fell_difference_*: per start, 1 where the action's episode ended with the robot down minus
    1 where tanh(mu)'s did; summary.md says more / fewer by the 3-SE rule. A step whose ends were
    not recorded gets no such cells, nor a folder where no episode fell."""
    falls = {"tanh_mu": [1, 0, 0, 1, 0, 0] * 5, "mode": [1, 1, 1, 1, 1, 0] * 5,
             "mean": [1, 0, 0, 1, 0, 0] * 5}

    def rows(step: int, action: str, ends: list[str]) -> list[list[str]]:
        return [[str(step), action, str(i), str(1000 + i), str(float(i % 7)), "10", "", "0", end]
                for i, end in enumerate(ends)]

    episodes = {}
    for action, fell in falls.items():
        episodes["run", 100, action] = rows(100, action, ["fell" if f else "dropped" for f in fell])
        episodes["run", 200, action] = rows(200, action, [""] * len(fell))  # not recorded
        episodes["other", 100, action] = rows(100, action, ["time_limit"] * len(fell))
    settings = {"runs": {"run": {"env_id": "task-v0", "seed": 0},
                         "other": {"env_id": "other-v0", "seed": 1}},
                "selectors": ["mode", "tanh_mu", "mean"], "source": "runs",
                "command": ["evaluate.py"], "episodes": 30, "eval_round": 0, "reset_noise": 0.01,
                "seconds": 1.0}
    per_seed = evaluate.per_seed_rows(settings, episodes)
    got = {(r["run"], r["step"], r["selector"]): r for r in per_seed}
    paired = np.array(falls["mode"], dtype=float) - falls["tanh_mu"]
    mode = got["run", 100, "mode"]
    assert mode["fell_difference_mean"] == pytest.approx(0.5)
    assert mode["fell_difference_se"] == pytest.approx(paired.std(ddof=1) / np.sqrt(30))
    assert mode["end_fell"] == 25 and got["run", 100, "tanh_mu"]["end_fell"] == 10
    assert got["run", 100, "mean"]["fell_difference_mean"] == 0.0
    assert "fell_difference_mean" not in got["run", 100, "tanh_mu"]
    assert "fell_difference_mean" not in got["run", 200, "mode"]
    # where some episode in the folder fell, as end_fell: none of the other task's did
    assert got["other", 100, "mode"]["fell_difference_mean"] == 0.0
    table = evaluate.campaign_markdown(settings, per_seed, episodes)
    assert "| fell (mode / tanh(mu)) |" in table and "fell, minus tanh(mu) |" in table
    assert f"| 25 / 10 (+0.50 +- {mode['fell_difference_se']:.2f}: **more**, 5.4 SE) |" in table
    assert "| 0 | 100 | mean | 20 | 10 | +0.00 +- 0.00: level, 0.0 SE |" in table
    assert "| 0 | 200 | mode | n/r | n/r |  |" in table  # step 200's ends: not recorded
    assert "| only the mode's fell |" in table  # the split by how the episodes ended
    no_falls = {k: v for k, v in episodes.items() if k[0] == "other"}
    settings["runs"].pop("run")
    assert "fell" not in evaluate.campaign_markdown(settings,
                                                    evaluate.per_seed_rows(settings, no_falls))


def test_a_gymnasium_termination_is_tested_paired_as_a_fall_is():
    """Hopper, Walker2d, Ant and Humanoid end early ("terminated") only when the body leaves its
    healthy range: per_seed.csv tests the paired share of such ends as it does the h1hand falls,
    summary.md counts them beside the time limits and splits the return difference by them."""
    ends = {"tanh_mu": [0, 0, 0, 0, 1, 0] * 5, "mode": [1, 1, 0, 1, 1, 0] * 5}
    cost = {"tanh_mu": 0.0, "mode": 2.0}  # the mode's terminated episodes return 2 less
    episodes = {("run", 100, action): [
        ["100", action, str(i), str(1000 + i), str(i % 5 - cost[action] * e), "10", "", "0",
         "terminated" if e else "time_limit"] for i, e in enumerate(flags)]
        for action, flags in ends.items()}
    settings = {"runs": {"run": {"env_id": "Hopper-v5", "seed": 0}},
                "selectors": ["mode", "tanh_mu"], "source": "runs", "command": ["evaluate.py"],
                "episodes": 30, "eval_round": 0, "reset_noise": None, "seconds": 1.0}
    per_seed = evaluate.per_seed_rows(settings, episodes)
    got = {r["selector"]: r for r in per_seed}
    paired = np.array(ends["mode"], dtype=float) - ends["tanh_mu"]
    assert got["mode"]["terminated_difference_mean"] == pytest.approx(0.5)
    assert got["mode"]["terminated_difference_se"] == pytest.approx(
        paired.std(ddof=1) / np.sqrt(30))
    assert got["mode"]["end_terminated"] == 20 and got["tanh_mu"]["end_terminated"] == 5
    assert got["mode"]["end_time_limit"] == 10
    assert "fell_difference_mean" not in got["mode"]
    assert "terminated_difference_mean" not in got["tanh_mu"]
    table = evaluate.campaign_markdown(settings, per_seed, episodes)
    se = got["mode"]["terminated_difference_se"]
    assert f"| 20 / 5 (+0.50 +- {se:.2f}: **more**, {0.5 / se:.2g} SE) | 10 / 25 |" in table
    assert "| terminated (mode / tanh(mu)) | time limit (mode / tanh(mu)) |" in table
    assert "terminated, minus tanh(mu) |" in table and "body left its healthy range" in table
    # starts per part (pattern of six: 2 neither, 3 only the mode's, 1 both), each difference
    assert ("| neither terminated | only the mode's terminated | only tanh(mu)'s terminated | "
            "both terminated |") in table
    assert "| 0 | 100 | 10, +0.00 +- 0.00 | 15, -2.00 +- 0.00 | 0 | 5, -2.00 +- 0.00 |" in table


def test_where_the_differences_are_names_the_task_when_the_runs_span_several():
    """A campaign of several tasks has one seed 0 per task: the split's rows name their task,
    so that Hopper's seed 0 is not read as HalfCheetah's."""
    def rows(end: str, cost: float) -> dict:
        return {("run-" + end, 100, action): [
            ["100", action, str(i), str(i), str(i - (cost if action == "mode" else 0)), "10", "",
             "0", end] for i in range(4)] for action in ("mode", "tanh_mu")}

    episodes = rows("time_limit", 1.0) | rows("terminated", 3.0)
    settings = {"runs": {"run-time_limit": {"env_id": "HalfCheetah-v5", "seed": 0},
                         "run-terminated": {"env_id": "Hopper-v5", "seed": 0}},
                "selectors": ["mode", "tanh_mu"]}
    table = "\n".join(evaluate.fall_split(settings, episodes))
    assert ("| task | seed | step | neither terminated |" in table
            and "| HalfCheetah-v5 | 0 | 100 | 4, -1.00 +- 0.00 | 0 | 0 | 0 |\n"
                "| Hopper-v5 | 0 | 100 | 0 | 0 | 0 | 4, -3.00 +- 0.00 |" in table), table
    one_task = {"runs": {"run-terminated": settings["runs"]["run-terminated"]},
                "selectors": settings["selectors"]}
    table = "\n".join(evaluate.fall_split(one_task, rows("terminated", 3.0)))
    assert "| seed | step | neither terminated |" in table and "task" not in table
    assert "\n| 0 | 100 | 0 | 0 | 0 | 4, -3.00 +- 0.00 |" in table


def test_summary_tabulates_the_shift_each_policy_makes_at_its_visited_states(tmp_path):
    """summary.md's last table is shift.csv's, per policy: the mode's shift per dimension and
    summed, sigma, the two-mode share and q_best's picks; a campaign without shift.csv (an
    older one) has no such table."""
    settings = {"runs": {"b": {"env_id": "Hopper-v5", "seed": 1},
                         "a": {"env_id": "Hopper-v5", "seed": 0}},
                "selectors": ["mode", "tanh_mu", "q_best"]}
    for run, rows in {"a": [["500", "0.05", "0.15", "0.3", "0.25", "0.1", "0.85", "0.05"]],
                      "b": [["500", "0.125", "0.375", "0.5", "0.0", "", "", ""]]}.items():
        (tmp_path / run).mkdir()
        (tmp_path / run / "shift.csv").write_text(
            "\n".join([",".join(evaluate.SHIFT_HEADER), *(",".join(r) for r in rows)]) + "\n")
    table = "\n".join(evaluate.shift_table(settings, evaluate.read_shifts(tmp_path, settings)))
    assert "over the states its mode episodes visited" in table
    assert table.index("| Hopper-v5 | 0 | 500 |") < table.index("| Hopper-v5 | 1 | 500 |")
    assert "| Hopper-v5 | 0 | 500 | 0.05 | 0.15 | 0.3 | 25.0% | 10% / 85% / 5% |" in table
    assert "| Hopper-v5 | 1 | 500 | 0.125 | 0.375 | 0.5 | 0.0% | - / - / - |" in table
    assert evaluate.shift_table(settings, evaluate.read_shifts(tmp_path / "none", settings)) == []
