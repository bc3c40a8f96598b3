"""bench/bench_presets.py times each preset at the batch size its runs get: the speeds behind
`sweep.py --dry-run --steps-per-second` (docs/sweep.md). No timing is asserted here."""

import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))

import bench_presets  # noqa: E402
import bench_sac  # noqa: E402

from sweep import PRESETS  # noqa: E402


@pytest.mark.parametrize(("preset", "batch"), [("classic", 256), ("paper", 64),
                                               ("dimensions", 64)])
def test_each_preset_is_timed_at_its_runs_batch_size(preset: str, batch: int) -> None:
    assert bench_presets.batch_size(PRESETS[preset]) == batch


def test_the_timed_runs_get_the_batch_size_and_the_cache_is_filled_first(monkeypatch) -> None:
    """Every sac_standard.py run it times gets --batch-size, and an untimed run comes first, so
    that neither timed run pays for compiling alone."""
    commands = []
    monkeypatch.setattr(subprocess, "run", lambda argv, **_: commands.append(argv))
    bench_sac.loop_seconds_per_step(bench_sac.Args(env_id="Hopper-v5", batch_size=256,
                                                   loop_steps=10, repeats=2))
    steps = [int(argv[argv.index("--total-timesteps") + 1]) for argv in commands]
    assert steps == [1001, 1010, 1001]  # untimed, then the long and the short one timed
    assert all(argv[argv.index("--batch-size") + 1] == "256" for argv in commands)
