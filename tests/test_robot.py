"""The h1hand robot model: layout, HumanoidBench's numbers, keyframe, stability, contacts."""

import mujoco
import numpy as np
import pytest

from humanoid_envs.robot import (
    ACTUATOR_NAMES,
    KEYFRAME_CTRL,
    KEYFRAME_QPOS,
    N_SUBSTEPS,
    NQ_ROBOT,
    NV_ROBOT,
    H1Hand,
    robot_spec,
)

# HumanoidBench's action layout, written out in full so that any reordering fails.
EXPECTED_ACTUATOR_NAMES = (
    "left_hip_yaw", "left_hip_roll", "left_hip_pitch", "left_knee", "left_ankle",
    "right_hip_yaw", "right_hip_roll", "right_hip_pitch", "right_knee", "right_ankle",
    "torso",
    "left_shoulder_pitch", "left_shoulder_roll", "left_shoulder_yaw", "left_elbow",
    "left_wrist_yaw",
    "right_shoulder_pitch", "right_shoulder_roll", "right_shoulder_yaw", "right_elbow",
    "right_wrist_yaw",
    "lh_A_WRJ2", "lh_A_WRJ1", "lh_A_THJ5", "lh_A_THJ4", "lh_A_THJ3", "lh_A_THJ2", "lh_A_THJ1",
    "lh_A_FFJ4", "lh_A_FFJ3", "lh_A_FFJ0", "lh_A_MFJ4", "lh_A_MFJ3", "lh_A_MFJ0",
    "lh_A_RFJ4", "lh_A_RFJ3", "lh_A_RFJ0", "lh_A_LFJ5", "lh_A_LFJ4", "lh_A_LFJ3", "lh_A_LFJ0",
    "rh_A_WRJ2", "rh_A_WRJ1", "rh_A_THJ5", "rh_A_THJ4", "rh_A_THJ3", "rh_A_THJ2", "rh_A_THJ1",
    "rh_A_FFJ4", "rh_A_FFJ3", "rh_A_FFJ0", "rh_A_MFJ4", "rh_A_MFJ3", "rh_A_MFJ0",
    "rh_A_RFJ4", "rh_A_RFJ3", "rh_A_RFJ0", "rh_A_LFJ5", "rh_A_LFJ4", "rh_A_LFJ3", "rh_A_LFJ0",
)  # fmt: skip


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return robot_spec().compile()


def at_keyframe(model: mujoco.MjModel) -> mujoco.MjData:
    data = mujoco.MjData(model)
    data.qpos[:NQ_ROBOT] = KEYFRAME_QPOS
    mujoco.mj_forward(model, data)
    return data


def robot_body_ids(model: mujoco.MjModel) -> set[int]:
    pelvis = model.body("pelvis").id
    return {b for b in range(model.nbody) if model.body_rootid[b] == pelvis}


def test_sizes_and_physics_options(model):
    assert (model.nq, model.nv, model.nu) == (NQ_ROBOT, NV_ROBOT, 61) == (76, 75, 61)
    assert model.opt.timestep == 0.002 and N_SUBSTEPS == 10
    assert model.opt.solver == mujoco.mjtSolver.mjSOL_NEWTON
    assert (model.opt.iterations, model.opt.ls_iterations) == (100, 50)
    assert model.opt.integrator == mujoco.mjtIntegrator.mjINT_EULER
    assert model.opt.cone == mujoco.mjtCone.mjCONE_PYRAMIDAL
    np.testing.assert_allclose(model.opt.gravity, [0, 0, -9.81])
    assert model.nkey == 0 and model.ncam == 0  # tasks add these


def test_actuator_names_in_action_order(model):
    assert ACTUATOR_NAMES == EXPECTED_ACTUATOR_NAMES
    names = tuple(model.actuator(i).name for i in range(model.nu))
    assert names == EXPECTED_ACTUATOR_NAMES


