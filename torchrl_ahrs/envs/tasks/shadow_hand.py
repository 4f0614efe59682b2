"""Shadow hand block reorientation (EnvPool ``HandManipulateBlockDense-v1``) with Isaac Gym-style terms.

EnvPool's hand task reports no reward terms, so they are computed from the observation's goals and the
action, following IsaacGymEnvs' ShadowHand reward (the paper's task):

    dist    = -10 * ||p - p*||                       block position error (m)
    rot     = 1 / (|theta| + 0.1)                    theta: angle between block and goal orientation
    action  = -0.0002 * sum(a^2)
    success = 250 if |theta| <= 0.1 else 0
    fall    = fall_penalty if ||p - p*|| >= 0.24 else 0

Their sum *replaces* the environment's reward for training (``("reward", "total")``); the native
gymnasium-robotics dense reward ``-(10 * ||p - p*|| + theta)`` is kept at ``("info", "native_reward")``.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.data import Composite, Unbounded
from torchrl.envs import EnvBase, TransformedEnv
from torchrl.envs.transforms import Compose, Transform

from torchrl_ahrs.envs.backends.envpool import INFO, EnvPoolEnv
from torchrl_ahrs.envs.settings import ShadowHandSettings
from torchrl_ahrs.envs.tasks.envpool_tasks import envpool_make_kwargs
from torchrl_ahrs.rewards.components import RewardComponents

COMPONENTS = ("dist", "rot", "action", "success", "fall")
NATIVE_REWARD = "native_reward"


def quat_angle(quat: torch.Tensor, goal_quat: torch.Tensor) -> torch.Tensor:
    """Rotation angle [*B] in [0, pi] between unit quaternions ``quat`` and ``goal_quat`` [*B, 4].

    Uses theta = 2 * atan2(||v||, |w|) of the relative rotation q * conj(q*) whose scalar part is
    w = <q, q*> and vector norm ||v|| = sqrt(1 - w^2); atan2 stays accurate near 0 and pi.
    """
    cos_half = (quat * goal_quat).sum(-1).abs()  # |w| of the relative rotation
    sin_half = (1.0 - cos_half.square()).clamp_min(0.0).sqrt()  # ||v|| = sqrt(1 - w^2)
    return 2.0 * torch.atan2(sin_half, cos_half)  # theta = 2 atan2(||v||, |w|)


def shadow_hand_terms(
    achieved_goal: torch.Tensor,
    desired_goal: torch.Tensor,
    action: torch.Tensor,
    dist_scale: float = -10.0,
    rot_eps: float = 0.1,
    action_scale: float = -0.0002,
    success_tolerance: float = 0.1,
    success_bonus: float = 250.0,
    fall_distance: float = 0.24,
    fall_penalty: float = -5.0,
) -> dict[str, torch.Tensor]:
    """Isaac Gym ShadowHand reward terms, each [*B].

    Args:
        achieved_goal: block position and quaternion (w, x, y, z), [*B, 7].
        desired_goal: goal position and quaternion, [*B, 7].
        action: [*B, A].
    """
    position_error = (achieved_goal[..., :3] - desired_goal[..., :3]).norm(dim=-1)  # ||p - p*||
    theta = quat_angle(achieved_goal[..., 3:], desired_goal[..., 3:])
    zero = torch.zeros_like(theta)
    return {
        "dist": dist_scale * position_error,  # -10 ||p - p*||
        "rot": 1.0 / (theta.abs() + rot_eps),  # 1 / (|theta| + eps)
        "action": action_scale * action.square().sum(-1),  # -0.0002 sum a^2
        "success": torch.where(theta.abs() <= success_tolerance, zero + success_bonus, zero),
        "fall": torch.where(position_error >= fall_distance, zero + fall_penalty, zero),
    }


class ShadowHandTerms(Transform):
    """Writes ``("info", "reward_<term>")`` [*B] for the terms of :func:`shadow_hand_terms`, keeps the native
    reward at ``("info", "native_reward")`` [*B] and replaces ``"reward"`` [*B, 1] with the terms' sum.

    Reads ``"action"`` from the step input and ``"achieved_goal"``/``"desired_goal"`` from its output.

    Example:
        >>> from torchrl_ahrs.app.shared.settings import load_task_settings
        >>> env = make_shadow_hand(load_task_settings("shadow_hand"), num_envs=2, seed=0, device="cpu")
        >>> sorted(env.rollout(2)["next", "reward"].keys())
        ['action', 'dist', 'fall', 'rot', 'success', 'total']
    """

    def __init__(self, **term_params: float):
        super().__init__(in_keys=["reward"], out_keys=["reward"])
        self.term_params = {k: float(v) for k, v in term_params.items()}

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        terms = shadow_hand_terms(
            next_tensordict.get("achieved_goal"),
            next_tensordict.get("desired_goal"),
            tensordict.get("action"),
            **self.term_params,
        )
        info = next_tensordict.get(INFO)
        native = next_tensordict.get("reward")
        info.set(NATIVE_REWARD, native.squeeze(-1))
        for name, value in terms.items():
            info.set(f"reward_{name}", value)
        next_tensordict.set("reward", torch.stack(list(terms.values()), -1).sum(-1, keepdim=True))  # sum of terms
        return next_tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        info = tensordict_reset.get(INFO)
        zero = torch.zeros(tensordict_reset.batch_size, device=tensordict_reset.device)
        info.set(NATIVE_REWARD, zero)
        for name in COMPONENTS:
            info.set(f"reward_{name}", zero.clone())
        return tensordict_reset

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        info = observation_spec[INFO]
        leaf = Unbounded(shape=info.shape, dtype=torch.float32, device=info.device)
        info[NATIVE_REWARD] = leaf.clone()
        for name in COMPONENTS:
            info[f"reward_{name}"] = leaf.clone()
        return observation_spec


TERM_PARAMS = (
    "dist_scale",
    "rot_eps",
    "action_scale",
    "success_tolerance",
    "success_bonus",
    "fall_distance",
    "fall_penalty",
)


def make_shadow_hand(task: ShadowHandSettings, num_envs: int, seed: int, device: str) -> EnvBase:
    """Shadow hand block task; ``("reward", "total")`` is the sum of the Isaac Gym-style terms.

    The policy observes ``"observation"`` = [hand and block state (61), goal (7)] ([N, 68]).
    """
    base = EnvPoolEnv(
        task.env_id,
        num_envs=num_envs,
        seed=seed,
        device=device,
        observation_keys=list(task.observation_keys),
        keep_observation_parts=True,
        num_threads=int(task.num_threads or 0),  # null from an override means EnvPool's default, as 0 does
        **envpool_make_kwargs(task),
    )
    params = {k: getattr(task, k) for k in TERM_PARAMS}
    components = list(task.components)
    return TransformedEnv(
        base,
        Compose(
            ShadowHandTerms(**params),
            RewardComponents(components, term_keys={c: (INFO, f"reward_{c}") for c in components}),
        ),
    )
