"""--num-seeds: K seeds trained side by side in one process, each in its own run folder."""

import copy
import csv
import functools
import json
import signal
import subprocess
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

from tests.test_sac import command, read_csv, run, wait_for

ROOT = Path(__file__).resolve().parent.parent
TINY = ["--env-id", "Pendulum-v1", "--seed", "3", "--num-seeds", "2", "--total-timesteps", "1200",
        "--learning-starts", "300", "--eval-interval", "400", "--eval-episodes", "2",
        "--hidden-sizes", "32", "32", "--batch-size", "32", "--log-interval", "100",
        "--print-interval", "1200", "--checkpoint-interval", "500", "--eval-workers", "0"]


def learner(seeds: int):
    """A tiny batched learner (the scripts' classes and optimisers), seed k from generator k."""
    from sac_standard import Actor, TwinQ

    generators = [torch.Generator().manual_seed(10 + k) for k in range(seeds)]
    space = gym.spaces.Box(-1.0, 2.0, (2,), np.float32)
    actor = Actor(3, (8, 8), space, -10.0, 2.0, seeds, generators)
    qf = TwinQ(3, 2, (8, 8), seeds, generators)
    qf_target = copy.deepcopy(qf)
    with torch.no_grad():
        for p in qf_target.parameters():
            p.add_(0.05)
    log_alpha = torch.linspace(-0.5, 0.5, seeds).requires_grad_()
    adam = functools.partial(torch.optim.Adam, lr=0.01, fused=True)
    return actor, qf, qf_target, log_alpha, (adam(actor.parameters()), adam(qf.parameters()),
                                             adam([log_alpha]))


def update(learner, batch: tuple[torch.Tensor, ...], noise: torch.Tensor) -> None:
    """The scripts' sac_update of a learner (as learner() makes them)."""
    from sac_standard import learner_tensors, sac_update

    actor, qf, qf_target, log_alpha, optimizers = learner
    sac_update(learner_tensors(actor, qf, qf_target, log_alpha, *optimizers), batch, noise,
               actor, qf, 0.99, 0.1, -1.0)


def single_seed(batch_learner, k: int):
    """Seed k of a batched learner as a K = 1 learner, its optimiser states included."""
    from run_folder import load_optimizer_seed_states, optimizer_seed_state, seed_slice

    actor, qf, qf_target, log_alpha, optimizers = batch_learner
    one = learner(1)
    for module, source in zip(one[:3], (actor, qf, qf_target), strict=True):
        module.load_state_dict(seed_slice(source, k).state_dict())
    with torch.no_grad():
        one[3].copy_(log_alpha.detach()[k:k + 1])
    for optimizer, source in zip(one[4], optimizers, strict=True):
        load_optimizer_seed_states(optimizer, [optimizer_seed_state(source, k)])
    return one


def test_the_batched_update_of_three_seeds_is_three_single_seed_updates():
    from run_folder import seed_slice

    torch.manual_seed(0)
    batch_learner = learner(3)
    update(batch_learner, make_batch(3, 0), torch.randn(2, 3, 16, 2))  # Adam's states exist
    singles = [single_seed(batch_learner, k) for k in range(3)]  # they must carry over
    for step in range(1, 4):
        batch = make_batch(3, step)
        noise = torch.randn(2, 3, 16, 2)  # the next action's, then the action's
        update(batch_learner, batch, noise)
        for k, one in enumerate(singles):
            update(one, tuple(t[k:k + 1] for t in batch), noise[:, k:k + 1])
    for k, one in enumerate(singles):
        for module, alone in zip(batch_learner[:3], one[:3], strict=True):  # targets included
            for (name, a), b in zip(seed_slice(module, k).state_dict().items(),
                                    alone.state_dict().values(), strict=True):
                torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6, msg=name)
        torch.testing.assert_close(batch_learner[3][k:k + 1], one[3])  # the temperature