def test_qpos_layout_matches_humanoidbench(model):
    qposadr = {
        "left_hip_yaw": 7, "torso": 17, "left_shoulder_pitch": 18, "left_wrist_yaw": 22,
        "lh_WRJ2": 23, "lh_THJ1": 46, "right_shoulder_pitch": 47, "rh_WRJ2": 52, "rh_THJ1": 75,
    }  # fmt: skip
    for name, adr in qposadr.items():
        assert model.joint(name).qposadr[0] == adr, name
    assert model.joint("free_base").type == mujoco.mjtJoint.mjJNT_FREE


@pytest.mark.parametrize(
    ("name", "kp", "kv", "ctrlrange", "forcerange"),
    [
        ("left_knee", 300, 6, (-0.26, 2.05), (-300, 300)),
        ("torso", 300, 6, (-2.35, 2.35), (-200, 200)),
        ("right_shoulder_roll", 100, 2, (-3.11, 0.34), (-40, 40)),
        ("left_ankle", 40, 2, (-0.87, 0.52), (-40, 40)),
        ("lh_A_WRJ1", 8, 0, (-0.69813, 0.48869), (-5, 5)),
        ("rh_A_THJ5", 0.4, 0, (-1.0472, 1.0472), (-3, 3)),
        ("rh_A_MFJ0", 0.5, 0, (0, 3.1415), (-1, 1)),
    ],
)
def test_actuators_are_position_servos(model, name, kp, kv, ctrlrange, forcerange):
    act = model.actuator(name)
    # Position servo: force = kp * ctrl - kp * q - kv * qdot, gear 1.
    assert act.gainprm[0] == pytest.approx(kp)
    np.testing.assert_allclose(act.biasprm[:3], [0, -kp, -kv])
    assert act.gear[0] == 1
    np.testing.assert_allclose(act.ctrlrange, ctrlrange)
    np.testing.assert_allclose(act.forcerange, forcerange)
    assert act.ctrllimited[0] and act.forcelimited[0]


def test_distal_finger_joints_are_coupled_by_a_tendon(model):
    data = mujoco.MjData(model)
    for hand in ("lh", "rh"):
        for finger in ("FF", "MF", "RF", "LF"):
            tendon = model.tendon(f"{hand}_{finger}J0")
            actuator = model.actuator(f"{hand}_A_{finger}J0")
            assert actuator.trntype[0] == mujoco.mjtTrn.mjTRN_TENDON
            assert actuator.trnid[0] == tendon.id
            data.qpos[model.joint(f"{hand}_{finger}J1").qposadr[0]] = 0.3
            data.qpos[model.joint(f"{hand}_{finger}J2").qposadr[0]] = 0.2
    mujoco.mj_forward(model, data)
    np.testing.assert_allclose(data.ten_length, 0.5)


def test_joint_properties(model):
    knee = model.joint("right_knee")
    np.testing.assert_allclose(knee.range, [-0.26, 2.05])
    assert model.dof_damping[knee.dofadr[0]] == 1.0
    assert model.dof_armature[knee.dofadr[0]] == 0.1
    finger = model.joint("lh_FFJ3")
    assert model.dof_damping[finger.dofadr[0]] == 0.05
    assert model.dof_armature[finger.dofadr[0]] == 0.0002
    assert model.dof_damping[model.joint("rh_WRJ2").dofadr[0]] == 0.5
    np.testing.assert_allclose(model.joint("rh_LFJ5").axis, [0.57358, 0, 0.81915], atol=1e-5)
    # HumanoidBench: friction loss 0.01 on the 48 hand joints, none on the body's.
    hand_dofs = [model.joint(j).dofadr[0] for j in range(model.njnt)
                 if model.joint(j).name.startswith(("lh_", "rh_"))]
    assert len(hand_dofs) == 48
    np.testing.assert_array_equal(model.dof_frictionloss[hand_dofs], 0.01)
    assert model.dof_frictionloss.sum() == pytest.approx(0.48)


def test_masses(model):
    assert mujoco.mj_getTotalmass(model) == pytest.approx(53.24, abs=0.01)
    for hand in ("left_hand", "right_hand"):
        root = model.body(hand).id
        in_hand = [b for b in range(model.nbody) if _is_descendant(model, b, root)]
        assert model.body_mass[in_hand].sum() == pytest.approx(0.795, abs=0.005)
    assert model.body("torso_link").mass[0] == pytest.approx(17.789)


