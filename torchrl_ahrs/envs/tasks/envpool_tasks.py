"""Task builders over :class:`~torchrl_ahrs.envs.backends.envpool.EnvPoolEnv` whose reward is a component tree.

Each builder follows the registry contract ``builder(task_cfg, num_envs, seed, device) -> EnvBase``:
a batched env (batch size ``[num_envs]``) that writes ``("next", "reward", c)`` for every component of
the task and ``("next", "reward", "total")`` = EnvPool's native reward.

Tasks whose EnvPool env reports its reward terms in ``info`` declare the mapping in their YAML::

    terms: {forward: reward_forward, ctrl: reward_ctrl, ...}   # component -> EnvPool info entry
                                                               # (default: "reward_" + component)
    term_scale: 1.0                                            # factor on every term (e.g. ctrl_dt)
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from torchrl.envs import EnvBase, TransformedEnv

from torchrl_ahrs.envs.backends.envpool import INFO, EnvPoolEnv
from torchrl_ahrs.envs.common.observation_prefix import KeepObservationPrefix
from torchrl_ahrs.rewards.components import RewardComponents

MAKE_KWARGS = ("max_episode_steps",)  # task fields forwarded to envpool.make when present
ANT_STATE_SIZE = 27  # gymnasium Ant-v5's observation without cfrc_ext: qpos[2:] (13) + qvel (14)


def _make_kwargs(task_cfg: Mapping[str, Any]) -> dict[str, Any]:
    return {key: task_cfg[key] for key in MAKE_KWARGS if task_cfg.get(key) is not None}


def make_info_terms_task(task_cfg: Mapping[str, Any], num_envs: int, seed: int, device: str) -> EnvBase:
    """EnvPool task whose components are ``info`` reward terms times ``term_scale``.

    Reads ``env_id``, ``components``, ``terms`` (component → info entry, default ``"reward_<c>"``),
    optional ``term_scale``
    (default 1), ``observation_keys`` (dict observation parts forming ``"observation"``),
    ``num_threads`` and ``max_episode_steps`` from ``task_cfg``.

    Example:
        >>> cfg = {"name": "ant_v5", "env_id": "Ant-v5", "components": ["forward", "survive"],
        ...        "terms": {"forward": "reward_forward", "survive": "reward_survive"}}
        >>> env = make_info_terms_task(cfg, num_envs=2, seed=0, device="cpu")
        >>> env.rollout(3)["next", "reward", "forward"].shape
        torch.Size([2, 3, 1])
    """
    components = list(task_cfg["components"])
    terms = {c: f"reward_{c}" for c in components} | dict(task_cfg.get("terms") or {})
    observation_keys = task_cfg.get("observation_keys")
    base = EnvPoolEnv(
        task_cfg["env_id"],
        num_envs=num_envs,
        seed=seed,
        device=device,
        observation_keys=list(observation_keys) if observation_keys is not None else None,
        num_threads=int(task_cfg.get("num_threads", 0) or 0),
        **_make_kwargs(task_cfg),
    )
    scale = float(task_cfg.get("term_scale", 1.0))
    return TransformedEnv(
        base,
        RewardComponents(
            components,
            term_keys={c: (INFO, terms[c]) for c in components},
            scales={c: scale for c in components},
        ),
    )


def make_ant_v5(task_cfg: Mapping[str, Any], num_envs: int, seed: int, device: str) -> EnvBase:
    """EnvPool Ant-v5; components forward, ctrl, contact, survive sum to the native reward.

    ``include_cfrc_ext_in_observation: false`` (gymnasium Ant-v5's option of that name) keeps the first
    27 observation entries and drops the 78 contact-force ones; the reward, contact cost included, is
    unchanged (EnvPool's own ``use_contact_force=False`` would drop the contact cost too).

    Example:
        >>> from torchrl_ahrs.app.shared.settings import load_task_config
        >>> env = make_ant_v5(load_task_config("ant_v5"), num_envs=2, seed=0, device="cpu")
        >>> sorted(env.rollout(2)["next", "reward"].keys())
        ['contact', 'ctrl', 'forward', 'survive', 'total']
    """
    env = make_info_terms_task(task_cfg, num_envs, seed, device)
    if not task_cfg.get("include_cfrc_ext_in_observation", True):
        env.append_transform(KeepObservationPrefix(ANT_STATE_SIZE))
    return env
