"""The compiled update (the scripts' default, --compile): the same SAC update as eager, one graph
compiled once, and whole runs that stay reproducible across kills, resumes and paths.

The other tests run the scripts with --no-compile (tests/test_sac.py, EAGER): compiling costs
20-60 s per process. Here the compiled runs share one module fixture; inductor's cache (on disk)
makes every compile after the first a fraction of the first.
"""

import copy
import functools
import os
import shutil
import signal
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
import torch

from tests.test_sac import ROOT, command, read_csv, run, wait_for

# Pendulum, tiny networks: updates from step 300, checkpoints at 600 and 1200.
TINY = ["--env-id", "Pendulum-v1", "--seed", "5", "--total-timesteps", "1200",
        "--learning-starts", "300", "--eval-interval", "400", "--eval-episodes", "2",
        "--hidden-sizes", "32", "32", "--batch-size", "32", "--log-interval", "100",
        "--print-interval", "1200", "--checkpoint-interval", "600", "--eval-workers", "0"]
# Compiled and eager runs of the same seed: equal up to the rounding of differently fused
# kernels. Measured here over these runs' 900 updates: losses at most 8e-6 apart (5e-7
# relative); the tolerances leave ~100x of room.
RUN_RTOL, RUN_ATOL = 1e-4, 1e-3
LOSSES = ("qf1_loss", "qf2_loss", "qf1_value", "qf2_value", "actor_loss", "alpha", "alpha_loss",
          "entropy")


def small_learner(seed: int) -> tuple:
    """The scripts' networks and optimizers, Hopper's dimensions."""
    from sac_standard import Actor, TwinQ

    generator = torch.Generator().manual_seed(seed)
    space = gym.spaces.Box(-1.0, 1.0, (3,), np.float32)
    actor = Actor(11, (64, 64), space, -10.0, 2.0, generator)
    qf = TwinQ(11, 3, (64, 64), generator)
    qf_target = copy.deepcopy(qf)
    log_alpha = torch.zeros((), requires_grad=True)
    adam = functools.partial(torch.optim.Adam, lr=3e-4, fused=True)
    return (actor, qf, qf_target, log_alpha,
            (adam(actor.parameters()), adam(qf.parameters()), adam([log_alpha])))


