"""The gymnasium environment every task shares: the H1Hand robot plus one task's objects,
stepped as HumanoidBench steps it (10 x 2 ms per action), with guards it lacks.

A `Task` (one module per task under `humanoid_envs/tasks/`) says what the scene adds to the
robot and how an episode starts, is observed, rewarded and ends; `H1HandEnv` owns everything
else: compiling the scene, the action -> control map, the physics loop, physics blow-ups and
rendering.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces

from humanoid_envs.robot import ACTUATOR_NAMES, KEYFRAME_QPOS, N_SUBSTEPS, H1Hand, robot_spec

# HumanoidBench's reset noise on qpos (its env.py's DEFAULT_RANDOMNESS): the half-width of a
# uniform draw added to every entry, quaternions included (MuJoCo normalises them).
HUMANOIDBENCH_QPOS_NOISE = 0.01

# MuJoCo's default contact parameters, which every HumanoidBench task object uses; set
# explicitly so the robot's default classes can never leak into the objects.
_OBJECT_CONTACT = {
    "condim": 3,
    "friction": [1.0, 0.005, 0.0001],
    "solref": [0.02, 1.0],
    "solimp": [0.9, 0.95, 0.001, 0.5, 2.0],
}


class Task:
    """One task on the H1Hand robot (dm_control's Task, bound to one compiled scene).

    Subclasses set the class attributes and override what differs from these defaults: no
    objects, observation = qpos and qvel of the whole scene.
    """

    episode_steps: int = 1000
    """Episode length in env steps (the TimeLimit used at registration)."""
    success_bar: float = math.inf
    """HumanoidBench's success bar: an episode return above it counts as solving the task."""
    camera: str = ""
    """Name of the camera (added in `add_objects`) that `render()` shows."""
    object_qpos: tuple[float, ...] = ()
    """qpos of the task's free objects in the keyframe, appended to the robot's."""
    qpos_noise: float = 0.0
    """Half-width of the uniform noise added to every qpos entry at reset, before
    `initialize_episode` (HumanoidBench's order). HumanoidBench uses 0.01 on every task but
    bookshelf, cube and kitchen, where it sets 0; `reset(options={"qpos_noise": x})` overrides
    it for one episode (evaluation from distinct starts)."""

    def add_objects(self, spec: mujoco.MjSpec) -> None:
        """Add the task's bodies, sites and camera to the robot's spec (before compiling)."""

    def bind(self, model: mujoco.MjModel, data: mujoco.MjData, robot: H1Hand) -> None:
        """Keep the compiled scene and cache the addresses the per-step code reads."""
        self.model, self.data, self.robot = model, data, robot

    def initialize_episode(self, np_random: np.random.Generator) -> None:
        """Randomise the start state; `data` holds the keyframe when this is called."""

    def episode_state(self) -> tuple[np.ndarray, ...]:
        """What the episode's future depends on beyond MuJoCo's integration state: whatever
        `initialize_episode` drew into the task or the model (a goal, an object order)."""
        return ()

    def get_observation(self) -> np.ndarray:
        return np.concatenate((self.data.qpos, self.data.qvel))

    def get_reward(self) -> tuple[float, dict[str, Any]]:
        """The reward and every term of it (goes into `info`); called once per env step."""
        raise NotImplementedError

    def termination(self) -> str:
        """Why the episode ends now ("fell", "dropped", "success"), or "" if it goes on."""
        raise NotImplementedError


def add_look_at_camera(
    spec: mujoco.MjSpec, name: str, pos: tuple[float, float, float], target: tuple[float, ...]
) -> None:
    """A fixed world camera at `pos` looking at `target`, with the world's z axis up."""
    forward = np.subtract(target, pos) / np.linalg.norm(np.subtract(target, pos))
    right = np.cross(forward, (0.0, 0.0, 1.0))
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    camera = spec.worldbody.add_camera(name=name, pos=list(pos))
    camera.alt.type = mujoco.mjtOrientation.mjORIENTATION_XYAXES
    camera.alt.xyaxes = [*right, *up]


def add_free_object(
    spec: mujoco.MjSpec,
    name: str,
    pos: tuple[float, ...],
    quat: tuple[float, ...],
    mass: float,
    inertia: tuple[float, ...],
    ipos: tuple[float, ...] = (0.0, 0.0, 0.0),
    iquat: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0),
) -> mujoco.MjsBody:
    """A free-floating body with HumanoidBench's mass and inertia (not derived from geoms)."""
    body = spec.worldbody.add_body(
        name=name,
        pos=list(pos),
        quat=list(quat),
        mass=mass,
        inertia=list(inertia),
        ipos=list(ipos),
        iquat=list(iquat),
        explicitinertial=True,
    )
    body.add_freejoint(name=f"free_{name}")
    return body


