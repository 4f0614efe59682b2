"""Loads a Cassie MJCF (the project's own or MuJoCo Menagerie's) and prepares it for the Cassie task.

Both models are edited the same way through ``mujoco.MjSpec`` before compiling:

* the ten actuated joints are found by name (:func:`canonical_joint_name` maps ``left-hip-roll``,
  ``l_hip_roll``, ``left-foot`` (Menagerie's toe) ... to ``l_hip_roll`` ... ``l_toe``);
* every actuator becomes a joint-space PD servo, torque = clip(kp·(target − q) − kv·q̇, ±limit), with the
  torque limit taken from the original motor (gear × ctrl limit) and gear 1 so that ctrl is the target
  angle in radians; MuJoCo then integrates the damping implicitly (``implicitfast``), which keeps
  kv = 6 N m s/rad stable at a 5 ms physics step;
* a touch sensor (box site around the body's collision geoms) is added on each foot and on the pelvis,
  so contact forces are plain ``sensordata`` columns;
* the physics time step is set from the task config.

The nominal pose (default joint angles, initial state) is the model's keyframe ``home``.

Example:
    >>> model, layout = load_cassie_model(stiffness=[100, 100, 200, 200, 40], damping=[3, 3, 6, 6, 1])
    >>> model.nu, layout.actuator_ids.shape, layout.foot_touch_adr.shape
    (10, (10,), (2,))
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import mujoco
import numpy as np

# order of the action vector and of every per-joint quantity: left leg, then right leg
LEG_JOINTS = ("hip_roll", "hip_yaw", "hip_pitch", "knee", "toe")
JOINT_NAMES = tuple(f"{side}_{joint}" for side in ("l", "r") for joint in LEG_JOINTS)
HOME_KEY = "home"
TOUCH_MARGIN = 0.02  # metres added around a body's collision geoms for its touch-sensor box


def default_model_path() -> Path:
    """Path of the project's own Cassie model (``torchrl_ahrs/envs/tasks/assets/cassie.xml``)."""
    return Path(str(resources.files("torchrl_ahrs.envs.tasks") / "assets" / "cassie.xml"))


def canonical_joint_name(name: str) -> str:
    """``left-hip-roll`` / ``l_hip_roll`` → ``l_hip_roll``; Menagerie's ``left-foot`` → ``l_toe``."""
    key = re.sub(r"[-\s]+", "_", name.strip().lower())
    key = re.sub(r"^left_", "l_", re.sub(r"^right_", "r_", key))
    return re.sub(r"_foot$", "_toe", key)


@dataclass(frozen=True)
class CassieLayout:
    """Indices into MuJoCo arrays for the ten actuated joints (``JOINT_NAMES`` order) and the touch sensors.

    Attributes:
        qpos_adr, dof_adr: [10] addresses of the actuated joints in qpos / qvel.
        actuator_ids: [10] actuator driving each joint (ctrl = target angle).
        joint_range: [10, 2] hard joint limits (rad).
        torque_limit: [10] PD torque clip (N m).
        default_joint_pos: [10] joint angles of the ``home`` keyframe.
        home_qpos: [nq] the full ``home`` configuration (free joint + all joints, passive ones included).
        foot_touch_adr: [2] sensordata columns of the left / right foot touch sensors (N).
        pelvis_touch_adr: int, sensordata column of the pelvis touch sensor (N).
    """

    qpos_adr: np.ndarray
    dof_adr: np.ndarray
    actuator_ids: np.ndarray
    joint_range: np.ndarray
    torque_limit: np.ndarray
    default_joint_pos: np.ndarray
    home_qpos: np.ndarray
    foot_touch_adr: np.ndarray
    pelvis_touch_adr: int


def _find_actuated_joints(spec: mujoco.MjSpec) -> dict[str, str]:
    """``{canonical name: joint name in the file}`` for the ten actuated joints."""
    found = {canonical_joint_name(j.name): j.name for j in spec.joints if j.name}
    missing = [name for name in JOINT_NAMES if name not in found]
    if missing:
        raise ValueError(f"the Cassie model has no joints {missing} (joints: {sorted(found.values())})")
    return {name: found[name] for name in JOINT_NAMES}


def _make_pd_servos(spec: mujoco.MjSpec, joint_of: dict[str, str], kp: np.ndarray, kv: np.ndarray) -> None:
    """Turns the actuator of each actuated joint into a PD servo with the motor's torque limit."""
    by_joint = {act.target: act for act in spec.actuators}
    for k, name in enumerate(JOINT_NAMES):
        act = by_joint.get(joint_of[name])
        if act is None:
            raise ValueError(f"no actuator drives joint {joint_of[name]!r}")
        # torque limit = gear × ctrl limit of the original motor (or its force limit if it had one)
        limit = float(act.gear[0]) * float(np.max(np.abs(act.ctrlrange)))
        if act.forcelimited == mujoco.mjtLimited.mjLIMITED_TRUE or limit == 0.0:
            limit = float(np.max(np.abs(act.forcerange)))
        act.set_to_position(kp=float(kp[k]), kv=float(kv[k]))
        act.gear = [1.0, 0, 0, 0, 0, 0]
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.forcerange = [-limit, limit]


