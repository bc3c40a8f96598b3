"""The five h1hand tasks: registration, layouts, rewards by hand, termination, seeding, bad
actions, physics blow-ups, rendering and gymnasium's checker."""

import math
import re
import subprocess
import sys
import warnings

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import humanoid_envs
from humanoid_envs import rewards
from humanoid_envs.robot import ACTUATOR_NAMES

ENV_IDS = list(humanoid_envs.ENVS)
# HumanoidBench's observation sizes: qpos + qvel of the whole scene + task extras.
OBS_DIMS = {
    "h1hand-stand-v0": 151,
    "h1hand-powerlift-v0": 164,
    "h1hand-cube-v0": 181,
    "h1hand-bookshelf_simple-v0": 308,
    "h1hand-bookshelf_hard-v0": 308,
}
EPISODE_STEPS = {
    "h1hand-stand-v0": 1000,
    "h1hand-powerlift-v0": 1000,
    "h1hand-cube-v0": 500,
    "h1hand-bookshelf_simple-v0": 1000,
    "h1hand-bookshelf_hard-v0": 1000,
}


def _actuator_names_from_reference() -> list[str]:
    leg = ["hip_yaw", "hip_roll", "hip_pitch", "knee", "ankle"]
    arm = ["shoulder_pitch", "shoulder_roll", "shoulder_yaw", "elbow", "wrist_yaw"]
    hand = "WRJ2 WRJ1 THJ5 THJ4 THJ3 THJ2 THJ1 FFJ4 FFJ3 FFJ0 MFJ4 MFJ3 MFJ0 RFJ4 RFJ3 RFJ0 "
    hand += "LFJ5 LFJ4 LFJ3 LFJ0"
    return (
        [f"left_{j}" for j in leg]
        + [f"right_{j}" for j in leg]
        + ["torso"]
        + [f"left_{j}" for j in arm]
        + [f"right_{j}" for j in arm]
        + [f"lh_A_{j}" for j in hand.split()]
        + [f"rh_A_{j}" for j in hand.split()]
    )


_ENVS: dict[str, gym.Env] = {}


def make(env_id: str) -> gym.Env:
    """One shared env per id (construction dominates these tests); tests reset it first."""
    if env_id not in _ENVS:
        _ENVS[env_id] = gym.make(env_id)
    return _ENVS[env_id]


def hold_pose_action(env: gym.Env) -> np.ndarray:
    """The action whose servo targets are the current joint (and tendon) positions."""
    model, data = env.unwrapped.model, env.unwrapped.data
    low, high = model.actuator_ctrlrange.T
    return np.clip(2 * (data.actuator_length - low) / (high - low) - 1, -1, 1)


def set_keyframe(env: gym.Env) -> None:
    """Exactly the keyframe (no reset noise), zero velocity and zero control."""
    model, data = env.unwrapped.model, env.unwrapped.data
    mujoco.mj_resetDataKeyframe(model, data, 0)
    mujoco.mj_forward(model, data)


# Tolerance arithmetic written out here, apart from rewards.tolerance.
def gaussian(distance: float, margin: float) -> float:
    return 0.1 ** ((distance / margin) ** 2)  # 0.1 at the margin


def small_control_by_hand(forces: np.ndarray) -> float:
    per_actuator = [max(0.0, 1 - (f / 10) ** 2) for f in forces]
    return (4 + sum(per_actuator) / len(per_actuator)) / 5


def stand_by_hand(robot, height_margin: float, min_upright: float) -> float:
    head, upright = robot.head_height(), robot.torso_upright()
    standing = 1.0 if head >= 1.65 else gaussian(1.65 - head, height_margin)
    upright_term = 1.0 if upright >= min_upright else max(0, 1 - (min_upright - upright) / 1.9)
    return standing * upright_term


def dont_move_by_hand(robot) -> float:
    vx, vy, _ = robot.center_of_mass_velocity()
    return (gaussian(abs(vx), 2) + gaussian(abs(vy), 2)) / 2