def updates(compiled: bool, steps: int = 200) -> tuple[list, dict]:
    """Each update's logged tensors over `steps` updates on fixed random batches, and the final
    actor."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # the scripts' default; and both paths then sum alike
    try:
        return run_updates(compiled, steps)
    finally:
        torch.set_num_threads(threads)


def run_updates(compiled: bool, steps: int) -> tuple[list, dict]:
    from sac_standard import agent_tensors, sac_update
    from sac_utils.speedups import compile_at_start

    actor, qf, qf_target, log_alpha, optimizers = small_learner(0)
    tensors = agent_tensors(actor, qf, qf_target, log_alpha, *optimizers)
    update = functools.partial(sac_update, actor=actor, qf=qf, gamma=0.99, tau=0.005,
                               target_entropy=-1.5)
    if compiled:
        torch._dynamo.reset()
        torch._dynamo.utils.counters.clear()
        zero = (torch.zeros(32, 11), torch.zeros(32, 3), torch.zeros(32), torch.zeros(32, 11),
                torch.zeros(32))
        update = compile_at_start(update, (tensors, zero, torch.zeros(2, 32, 3)),
                                  (actor, qf, qf_target, log_alpha, *optimizers), "the update")
    g = torch.Generator().manual_seed(1)
    logs = []
    for _ in range(steps):
        batch = (torch.randn(32, 11, generator=g), torch.rand(32, 3, generator=g) * 2 - 1,
                 torch.randn(32, generator=g), torch.randn(32, 11, generator=g),
                 (torch.rand(32, generator=g) > 0.05).float())
        logs.append([t.detach().clone() for t in update(tensors, batch,
                                                        torch.randn(2, 32, 3, generator=g))])
    return logs, actor.state_dict()


@pytest.mark.slow
def test_the_compiled_update_is_the_eager_update_in_one_graph():
    eager, eager_actor = updates(compiled=False)
    compiled, compiled_actor = updates(compiled=True)
    # One graph for the whole update, compiled once: no graph break (fullgraph would have
    # failed) and no recompile in 200 calls.
    assert torch._dynamo.utils.counters["stats"]["unique_graphs"] == 1
    # Inductor fuses kernels and orders float sums its own way. Measured here (torch 2.13, one
    # thread): every logged tensor of the 200 updates within 2e-6 of eager's, the final actor's
    # parameters within 6e-8. The tolerances leave ~50x of room.
    for step_compiled, step_eager in zip(compiled, eager, strict=True):
        for a, b in zip(step_compiled, step_eager, strict=True):
            torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-4)
    for name, value in eager_actor.items():
        torch.testing.assert_close(compiled_actor[name], value, rtol=1e-5, atol=3e-6, msg=name)
    assert not torch.equal(eager[0][0], eager[-1][0])  # they learned


def test_the_update_steps_adam_as_torch_optim_adam_does():
    """sac_update's own Adam step (foreach ops, so that it compiles) against torch's."""
    from sac_utils.speedups import adam_state, adam_step

    torch.manual_seed(0)
    params = [torch.randn(5, 7, requires_grad=True), torch.randn(3, requires_grad=True)]
    reference = [p.detach().clone().requires_grad_() for p in params]
    ours = torch.optim.Adam(params, lr=1e-2, betas=(0.8, 0.95), eps=1e-6, fused=True)
    torch_adam = torch.optim.Adam(reference, lr=1e-2, betas=(0.8, 0.95), eps=1e-6)
    state = adam_state(ours)
    for step in range(50):
        grads = [torch.randn_like(p) * 10.0 ** (step % 4 - 2) for p in params]
        with torch.no_grad():
            adam_step(params, grads, state)
        for p, grad in zip(reference, grads, strict=True):
            p.grad = grad
        torch_adam.step()
    for a, b in zip(params, reference, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)
    assert float(state["steps"][0]) == 50 and not torch.equal(params[0], reference[0] * 0)


def kill_after_checkpoint(out, name: str, *flags: str) -> None:
    """A run of sac_standard.py SIGKILLed after its checkpoint at step 600 (mid-run)."""
    process = subprocess.Popen(command("sac_standard.py", *TINY, *flags, "--output-dir",
                                       str(out), "--run-name", name), cwd=ROOT,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wait_for(lambda: (out / name / "train.csv").exists()
             and "\n700," in (out / name / "train.csv").read_text(), timeout=600)
    process.send_signal(signal.SIGKILL)
    process.wait()
    assert not (out / name / "done.json").exists()
    assert torch.load(out / name / "checkpoint.pt", weights_only=True)["global_step"] == 600


@pytest.fixture(scope="module")
def compiled_runs(tmp_path_factory):
    """Both scripts, compiled, same seed; and a compiled standard run killed after its
    checkpoint (a copy of its folder kept)."""
    out = tmp_path_factory.mktemp("compiled")
    first = run("sac_standard.py", *TINY, "--compile", "--output-dir", str(out), "--run-name",
                "std")
    run("sac_corrected.py", *TINY, "--compile", "--output-dir", str(out), "--run-name", "cor",
        "--eval-selectors", "mean")
    kill_after_checkpoint(out, "killed", "--compile")
    shutil.copytree(out / "killed", out / "killed-copy")
    return out, first.stdout


@pytest.mark.slow
def test_a_compiled_run_says_what_compiling_cost(compiled_runs):
    out, stdout = compiled_runs
    assert stdout.count("compiled the update in ") == 1


@pytest.mark.slow
def test_compiled_scripts_make_the_same_training_decisions(compiled_runs):
    out, _ = compiled_runs
    assert read_csv(out / "std" / "train.csv") == read_csv(out / "cor" / "train.csv")
    standard, corrected = read_csv(out / "std" / "eval.csv"), read_csv(out / "cor" / "eval.csv")
    assert len(standard) == 3
    for row_s, row_c in zip(standard, corrected, strict=True):
        assert row_c["tanh_mu_return_mean"] == row_s["return_mean"]


@pytest.mark.slow
def test_compiled_sigkill_and_resume_equals_the_uninterrupted_run(compiled_runs):
    out, _ = compiled_runs
    # No flag: a resume keeps the run's path (sweep.py resumes runs so).
    result = subprocess.run([sys.executable, str(ROOT / "sac_standard.py"), "--resume",
                             str(out / "killed")], cwd=ROOT, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert "resuming" in result.stdout and "at step 600" in result.stdout
    assert "compiled the update in " in result.stdout
    for name in ("train.csv", "eval.csv"):
        assert read_csv(out / "killed" / name) == read_csv(out / "std" / name), name


def close_rows(run_dir, reference) -> None:
    """The same rows, losses within RUN_RTOL/RUN_ATOL of the reference run's."""
    rows, expected = read_csv(run_dir / "train.csv"), read_csv(reference / "train.csv")
    assert [r["global_step"] for r in rows] == [r["global_step"] for r in expected]
    values = np.array([[float(r[k]) for k in LOSSES] for r in rows if r["qf1_loss"]])
    reference_values = np.array([[float(r[k]) for k in LOSSES] for r in expected
                                 if r["qf1_loss"]])
    np.testing.assert_allclose(values, reference_values, rtol=RUN_RTOL, atol=RUN_ATOL)
    assert len(read_csv(run_dir / "eval.csv")) == 3 and (run_dir / "done.json").exists()


