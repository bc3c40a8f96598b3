"""--track: a run logs to Weights & Biases as CleanRL does. Offline (WANDB_MODE=offline), so CI
needs no account; the offline run files are read back with wandb's own protobuf records."""

import csv
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.test_sac import EAGER, wait_for

ROOT = Path(__file__).resolve().parent.parent
SHORT = ["--env-id", "Pendulum-v1", "--total-timesteps", "3000", "--learning-starts", "200",
         "--eval-interval", "400", "--eval-episodes", "1", "--log-interval", "200",
         "--checkpoint-interval", "200", "--hidden-sizes", "32", "32", "--track",
         "--wandb-project-name", "test-project", "--wandb-group", "Pendulum-v1__corrected"]
OFFLINE = {**os.environ, "WANDB_MODE": "offline", "WANDB_SILENT": "true"}


def history(wandb_file: Path) -> list[dict]:
    """The history rows of an offline run: its .wandb file is a LevelDB-style log (a 7-byte
    header, then 32 KiB blocks of records with a 7-byte header each) of protobuf Records."""
    from wandb.proto import wandb_internal_pb2

    data, rows, pending = wandb_file.read_bytes(), [], b""
    assert data[:4] == b":W&B"
    position = 7
    while position + 7 <= len(data):
        left = 32768 - position % 32768
        if left < 7:  # a block's tail too short for a record header is padding
            position += left
            continue
        header = data[position: position + 7]
        length, kind = int.from_bytes(header[4:6], "little"), header[6]
        pending += data[position + 7: position + 7 + length]
        position += 7 + length
        if kind in (1, 4):  # a full record, or the last piece of one
            record = wandb_internal_pb2.Record()
            record.ParseFromString(pending)
            pending = b""
            if record.HasField("history"):
                rows.append({item.key or "/".join(item.nested_key): json.loads(item.value_json)
                             for item in record.history.item})
    return rows


def offline_runs(run_dir: Path) -> list[Path]:
    return sorted(run_dir.glob("wandb/offline-run-*/run-*.wandb"))


def csv_rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_track_logs_our_scalars_offline_and_a_resume_continues_the_run(tmp_path):
    run_dir = tmp_path / "tracked"
    command = [sys.executable, str(ROOT / "sac_corrected.py"), *SHORT, *EAGER, "--output-dir",
               str(tmp_path), "--run-name", "tracked"]
    process = subprocess.Popen(command, cwd=ROOT, env=OFFLINE, stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL)
    # Stop it once it is learning and has checkpointed, then resume it.
    wait_for(lambda: (run_dir / "train.csv").exists()
             and "\n600," in (run_dir / "train.csv").read_text())
    process.send_signal(signal.SIGTERM)
    assert process.wait() == 3
    resumed = subprocess.run([sys.executable, str(ROOT / "sac_corrected.py"), "--resume",
                              str(run_dir), *EAGER], cwd=ROOT, env=OFFLINE, capture_output=True,
                             text=True)
    assert resumed.returncode == 0, resumed.stderr

    run_id = (run_dir / "wandb_run_id.txt").read_text().strip()
    files = offline_runs(run_dir)
    assert len(files) == 2 and all(f.name == f"run-{run_id}.wandb" for f in files)  # one run id
    first, second = (history(f) for f in files)
    rows = first + second
    # Every train.csv and eval.csv scalar, at its global_step (the resumed session may log the
    # steps after the checkpoint again: W&B keeps what was sent, the CSVs are exact).
    logged = {(row["global_step"], key): value for row in rows for key, value in row.items()}
    for name, group in (("train.csv", "train"), ("eval.csv", "eval")):
        for row in csv_rows(run_dir / name):
            step = int(row["global_step"])
            for key, value in row.items():
                if value and key not in ("global_step", "wall_time"):
                    assert logged[step, f"{group}/{key}"] == pytest.approx(float(value)), key
    assert max(r["global_step"] for r in second) == 3000  # the resumed session logged the rest
    assert min(r["global_step"] for r in second) > min(r["global_step"] for r in first)


def test_wandb_is_imported_only_with_track():
    code = ("import sys, sac_standard; from sac_utils import cli; "
            "cli.check_args(sac_standard.Args(), sac_standard.eval_actions); "
            "print('wandb' in sys.modules)")
    result = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                            text=True)
    assert result.stdout.strip() == "False", result.stderr