def add_solid(
    body: mujoco.MjsBody,
    geom_type: mujoco.mjtGeom,
    size: tuple[float, ...],
    pos: tuple[float, ...] = (0.0, 0.0, 0.0),
    quat: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0),
    rgba: tuple[float, ...] = (0.5, 0.5, 0.5, 1.0),
) -> None:
    """A geom that both collides (with the robot, the floor and other objects) and renders."""
    body.add_geom(
        type=geom_type,
        size=[*size, *[0.0] * (3 - len(size))],
        pos=list(pos),
        quat=list(quat),
        rgba=list(rgba),
        contype=1,
        conaffinity=1,
        group=0,
        **_OBJECT_CONTACT,
    )


class H1HandEnv(gym.Env):
    """The H1Hand robot doing one `Task`: Box(-1, 1, (61,)) actions in ACTUATOR_NAMES order,
    float64 observations, 50 Hz control.

    Beyond HumanoidBench: all randomness comes from `self.np_random`, and only at reset (a step
    is a function of the state and the action); a bad action raises ValueError; a physics
    blow-up truncates the episode with `info["physics_unstable"]`; a terminated episode says why
    in `info["termination"]`.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(
        self, task: Task, render_mode: str | None = None, width: int = 640, height: int = 480
    ) -> None:
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(
                f"render_mode must be None or one of {self.metadata['render_modes']}, "
                f"got {render_mode!r}"
            )
        self.task = task
        self.render_mode = render_mode
        self.success_bar = task.success_bar
        self.model = self._compile_scene(task, width, height)
        self.data = mujoco.MjData(self.model)
        self.robot = H1Hand(self.model, self.data)
        self._warning_counts = self.data.warning.number  # a view: MuJoCo updates it in place
        task.bind(self.model, self.data, self.robot)

        self._action_shape = (len(ACTUATOR_NAMES),)
        self.action_space = spaces.Box(-1.0, 1.0, self._action_shape, dtype=np.float32)
        self._reset_to_keyframe()
        obs_dim = task.get_observation().shape[0]
        self.observation_space = spaces.Box(-np.inf, np.inf, (obs_dim,), dtype=np.float64)
        self._last_obs = np.zeros(obs_dim)
        self._renderer: mujoco.Renderer | None = None
        self._render_size = (height, width)

    @staticmethod
    def _compile_scene(task: Task, width: int, height: int) -> mujoco.MjModel:
        spec = robot_spec()
        task.add_objects(spec)
        spec.add_key(name="home", qpos=[*KEYFRAME_QPOS, *task.object_qpos])
        spec.visual.global_.offwidth = max(width, spec.visual.global_.offwidth)
        spec.visual.global_.offheight = max(height, spec.visual.global_.offheight)
        return spec.compile()

    def _reset_to_keyframe(self) -> None:
        mujoco.mj_resetDataKeyframe(self.model, self.data, 0)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self._reset_to_keyframe()
        noise = self._qpos_noise(options)
        if noise > 0:  # no draw at all without noise: the task's random stream is unchanged
            self.data.qpos += self.np_random.uniform(-noise, noise, self.model.nq)
        self.task.initialize_episode(self.np_random)
        mujoco.mj_forward(self.model, self.data)
        self._last_obs = self.task.get_observation()
        return self._last_obs, {}

    def _qpos_noise(self, options: dict[str, Any] | None) -> float:
        """The reset noise of this episode: options["qpos_noise"] if given, else the task's."""
        unknown = set(options or {}) - {"qpos_noise"}
        if unknown:
            raise ValueError(f"unknown reset options {sorted(unknown)}; the only one is "
                             "'qpos_noise' (half-width of the uniform noise on qpos)")
        noise = (options or {}).get("qpos_noise", self.task.qpos_noise)
        if not (isinstance(noise, int | float) and math.isfinite(noise) and noise >= 0):
            raise ValueError(f"reset option qpos_noise must be a finite number >= 0 (0: the "
                             f"keyframe exactly; HumanoidBench's noise is 0.01), got {noise!r}")
        return float(noise)

    def start_state(self) -> bytes:
        """The state after `reset`, as bytes: MuJoCo's whole integration state plus the task's
        episode state. Steps draw no randomness, so two episodes with equal start states given
        equal actions are one episode (sac_utils/eval_rounds.py steps it once)."""
        what = mujoco.mjtState.mjSTATE_INTEGRATION
        state = np.empty(mujoco.mj_stateSize(self.model, what))
        mujoco.mj_getState(self.model, self.data, state, what)
        return b"".join(np.asarray(part).tobytes() for part in (state, *self.task.episode_state()))

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        self.data.ctrl[:] = self.robot.action_to_ctrl(self._checked_action(action))
        mujoco.mj_step(self.model, self.data, nstep=N_SUBSTEPS)
        reason = self._instability()
        if reason:
            return self._truncate_unstable(reason)
        # HumanoidBench's order: the observation, then the reward (which may change the task's
        # state, e.g. advance bookshelf's current object), then the termination.
        obs = self.task.get_observation()
        reward, info = self.task.get_reward()
        termination = self.task.termination()
        if not np.isfinite(obs).all():
            return self._truncate_unstable("non-finite observation")
        self._last_obs = obs
        if termination:
            info["termination"] = termination
        return obs, reward, bool(termination), False, info

    def _checked_action(self, action: np.ndarray) -> np.ndarray:
        """The action as float64, clipped to [-1, 1]; ValueError for a wrong shape or NaN/inf."""
        try:
            action = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError) as error:
            raise ValueError(
                f"action must be an array of {self._action_shape[0]} numbers in [-1, 1] (one per "
                f"actuator, ACTUATOR_NAMES order); could not convert it: {error}"
            ) from error
        if action.shape != self._action_shape:
            raise ValueError(
                f"action must have shape {self._action_shape} (one value per actuator, "
                f"ACTUATOR_NAMES order), got shape {action.shape}"
            )
        # The sum is the cheap test; it can overflow for huge finite actions, so confirm.
        if not math.isfinite(action.sum()) and not np.isfinite(action).all():
            bad = np.flatnonzero(~np.isfinite(action))
            names = ", ".join(ACTUATOR_NAMES[i] for i in bad[:5])
            raise ValueError(
                f"action has NaN or inf at {len(bad)} entries (first: {names}); "
                "check the policy's output before stepping"
            )
        clipped = np.maximum(action, -1.0)
        return np.minimum(clipped, 1.0, out=clipped)

    def _instability(self) -> str:
        """Why the physics can no longer be trusted, or "" if it can."""
        # Any MuJoCo warning (bad qpos/qvel/qacc, which MuJoCo answers by resetting the state to
        # qpos0; full contact or constraint buffers; bad inertia) leaves the state untrustworthy.
        if not np.count_nonzero(self._warning_counts):
            return ""
        first = mujoco.mjtWarning(int(np.flatnonzero(self._warning_counts)[0]))
        return f"MuJoCo warning {first.name} at t = {self.data.time:.3f} s"

    def _truncate_unstable(self, reason: str) -> tuple[np.ndarray, float, bool, bool, dict]:
        """End the episode without crashing: the last finite observation, reward 0."""
        info = {"physics_unstable": True, "instability_reason": reason}
        return self._last_obs.copy(), 0.0, False, True, info

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array'")
            return None
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.model, *self._render_size)
        self._renderer.update_scene(self.data, camera=self.task.camera)
        return self._renderer.render()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