def _is_descendant(model: mujoco.MjModel, body: int, root: int) -> bool:
    while body != 0:
        if body == root:
            return True
        body = model.body_parentid[body]
    return False


def test_keyframe_pose(model):
    data = at_keyframe(model)
    robot = H1Hand(model, data)
    assert robot.head_height() == pytest.approx(1.68, abs=0.01)
    assert robot.torso_upright() == pytest.approx(1.0, abs=0.01)
    assert robot.pelvis_height() == pytest.approx(0.98)
    assert robot.qpos_slice == slice(0, 76) and robot.qvel_slice == slice(0, 75)
    np.testing.assert_allclose(robot.center_of_mass_velocity(), np.zeros(3))
    left, right = robot.left_hand_position(), robot.right_hand_position()
    np.testing.assert_allclose(left, data.site("left_hand").xpos)
    assert left[1] > 0.1 and right[1] < -0.1 and left[0] > 0.2  # forearms point forward
    np.testing.assert_allclose(left * [1, -1, 1], right, atol=1e-6)  # mirror images


def test_keyframe_ctrl_targets_the_keyframe_joint_angles(model):
    for i, target in enumerate(KEYFRAME_CTRL):
        if model.actuator_trntype[i] == mujoco.mjtTrn.mjTRN_JOINT:
            joint = model.actuator_trnid[i, 0]
            assert target == KEYFRAME_QPOS[model.jnt_qposadr[joint]]
        else:
            assert target == 0.0  # J1 + J2 of straight fingers
        lo, hi = model.actuator_ctrlrange[i]
        assert lo <= target <= hi


def test_holding_the_keyframe_is_stable(model):
    data = at_keyframe(model)
    robot = H1Hand(model, data)
    data.ctrl[:] = KEYFRAME_CTRL
    for _ in range(50):
        mujoco.mj_step(model, data, nstep=N_SUBSTEPS)
        assert np.isfinite(data.qpos).all() and np.isfinite(data.qvel).all()
        assert np.abs(data.qvel).max() < 5.0
    assert robot.head_height() > 1.55 and robot.torso_upright() > 0.95
    assert np.abs(robot.actuator_forces()).max() < 200


def test_action_maps_onto_ctrlrange(model):
    robot = H1Hand(model, mujoco.MjData(model))
    lo, hi = model.actuator_ctrlrange.T
    np.testing.assert_allclose(robot.action_to_ctrl(-np.ones(61)), lo)
    np.testing.assert_allclose(robot.action_to_ctrl(np.ones(61)), hi)
    np.testing.assert_allclose(robot.action_to_ctrl(np.zeros(61)), (lo + hi) / 2)


def test_sites_and_sensor(model):
    for site in ("head", "left_hand", "right_hand"):
        assert model.site(site).id >= 0
    np.testing.assert_allclose(model.site("head").pos, [0, 0, 0.7])
    np.testing.assert_allclose(model.site("left_hand").pos, [0.31, 0, -0.01])
    assert model.site("right_hand").bodyid[0] == model.body("right_elbow_link").id
    sensor = model.sensor("pelvis_subtreelinvel")
    assert sensor.type[0] == mujoco.mjtSensor.mjSENS_SUBTREELINVEL
    assert sensor.objid[0] == model.body("pelvis").id


def test_center_of_mass_velocity_reads_the_sensor(model):
    data = at_keyframe(model)
    data.qvel[:3] = [0.3, -0.2, 0.1]  # the whole robot translates rigidly
    mujoco.mj_forward(model, data)
    np.testing.assert_allclose(H1Hand(model, data).center_of_mass_velocity(), [0.3, -0.2, 0.1])


def test_feet_stand_on_the_floor(model):
    data = at_keyframe(model)
    floor = model.geom("floor").id
    feet = {model.body("left_ankle_link").id, model.body("right_ankle_link").id}
    touching = {
        int(model.geom_bodyid[c.geom2 if c.geom1 == floor else c.geom1])
        for c in data.contact
        if floor in (c.geom1, c.geom2)
    }
    assert touching == feet