def make_batch(seeds: int, step: int) -> tuple[torch.Tensor, ...]:
    g = torch.Generator().manual_seed(step)
    return (torch.randn(seeds, 16, 3, generator=g), torch.rand(seeds, 16, 2, generator=g) * 3 - 1,
            torch.randn(seeds, 16, generator=g), torch.randn(seeds, 16, 3, generator=g),
            (torch.rand(seeds, 16, generator=g) > 0.2).float())


def test_one_adam_over_stacked_parameters_is_one_adam_per_seed():
    torch.manual_seed(0)
    stacked = torch.randn(4, 5, 3, requires_grad=True)
    apart = [stacked.detach()[k].clone().requires_grad_() for k in range(4)]
    adam = functools.partial(torch.optim.Adam, lr=0.1, fused=True)
    optimizers = [adam([stacked]), *(adam([p]) for p in apart)]
    for _ in range(5):
        grads = torch.randn(4, 5, 3) * torch.tensor([1.0, 10.0, 0.01, 100.0])[:, None, None]
        stacked.grad = grads.clone()
        for k, p in enumerate(apart):
            p.grad = grads[k].clone()
        for optimizer in optimizers:
            optimizer.step()
    for k, p in enumerate(apart):
        torch.testing.assert_close(stacked.detach()[k], p.detach(), rtol=0, atol=1e-7)


