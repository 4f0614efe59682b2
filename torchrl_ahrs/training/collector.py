"""A TorchRL ``Collector`` whose ``state_dict`` also holds the running episodes, for exact resume."""

from __future__ import annotations

from collections import OrderedDict
from typing import Any

from tensordict import TensorDict
from torchrl.collectors import Collector

from torchrl_ahrs.envs.common.snapshot import restores_episodes


class ResumableCollector(Collector):
    """``Collector`` that also saves the tensordict it carries from one batch to the next, and not the policy.

    Between two batches the collector keeps ``_carrier``: the last ``next`` observation the policy acts
    on, RewardSum's running episode sums, step counters and trajectory ids. TorchRL's ``state_dict``
    stores the environment (through its transforms, see :mod:`torchrl_ahrs.envs.common.snapshot`), the
    policy and the frame counters, not the carrier. With the carrier too, a collector built anew and
    loaded continues the episodes exactly where the saved one was. The carrier is saved only when the
    environment's state is (:func:`restores_episodes`): with an environment that cannot be snapshotted
    (EnvPool), the loaded collector keeps the fresh episodes it started at construction.

    The policy's weights are left out: a run checkpoints its actor once, under its own name, and the
    collector's policy is that actor (or, in worker processes, receives its weights from
    ``update_policy_weights_()`` after loading).
    """

    def state_dict(self) -> OrderedDict:
        state = super().state_dict()
        state.pop("policy_state_dict", None)  # the actor's own registry entry holds it
        if restores_episodes(self.env):
            state["carrier"] = self._carrier.clone()
        return state

    def load_state_dict(self, state_dict: Any, **kwargs) -> None:
        if "policy_state_dict" not in state_dict and hasattr(self, "_policy_w_state_dict"):
            # the base class loads a policy state strictly: give it the policy's own (a no-op)
            state_dict = {**state_dict, "policy_state_dict": self._policy_w_state_dict.state_dict()}
        super().load_state_dict(state_dict, **kwargs)
        carrier = state_dict.get("carrier")
        if carrier is not None:
            # a worker of a multi-process collector receives it as a nested dict
            self._carrier = (
                TensorDict(carrier, batch_size=self.env.batch_size) if isinstance(carrier, dict) else carrier.clone()
            )
            if "traj_pool" in state_dict:  # the base class drew new trajectory ids for a fresh carrier
                self._traj_pool.load_state_dict(state_dict["traj_pool"])