def test_no_self_contact_at_the_keyframe(model):
    data = at_keyframe(model)
    robot = robot_body_ids(model)
    assert not [c for c in data.contact
                if model.geom_bodyid[c.geom1] in robot and model.geom_bodyid[c.geom2] in robot]


def _robot_contact_pairs(model, data) -> set[tuple[str, str]]:
    robot = robot_body_ids(model)
    return {tuple(sorted((model.body(model.geom_bodyid[c.geom1]).name,
                          model.body(model.geom_bodyid[c.geom2]).name)))
            for c in data.contact
            if model.geom_bodyid[c.geom1] in robot and model.geom_bodyid[c.geom2] in robot}


@pytest.mark.parametrize("roll", [-0.2, 0.2])
def test_legs_touch_where_humanoidbench_meshes_touch(model, roll):
    """Shapes fitted to the meshes' hulls, not their bounding boxes: rolling the hips clears
    (the bounding boxes of the two hip-roll links touched each other here); raising the thighs
    by 0.5 rad brings each against its hip-yaw cylinder, as HumanoidBench's meshes do."""
    data = at_keyframe(model)
    for side, sign in (("left", 1), ("right", -1)):
        data.qpos[model.joint(f"{side}_hip_roll").qposadr[0]] = sign * roll
    mujoco.mj_forward(model, data)
    assert _robot_contact_pairs(model, data) == set()
    for side in ("left", "right"):
        data.qpos[model.joint(f"{side}_hip_pitch").qposadr[0]] = 0.5
    mujoco.mj_forward(model, data)
    assert _robot_contact_pairs(model, data) == {
        ("left_hip_pitch_link", "left_hip_yaw_link"), ("right_hip_pitch_link", "right_hip_yaw_link")
    }


def test_an_arm_driven_into_the_torso_collides_with_it(model):
    """Self-collisions are on, as HumanoidBench's collision classes have them."""
    data = at_keyframe(model)
    torso = model.body("torso_link").id
    # Roll the left shoulder inwards, past the torso (within the joint's range).
    data.qpos[model.joint("left_shoulder_roll").qposadr[0]] = -0.34
    data.qpos[model.joint("left_shoulder_yaw").qposadr[0]] = 0.0
    data.qpos[model.joint("left_elbow").qposadr[0]] = 1.6
    data.qpos[model.joint("left_shoulder_pitch").qposadr[0]] = -1.2
    mujoco.mj_forward(model, data)
    arm = {b for b in range(model.nbody) if _is_descendant(model, b, model.body(
        "left_shoulder_roll_link").id)}
    touching = {(int(model.geom_bodyid[c.geom1]), int(model.geom_bodyid[c.geom2]))
                for c in data.contact}
    assert any(torso in pair and (set(pair) & arm) for pair in touching), touching


def test_hands_touch_objects():
    spec = robot_spec()
    # A free box overlapping the left palm, with MuJoCo's default contact bits.
    box = spec.worldbody.add_body(name="box")
    box.add_freejoint()
    box.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.03, 0.03, 0.03], mass=0.1)
    model = spec.compile()
    data = mujoco.MjData(model)
    data.qpos[:NQ_ROBOT] = KEYFRAME_QPOS
    mujoco.mj_kinematics(model, data)
    data.qpos[NQ_ROBOT : NQ_ROBOT + 3] = data.xpos[model.body("lh_palm").id]
    data.qpos[NQ_ROBOT + 3] = 1.0
    mujoco.mj_forward(model, data)
    box_geom = model.body("box").geomadr[0]
    hand_bodies = {b for b in range(model.nbody) if model.body(b).name.startswith("lh_")}
    touching = {
        int(model.geom_bodyid[c.geom1 + c.geom2 - box_geom])
        for c in data.contact
        if box_geom in (c.geom1, c.geom2)
    }
    assert touching and touching <= hand_bodies
