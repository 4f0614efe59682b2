"""Two Shadow hands on the batched MuJoCo base: the pieces shared by the Bi-DexHands tasks of the paper's
appendix C (``shadow_hand_scissors``, ``shadow_hand_bottle_cap``).

The hand is the gymnasium-robotics Shadow hand that EnvPool installs (``envpool_assets``: ``robot.xml``,
``shared.xml``, ``shared_asset.xml`` and its meshes), read at run time and never copied here. Each hand is
compiled into an ``MjSpec`` and attached twice (prefixes ``rh_`` and ``lh_``) to a scene written for this
project (``assets/bimanual_<task>.xml``: table, object, and the bodies ``right_mount``/``left_mount``).

Per hand, as in Bi-DexHands (52 actions for two hands, in this order)::

    action[0:3]   base translation   -> position targets of 3 world-aligned slide joints (± base_range m)
    action[3:6]   base rotation      -> position targets of 3 hinge joints about x, y, z (± base_rot_range rad)
    action[6:26]  20 finger/wrist actuators -> targets lo + (a + 1)/2 (hi - lo) of their ctrlrange

Bi-DexHands drives a free-floating hand base with forces and damping and disables the hands' gravity;
here the base is a stiff, damped position servo on six joints and every hand body has ``gravcomp=1``.
Both hands are the right-hand model (the installed assets have no left hand).

Observation per hand [95]: joint positions scaled to [-1, 1] (24), joint velocities × 0.2 (24), fingertip
positions (5 × 3), base joint positions (6), the hand's last action (26) — Bi-DexHands' full state without
the force sensors. The task appends its object state.
"""

from __future__ import annotations

import re
from importlib.resources import files
from typing import Any

import mujoco
import numpy as np
import torch

from torchrl_ahrs.envs.backends.mujoco_base import BatchedMujocoEnv
from torchrl_ahrs.envs.settings import BimanualSettings

HANDS = ("rh_", "lh_")  # right hand first: action[0:26] and the first half of the observation
FINGERS = ("ff", "mf", "rf", "lf", "th")
BASE_JOINTS = ("base_x", "base_y", "base_z", "base_rx", "base_ry", "base_rz")
HAND_ACTIONS = 26
HAND_OBS = 95
VEL_OBS_SCALE = 0.2  # Bi-DexHands' vel_obs_scale
Vec3 = tuple[float, float, float]
Pose = tuple[Vec3, Vec3]  # (finger direction, palm normal) of a hand, in the world


def hand_asset_dir():
    """EnvPool's installed robotics assets (``.../envpool_assets/mujoco/robotics/assets``)."""
    return files("envpool_assets") / "mujoco" / "robotics" / "assets"


def _inner(text: str) -> str:
    """The children of a file's ``<mujoco>`` root, comments and ``<size>`` (the scene's to set) removed."""
    text = re.sub(r"<!--.*?-->|<size[^>]*>(</size>)?", "", text, flags=re.S).strip()
    return re.sub(r"^<mujoco>|</mujoco>$", "", text).strip()


def hand_quat(fingers: tuple[float, float, float], palm: tuple[float, float, float]) -> list[float]:
    """Forearm quaternion (w, x, y, z) pointing the fingers along ``fingers`` with the palm facing ``palm``.

    In the hand's frame the fingers extend along +z and the palm faces -y, so the rotation's columns are
    x = y × z, y = -palm, z = fingers (both unit, orthogonal).

    Example:
        >>> [round(v, 3) + 0.0 for v in hand_quat((0.0, 0.0, 1.0), (0.0, -1.0, 0.0))]  # the hand's own frame
        [1.0, 0.0, 0.0, 0.0]
        >>> [round(v, 3) + 0.0 for v in hand_quat((-1.0, 0.0, 0.0), (0.0, 0.0, -1.0))]  # pointing -x, palm down
        [-0.5, -0.5, 0.5, 0.5]
    """
    z, y = np.asarray(fingers, np.float64), -np.asarray(palm, np.float64)
    matrix = np.stack([np.cross(y, z), y, z], axis=1)  # columns: the hand's axes in the world
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, matrix.reshape(-1))
    return quat.tolist()