@pytest.mark.slow
def test_a_compiled_checkpoint_resumes_eager(compiled_runs):
    out, _ = compiled_runs
    result = run("sac_standard.py", "--resume", str(out / "killed-copy"), "--no-compile")
    assert "compiled the update" not in result.stdout
    rows, compiled = read_csv(out / "killed-copy" / "train.csv"), read_csv(out / "std" /
                                                                           "train.csv")
    assert rows[:6] == compiled[:6]  # up to the checkpoint, the compiled run's own rows
    close_rows(out / "killed-copy", out / "std")


@pytest.mark.slow
def test_an_eager_checkpoint_resumes_compiled(compiled_runs, tmp_path):
    out, _ = compiled_runs
    kill_after_checkpoint(tmp_path, "eager", "--no-compile")
    result = run("sac_standard.py", "--resume", str(tmp_path / "eager"), "--compile")
    assert "compiled the update in " in result.stdout
    close_rows(tmp_path / "eager", out / "std")


@pytest.mark.slow
def test_without_a_cpp_compiler_the_run_names_the_fix_in_one_line(tmp_path):
    # A fresh inductor cache: a cached kernel would need no compiler.
    env = {**os.environ, "CXX": str(tmp_path / "no-such-compiler"),
           "TORCHINDUCTOR_CACHE_DIR": str(tmp_path / "cache")}
    result = subprocess.run(command("sac_standard.py", *TINY, "--compile", "--output-dir",
                                    str(tmp_path), "--run-name", "r"),
                            cwd=ROOT, env=env, capture_output=True, text=True)
    assert result.returncode != 0
    assert "Traceback" not in result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert "compiling " in last and " failed (" in last
    assert "apt-get install g++ python3-dev" in last and "--no-compile" in last


def test_the_eager_gradient_is_torch_funcs():
    """Uncompiled, speedups.grad takes sac_losses's gradient from torch.autograd (faster eager);
    the graph is traced from torch.func.grad. Both give the same gradient and the same logs, and
    neither leaves the logs attached to an autograd graph."""
    from sac_standard import agent_tensors, sac_losses
    from sac_utils.speedups import grad

    actor, qf, qf_target, log_alpha, optimizers = small_learner(seed=3)
    tensors = agent_tensors(actor, qf, qf_target, log_alpha, *optimizers)
    torch.manual_seed(4)
    batch = (torch.randn(32, 11), torch.rand(32, 3) * 2 - 1, torch.randn(32),
             torch.randn(32, 11), (torch.rand(32) > 0.1).float())
    noise = torch.randn(2, 32, 3)
    params = (tensors["actor"], tensors["qf"], tensors["log_alpha"])
    args = (params, tensors["qf_target"], batch, noise, actor, qf, 0.99, -1.5)
    with torch.no_grad():  # as sac_update calls it
        ours, our_logs = grad(sac_losses)(*args)
        reference, reference_logs = torch.func.grad(sac_losses, has_aux=True)(*args)
    for mine, theirs in zip(ours[:2], reference[:2], strict=True):
        assert mine.keys() == theirs.keys()
        for name in theirs:
            torch.testing.assert_close(mine[name], theirs[name], rtol=1e-6, atol=1e-7, msg=name)
            assert mine[name].abs().sum() > 0, name  # every parameter gets a gradient
    torch.testing.assert_close(ours[2], reference[2], rtol=1e-6, atol=1e-7)
    for mine, theirs in zip(our_logs, reference_logs, strict=True):
        torch.testing.assert_close(mine, theirs, rtol=1e-6, atol=1e-7)
        assert not mine.requires_grad
    assert all(not p.grad_fn for p in ours[0].values())
