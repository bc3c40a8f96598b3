"""sweep.py with stand-ins: --mps (NVIDIA's Multi-Process Service around a local sweep; CI has no
GPU, so a stand-in nvidia-cuda-mps-control records what sweep.py asks of it; bench/bench_gpu.py
uses the real one) and --track, with a stand-in training script that records its arguments and
the environment its runs inherit."""

import json
import os
import stat
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

FAKE_MPS = """#!/bin/sh
# stand-in for nvidia-cuda-mps-control: one line per call (time, arguments, stdin, pipe folder)
if [ "$1" = "-d" ]; then input=""; else input=$(cat); fi
echo "$(date +%s.%N) args=$* stdin=$input pipe=$CUDA_MPS_PIPE_DIRECTORY" >> "$MPS_LOG"
"""
FAKE_RUN = """import json, os, sys, time
args = dict(zip(sys.argv[1::2], sys.argv[2::2]))
run_dir = os.path.join(args["--output-dir"], args["--run-name"])
os.makedirs(run_dir, exist_ok=True)
with open(os.path.join(run_dir, "done.json"), "w") as f:
    json.dump({"pipe": os.environ.get("CUDA_MPS_PIPE_DIRECTORY"), "time": time.time(),
               "argv": sys.argv[1:]}, f)
"""


def executable(path: Path, text: str) -> Path:
    path.write_text(text)
    path.chmod(path.stat().st_mode | stat.S_IEXEC)
    return path


def sweep(*args: str, path: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "sweep.py"), *args], capture_output=True,
                          text=True, timeout=120, env={**os.environ, "PATH": path,
                                                       "MPS_LOG": path.split(":")[0] + "/log"})


def test_mps_runs_start_inside_the_daemon_and_it_stops_after(tmp_path):
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    executable(bin_dir / "nvidia-cuda-mps-control", FAKE_MPS)
    script = executable(tmp_path / "fake_run.py", FAKE_RUN)
    result = sweep("--env-ids", "Pendulum-v1", "--seeds", "0", "1", "--scripts", str(script),
                   "--workers", "2", "--mps", "--output-dir", str(tmp_path / "runs"),
                   path=f"{bin_dir}:{os.environ['PATH']}")
    assert result.returncode == 0, result.stderr
    assert "MPS started" in result.stdout and "MPS stopped" in result.stdout
    start, stop = (line.split() for line in (bin_dir / "log").read_text().splitlines())
    assert start[1] == "args=-d" and stop[2] == "stdin=quit"
    pipe = start[3].removeprefix("pipe=")
    assert pipe and stop[3] == start[3]
    runs = [json.loads(p.read_text()) for p in (tmp_path / "runs").glob("*/done.json")]
    assert len(runs) == 2
    for run in runs:  # each run saw the daemon's pipe folder, while the daemon was up
        assert run["pipe"] == pipe
        assert float(start[0]) < run["time"] < float(stop[0])
    assert not Path(pipe).exists()  # the private folder is removed afterwards


