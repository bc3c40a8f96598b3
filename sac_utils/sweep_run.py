"""One run of a sweep.py grid: its identity (Run; the hash of its arguments names its folder), the
files sweep.py keeps in its folder beside the script's own (sweep_run.json, sweep_attempt.json,
sweep.log), its state, and its process, started or resumed, on this machine or as one task of a
Slurm job array (SlurmRun). The job unpickles Run and SlurmRun from this module, so it imports
nothing else of sweep.py's.
"""

from __future__ import annotations

import csv
import fcntl
import hashlib
import json
import os
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import submitit

from sac_utils.cli import INTERRUPTED_EXIT_CODE as EXIT_INTERRUPTED
from sac_utils.files import complete_lines, write_json

IDENTITY_FILE = "sweep_run.json"
ATTEMPT_FILE = "sweep_attempt.json"
LOG_FILE = "sweep.log"
LAUNCH_ACTIONS = ("start", "resume", "retry")


@dataclass(frozen=True)
class Run:
    """One cell of the grid: a script trained on one env id with one seed."""

    script: Path
    env_id: str
    seed: int
    extra_args: tuple[str, ...]
    output_dir: Path
    checkpoint_interval: int
    tracking: tuple[str, ...] = ()  # W&B flags: where the run logs, not what it computes
    eval_workers: int | None = None  # --eval-workers; None: the script's default

    @property
    def algorithm(self) -> str:
        return self.script.stem.removeprefix("sac_")

    @property
    def name(self) -> str:
        return f"{self.env_id}__{self.algorithm}__seed{self.seed}__{args_hash(self.extra_args)}"

    @property
    def run_dir(self) -> Path:
        return self.output_dir / self.name

    def identity(self) -> dict:
        return {"script": self.script.name, "env_id": self.env_id, "seed": self.seed,
                "extra_args": list(self.extra_args)}


def args_hash(extra_args: tuple[str, ...]) -> str:
    """Short stable hash of the arguments every run of a sweep gets (it names existing folders:
    never change it)."""
    return hashlib.sha256(json.dumps(list(extra_args)).encode()).hexdigest()[:8]


