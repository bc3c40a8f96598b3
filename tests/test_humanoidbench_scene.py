"""h1hand-<task>-hbscene-v0: our task code on a scene XML read from a HumanoidBench checkout.

No test needs HumanoidBench: a fake checkout holds our own cube scene written out as XML, which
must then behave as our env does; the errors name the fix."""

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import humanoid_envs  # noqa: F401
from humanoid_envs.robot import KEYFRAME_QPOS, robot_spec
from humanoid_envs.tasks.cube import Cube


def fake_checkout(root: Path, xml: str) -> Path:
    envs = root / "humanoid_bench" / "assets" / "envs"
    envs.mkdir(parents=True)
    (envs / "h1hand_pos_cube.xml").write_text(xml)
    return root


def test_our_scene_written_as_xml_behaves_as_our_env(tmp_path):
    spec, task = robot_spec(), Cube()
    task.add_objects(spec)
    spec.add_key(name="home", qpos=[*KEYFRAME_QPOS, *task.object_qpos])
    root = fake_checkout(tmp_path, spec.to_xml())
    ours = gym.make("h1hand-cube-v0")
    theirs = gym.make("h1hand-cube-hbscene-v0", humanoidbench=str(root))
    assert theirs.spec.max_episode_steps == ours.spec.max_episode_steps == 500
    a, _ = ours.reset(seed=3)
    b, _ = theirs.reset(seed=3)
    np.testing.assert_array_equal(a, b)  # the same start: the task's draws, not the model's
    action = np.random.default_rng(0).uniform(-1, 1, 61)
    step_a, step_b = ours.step(action), theirs.step(action)
    # XML keeps floats to a few digits: one step later they agree to ~1e-6, not bit for bit.
    np.testing.assert_allclose(step_a[0], step_b[0], atol=1e-4)
    assert step_a[1] == pytest.approx(step_b[1], abs=1e-6)
    assert step_a[1] != 0.0


def test_errors_name_the_fix(tmp_path, monkeypatch):
    monkeypatch.delenv("HUMANOIDBENCH", raising=False)
    with pytest.raises(ValueError, match="set HUMANOIDBENCH"):
        gym.make("h1hand-cube-hbscene-v0")
    with pytest.raises(ValueError, match="not found: HUMANOIDBENCH must name"):
        gym.make("h1hand-cube-hbscene-v0", humanoidbench=str(tmp_path))
    one_motor = ("<mujoco><worldbody><body><joint name='j'/><geom size='1'/></body></worldbody>"
                 "<actuator><motor joint='j' name='m'/></actuator></mujoco>")
    root = fake_checkout(tmp_path / "other", one_motor)
    with pytest.raises(ValueError, match="not ours in our order"):
        gym.make("h1hand-cube-hbscene-v0", humanoidbench=str(root))