def test_mps_refused_where_it_cannot_work(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    args = ("--env-ids", "Pendulum-v1", "--seeds", "0", "--output-dir", str(tmp_path / "r"))
    result = sweep(*args, "--mps", path=str(empty))
    assert result.returncode == 2 and "needs nvidia-cuda-mps-control" in result.stderr
    result = sweep(*args, "--mps", "--launcher", "slurm", path=os.environ["PATH"])
    assert result.returncode == 2 and "--mps is for --launcher local" in result.stderr
    assert "Traceback" not in result.stderr


def test_track_passes_through_with_a_group_per_task_and_algorithm(tmp_path):
    script = executable(tmp_path / "sac_fake.py", FAKE_RUN)
    result = sweep("--env-ids", "Pendulum-v1", "Hopper-v5", "--seeds", "0", "--scripts",
                   str(script), "--track", "--wandb-project-name", "proj", "--output-dir",
                   str(tmp_path / "runs"), path=os.environ["PATH"])
    assert result.returncode == 0, result.stderr
    runs = [json.loads(p.read_text()) for p in sorted((tmp_path / "runs").glob("*/done.json"))]
    groups = []
    for run in runs:
        argv = run["argv"]
        assert argv[argv.index("--wandb-project-name") + 1] == "proj" and "--track" in argv
        groups.append(argv[argv.index("--wandb-group") + 1])
    assert groups == ["Hopper-v5__fake", "Pendulum-v1__fake"]
    # The tracking flags are not part of a run's identity: the same grid without --track
    # finds the same run folders done.
    again = sweep("--env-ids", "Pendulum-v1", "Hopper-v5", "--seeds", "0", "--scripts",
                  str(script), "--output-dir", str(tmp_path / "runs"), path=os.environ["PATH"])
    assert "0 to launch" in again.stdout


# A stand-in that stops after starting (exit code 3, "interrupted", with a config.json) and
# finishes when resumed: each attempt's arguments stay in its run folder. --dry-run imports it
# for its default step budget.
FAKE_INTERRUPTED = """import json, os, sys
class Args:
    total_timesteps = 1000
if __name__ == "__main__":
    argv = sys.argv[1:]
    if "--resume" in argv:
        run_dir, name, code = argv[argv.index("--resume") + 1], "done.json", 0
    else:
        run_dir = os.path.join(argv[argv.index("--output-dir") + 1],
                               argv[argv.index("--run-name") + 1])
        name, code = "config.json", 3
    os.makedirs(run_dir, exist_ok=True)
    with open(os.path.join(run_dir, name), "w") as f:
        json.dump({"argv": argv}, f)
    sys.exit(code)
"""


def eval_workers_of(argv: list[str]) -> list[str]:
    return [argv[i + 1] for i, arg in enumerate(argv) if arg == "--eval-workers"]


def test_free_cores_are_divided_among_the_runs_on_start_and_resume(tmp_path, monkeypatch,
                                                                    capsys):
    """16 cores, --workers 2: each run trains on one core and gets (16 - 2) // 2 = 7 evaluation
    workers; resumed with --workers 4 but only 2 runs left (2 at a time): 7 again; resumed
    alone (--workers 1): 15. The folders are the same whatever the division."""
    import sweep as sweep_module

    monkeypatch.setattr(sweep_module.os, "sched_getaffinity", lambda pid: set(range(16)))
    script = executable(tmp_path / "sac_fake.py", FAKE_INTERRUPTED)
    out = tmp_path / "runs"

    def run(*args: str) -> str:
        sweep_module.main(["--env-ids", "Pendulum-v1", "--scripts", str(script),
                           "--output-dir", str(out), *args])
        return capsys.readouterr().out

    assert "evaluation: 7 workers per run (16 cores, 2 runs at a time)" in run(
        "--seeds", "0", "1", "--workers", "2", "--dry-run")
    assert not out.exists()
    assert "evaluation: 7 workers per run (16 cores, 2 runs at a time)" in run(
        "--seeds", "0", "1", "--workers", "2")
    folders = sorted(out.glob("*/config.json"))
    assert len(folders) == 2
    for config in folders:
        assert eval_workers_of(json.loads(config.read_text())["argv"]) == ["7"]

    # --workers 4, but 2 runs to launch: 2 at a time; 1 to launch: it has the cores to itself.
    assert "evaluation: 7 workers per run (16 cores, 2 runs at a time)" in run(
        "--seeds", "0", "1", "--workers", "4", "--dry-run")
    assert "evaluation: 15 workers per run (16 cores, 1 run at a time)" in run(
        "--seeds", "0", "--workers", "4", "--dry-run")
    assert "2 to launch" in run("--seeds", "0", "1", "--workers", "4")
    for config in folders:
        argv = json.loads((config.parent / "done.json").read_text())["argv"]
        assert argv[:2] == ["--resume", str(config.parent)]
        assert eval_workers_of(argv) == ["7"]
    assert sorted(out.glob("*/done.json")) == [c.parent / "done.json" for c in folders]


def test_resume_with_other_workers_finds_the_same_folders(tmp_path, monkeypatch, capsys):
    import sweep as sweep_module

    monkeypatch.setattr(sweep_module.os, "sched_getaffinity", lambda pid: set(range(16)))
    script = executable(tmp_path / "sac_fake.py", FAKE_INTERRUPTED)
    grid = ["--env-ids", "Pendulum-v1", "--seeds", "0", "--scripts", str(script),
            "--output-dir", str(tmp_path / "runs")]
    assert sweep_module.main([*grid, "--workers", "8", "--", "--batch-size", "32"]) == 3
    (config,) = (tmp_path / "runs").glob("*/config.json")
    assert eval_workers_of(json.loads(config.read_text())["argv"]) == ["15"]
    # A user's own --eval-workers after `--` stands, alone, and is no part of the identity.
    assert sweep_module.main([*grid, "--workers", "1", "--", "--batch-size", "32",
                              "--eval-workers=0"]) == 0
    assert "evaluation: 0 workers per run (--eval-workers after `--`)" in capsys.readouterr().out
    (done,) = (tmp_path / "runs").glob("*/done.json")
    assert done.parent == config.parent
    assert eval_workers_of(json.loads(done.read_text())["argv"]) == ["0"]
    assert "--eval-workers=0" not in json.loads(done.read_text())["argv"]


def test_run_command_passes_the_division_once_and_the_identity_ignores_it(tmp_path):
    import sweep as sweep_module
    from sac_utils.sweep_run import run_command

    def grid(*extra: str, **options) -> list:
        args = sweep_module.Args(env_ids=["Pendulum-v1"], seeds=[0], output_dir=str(tmp_path),
                                 scripts=["sac_standard.py"], **options)
        return sweep_module.build_grid(args, extra)

    (plain,) = grid("--batch-size", "32")
    for extra in (("--eval-workers", "3"), ("--eval-workers=3",), ("--eval_workers", "1",
                                                                    "--eval-workers", "3")):
        (run,) = grid("--batch-size", "32", *extra)
        assert (run.name, run.identity(), run.eval_workers) == (plain.name, plain.identity(), 3)
        _, command = run_command(run)
        assert command.count("--eval-workers") == 1 and command[-2:] == ["--eval-workers", "3"]
        assert not any(arg.startswith("--eval_workers") for arg in command)
    # None: the script's default.
    assert "--eval-workers" not in run_command(plain)[1]

    divided = sweep_module.eval_division
    assert divided(sweep_module.Args(launcher="slurm", cpus_per_task=4), None, 9)[0] == 3
    assert divided(sweep_module.Args(launcher="slurm"), None, 9) == (
        1, "evaluation: 1 worker per run (1 CPU per Slurm task, one for training)")
    assert divided(sweep_module.Args(launcher="slurm", cpus_per_task=4,
                                     sbatch=["cpus-per-task=8"]), None, 9)[0] == 7
    assert divided(sweep_module.Args(launcher="slurm"), 2, 9)[0] == 2
    assert [sweep_module.eval_workers_per_run(16, w) for w in (1, 2, 8, 16, 32)] == [
        15, 7, 1, 1, 1]  # at least one: in-process evaluation would stall training