def shadow_hand_spec(
    forearm_quat: list[float],
    base_range: float = 0.15,
    base_rot_range: float = 0.5,
    base_kp: float = 2000.0,
    base_rot_kp: float = 300.0,
) -> mujoco.MjSpec:
    """One Shadow hand from EnvPool's assets on a six-joint servoed base, ready to attach.

    The mount body sits at the attachment frame's origin with world-aligned base joints; the forearm
    below it is turned by ``forearm_quat`` (see :func:`hand_quat`). Adds sites ``tip_<finger>`` (distal body + 0.02 m
    along its axis, as Bi-DexHands' fingertip points) and ``grasp`` (palm + 0.08 m along the fingers and
    0.02 m toward the palm side, Bi-DexHands' hand position).
    """
    root = hand_asset_dir()
    hand = root / "hand"
    xml = (
        f'<mujoco model="shadow_hand"><compiler angle="radian" meshdir="{root / "stls" / "hand"}"/>'
        f"{_inner((hand / 'shared.xml').read_text())}"
        f"<asset>{_inner((hand / 'shared_asset.xml').read_text())}</asset>"
        f"<worldbody>{_inner((hand / 'robot.xml').read_text())}</worldbody></mujoco>"
    )
    spec = mujoco.MjSpec.from_string(xml)
    mount = spec.body("robot0:hand mount")
    forearm = spec.body("robot0:forearm")
    for body, quat in ((mount, [1.0, 0.0, 0.0, 0.0]), (forearm, list(forearm_quat))):
        body.alt.type = mujoco.mjtOrientation.mjORIENTATION_QUAT  # the file's euler= would override quat
        body.quat = quat
    mount.pos = [0.0, 0.0, 0.0]
    for i, name in enumerate(BASE_JOINTS):
        axis = [0.0, 0.0, 0.0]
        axis[i % 3] = 1.0
        rotation = i >= 3
        mount.add_joint(
            name=name,
            type=mujoco.mjtJoint.mjJNT_HINGE if rotation else mujoco.mjtJoint.mjJNT_SLIDE,
            axis=axis,
            range=[-1.5 * base_rot_range, 1.5 * base_rot_range] if rotation else [-1.5 * base_range, 1.5 * base_range],
            damping=20.0 if rotation else 200.0,  # about critical: c = 2 sqrt(k m), hand ~5 kg, ~0.35 kg m^2
            armature=0.01,
        )
        limit = base_rot_range if rotation else base_range
        actuator = spec.add_actuator(
            name=f"A_{name}", target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT, ctrlrange=[-limit, limit]
        )
        actuator.set_to_position(kp=base_rot_kp if rotation else base_kp)
    for body in spec.bodies:
        body.gravcomp = 1.0  # Bi-DexHands disables gravity on the hands
    for finger in FINGERS:
        spec.body(f"robot0:{finger}distal").add_site(name=f"tip_{finger}", pos=[0, 0, 0.02], size=[0.004])
    spec.body("robot0:palm").add_site(name="grasp", pos=[0, -0.02, 0.08], size=[0.006])
    return spec


def bimanual_model(scene_xml: str, poses: tuple[Pose, Pose], **hand_kwargs: float) -> mujoco.MjModel:
    """Compiles ``scene_xml`` (a path) with Shadow hands attached at ``right_mount`` and ``left_mount``.

    ``poses`` gives (finger direction, palm normal) of the right and the left hand, in the world.
    """
    scene = mujoco.MjSpec.from_file(scene_xml)
    for prefix, (fingers, palm) in zip(HANDS, poses, strict=True):
        frame = scene.body("right_mount" if prefix == "rh_" else "left_mount").add_frame()
        scene.attach(shadow_hand_spec(hand_quat(fingers, palm), **hand_kwargs), prefix=prefix, frame=frame)
    return scene.compile()


ENV_KEYS = ("decimation", "max_episode_steps", "reset_dof_noise", "reset_position_noise", "num_threads")
HAND_KEYS = ("base_range", "base_rot_range", "base_kp", "base_rot_kp")