@pytest.fixture(scope="module")
def batch(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("batch")
    run("sac_standard.py", *TINY, "--output-dir", str(out), "--run-name", "std{seed}")
    return out


def test_a_batch_gives_each_seed_its_own_run_folder(batch):
    configs = [json.loads((batch / f"std{s}" / "config.json").read_text()) for s in (3, 4)]
    assert [c["seed"] for c in configs] == [3, 4]
    assert configs[0]["batch"] == configs[1]["batch"] == {
        "first_seed": 3, "num_seeds": 2, "run_dirs": ["std3", "std4"]}
    for s in (3, 4):
        folder = batch / f"std{s}"
        assert {"done.json", "final_model.pt", "checkpoint.pt", "eval.csv", "train.csv"} <= {
            p.name for p in folder.iterdir()}
        assert [r["global_step"] for r in read_csv(folder / "eval.csv")] == ["400", "800", "1200"]
        losses = [r["qf1_loss"] for r in read_csv(folder / "train.csv") if r["qf1_loss"]]
        assert len(set(losses)) == len(losses) == 10  # updates ran and moved the critic
    # The seeds differ: other start states, other networks, other returns.
    assert read_csv(batch / "std3" / "eval.csv") != read_csv(batch / "std4" / "eval.csv")


def test_a_batch_is_reproducible(batch, tmp_path):
    run("sac_standard.py", *TINY, "--output-dir", str(tmp_path), "--run-name", "std{seed}")
    for s in (3, 4):
        assert_same_run(tmp_path / f"std{s}", batch / f"std{s}")


def assert_same_run(a: Path, b: Path) -> None:
    for name in ("eval.csv", "train.csv"):
        assert read_csv(a / name) == read_csv(b / name), name
    first, second = (torch.load(r / "final_model.pt") for r in (a, b))
    for part in ("actor", "qf"):
        for key, value in first[part].items():
            assert torch.equal(value, second[part][key]), key


def test_a_seed_of_a_batch_loads_in_evaluate_py(batch, tmp_path):
    import evaluate

    evaluate.main([str(batch / "std4"), "--episodes", "2", "--seed", "4", "--eval-round", "3",
                   "--workers", "0",
                   "--reps", "50", "--out", str(tmp_path)])
    with open(tmp_path / "episodes.csv", newline="") as f:
        episodes = [r for r in csv.DictReader(f) if r["selector"] == "tanh_mu"]
    # Round 3 of seed 4 is the run's own evaluation at step 1200: the same returns.
    last = read_csv(batch / "std4" / "eval.csv")[-1]
    assert np.isclose(np.mean([float(r["return"]) for r in episodes]), float(last["return_mean"]))


def test_standard_and_corrected_batches_pair_seed_by_seed(batch, tmp_path):
    run("sac_corrected.py", *TINY, "--output-dir", str(tmp_path), "--run-name", "cor{seed}",
        "--eval-selectors", "mean")
    for s in (3, 4):
        standard = read_csv(batch / f"std{s}" / "eval.csv")
        corrected = read_csv(tmp_path / f"cor{s}" / "eval.csv")
        for row_s, row_c in zip(standard, corrected, strict=True):
            assert row_c["tanh_mu_return_mean"] == row_s["return_mean"]
            assert row_c["tanh_mu_length_mean"] == row_s["length_mean"]
        assert read_csv(batch / f"std{s}" / "train.csv") == read_csv(
            tmp_path / f"cor{s}" / "train.csv")


def test_sigkill_mid_batch_then_resume_equals_the_uninterrupted_batch(batch, tmp_path):
    args = [*TINY, "--output-dir", str(tmp_path), "--run-name", "std{seed}"]
    process = subprocess.Popen(command("sac_standard.py", *args), cwd=ROOT,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    # The checkpoint at step 500 falls mid-episode (Pendulum's are 200 steps): it is replayed.
    wait_for(lambda: (tmp_path / "std4" / "train.csv").exists()
             and "\n700," in (tmp_path / "std4" / "train.csv").read_text())
    process.send_signal(signal.SIGKILL)
    process.wait()
    # Killed before the end, or the resume would have nothing to do and the batch would equal
    # the uninterrupted one whatever --resume does.
    steps = set()
    for s in (3, 4):
        assert not (tmp_path / f"std{s}" / "done.json").exists()
        steps.add(torch.load(tmp_path / f"std{s}" / "checkpoint.pt",
                             weights_only=True)["global_step"])
    assert len(steps) == 1 and steps <= {500, 1000}
    (step,) = steps
    assert_analyze_counts_the_seeds(tmp_path, tmp_path / "report")  # an interrupted batch
    result = run("sac_standard.py", "--resume", str(tmp_path / "std4"), "--eval-workers", "1")
    assert f"resuming {tmp_path / 'std3'}, {tmp_path / 'std4'} at step {step}\n" in result.stdout
    for s in (3, 4):
        assert_same_run(tmp_path / f"std{s}", batch / f"std{s}")


def assert_analyze_counts_the_seeds(runs: Path, out: Path) -> None:
    """analyze.py on a batch's folders (finished or not): two seeds of Pendulum-v1, standard,
    each to the last step of its eval.csv, and the final return the mean of the two at the last
    step they share."""
    import analyze

    finals = {}
    for s in (3, 4):
        rows = read_csv(runs / f"std{s}" / "eval.csv")
        finals[s] = {int(r["global_step"]): float(r["return_mean"]) for r in rows}
    last = sorted({max(f) for f in finals.values()})
    shared = max(set(finals[3]) & set(finals[4]))
    assert analyze.main([str(runs), "--out", str(out), "--reps", "100", "--curve-reps", "20",
                         "--curve-points", "3"]) == 0
    text = (out / "summary.md").read_text()
    assert f"Found 2 runs under {runs}:" in text
    span = "-".join(f"{step:,}" for step in last)
    assert f"| Pendulum-v1 | 2 seeds, to step {span} |" in text
    with (out / "summary.csv").open(newline="") as f:
        (final,) = [r for r in csv.DictReader(f)
                    if r["section"] == "task_final" and r["metric"] == "return"]
    assert (final["task"], final["group"], final["step"], final["n_runs"]) == (
        "Pendulum-v1", "standard", str(shared), "2")
    assert float(final["estimate"]) == pytest.approx((finals[3][shared] + finals[4][shared]) / 2)


def test_analyze_reads_a_batch(batch, tmp_path):
    assert_analyze_counts_the_seeds(batch, tmp_path / "report")


def test_an_interrupted_batch_checkpoint_is_completed_on_resume(tmp_path):
    from run_folder import read_batch_checkpoints, save_batch_checkpoint

    dirs = [tmp_path / "a", tmp_path / "b"]
    for d in dirs:
        d.mkdir()
    state = {key: {} for key in ("args", "progress", "actor", "qf", "qf_target", "q_optimizer",
                                 "actor_optimizer", "alpha_optimizer", "buffer")}
    at = lambda step: state | {"global_step": step, "elapsed": 0.0,  # noqa: E731
                               "log_alpha": torch.zeros(1), "rng": {"episode": None}}
    save_batch_checkpoint(dirs, [at(100), at(100)])
    # A kill in the second phase of the next checkpoint: a's is moved in, b's still .tmp.
    for d in dirs:
        torch.save(at(200), d / "checkpoint.pt.tmp")
    (dirs[0] / "checkpoint.pt.tmp").replace(dirs[0] / "checkpoint.pt")
    assert [c["global_step"] for c in read_batch_checkpoints(dirs)] == [200, 200]
    assert not (dirs[1] / "checkpoint.pt.tmp").exists()


def test_a_foreign_folder_in_the_batch_is_named_and_nothing_is_written(batch, tmp_path):
    from tests.test_validation import snapshot

    for s in (3, 4):
        copy_dir = tmp_path / f"std{s}"
        __import__("shutil").copytree(batch / f"std{s}", copy_dir)
        (copy_dir / "done.json").unlink()
    config_path = tmp_path / "std4" / "config.json"
    config = json.loads(config_path.read_text())
    config_path.write_text(json.dumps(config | {"batch": {**config["batch"], "first_seed": 9}}))
    before = {s: snapshot(tmp_path / f"std{s}") for s in (3, 4)}
    result = run("sac_standard.py", "--resume", str(tmp_path / "std3"), check=False)
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert f"{tmp_path / 'std4'} is not a run of the batch" in result.stderr
    assert {s: snapshot(tmp_path / f"std{s}") for s in (3, 4)} == before


def test_a_batch_folder_in_use_refuses_a_second_writer(batch, tmp_path):
    """One writer per run folder, for a batch too: with one of its folders locked by another
    process (this one, as lock_run_folders locks it), a --resume of the batch and a fresh batch
    into a held folder are refused in one line naming that folder, before anything is written."""
    import fcntl
    import os
    import shutil

    from tests.test_validation import snapshot

    for s in (3, 4):
        shutil.copytree(batch / f"std{s}", tmp_path / f"std{s}")
        (tmp_path / f"std{s}" / "done.json").unlink()  # else the resume would have nothing to do
    (tmp_path / "new4").mkdir()  # a fresh batch's second folder, locked before its config.json
    held = [tmp_path / "std4" / "lock", tmp_path / "new4" / "lock"]  # the second of each batch
    fds = [os.open(path, os.O_RDWR | os.O_CREAT) for path in held]
    try:
        for fd in fds:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        before = snapshot(tmp_path)
        for args, folder in ((["--resume", str(tmp_path / "std3")], tmp_path / "std4"),
                             ([*TINY, "--output-dir", str(tmp_path), "--run-name", "new{seed}"],
                              tmp_path / "new4")):
            result = run("sac_standard.py", *args, check=False)
            lines = result.stderr.strip().splitlines()
            assert result.returncode == 2 and len(lines) == 1, result.stderr
            assert f"{folder} is in use by process {os.getpid()}" in lines[0]
            # Nothing written: the fresh batch's first folder, made and locked before its
            # second was found held, is gone again.
            assert snapshot(tmp_path) == before and not (tmp_path / "new3").exists()
    finally:
        for fd in fds:
            os.close(fd)


def test_a_batch_needs_seed_in_its_run_name(tmp_path):
    result = run("sac_standard.py", *TINY, "--output-dir", str(tmp_path), "--run-name", "x",
                 check=False)
    assert result.returncode == 2 and "containing {seed}" in result.stderr
    assert not any(tmp_path.iterdir())