def _collision_box(model: mujoco.MjModel, body_id: int) -> tuple[np.ndarray, np.ndarray]:
    """Centre and half-size [3] (body frame) of a box around the body's colliding geoms."""
    corners = []
    for g in np.nonzero(model.geom_bodyid == body_id)[0]:
        if model.geom_contype[g] == 0 and model.geom_conaffinity[g] == 0:
            continue
        centre, half = model.geom_aabb[g, :3], model.geom_aabb[g, 3:]
        signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T  # the 8 corners
        local = centre + signs * half  # corners in the geom frame
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, model.geom_quat[g])
        corners.append(local @ rot.reshape(3, 3).T + model.geom_pos[g])  # geom frame → body frame
    if not corners:
        raise ValueError(f"body {model.body(body_id).name!r} has no colliding geom for a touch sensor")
    points = np.concatenate(corners)
    low, high = points.min(0), points.max(0)
    return (low + high) / 2, (high - low) / 2 + TOUCH_MARGIN


def _add_touch_sensor(spec: mujoco.MjSpec, model: mujoco.MjModel, body_name: str, sensor_name: str) -> None:
    centre, half = _collision_box(model, model.body(body_name).id)
    site = spec.body(body_name).add_site(name=sensor_name + "_site", type=mujoco.mjtGeom.mjGEOM_BOX)
    site.pos, site.size = centre.tolist(), half.tolist()
    spec.add_sensor(
        name=sensor_name,
        type=mujoco.mjtSensor.mjSENS_TOUCH,
        objtype=mujoco.mjtObj.mjOBJ_SITE,
        objname=site.name,
    )


def load_cassie_model(
    model_path: str | Path | None = None,
    physics_dt: float = 0.005,
    stiffness: np.ndarray | Sequence[float] = (100, 100, 200, 200, 40),
    damping: np.ndarray | Sequence[float] = (3, 3, 6, 6, 1),
) -> tuple[mujoco.MjModel, CassieLayout]:
    """Compiles a Cassie model with PD servos and touch sensors.

    Args:
        model_path: an MJCF scene with a floor (default: the project's ``assets/cassie.xml``; Menagerie's
            ``agility_cassie/scene.xml`` also works).
        physics_dt: MuJoCo time step (s).
        stiffness, damping: PD gains per leg joint, [5] (``LEG_JOINTS`` order, used for both legs) or [10].

    Returns:
        The compiled ``MjModel`` and its :class:`CassieLayout`.
    """
    path = Path(model_path) if model_path else default_model_path()
    spec = mujoco.MjSpec.from_file(str(path))
    spec.option.timestep = float(physics_dt)
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    kp = np.resize(np.asarray(stiffness, np.float64), len(JOINT_NAMES))  # [5] → [10]: same gains both legs
    kv = np.resize(np.asarray(damping, np.float64), len(JOINT_NAMES))
    joint_of = _find_actuated_joints(spec)
    _make_pd_servos(spec, joint_of, kp, kv)

    plain = spec.compile()  # a first compile gives geom extents for the touch sites
    pelvis = next(b for b in range(plain.nbody) if plain.body_jntnum[b] and plain.jnt_type[plain.body_jntadr[b]] == 0)
    foot_bodies = [plain.body(plain.jnt_bodyid[plain.joint(joint_of[f"{s}_toe"]).id]).name for s in "lr"]
    for side, body in zip("lr", foot_bodies, strict=True):
        _add_touch_sensor(spec, plain, body, f"{side}_foot_touch")
    _add_touch_sensor(spec, plain, plain.body(pelvis).name, "pelvis_touch")
    model = spec.compile()

    joint_ids = np.array([model.joint(joint_of[name]).id for name in JOINT_NAMES])
    by_joint = {int(model.actuator_trnid[a, 0]): a for a in range(model.nu)}
    key = model.key(HOME_KEY).id if HOME_KEY in [model.key(i).name for i in range(model.nkey)] else 0
    if model.nkey == 0:
        raise ValueError(f"{path} has no keyframe to take the nominal pose from")
    home_qpos = model.key_qpos[key].copy()
    qpos_adr = model.jnt_qposadr[joint_ids].copy()
    layout = CassieLayout(
        qpos_adr=qpos_adr,
        dof_adr=model.jnt_dofadr[joint_ids].copy(),
        actuator_ids=np.array([by_joint[int(j)] for j in joint_ids]),
        joint_range=model.jnt_range[joint_ids].copy(),
        torque_limit=np.array([model.actuator_forcerange[by_joint[int(j)], 1] for j in joint_ids]),
        default_joint_pos=home_qpos[qpos_adr].copy(),
        home_qpos=home_qpos,
        foot_touch_adr=np.array([model.sensor_adr[model.sensor(f"{s}_foot_touch").id] for s in "lr"]),
        pelvis_touch_adr=int(model.sensor_adr[model.sensor("pelvis_touch").id]),
    )
    return model, layout
