"""`pip install .` and `pip install -e .` make humanoid_envs and mode_search importable from
anywhere, with the tasks reachable the gymnasium way ("humanoid_envs:<id>").

Each test installs into a fresh venv that sees this interpreter's site-packages through a .pth
file, so torch and mujoco are not downloaded again, and builds with --no-build-isolation
--no-index so that nothing is fetched: CI stays offline-safe and fast.
"""

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import tomllib
import venv
import zipfile
from pathlib import Path

import pytest
from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parent.parent
TASK_IDS = [
    "h1hand-stand-v0",
    "h1hand-powerlift-v0",
    "h1hand-cube-v0",
    "h1hand-bookshelf_simple-v0",
    "h1hand-bookshelf_hard-v0",
]
# What the install must not need from a checkout: caches, runs, build leftovers, git.
COPY_IGNORE = shutil.ignore_patterns(
    ".git",
    ".venv",
    ".venv-peers",
    "runs",
    "report",
    "figures",
    "build",
    "dist",
    "*.egg-info",
    "__pycache__",
    ".pytest_cache",
    ".ruff_cache",
)

# Runs in the fresh venv from a folder outside the repository: makes every task the gymnasium
# way (no import of humanoid_envs first), steps it, calls the mode, and reports where the
# modules came from.
CHECK = """
import json, sys
import gymnasium as gym
import numpy as np
import torch

ids = json.loads(sys.argv[1])
for env_id in ids:
    env = gym.make(f"humanoid_envs:{env_id}")
    obs, _ = env.reset(seed=0)
    env.action_space.seed(0)
    for _ in range(3):
        obs, reward, terminated, truncated, _ = env.step(env.action_space.sample())
    assert np.all(np.isfinite(obs)) and np.isfinite(reward), env_id
    env.close()

import humanoid_envs
import mode_search
from mode_search import mode_action

mode = mode_action(torch.tensor([0.5, -2.0]), torch.tensor([-1.0, 0.0]))
assert mode.shape == (2,) and bool(torch.all(mode.abs() < 1)), mode
print(json.dumps({
    "humanoid_envs": humanoid_envs.__file__,
    "mode_search": mode_search.__file__,
    "registered": sorted(humanoid_envs.ENVS),
}))
"""


def make_venv(path: Path) -> Path:
    """A venv without pip of its own that sees this interpreter's packages after its own."""
    venv.create(path, with_pip=False, symlinks=True)
    python = path / "bin" / "python"
    purelib = subprocess.run(
        [python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    host_paths = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (Path(purelib) / "host_site_packages.pth").write_text("\n".join(sorted(host_paths)) + "\n")
    return python


def clean_env() -> dict[str, str]:
    # PYTHONPATH could smuggle the checkout back in and hide a broken install.
    return {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}


def pip_install(python: Path, *args: str) -> None:
    result = subprocess.run(
        [
            python,
            "-m",
            "pip",
            "install",
            "-q",
            "--no-deps",
            "--no-build-isolation",
            "--no-index",
            "--ignore-installed",
            *args,
        ],
        capture_output=True,
        text=True,
        env=clean_env(),
        timeout=300,
    )
    assert result.returncode == 0, result.stdout + result.stderr


def run_check(python: Path, cwd: Path) -> dict:
    result = subprocess.run(
        [python, "-c", CHECK, json.dumps(TASK_IDS)],
        cwd=cwd,
        capture_output=True,
        text=True,
        env=clean_env(),
        timeout=300,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    return json.loads(result.stdout.strip().splitlines()[-1])


@pytest.fixture
def source(tmp_path: Path) -> Path:
    # A copy, so that the in-tree build leaves nothing in the checkout.
    src = tmp_path / "src"
    shutil.copytree(ROOT, src, ignore=COPY_IGNORE)
    return src


@pytest.mark.slow
def test_pip_install_makes_tasks_and_mode_importable_anywhere(tmp_path: Path, source: Path) -> None:
    env_dir = tmp_path / "venv"
    python = make_venv(env_dir)
    pip_install(python, str(source))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    found = run_check(python, elsewhere)
    for module in ("humanoid_envs", "mode_search"):
        assert Path(found[module]).is_relative_to(env_dir), found
    assert found["registered"] == sorted(TASK_IDS)


@pytest.mark.slow
def test_editable_install_points_at_the_source(tmp_path: Path, source: Path) -> None:
    python = make_venv(tmp_path / "venv")
    pip_install(python, "-e", str(source))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    found = run_check(python, elsewhere)
    for module in ("humanoid_envs", "mode_search"):
        assert Path(found[module]).is_relative_to(source), found


def test_the_wheel_holds_the_package_and_no_scripts_or_tests(tmp_path: Path, source: Path) -> None:
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "-q",
            "--no-deps",
            "--no-build-isolation",
            "--no-index",
            "-w",
            str(tmp_path / "wheel"),
            str(source),
        ],
        capture_output=True,
        text=True,
        env=clean_env(),
        timeout=300,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    (wheel,) = (tmp_path / "wheel").glob("*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert "mode_search.py" in names and "humanoid_envs/assets/h1hand.xml" in names
    assert any(n.endswith("licenses/LICENSE") for n in names)
    top = {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")}
    assert top == {"mode_search.py", "humanoid_envs"}, top


def test_requirements_pins_satisfy_the_declared_dependencies() -> None:
    """So that `pip install .` into the pinned environment installs nothing new."""
    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    pins = {}
    for line in (ROOT / "requirements.txt").read_text().splitlines():
        line = line.split("#")[0].strip()
        if line:
            req = Requirement(line)
            (version,) = [spec.version for spec in req.specifier]
            pins[req.name.lower()] = version
    for dependency in map(Requirement, declared):
        assert dependency.name.lower() in pins, f"{dependency.name} is not pinned"
        pinned = pins[dependency.name.lower()]
        assert dependency.specifier.contains(pinned), f"{dependency} excludes the pin {pinned}"