def read_json(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return None


def log_tail(run_dir: Path, lines: int = 8) -> list[str]:
    try:
        return (run_dir / LOG_FILE).read_text(errors="replace").splitlines()[-lines:]
    except FileNotFoundError:
        return []


def last_eval_step(run_dir: Path) -> int | None:
    try:
        rows = list(csv.DictReader(complete_lines(run_dir / "eval.csv")))
    except FileNotFoundError:
        return None
    return int(float(rows[-1]["global_step"])) if rows else None


# The state of a run.


def squeue_states(job_id: str) -> list[str] | None:
    """The states of the job's tasks still queued or running; None when squeue fails."""
    result = subprocess.run(["squeue", "-h", "-j", job_id, "-o", "%T"], capture_output=True,
                            text=True, timeout=60)
    return result.stdout.split() if result.returncode == 0 else None


def slurm_job_state(job_id: str) -> str | None:
    """squeue's state of a queued or running job, None when it is no longer in the queue."""
    states = squeue_states(job_id) if shutil.which("squeue") else None
    return states[0].lower() if states else None


def process_alive(attempt: dict) -> bool:
    """Whether the attempt's process still runs (knowable only on the host that ran it)."""
    if attempt.get("host") != socket.gethostname() or attempt.get("returncode") is not None:
        return False
    try:
        os.kill(attempt["pid"], 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, but another user's
        pass
    return True


def lock_holder(run_dir: Path) -> str | None:
    """The pid in run_dir/lock while a training script holds its flock, else None. The kernel
    drops the flock with its holder, so the file alone means nothing. A probe only: released at
    once, and the file is never created here."""
    try:
        fd = os.open(run_dir / "lock", os.O_RDONLY)
    except FileNotFoundError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
    finally:
        os.close(fd)
    return None


def run_state(run_dir: Path) -> str:
    """done, running, pending (queued on Slurm), interrupted, failed or not started."""
    if (run_dir / "done.json").exists():
        return "done"
    # Before the attempt file: a process this sweep did not start (a sweep launched twice, a
    # requeued job racing one not dead yet) is at work on the folder.
    if lock_holder(run_dir) is not None:
        return "running"
    identity = read_json(run_dir / IDENTITY_FILE) or {}
    if identity.get("slurm_job_id"):
        queued = slurm_job_state(identity["slurm_job_id"])
        if queued is not None:
            return "running" if queued in ("running", "completing") else "pending"
    attempt = read_json(run_dir / ATTEMPT_FILE) or {}
    if process_alive(attempt):
        return "running"
    returncode = attempt.get("returncode")
    if returncode is not None and returncode != EXIT_INTERRUPTED and returncode >= 0:
        return "failed"
    if (run_dir / "config.json").exists():
        return "interrupted"
    return "not started"


def action_for(state: str) -> str:
    return {"done": "skip", "running": "skip (running)", "pending": "skip (queued)",
            "interrupted": "resume", "failed": "retry"}.get(state, "start")


# Starting one run (both launchers).


def run_command(run: Run) -> tuple[str, list[str]]:
    """Resume a run that has started (its config.json exists), else start it."""
    python = [sys.executable, str(run.script)]
    tracking = [*run.tracking, "--wandb-group", f"{run.env_id}__{run.algorithm}"] \
        if run.tracking else []
    # A runtime flag: passed on resume too, where the stored arguments do not hold it.
    runtime = ["--eval-workers", str(run.eval_workers)] if run.eval_workers is not None else []
    if (run.run_dir / "config.json").exists():
        return "resume", [*python, "--resume", str(run.run_dir), *runtime, *tracking]
    return "start", [
        *python, "--env-id", run.env_id, "--seed", str(run.seed),
        "--output-dir", str(run.output_dir), "--run-name", run.name,
        "--checkpoint-interval", str(run.checkpoint_interval),
        *run.extra_args, *runtime, *tracking,
    ]


def start_run(run: Run, *, new_session: bool, block_user_signals: bool) -> subprocess.Popen:
    """Start or resume the run in its own process, its output appended to its log file."""
    action, command = run_command(run)
    job_id = slurm_array_task_id()
    where = socket.gethostname() + (f", Slurm job {job_id}" if job_id else "")
    # On Slurm the signal before the time limit reaches every process of the job; the child
    # must get it only once, through checkpoint(), or it would take a second signal as "exit now".
    preexec = _block_user_signals if block_user_signals else None
    with open(run.run_dir / LOG_FILE, "a") as log:
        log.write(f"=== sweep.py {action} on {where} at {time.strftime('%F %T')}: "
                  f"{shlex.join(command)}\n")
        log.flush()
        child = subprocess.Popen(
            command, stdout=log, stderr=subprocess.STDOUT, start_new_session=new_session,
            preexec_fn=preexec, env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
    write_json(run.run_dir / ATTEMPT_FILE, {
        "action": action, "host": socket.gethostname(), "pid": child.pid,
        "slurm_job_id": job_id, "started": time.time(), "returncode": None,
    })
    return child


def _block_user_signals() -> None:
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGUSR1, signal.SIGUSR2})


def record_exit(run: Run, returncode: int | None) -> None:
    attempt = read_json(run.run_dir / ATTEMPT_FILE) or {}
    attempt.update(returncode=returncode, ended=time.time())
    write_json(run.run_dir / ATTEMPT_FILE, attempt)
    with open(run.run_dir / LOG_FILE, "a") as log:
        log.write(f"=== sweep.py: exit code {returncode} at {time.strftime('%F %T')}\n")


def slurm_array_task_id() -> str | None:
    array_job = os.environ.get("SLURM_ARRAY_JOB_ID")
    if array_job:
        return f"{array_job}_{os.environ['SLURM_ARRAY_TASK_ID']}"
    return os.environ.get("SLURM_JOB_ID")


def prepare_run_dir(run: Run, **extra: str) -> None:
    run.run_dir.mkdir(parents=True, exist_ok=True)
    write_json(run.run_dir / IDENTITY_FILE, {**run.identity(), "run_name": run.name, **extra})


# The Slurm launcher's side in the job.


class SlurmRun:
    """A run as one task of a Slurm job array (submitit's checkpointable callable): on
    preemption or near the time limit submitit calls checkpoint(), which makes the script
    checkpoint and exit, and requeues the job, which then resumes the run."""

    def __init__(self) -> None:
        self._child: subprocess.Popen | None = None
        self._returncode: int | None = None

    def __getstate__(self) -> dict:
        return {}  # a fresh instance for each job; a process cannot travel

    def __setstate__(self, state: dict) -> None:
        self.__init__()

    def __call__(self, run: Run) -> str:
        if (run.run_dir / "done.json").exists():
            return str(run.run_dir)
        self._child = start_run(run, new_session=False, block_user_signals=True)
        # Poll with os.waitpid, not Popen.wait: checkpoint() runs in a signal handler on this
        # same thread, and Popen.wait holds a lock there that it would wait on forever.
        while self._reap(block=False) is None:
            time.sleep(1.0)
        record_exit(run, self._returncode)
        if self._returncode == 0:
            return str(run.run_dir)
        if self._returncode == EXIT_INTERRUPTED:
            raise RuntimeError(f"{run.name} was interrupted: rerun the sweep to resume it")
        tail = "\n".join(log_tail(run.run_dir))
        raise RuntimeError(f"{run.name} failed (exit code {self._returncode}):\n{tail}")

    def checkpoint(self, run: Run) -> submitit.helpers.DelayedSubmission:
        if self._child is not None and self._returncode is None:
            self._child.send_signal(signal.SIGTERM)
            self._reap(block=True)
            record_exit(run, self._returncode)
        return submitit.helpers.DelayedSubmission(SlurmRun(), run)

    def _reap(self, block: bool) -> int | None:
        if self._returncode is None:
            try:
                pid, status = os.waitpid(self._child.pid, 0 if block else os.WNOHANG)
            except ChildProcessError:  # reaped by the frame this signal handler interrupted
                return EXIT_INTERRUPTED
            if pid:
                self._returncode = os.waitstatus_to_exitcode(status)
                self._child.returncode = self._returncode
        return self._returncode
