"""bookshelf: move five objects, one after the other, to goal spots on a shelf.

simple: always the trophy, book_c, chalk, book_e, book_b, to the goals in order; hard: five of
the twelve objects drawn without replacement, and the goals permuted, every episode.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import mujoco
import numpy as np

from humanoid_envs import rewards
from humanoid_envs.base import H1HandEnv, Task, add_free_object, add_look_at_camera, add_solid

# An object is placed when its origin is this close (m) to its goal; the next one is then due.
_PLACED_DISTANCE = 0.15
# Episode ends when the pelvis or the current object drops below these heights (m).
_FALLEN_PELVIS_HEIGHT = 0.58
_DROPPED_OBJECT_HEIGHT = 0.5
# Placing the k-th object (k = 1..5) pays this times k once.
_PLACEMENT_BONUS = 100.0

# Goal positions of the object origins, in task order.
_GOALS = np.array(
    [(0.75, -0.25, 1.55), (0.8, 0.05, 0.95), (0.8, -0.25, 0.95), (0.85, 0.05, 0.35),
     (0.85, -0.25, 0.35)]
)  # fmt: skip
_SIMPLE_ORDER = ("trophy", "book_c", "chalk", "book_e", "book_b")

# The shelf (static, origin on the floor at x = 0.95): six boards with tops at 0.05, 0.35, ...,
# 1.55 m, a top board, two sides and a back, as (half-size, position in the shelf frame).
_SHELF_POS = (0.95, 0.0, 0.0)
_SHELF_BOXES = (
    *(((0.3, 0.4, 0.025), (0.0, 0.0, 0.025 + 0.3 * board)) for board in range(6)),
    ((0.325, 0.45, 0.025), (0.025, 0.0, 1.825)),
    ((0.325, 0.025, 0.9), (0.025, 0.425, 0.9)),
    ((0.325, 0.025, 0.9), (0.025, -0.425, 0.9)),
    ((0.025, 0.4, 0.9), (0.325, 0.0, 0.9)),
)

_BOX, _CYLINDER, _SPHERE = (
    mujoco.mjtGeom.mjGEOM_BOX, mujoco.mjtGeom.mjGEOM_CYLINDER, mujoco.mjtGeom.mjGEOM_SPHERE
)  # fmt: skip
_IDENTITY = (1.0, 0.0, 0.0, 0.0)


class _Object(NamedTuple):
    """A free object: keyframe pose, HumanoidBench's inertia, and its collision primitives as
    (geom type, size, pos, quat); books were meshes drawn around these boxes."""

    name: str
    pos: tuple[float, ...]
    quat: tuple[float, ...]
    mass: float
    inertia: tuple[float, ...]
    ipos: tuple[float, ...]
    iquat: tuple[float, ...]
    rgba: tuple[float, ...]
    solids: tuple[tuple[Any, ...], ...]


_BOOK_INERTIA = {
    "mass": 2.26603,
    "inertia": (0.0143348, 0.0097093, 0.0055504),
    "ipos": (0.00088, 0.00239, 0.1151),
    "iquat": (0.70854, -0.00315, -0.00348, 0.70565),
}
_BOOK = ((_BOX, (0.082, 0.025, 0.115), (0.0025, 0.0, 0.115), _IDENTITY),)
_GREY, _PINK = (0.59, 0.61, 0.62, 1.0), (1.0, 0.8, 0.8, 1.0)

_OBJECTS = (
    # Five books and the trophy stand on the 1.25 m board, the flat book lies beside them.
    _Object("book_a", (0.95, -0.36, 1.25), _IDENTITY, **_BOOK_INERTIA, rgba=_GREY, solids=_BOOK),
    _Object("book_b", (0.95, -0.3, 1.25), _IDENTITY, **_BOOK_INERTIA, rgba=_GREY, solids=_BOOK),
    _Object("book_c", (0.95, -0.24, 1.25), _IDENTITY, **_BOOK_INERTIA, rgba=_GREY, solids=_BOOK),
    _Object("book_d", (0.95, -0.18, 1.25), _IDENTITY, **_BOOK_INERTIA, rgba=_GREY, solids=_BOOK),
    _Object("book_e", (0.95, -0.12, 1.25), _IDENTITY, **_BOOK_INERTIA, rgba=_PINK, solids=_BOOK),
    _Object(
        "trophy", (0.95, 0.02, 1.25), _IDENTITY,
        mass=1.51477, inertia=(0.0104893, 0.0104893, 0.0049231), ipos=(0.0, 0.0, 0.06286),
        iquat=_IDENTITY, rgba=_GREY,
        solids=(
            (_CYLINDER, (0.1, 0.015), (0.0, 0.0, 0.015), _IDENTITY),
            (_CYLINDER, (0.025, 0.1), (0.0, 0.0, 0.115), _IDENTITY),
            (_SPHERE, (0.035,), (0.0, 0.0, 0.2), _IDENTITY),
        ),
    ),
    _Object(
        "book_flat", (0.95, 0.12, 1.255), (0.70739, -0.70683, 0.0, 0.0),
        **{**_BOOK_INERTIA, "ipos": (0.00088, -0.02261, 0.1151)}, rgba=(0.5, 0.5, 0.5, 1.0),
        solids=((_BOX, (0.082, 0.028, 0.115), (0.0, -0.022, 0.115), _IDENTITY),),
    ),
    # Soda can, thick book, chalk and snow globe on the 0.65 m board.
    _Object(
        "soda_can", (0.95, -0.3, 0.65), _IDENTITY,
        mass=1.5708, inertia=(0.0062177, 0.0062177, 0.0019635), ipos=(0.0, 0.0, 0.1),
        iquat=_IDENTITY, rgba=_GREY, solids=((_CYLINDER, (0.05, 0.1), (0.0, 0.0, 0.1), _IDENTITY),),
    ),
    _Object(
        "book_thick", (0.95, -0.13, 0.65), _IDENTITY,
        mass=3.77404, inertia=(0.0238813, 0.0175445, 0.0106166), ipos=(0.00089, 0.0041, 0.11509),
        iquat=(0.71003, -0.00301, -0.00362, 0.70415), rgba=(0.9, 0.2, 0.2, 1.0),
        solids=((_BOX, (0.082, 0.0415, 0.115), (0.0025, 0.003, 0.115), _IDENTITY),),
    ),
    _Object(
        "chalk", (0.95, 0.0, 0.65), _IDENTITY,
        mass=0.04398, inertia=(7.29e-05, 7.29e-05, 2.2e-06), ipos=(0.0, 0.0, 0.01),
        iquat=(0.70711, -0.5, 0.5, 0.0), rgba=(0.5, 0.0, 0.0, 1.0),
        solids=((_CYLINDER, (0.01, 0.07), (0.0, 0.0, 0.01), (0.70711, -0.5, 0.5, 0.0)),),
    ),
    _Object(
        "snow_globe", (0.95, 0.2, 0.65), _IDENTITY,
        mass=5.13127, inertia=(0.0248723, 0.0248723, 0.0214675), ipos=(0.0, 0.0, 0.0852),
        iquat=_IDENTITY, rgba=_GREY,
        solids=(
            (_CYLINDER, (0.1, 0.015), (0.0, 0.0, 0.015), _IDENTITY),
            (_SPHERE, (0.1,), (0.0, 0.0, 0.101), _IDENTITY),
        ),
    ),
    # Headphones, tilted, on the top board (1.55 m).
    _Object(
        "headphone", (0.85, 0.0, 1.58), (0.86893, -0.06693, 0.12251, 0.47484),
        mass=2.90662, inertia=(0.031497, 0.0207951, 0.0173748), ipos=(0.13963, 0.0, 0.08),
        iquat=(0.0, 0.70711, 0.0, 0.70711), rgba=(0.25, 0.0, 0.0, 1.0),
        solids=(
            (_CYLINDER, (0.08, 0.025), (0.1, -0.07, 0.08), (0.70711, -0.70711, 0.0, 0.0)),
            (_CYLINDER, (0.08, 0.025), (0.1, 0.07, 0.08), (0.70711, -0.70711, 0.0, 0.0)),
            (_BOX, (0.1, 0.02, 0.02), (0.2, -0.07, 0.08), _IDENTITY),
            (_BOX, (0.1, 0.02, 0.02), (0.2, 0.07, 0.08), _IDENTITY),
            (_BOX, (0.02, 0.08, 0.02), (0.3, 0.0, 0.08), _IDENTITY),
        ),
    ),
)  # fmt: skip
_OBJECT_NAMES = tuple(obj.name for obj in _OBJECTS)
# The observation's last entry names the current object as HumanoidBench does: the index of its
# body counted from the end of HumanoidBench's scene body list (Python negative indexing into
# data.xpos). A fixed table, whatever our own body order: book_a -24, book_b -23, book_c -22,
# book_d -21, book_e -20, trophy -19, book_flat -18, soda_can -17, book_thick -16, chalk -15,
# snow_globe -14, headphone -13 (simple's order trophy, book_c, chalk, book_e, book_b is
# -19, -22, -15, -20, -23).
OBJECT_IDENTIFIERS = dict(zip(_OBJECT_NAMES, range(-24, -12), strict=True))


class Bookshelf(Task):
    """reward = 0.2 * stand(1.65/4, 0.9) * small_control + 0.4 * placed + 0.4 * reach, plus
    100 * k when the k-th object gets within 0.15 m of its goal.

    placed: linear tolerance of the object-goal distance beyond 0.15 m (0.1 at 1 m more);
    reach: exp(-distance from the nearer hand site to the object). Observation (HumanoidBench's):
    qpos, qvel and the current object's identifier (OBJECT_IDENTIFIERS), taken before the reward
    that may advance to the next object, so it names the next object one step after a
    placement; with `observe_goal` (our extra) also the current object's position and its goal.
    """

    episode_steps = 1000
    success_bar = 2000.0
    camera = "bookshelf_view"
    object_qpos = tuple(x for obj in _OBJECTS for x in (*obj.pos, *obj.quat))

    def __init__(self, randomize_order: bool, observe_goal: bool = False) -> None:
        self.randomize_order = randomize_order
        self.observe_goal = observe_goal
        self.subtask = 0
        self._order = np.array([_OBJECT_NAMES.index(name) for name in _SIMPLE_ORDER])
        self._goals = _GOALS.copy()

    def add_objects(self, spec: mujoco.MjSpec) -> None:
        shelf = spec.worldbody.add_body(name="shelf", pos=list(_SHELF_POS))
        for half_size, pos in _SHELF_BOXES:
            add_solid(shelf, _BOX, half_size, pos, rgba=(0.55, 0.4, 0.25, 1.0))
        for obj in _OBJECTS:
            body = add_free_object(
                spec, obj.name, obj.pos, obj.quat, obj.mass, obj.inertia, obj.ipos, obj.iquat
            )
            for geom_type, size, pos, quat in obj.solids:
                add_solid(body, geom_type, size, pos, quat, obj.rgba)
        # Marks the current goal; sites never collide.
        spec.worldbody.add_site(
            name="goal", pos=list(_GOALS[0]), size=[0.03, 0, 0], rgba=[0.1, 0.9, 0.2, 0.7]
        )
        # Over the robot's right shoulder, into the open face of the shelf.
        add_look_at_camera(spec, self.camera, pos=(-1.3, -1.3, 2.3), target=(0.85, 0.0, 0.9))
        # Physics flags as HumanoidBench's: multi-point convex collisions (multiccd) on, which
        # is MuJoCo 4's default; no sleeping of bodies at rest (its MuJoCo has none).

    def bind(self, model, data, robot) -> None:
        super().bind(model, data, robot)
        self._object_ids = np.array([model.body(name).id for name in _OBJECT_NAMES])
        self._goal_site = model.site("goal").id

    def initialize_episode(self, np_random: np.random.Generator) -> None:
        if self.randomize_order:
            self._order = np_random.choice(len(_OBJECTS), size=len(_GOALS), replace=False)
            self._goals = _GOALS[np_random.permutation(len(_GOALS))]
        self.subtask = 0
        self.model.site_pos[self._goal_site] = self._goals[0]

    def episode_state(self) -> tuple[np.ndarray, ...]:
        return (np.array(self.subtask), self._order, self._goals)

    def current_object(self) -> str:
        return _OBJECT_NAMES[self._order[min(self.subtask, len(_GOALS) - 1)]]

    def _object_and_goal(self) -> tuple[np.ndarray, np.ndarray]:
        """Position of the current object's origin and its goal (the last ones once all five
        are placed)."""
        k = min(self.subtask, len(_GOALS) - 1)
        return self.data.xpos[self._object_ids[self._order[k]]], self._goals[k]

    def get_observation(self) -> np.ndarray:
        parts = [self.data.qpos, self.data.qvel, [float(OBJECT_IDENTIFIERS[self.current_object()])]]
        if self.observe_goal:
            parts.extend(self._object_and_goal())
        return np.concatenate(parts)

    def get_reward(self) -> tuple[float, dict[str, Any]]:
        """The reward at this state; advances to the next object when this one is placed."""
        robot = self.robot
        obj, goal = self._object_and_goal()
        stand = rewards.stand(
            robot.head_height(), robot.torso_upright(), rewards.STAND_HEIGHT / 4, 0.9
        )
        small_control = rewards.small_control(robot.actuator_forces())
        distance = math.dist(obj, goal)
        placed = rewards.tolerance(distance, (0, _PLACED_DISTANCE), margin=1, sigmoid="linear")
        hand_distance = min(
            math.dist(robot.left_hand_position(), obj), math.dist(robot.right_hand_position(), obj)
        )
        reach = math.exp(-hand_distance)
        reward = 0.2 * stand * small_control + 0.4 * placed + 0.4 * reach
        bonus = 0.0
        if distance < _PLACED_DISTANCE:
            self.subtask += 1
            bonus = _PLACEMENT_BONUS * self.subtask
            if self.subtask < len(_GOALS):
                self.model.site_pos[self._goal_site] = self._goals[self.subtask]
        return reward + bonus, {
            "stand": stand,
            "small_control": small_control,
            "placed": placed,
            "reach": reach,
            "placement_bonus": bonus,
            "success_subtasks": self.subtask,
            "success": self.subtask == len(_GOALS),
        }

    def termination(self) -> str:
        obj, _ = self._object_and_goal()
        if self.robot.pelvis_height() < _FALLEN_PELVIS_HEIGHT:
            return "fell"
        if self.subtask == len(_GOALS):
            return "success"
        return "dropped" if obj[2] < _DROPPED_OBJECT_HEIGHT else ""


def make_simple_env(observe_goal: bool = False, **kwargs: Any) -> H1HandEnv:
    """gymnasium entry point of `h1hand-bookshelf_simple-v0` (kwargs: observe_goal,
    render_mode, width, height)."""
    return H1HandEnv(Bookshelf(randomize_order=False, observe_goal=observe_goal), **kwargs)


def make_hard_env(observe_goal: bool = False, **kwargs: Any) -> H1HandEnv:
    """gymnasium entry point of `h1hand-bookshelf_hard-v0` (kwargs as the simple variant)."""
    return H1HandEnv(Bookshelf(randomize_order=True, observe_goal=observe_goal), **kwargs)