def bimanual_kwargs(task: BimanualSettings, keys: tuple[str, ...]) -> dict[str, Any]:
    """Constructor keywords: the fields of ``task`` among ``keys`` (plus the env's and the hand's) that are set
    (``None`` leaves the constructor's own: ``num_threads``' automatic count, the hand's servo gains)."""
    values = {k: getattr(task, k) for k in (*ENV_KEYS, *HAND_KEYS, *keys)}
    return {k: v for k, v in values.items() if v is not None}


def finger_distance(grasp: torch.Tensor, tips: torch.Tensor) -> torch.Tensor:
    """Σ_f ‖g − tip_f‖ [N] of a grasp point [N, 3] and fingertips [N, F, 3] (Bi-DexHands' finger distance).

    Example:
        >>> finger_distance(torch.zeros(1, 3), torch.tensor([[[3.0, 4.0, 0.0], [0.0, 0.0, 1.0]]]))
        tensor([6.])
    """
    return (tips - grasp.unsqueeze(-2)).norm(dim=-1).sum(-1)  # Σ_f ‖g − tip_f‖


class BimanualShadowEnv(BatchedMujocoEnv):
    """Two Shadow hands and one object on the batched base; subclasses add the object and the reward.

    A subclass sets ``scene_file`` (under ``assets/``), ``hand_poses`` (see :func:`bimanual_model`) and
    ``object_sites``, and implements ``object_observation`` [N, D], ``reward_terms`` and ``total_reward``.
    Actions are [N, 52] in [-1, 1]; observations [N, 190 + D].

    Example:
        >>> from torchrl_ahrs.envs.tasks.shadow_hand_scissors import ShadowHandScissorsEnv
        >>> env = ShadowHandScissorsEnv(num_envs=2, num_threads=1)
        >>> env.tips(0).shape, env.grasp_point(1).shape, env.hand_observation(0).shape
        (torch.Size([2, 5, 3]), torch.Size([2, 3]), torch.Size([2, 95]))
    """

    scene_file: str = ""
    hand_poses: tuple[Pose, Pose] = (((-1.0, 0.0, 0.0), (0.0, 0.0, -1.0)),) * 2
    object_sites: tuple[str, ...] = ()
    state_fields = ("site_xpos",)

    def __init__(
        self,
        num_envs: int,
        decimation: int = 4,
        max_episode_steps: int = 150,
        reset_dof_noise: float = 0.05,
        reset_position_noise: float = 0.01,
        num_threads: int | None = None,
        seed: int = 0,
        device: str = "cpu",
        **hand_kwargs: float,
    ):
        path = str(files("torchrl_ahrs.envs.tasks") / "assets" / self.scene_file)
        model = bimanual_model(path, self.hand_poses, **hand_kwargs)
        self.reset_dof_noise, self.reset_position_noise = float(reset_dof_noise), float(reset_position_noise)
        self._index_model(model)
        super().__init__(model, num_envs, decimation, max_episode_steps, num_threads, seed, device)

    def _index_model(self, model: mujoco.MjModel) -> None:
        """Address arrays: hand joints (qpos/qvel), actuators in policy order, sites."""
        hand_joints = [f"robot0:{name}" for name in ("WRJ1", "WRJ0")] + [
            f"robot0:{f}J{j}"
            for f, js in (("FF", 3), ("MF", 3), ("RF", 3), ("LF", 4), ("TH", 4))
            for j in range(js, -1, -1)
        ]
        self.hand_qpos, self.hand_qvel, self.base_qpos, self.actuators = [], [], [], []
        for prefix in HANDS:
            joints = [model.joint(prefix + name) for name in hand_joints]
            self.hand_qpos.append(torch.tensor([int(j.qposadr[0]) for j in joints]))
            self.hand_qvel.append(torch.tensor([int(j.dofadr[0]) for j in joints]))
            self.base_qpos.append(torch.tensor([int(model.joint(prefix + n).qposadr[0]) for n in BASE_JOINTS]))
            base = [model.actuator(f"{prefix}A_{n}").id for n in BASE_JOINTS]
            fingers = [i for i in range(model.nu) if model.actuator(i).name.startswith(prefix + "robot0:A_")]
            self.actuators += base + fingers
        ranges = [model.jnt_range[model.joint(prefix + n).id] for prefix in HANDS for n in hand_joints]
        self.joint_lo, self.joint_hi = (torch.tensor(np.array(ranges)[:, k]).reshape(2, -1) for k in (0, 1))
        ctrl_range = model.actuator_ctrlrange[self.actuators]
        self.ctrl_lo, self.ctrl_hi = ctrl_range[:, 0], ctrl_range[:, 1]
        self.tip_sites = torch.tensor([[model.site(f"{p}tip_{f}").id for f in FINGERS] for p in HANDS])  # [2, 5]
        self.grasp_sites = torch.tensor([model.site(f"{p}grasp").id for p in HANDS])  # [2]
        self.sites = {name: model.site(name).id for name in self.object_sites}

    # ------------------------------------------------------------ readouts (all [N, ...], float64)
    def tips(self, hand: int) -> torch.Tensor:
        """Fingertip points of hand 0 (right) or 1 (left) [N, 5, 3]."""
        return self.state_t["site_xpos"][:, self.tip_sites[hand]]

    def grasp_point(self, hand: int) -> torch.Tensor:
        """Bi-DexHands' hand position (palm + offsets) [N, 3]."""
        return self.state_t["site_xpos"][:, self.grasp_sites[hand]]

    def site(self, name: str) -> torch.Tensor:
        """World position [N, 3] of an object site."""
        return self.state_t["site_xpos"][:, self.sites[name]]

    # ------------------------------------------------------------ hooks
    @property
    def action_dim(self) -> int:
        return 2 * HAND_ACTIONS

    def apply_action(self, action: torch.Tensor) -> np.ndarray:
        a = action.clamp(-1.0, 1.0).double().numpy()
        ctrl = np.zeros((self.num_envs, self.model.nu))
        ctrl[:, self.actuators] = self.ctrl_lo + (a + 1.0) / 2.0 * (self.ctrl_hi - self.ctrl_lo)  # lo + (a+1)/2 (hi-lo)
        return ctrl

    def reset_state(self, env_ids, rng):
        n = len(env_ids)
        qpos = np.tile(self.model.qpos0, (n, 1))
        for hand in range(2):
            idx = self.hand_qpos[hand].numpy()
            lo, hi = self.joint_lo[hand].numpy(), self.joint_hi[hand].numpy()
            noise = self.reset_dof_noise * rng.uniform(-1.0, 1.0, (n, len(idx))) * (hi - lo)
            qpos[:, idx] = np.clip(qpos[:, idx] + noise, lo, hi)  # Bi-DexHands: default + noise · interval
        self.reset_object(qpos, rng)
        return qpos, np.zeros((n, self.model.nv))

    def reset_object(self, qpos: np.ndarray, rng: np.random.Generator) -> None:
        """Perturbs the object's rows of ``qpos`` [n, nq] in place (default: none)."""

    def hand_observation(self, hand: int) -> torch.Tensor:
        """[N, 95]: scaled joint positions, scaled velocities, fingertips, base joints, last action."""
        lo, hi = self.joint_lo[hand], self.joint_hi[hand]
        q = self.qpos[:, self.hand_qpos[hand]]
        return torch.cat(
            [
                2.0 * (q - lo) / (hi - lo) - 1.0,  # unscale: [lo, hi] -> [-1, 1]
                VEL_OBS_SCALE * self.qvel[:, self.hand_qvel[hand]],
                self.tips(hand).flatten(1),
                self.qpos[:, self.base_qpos[hand]],
                self.action[:, hand * HAND_ACTIONS : (hand + 1) * HAND_ACTIONS].double(),
            ],
            dim=-1,
        )

    def object_observation(self) -> torch.Tensor:
        """Object state [N, D]."""
        raise NotImplementedError

    def observation(self) -> torch.Tensor:
        return torch.cat([self.hand_observation(0), self.hand_observation(1), self.object_observation()], dim=-1)
