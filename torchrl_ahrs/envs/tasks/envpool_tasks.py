"""Task builders over :class:`~torchrl_ahrs.envs.backends.envpool.EnvPoolEnv` whose reward is a component tree.

Each builder follows the registry contract ``builder(task, num_envs, seed, device) -> EnvBase`` (``task``: an
:class:`~torchrl_ahrs.envs.settings.InfoTermsSettings`):
a batched env (batch size ``[num_envs]``) that writes ``("next", "reward", c)`` for every component of
the task and ``("next", "reward", "total")`` = EnvPool's native reward.

Tasks whose EnvPool env reports its reward terms in ``info`` declare the mapping in their YAML::

    terms: {forward: reward_forward, ctrl: reward_ctrl, ...}   # component -> EnvPool info entry
                                                               # (default: "reward_" + component)
    term_scale: 1.0                                            # factor on every term (e.g. ctrl_dt)
"""

from __future__ import annotations

from typing import Any

from torchrl.envs import EnvBase, TransformedEnv

from torchrl_ahrs.envs.backends.envpool import INFO, EnvPoolEnv
from torchrl_ahrs.envs.common.observation_prefix import KeepObservationPrefix
from torchrl_ahrs.envs.settings import AntV5Settings, EnvPoolSettings, InfoTermsSettings
from torchrl_ahrs.rewards.components import RewardComponents

ANT_STATE_SIZE = 27  # gymnasium Ant-v5's observation without cfrc_ext: qpos[2:] (13) + qvel (14)


def envpool_make_kwargs(task: EnvPoolSettings) -> dict[str, Any]:
    """The settings forwarded to ``envpool.make``: ``max_episode_steps`` unless null (EnvPool's own limit)."""
    return {"max_episode_steps": task.max_episode_steps} if task.max_episode_steps else {}


def make_info_terms_task(task: InfoTermsSettings, num_envs: int, seed: int, device: str) -> EnvBase:
    """EnvPool task whose components are ``info`` reward terms times ``term_scale``.

    Reads ``env_id``, ``components``, ``terms`` (component → info entry; ``None``: ``"reward_<c>"``),
    ``term_scale``, ``observation_keys`` (dict observation parts forming ``"observation"``),
    ``num_threads`` and ``max_episode_steps`` from ``task``.

    Example:
        >>> task = InfoTermsSettings(name="ant_v5", backend="cpu", components=("forward", "survive"),
        ...     env_id="Ant-v5", max_episode_steps=1000, num_threads=0, term_scale=1.0)
        >>> env = make_info_terms_task(task, num_envs=2, seed=0, device="cpu")
        >>> env.rollout(3)["next", "reward", "forward"].shape
        torch.Size([2, 3, 1])
    """
    components = list(task.components)
    terms = {c: f"reward_{c}" for c in components} | dict(task.terms or {})
    base = EnvPoolEnv(
        task.env_id,
        num_envs=num_envs,
        seed=seed,
        device=device,
        observation_keys=list(task.observation_keys) if task.observation_keys is not None else None,
        num_threads=int(task.num_threads or 0),  # null from an override means EnvPool's default, as 0 does
        **envpool_make_kwargs(task),
    )
    scale = float(task.term_scale)
    return TransformedEnv(
        base,
        RewardComponents(
            components,
            term_keys={c: (INFO, terms[c]) for c in components},
            scales={c: scale for c in components},
        ),
    )


def make_ant_v5(task: AntV5Settings, num_envs: int, seed: int, device: str) -> EnvBase:
    """EnvPool Ant-v5; components forward, ctrl, contact, survive sum to the native reward.

    ``include_cfrc_ext_in_observation: false`` (gymnasium Ant-v5's option of that name) keeps the first
    27 observation entries and drops the 78 contact-force ones; the reward, contact cost included, is
    unchanged (EnvPool's own ``use_contact_force=False`` would drop the contact cost too).

    Example:
        >>> from torchrl_ahrs.app.shared.settings import load_task_settings
        >>> env = make_ant_v5(load_task_settings("ant_v5"), num_envs=2, seed=0, device="cpu")
        >>> sorted(env.rollout(2)["next", "reward"].keys())
        ['contact', 'ctrl', 'forward', 'survive', 'total']
    """
    env = make_info_terms_task(task, num_envs, seed, device)
    if not task.include_cfrc_ext_in_observation:
        env.append_transform(KeepObservationPrefix(ANT_STATE_SIZE))
    return env
