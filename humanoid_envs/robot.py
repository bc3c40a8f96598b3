"""The h1hand robot: a Unitree H1 body with two Shadow-style hands (61 position servos).

The model lives in `assets/h1hand.xml`. Its kinematic tree, joint axes and ranges, masses and
inertias, joint damping and armature, actuators (kp, kv, ctrlrange, forcerange, gear 1, in
action order), finger tendons (J0 = J1 + J2), contact exclusions, sites, sensors and physics
options (0.002 s, Newton, 100/50 iterations, Euler, pyramidal cone) are HumanoidBench's
h1hand numbers.

How it differs from HumanoidBench's model: collision shapes are primitives instead of 28
collision meshes (we ship no third-party meshes). MuJoCo collides a mesh as its convex hull, so
each primitive was fitted to the convex hull of HumanoidBench's mesh, in the body frame, by
maximising their intersection over union (volumes estimated on 30 000 points; a one-off fit
whose numbers are written into assets/h1hand.xml; the left side fitted, the right side its
mirror image, as the meshes are): one box or capsule per link, two where one shape leaves much
of the hull out or sticks far out of it (torso: trunk box and head-and-chest box; thigh and
shin: capsule plus box). Two constraints on top: each foot is a sole plate, flat at the height
that touches the floor at the keyframe and as long and wide as the hull's cross-section there,
plus an ankle block that never reaches below it; the thigh's hub box is shrunk to 90% of its
fit so that, as the mesh, it clears the hip-yaw cylinder at the keyframe. The hands' own
primitives are kept (the thumb tips, meshes too, are fitted capsules). Nothing is drawn but
these primitives (plus a visor on the head). Robot self-collisions are on, as HumanoidBench's
collision classes have them, minus its four excluded body pairs; so is its friction loss of
0.01 on the 48 hand joints.

Why fitted to the hull and not to the bounding box (this model's previous shapes): with
self-collisions on, bounding-box shapes touch each other where HumanoidBench's meshes do not.
`python bench/bench_contacts.py --humanoidbench PATH` (removed from bench/ since; `git show
feef783:bench/bench_contacts.py`) sets both models to 1500 poses of
HumanoidBench's own model under random controls: robot self-contacts between body links
((pose, body pair) contacts, hand bodies aside) were in both models 227, only the bounding
boxes 1837 (the two hip-roll boxes touching each other in 946 poses, the thighs the hip-yaw
cylinders and the pelvis), only HumanoidBench 0; with the hull fits 179 / 15 / 48. Floor
contacts: 1620 / 191 / 69 before, 1604 / 89 / 85 now. Fall times from the keyframe on 20 fixed
action sequences stay as close to HumanoidBench's as before (mean difference 6.3 env steps, 6.0
before; a chaotic measure).

What fidelity costs, bare physics in env steps per second (`python bench/bench_robot.py`, removed
from bench/ since, `git show 7d129d4:bench/bench_robot.py`: 10 x
mj_step with uniform random ctrl, back to the keyframe when the pelvis drops below 0.2 m; thread
CPU time, median of 5 x 1500 steps on the shared 2-core dev machine, one other process busy),
each task scene built from robot_spec() with HumanoidBench's choices undone:
    scene       this model (HumanoidBench's)  no self-collisions  both off
    stand       1179 (nefc  69)               1577 (nefc  59)     2210 (nefc  10)
    powerlift   1074 (nefc  86)               1396 (nefc  75)     1818 (nefc  26)
    cube        1119 (nefc  85)               1483 (nefc  74)     1989 (nefc  25)
    bookshelf    683 (nefc 263)                804 (nefc 251)      919 (nefc 203)
(nefc: mean number of constraint rows; collision shapes are our primitives in all three.) The
bounding-box shapes ran at 1215, 1116, 1130 and 678 in the first column in the same session:
the hull fits' seven more geoms cost 1-4% on stand, powerlift and cube, nothing measurable on
bookshelf.
MuJoCo's default sparse Jacobian beats a dense one here: 1698 vs 1476 env steps/s on powerlift
(measured with both choices off).
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

ASSET_PATH = Path(__file__).resolve().parent / "assets" / "h1hand.xml"

# Physics steps per environment step: 10 x 0.002 s = 50 Hz control, as in HumanoidBench.
N_SUBSTEPS = 10
# qpos/qvel sizes of the robot alone: free base (7 / 6) + 69 hinges.
NQ_ROBOT = 76
NV_ROBOT = 75

_LEG = ("hip_yaw", "hip_roll", "hip_pitch", "knee", "ankle")
_ARM = ("shoulder_pitch", "shoulder_roll", "shoulder_yaw", "elbow", "wrist_yaw")
# Within a hand: wrist, thumb, then first/middle/ring/little finger. The xxJ0 actuators drive
# the tendon J0 = J1 + J2 that couples a finger's two distal joints.
_HAND = (
    "WRJ2", "WRJ1", "THJ5", "THJ4", "THJ3", "THJ2", "THJ1", "FFJ4", "FFJ3", "FFJ0",
    "MFJ4", "MFJ3", "MFJ0", "RFJ4", "RFJ3", "RFJ0", "LFJ5", "LFJ4", "LFJ3", "LFJ0",
)  # fmt: skip

# Actuator names in action order: action[i] drives ACTUATOR_NAMES[i].
ACTUATOR_NAMES: tuple[str, ...] = (
    *(f"left_{j}" for j in _LEG),
    *(f"right_{j}" for j in _LEG),
    "torso",
    *(f"left_{j}" for j in _ARM),
    *(f"right_{j}" for j in _ARM),
    *(f"lh_A_{j}" for j in _HAND),
    *(f"rh_A_{j}" for j in _HAND),
)

# Standing pose: pelvis 0.98 m above the floor, upright, knees bent, everything else at 0.
_PELVIS_START = (0.0, 0.0, 0.98, 1.0, 0.0, 0.0, 0.0)
_LEG_START = (0.0, 0.0, -0.4, 0.8, -0.4)
KEYFRAME_QPOS: np.ndarray = np.concatenate(
    [_PELVIS_START, _LEG_START, _LEG_START, np.zeros(NQ_ROBOT - 17)]
)
# Position targets (action order) that hold the keyframe's joint angles; note that it is not
# the ctrl of action 0, which is the middle of each ctrlrange.
KEYFRAME_CTRL: np.ndarray = np.concatenate([_LEG_START, _LEG_START, np.zeros(51)])


def robot_spec() -> mujoco.MjSpec:
    """A fresh spec with physics options, floor, lights and the robot; tasks add the rest."""
    return mujoco.MjSpec.from_file(str(ASSET_PATH))


class H1Hand:
    """Named read-outs of the robot inside a compiled scene (dm_control's Physics style).

    Positions and velocities are those MuJoCo last computed into `data` (mj_step computes
    them at the start of a step, so call mj_forward after changing the state by hand).
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        self.model = model
        self.data = data
        self._head = model.site("head").id
        self._left_hand = model.site("left_hand").id
        self._right_hand = model.site("right_hand").id
        self._torso = model.body("torso_link").id
        self._com_velocity_adr = model.sensor("pelvis_subtreelinvel").adr[0]
        self._actuator_ids = np.array([model.actuator(n).id for n in ACTUATOR_NAMES])
        low, high = model.actuator_ctrlrange[self._actuator_ids].T
        # lo + (a + 1) / 2 * (hi - lo), rearranged to two array operations per step.
        self._ctrl_mid = (low + high) / 2
        self._ctrl_half_span = (high - low) / 2
        base = model.joint("free_base")
        self.qpos_slice = slice(int(base.qposadr[0]), int(base.qposadr[0]) + NQ_ROBOT)
        self.qvel_slice = slice(int(base.dofadr[0]), int(base.dofadr[0]) + NV_ROBOT)
        self._pelvis_z_adr = self.qpos_slice.start + 2

    def head_height(self) -> float:
        """Height of the `head` site above the floor (1.68 m at the keyframe)."""
        return float(self.data.site_xpos[self._head, 2])

    def torso_upright(self) -> float:
        """zz entry of the torso's rotation matrix: 1 upright, 0 lying, -1 upside down."""
        return float(self.data.xmat[self._torso, 8])

    def pelvis_height(self) -> float:
        """z of the pelvis (the free base's position)."""
        return float(self.data.qpos[self._pelvis_z_adr])

    def center_of_mass_velocity(self) -> np.ndarray:
        """Linear velocity of the whole robot's centre of mass (pelvis subtree), (3,)."""
        adr = self._com_velocity_adr
        return self.data.sensordata[adr : adr + 3].copy()

    def left_hand_position(self) -> np.ndarray:
        """World position of the `left_hand` site (on the forearm, not the palm), (3,)."""
        return self.data.site_xpos[self._left_hand].copy()

    def right_hand_position(self) -> np.ndarray:
        """World position of the `right_hand` site (on the forearm, not the palm), (3,)."""
        return self.data.site_xpos[self._right_hand].copy()

    def actuator_forces(self) -> np.ndarray:
        """Force of each actuator in action order, (61,)."""
        return self.data.actuator_force[self._actuator_ids]

    def action_to_ctrl(self, action: np.ndarray) -> np.ndarray:
        """Map an action in [-1, 1]^61 linearly onto the actuators' ctrlrange (action order)."""
        return self._ctrl_mid + self._ctrl_half_span * action
