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