def test_import_registers_and_module_prefix_imports() -> None:
    code = (
        "import gymnasium as gym\n"
        "env = gym.make('humanoid_envs:h1hand-cube-v0')\n"
        "print(env.unwrapped.spec.id, env.spec.max_episode_steps)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["h1hand-cube-v0", "500"]
    for env_id in ENV_IDS:
        assert gym.spec(env_id).max_episode_steps == EPISODE_STEPS[env_id]


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_spaces_and_observation_layout(env_id: str) -> None:
    env = make(env_id)
    obs, _ = env.reset(seed=0)
    assert obs.shape == env.observation_space.shape == (OBS_DIMS[env_id],)
    assert obs.dtype == np.float64
    assert env.action_space.shape == (61,)
    assert (env.action_space.low == -1).all() and (env.action_space.high == 1).all()
    model, data = env.unwrapped.model, env.unwrapped.data
    np.testing.assert_array_equal(obs[: model.nq], data.qpos)
    np.testing.assert_array_equal(obs[model.nq : model.nq + model.nv], data.qvel)


def test_action_layout_is_the_reference_actuator_order() -> None:
    model = make("h1hand-powerlift-v0").unwrapped.model
    names = [model.actuator(i).name for i in range(model.nu)]
    assert names == _actuator_names_from_reference()
    assert list(ACTUATOR_NAMES) == names


def test_action_maps_linearly_onto_ctrlrange_and_is_clipped() -> None:
    env = make("h1hand-stand-v0")
    model, data = env.unwrapped.model, env.unwrapped.data
    low, high = model.actuator_ctrlrange.T
    env.reset(seed=0)
    env.step(np.zeros(61))
    np.testing.assert_allclose(data.ctrl, (low + high) / 2)
    env.step(np.full(61, 7.0))  # out of range: clipped to 1
    np.testing.assert_allclose(data.ctrl, high)
    env.step(np.full(61, -1e9))
    np.testing.assert_allclose(data.ctrl, low)


@pytest.mark.parametrize(
    "action, message",
    [
        (np.zeros(60), "shape"),
        (np.zeros((1, 61)), "shape"),
        (np.r_[np.zeros(60), np.nan], "NaN or inf"),
        (np.r_[np.inf, np.zeros(60)], "NaN or inf"),
        (["a"] * 61, "could not convert"),
    ],
)
def test_bad_actions_raise_clear_errors(action, message: str) -> None:
    env = make("h1hand-stand-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=message):
        env.step(action)


def test_powerlift_keyframe_reward_by_hand() -> None:
    env = make("h1hand-powerlift-v0")
    env.reset(seed=0)
    set_keyframe(env)
    task, robot = env.unwrapped.task, env.unwrapped.robot
    reward, info = task.get_reward()
    dumbbell_z = env.unwrapped.data.body("dumbbell").xpos[2]
    assert dumbbell_z == pytest.approx(0.2)
    expected = 0.2 * small_control_by_hand(robot.actuator_forces()) * stand_by_hand(
        robot, 1.65 / 3, 0.8
    ) + 0.8 * gaussian(1.9 - dumbbell_z, 2.0)
    assert reward == pytest.approx(expected, rel=1e-12)
    # The reference's figure: about 0.35 at the keyframe with zero control.
    assert reward == pytest.approx(0.35, abs=0.01)
    assert info["stand"] == 1.0


def test_stand_keyframe_reward_by_hand() -> None:
    env = make("h1hand-stand-v0")
    env.reset(seed=0)
    set_keyframe(env)
    robot = env.unwrapped.robot
    reward, _ = env.unwrapped.task.get_reward()
    expected = (
        small_control_by_hand(robot.actuator_forces())
        * stand_by_hand(robot, 1.65 / 4, 0.9)
        * dont_move_by_hand(robot)
    )
    assert reward == pytest.approx(expected, rel=1e-12)
    # At rest the only cost is the leg servos pulling towards ctrl = 0 (6 of 61 saturate).
    assert reward == pytest.approx((4 + 55 / 61) / 5, abs=1e-6)


def test_cube_keyframe_reward_by_hand() -> None:
    env = make("h1hand-cube-v0")
    env.reset(seed=0)
    model, data = env.unwrapped.model, env.unwrapped.data
    model.body_quat[model.body("target_cube").id] = [0.0, 1.0, 0.0, 0.0]  # half turn about x
    set_keyframe(env)  # cubes upright: |q_cube - q_target| = sqrt(2)
    robot = env.unwrapped.robot
    reward, info = env.unwrapped.task.get_reward()
    orient = gaussian(math.sqrt(2), 0.3)
    close = 0.0
    for hand, cube in (
        (robot.left_hand_position(), "left_cube_to_rotate"),
        (robot.right_hand_position(), "right_cube_to_rotate"),
    ):
        distance = np.linalg.norm(hand - data.body(cube).xpos)
        close += (1.0 if distance <= 0.1 else gaussian(distance - 0.1, 0.5)) / 2
    expected = (
        0.2
        * small_control_by_hand(robot.actuator_forces())
        * stand_by_hand(robot, 1.65 / 4, 0.9)
        * dont_move_by_hand(robot)
        + 0.5 * orient
        + 0.3 * close
    )
    assert reward == pytest.approx(expected, rel=1e-12)
    assert info["close"] == pytest.approx(close) and 0.0 < close < 1.0


@pytest.mark.parametrize("env_id", ["h1hand-bookshelf_simple-v0", "h1hand-bookshelf_hard-v0"])
def test_bookshelf_keyframe_reward_by_hand(env_id: str) -> None:
    env = make(env_id)
    env.reset(seed=0)
    set_keyframe(env)
    task, robot, data = env.unwrapped.task, env.unwrapped.robot, env.unwrapped.data
    obj = data.body(task.current_object()).xpos.copy()
    goal = task._goals[0]
    distance = np.linalg.norm(obj - goal)
    placed = 1.0 if distance <= 0.15 else max(0.0, 1 - (distance - 0.15) * 0.9)
    reach = math.exp(
        -min(
            np.linalg.norm(robot.left_hand_position() - obj),
            np.linalg.norm(robot.right_hand_position() - obj),
        )
    )
    expected = (
        0.2 * stand_by_hand(robot, 1.65 / 4, 0.9) * small_control_by_hand(robot.actuator_forces())
        + 0.4 * placed
        + 0.4 * reach
    )
    reward, info = task.get_reward()
    assert reward == pytest.approx(expected, rel=1e-12)
    assert info["placement_bonus"] == 0.0 and info["success_subtasks"] == 0


# The reward recomposed from the terms in info, per task.
REWARD_FROM_INFO = {
    "h1hand-stand-v0": lambda i: i["small_control"] * i["stand"] * i["dont_move"],
    "h1hand-powerlift-v0": lambda i: 0.2 * i["small_control"] * i["stand"] + 0.8 * i["lifted"],
    "h1hand-cube-v0": lambda i: (
        0.2 * i["small_control"] * i["stand"] * i["dont_move"]
        + 0.5 * i["orient"]
        + 0.3 * i["close"]
    ),
    "h1hand-bookshelf_simple-v0": lambda i: (
        0.2 * i["stand"] * i["small_control"]
        + 0.4 * i["placed"]
        + 0.4 * i["reach"]
        + i["placement_bonus"]
    ),  # fmt: skip
}
REWARD_FROM_INFO["h1hand-bookshelf_hard-v0"] = REWARD_FROM_INFO["h1hand-bookshelf_simple-v0"]


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_info_carries_every_reward_term(env_id: str) -> None:
    env = make(env_id)
    env.reset(seed=1)
    rng = np.random.default_rng(0)
    for _ in range(3):
        _, reward, _, _, info = env.step(rng.uniform(-1, 1, 61))
        assert reward == pytest.approx(REWARD_FROM_INFO[env_id](info), rel=1e-12)
        bounded = {
            k: v for k, v in info.items() if k not in ("placement_bonus", "success_subtasks")
        }
        assert all(0.0 <= v <= 1.0 for v in bounded.values()), bounded


LYING = [math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0]  # pitched 90 degrees


@pytest.mark.parametrize(
    "env_id, fallen, not_yet",
    [
        ("h1hand-stand-v0", 0.1, 0.3),
        ("h1hand-powerlift-v0", 0.1, 0.3),
        ("h1hand-cube-v0", 0.5, 0.65),
    ],
)
def test_falling_terminates(env_id: str, fallen: float, not_yet: float) -> None:
    """The robot lying with its pelvis below the task's bar ends the episode; above, it goes on."""
    env = make(env_id)
    for pelvis_height, ends in ((not_yet, False), (fallen, True)):
        env.reset(seed=0)
        env.unwrapped.data.qpos[2:7] = [pelvis_height, *LYING]
        _, _, terminated, truncated, info = env.step(hold_pose_action(env))
        assert terminated == ends and not truncated and "physics_unstable" not in info
        assert info.get("termination") == ("fell" if ends else None)


def _set_body_height(env: gym.Env, body: str, z: float) -> None:
    model, data = env.unwrapped.model, env.unwrapped.data
    data.qpos[model.jnt_qposadr[model.body(body).jntadr[0]] + 2] = z


def test_dropping_a_cube_terminates() -> None:
    env = make("h1hand-cube-v0")
    env.reset(seed=0)
    _set_body_height(env, "right_cube_to_rotate", 0.3)
    _, _, terminated, _, info = env.step(hold_pose_action(env))
    assert terminated and info["termination"] == "dropped"


def test_dropping_the_current_book_terminates() -> None:
    env = make("h1hand-bookshelf_simple-v0")
    env.reset(seed=0)
    _set_body_height(env, "book_d", 0.3)  # not the current object: goes on
    assert not env.step(hold_pose_action(env))[2]
    _set_body_height(env, "trophy", 0.3)  # the first object of bookshelf_simple
    _, _, terminated, _, info = env.step(hold_pose_action(env))
    assert terminated and info["termination"] == "dropped"


def _place_current_object_at_goal(env: gym.Env) -> None:
    task, model, data = env.unwrapped.task, env.unwrapped.model, env.unwrapped.data
    body = model.body(task.current_object())
    adr = model.jnt_qposadr[body.jntadr[0]]
    data.qpos[adr : adr + 3] = task._goals[task.subtask]
    data.qvel[model.jnt_dofadr[body.jntadr[0]] : model.jnt_dofadr[body.jntadr[0]] + 6] = 0


@pytest.mark.parametrize("observe_goal", [False, True])
def test_bookshelf_subtasks_advance_and_pay_their_bonus(observe_goal: bool) -> None:
    env = gym.make("h1hand-bookshelf_simple-v0", observe_goal=observe_goal)
    obs, _ = env.reset(seed=0)
    task = env.unwrapped.task
    hold = hold_pose_action(env)  # the keyframe's pose
    identifier = -7 if observe_goal else -1  # the observation's entry naming the current object
    assert obs[identifier] == -19  # HumanoidBench's number for the trophy, the first object
    for _ in range(10):
        obs = env.step(hold)[0]
    order, seen = [], [obs[identifier]]
    for k in range(1, 6):
        order.append(task.current_object())
        _place_current_object_at_goal(env)
        obs, reward, terminated, _, info = env.step(hold)
        assert info["placement_bonus"] == 100 * k and info["success_subtasks"] == k
        assert 100 * k < reward <= 100 * k + 1
        # HumanoidBench's one-step lag: the observation was taken before the reward moved on.
        assert obs[identifier] == seen[-1]
        assert terminated == info["success"] == (k == 5)
        assert info.get("termination") == ("success" if k == 5 else None)
        if k < 5:
            obs = env.step(hold)[0]
            seen.append(obs[identifier])
    assert order == ["trophy", "book_c", "chalk", "book_e", "book_b"]
    assert seen == [-19, -22, -15, -20, -23]
    assert obs.shape == ((314,) if observe_goal else (308,))
    env.close()


def test_bookshelf_hard_names_each_drawn_object_with_the_lag() -> None:
    from humanoid_envs.tasks.bookshelf import OBJECT_IDENTIFIERS

    env = make("h1hand-bookshelf_hard-v0")
    obs, _ = env.reset(seed=3)
    task, hold = env.unwrapped.task, hold_pose_action(env)
    for k in range(1, 4):
        current = task.current_object()
        assert obs[-1] == OBJECT_IDENTIFIERS[current] and -24 <= obs[-1] <= -13
        _place_current_object_at_goal(env)
        obs = env.step(hold)[0]
        assert task.subtask == k and task.current_object() != current  # moved on
        assert obs[-1] == OBJECT_IDENTIFIERS[current]  # still the placed one: the lag
        obs = env.step(hold)[0]
        assert obs[-1] == OBJECT_IDENTIFIERS[task.current_object()] != OBJECT_IDENTIFIERS[current]
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_physics_flags_as_humanoidbench(env_id: str) -> None:
    model = make(env_id).unwrapped.model
    assert not model.opt.enableflags & mujoco.mjtEnableBit.mjENBL_SLEEP  # no sleeping bodies
    # multiccd: bookshelf's scene turns it on in HumanoidBench; MuJoCo 4 has it on by default.
    assert not model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_MULTICCD


def test_observe_goal_appends_current_object_and_goal() -> None:
    env = gym.make("h1hand-bookshelf_hard-v0", observe_goal=True)
    obs, _ = env.reset(seed=4)
    task, data = env.unwrapped.task, env.unwrapped.data
    np.testing.assert_allclose(obs[-6:-3], data.body(task.current_object()).xpos)
    np.testing.assert_allclose(obs[-3:], task._goals[0])
    from humanoid_envs.tasks.bookshelf import OBJECT_IDENTIFIERS

    assert obs[-7] == OBJECT_IDENTIFIERS[task.current_object()]
    env.close()


@pytest.mark.parametrize(
    "env_id", ["h1hand-powerlift-v0", "h1hand-cube-v0", "h1hand-bookshelf_hard-v0"]
)
def test_same_seed_same_trajectory(env_id: str) -> None:
    env = make(env_id)
    actions = np.random.default_rng(1).uniform(-1, 1, (15, 61))

    def rollout(seed: int) -> tuple[np.ndarray, list[float]]:
        observations, rewards_ = [env.reset(seed=seed)[0]], []
        for action in actions:
            obs, reward, terminated, truncated, _ = env.step(action)
            observations.append(obs)
            rewards_.append(reward)
            if terminated or truncated:
                break
        return np.array(observations), rewards_

    first, second, other = rollout(7), rollout(7), rollout(8)
    np.testing.assert_array_equal(first[0], second[0])
    assert first[1] == second[1]
    # bookshelf_hard's draw is not observed, only rewarded.
    assert not np.array_equal(first[0][0], other[0][0]) or first[1] != other[1]


def test_bookshelf_hard_draws_objects_and_goals_from_the_seed() -> None:
    env = make("h1hand-bookshelf_hard-v0")
    draws = []
    for seed in (0, 0, 1):
        env.reset(seed=seed)
        task = env.unwrapped.task
        draws.append((tuple(task._order), task._goals.tolist()))
    assert draws[0] == draws[1] and draws[0] != draws[2]
    order, goals = draws[2]
    assert len(set(order)) == 5 and all(0 <= i < 12 for i in order)
    simple_goals = make("h1hand-bookshelf_simple-v0").unwrapped.task._goals.tolist()
    assert sorted(goals) == sorted(simple_goals)


@pytest.mark.parametrize(
    "corrupt, warning",
    [
        (lambda data: data.qvel.__setitem__(slice(None), 1e20), "BADQVEL"),
        (lambda data: data.qpos.__setitem__(7, np.nan), "BADQPOS"),
    ],
)
def test_physics_blow_up_truncates_with_a_finite_observation(
    corrupt, warning: str, tmp_path, monkeypatch
) -> None:
    monkeypatch.chdir(tmp_path)  # MuJoCo logs its warnings to ./MUJOCO_LOG.TXT
    env = make("h1hand-cube-v0")
    env.reset(seed=0)
    before, *_ = env.step(np.zeros(61))
    corrupt(env.unwrapped.data)
    obs, reward, terminated, truncated, info = env.step(np.zeros(61))
    assert truncated and not terminated and reward == 0.0
    assert info["physics_unstable"] and warning in info["instability_reason"]
    assert np.isfinite(obs).all()
    np.testing.assert_array_equal(obs, before)
    obs, _ = env.reset(seed=0)  # reset recovers
    assert np.isfinite(obs).all() and "physics_unstable" not in env.step(np.zeros(61))[4]


def test_rewards_tolerance_matches_reference_sigmoids() -> None:
    tol = rewards.tolerance
    assert tol(0.5, (0, 1)) == 1.0 and tol(1.5, (0, 1)) == 0.0  # margin 0: indicator
    for sigmoid in ("gaussian", "linear", "quadratic"):
        assert tol(3.0, (1, 2), margin=1, sigmoid=sigmoid) == pytest.approx(0.1)
        assert tol(0.0, (1, 2), margin=1, sigmoid=sigmoid) == pytest.approx(0.1)
    assert tol(2.5, margin=5, sigmoid="linear", value_at_margin=0) == pytest.approx(0.5)
    assert tol(2.5, margin=5, sigmoid="quadratic", value_at_margin=0) == pytest.approx(0.75)
    assert tol(10.0, margin=5, sigmoid="linear", value_at_margin=0) == 0.0
    np.testing.assert_allclose(tol(np.array([0.0, 1.0]), margin=1), [1.0, 0.1])
    with pytest.raises(ValueError, match="lower bound"):
        tol(0.0, (1, 0))
    with pytest.raises(ValueError, match="value_at_margin"):
        tol(0.0, margin=1, value_at_margin=0.0)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_render_shows_the_task(env_id: str) -> None:
    env = gym.make(env_id, render_mode="rgb_array", width=160, height=120)
    env.reset(seed=0)
    env.step(np.zeros(61))
    frame = env.render()
    env.close()
    assert frame.shape == (120, 160, 3) and frame.dtype == np.uint8
    assert frame.std() > 10.0
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 50


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_gymnasium_env_checker_passes(env_id: str) -> None:
    env = gym.make(env_id)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        # Unbounded observations are correct here; the checker flags any infinite bound.
        warnings.filterwarnings("ignore", message=".*is probably too (low|high)")
        check_env(env.unwrapped)
    env.close()


def _start_state(env_id: str, seed: int) -> bytes:
    env = gym.make(env_id)
    env.reset(seed=seed)
    return env.unwrapped.start_state()


@pytest.mark.parametrize(
    ("env_id", "same"),
    [
        ("h1hand-bookshelf_simple-v0", True),  # no reset noise
        ("h1hand-bookshelf_hard-v0", False),  # same physics, another object order and goals
        ("h1hand-cube-v0", False),
        ("h1hand-powerlift-v0", False),
    ],
)
def test_start_state_is_equal_exactly_where_resets_draw_nothing(env_id: str, same: bool) -> None:
    assert (_start_state(env_id, 1) == _start_state(env_id, 2)) is same
    assert _start_state(env_id, 3) == _start_state(env_id, 3)


def test_start_state_sees_the_task_state_beyond_physics() -> None:
    env = gym.make("h1hand-bookshelf_hard-v0")
    env.reset(seed=1)
    first = env.unwrapped.start_state()
    env.unwrapped.task.subtask = 1  # physics untouched
    assert env.unwrapped.start_state() != first


def test_reset_option_qpos_noise_sets_the_episodes_reset_noise() -> None:
    env = make("h1hand-bookshelf_simple-v0")
    keyframe = env.unwrapped.model.key_qpos[0]
    starts = [env.reset(seed=s, options={"qpos_noise": 0.01})[0] for s in (1, 2, 1)]
    assert not np.array_equal(starts[0], starts[1]) and np.array_equal(starts[0], starts[2])
    qpos = env.unwrapped.data.qpos
    # Every entry moved, by at most the half-width (the free joints' quaternions renormalised).
    offsets = np.abs(qpos - keyframe)
    assert (offsets > 0).all() and offsets.max() < 0.011
    # Without the option, the task's own: bookshelf none, powerlift HumanoidBench's 0.01.
    assert np.array_equal(env.reset(seed=1)[0], env.reset(seed=2)[0])
    powerlift = make("h1hand-powerlift-v0")
    default = powerlift.reset(seed=3)[0]
    assert np.array_equal(default, powerlift.reset(seed=3, options={"qpos_noise": 0.01})[0])
    powerlift.reset(seed=3, options={"qpos_noise": 0.0})
    assert np.array_equal(powerlift.unwrapped.data.qpos, powerlift.unwrapped.model.key_qpos[0])


@pytest.mark.parametrize(
    ("options", "message"),
    [({"qpos_noise": -0.1}, "qpos_noise must be a finite number >= 0"),
     ({"qpos_noise": float("nan")}, "qpos_noise must be a finite number >= 0"),
     ({"noise": 0.01}, "unknown reset options ['noise']")],
)
def test_bad_reset_options_raise_clear_errors(options: dict, message: str) -> None:
    with pytest.raises(ValueError, match=re.escape(message)):
        make("h1hand-cube-v0").reset(seed=0, options=options)
