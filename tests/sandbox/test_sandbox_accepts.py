"""The sandbox accepts ordinary numeric code: a held-out corpus of rules and auxiliary rewards written the way an LLM
following our prompts writes them, each accepted at the task's K (or on the task's inputs), in bounded time."""

import textwrap
import time

import pytest
import torch

from torchrl_ahrs.sandbox import (
    check,
)
from torchrl_ahrs.sandbox.__main__ import main as cli_main

TASK_K = 11  # Cassie + aux: the K the held-out rules are validated at


ORDINARY_RULES = {
    "torch.zeros(k) filled in a loop": """
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            k = mean_returns.shape[0]
            scores = torch.zeros(k)
            for i in range(k):
                scores[i] = -mean_returns[i] + 0.1 * torch.sqrt(var_returns[i] + 1e-8)
            return scores
    """,
    "empty_like": """
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            out = torch.empty_like(mean_returns)
            for i in range(len(mean_returns)):
                out[i] = history[:, i].std() / (history[:, i].abs().mean() + 1e-6)
            return out
    """,
    "torch.nn.functional as F": """
        import torch
        import torch.nn.functional as F

        def rule(mean_returns, var_returns, history, previous_weights):
            scale = mean_returns.abs().max() + 1e-8
            return F.softmax(-mean_returns / scale, dim=0)
    """,
    "np.asarray and numpy functions": """
        import numpy as np
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            means = np.asarray(mean_returns)
            spread = np.sqrt(np.asarray(var_returns)) + 1e-8
            scores = np.clip(-means / spread, -10.0, 10.0)
            return torch.from_numpy(scores).float()
    """,
    "range over a computed history length": """
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            steps = history.shape[0]
            gains = torch.zeros_like(mean_returns)
            for t in range(1, steps):
                gains = gains + (history[t] - history[t - 1])
            return -gains / max(steps - 1, 1)
    """,
    "NaN only at K=1 (unbiased std)": """
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            z = (mean_returns - mean_returns.mean()) / (mean_returns.std() + 1e-8)
            return -z
    """,
    "ones_like and math": """
        import math
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            base = torch.ones_like(mean_returns)
            bonus = math.log(1.0 + len(mean_returns))
            return base * bonus - torch.tanh(mean_returns / 1000.0)
    """,
    "list comprehension into torch.tensor": """
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            stds = [float(v) ** 0.5 for v in var_returns]
            return torch.tensor(stds) / (sum(stds) + 1e-8)
    """,
    "top-level helper and constants": """
        import torch

        EPS = 1e-8
        TEMPERATURE = 2.0

        def normalise(x):
            return (x - x.min()) / (x.max() - x.min() + EPS)

        def rule(mean_returns, var_returns, history, previous_weights):
            return torch.exp(-normalise(mean_returns) / TEMPERATURE)
    """,
    "torch.where and clamp": """
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            deficit = torch.where(mean_returns < 0, -mean_returns, torch.zeros_like(mean_returns))
            return torch.clamp(deficit, min=0.0, max=1e6)
    """,
    "least-squares slope of the history": """
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            length = history.shape[0]
            t = torch.arange(length, dtype=torch.float32)
            t = t - t.mean()
            centred = history - history.mean(dim=0, keepdim=True)
            slope = (t[:, None] * centred).sum(dim=0) / (t.pow(2).sum() + 1e-8)
            return -slope
    """,
    "augmented item assignment": """
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            k = len(mean_returns)
            scores = torch.zeros(k)
            for i in range(k):
                scores[i] += previous_weights[i]
                scores[i] -= 0.01 * mean_returns[i]
            return scores
    """,
    "enumerate over zip with unpacking": """
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            scores = []
            for i, (m, v) in enumerate(zip(mean_returns.tolist(), var_returns.tolist())):
                scores.append(v / (abs(m) + 1.0) + 0.0 * i)
            return torch.tensor(scores, dtype=torch.float32)
    """,
    "rank with argsort": """
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            ranks = torch.argsort(torch.argsort(mean_returns)).float()
            return ranks.max() - ranks
    """,
    "momentum on previous weights, annotated": """
        import torch

        def rule(
            mean_returns: torch.Tensor,
            var_returns: torch.Tensor,
            history: torch.Tensor,
            previous_weights: torch.Tensor,
        ) -> torch.Tensor:
            target = torch.sigmoid(-mean_returns / (mean_returns.abs().mean() + 1e-8))
            return 0.9 * previous_weights + 0.1 * target
    """,
    "dict of statistics and print for debugging": """
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            stats = {"mean": mean_returns, "spread": var_returns.sqrt()}
            print("stats", stats["mean"].shape)
            return stats["spread"] - stats["mean"]
    """,
    "tuple unpacking of a shape, F.normalize": """
        import torch
        from torch.nn import functional as F

        def rule(mean_returns, var_returns, history, previous_weights):
            length, k = history.shape
            drift = (history[-1] - history[0]) / max(length, 1)
            return F.normalize(-drift.abs() - 1e-3, p=1, dim=0) * k
    """,
    "numpy loop with a variable bound": """
        import numpy as np
        import torch

        def rule(mean_returns, var_returns, history, previous_weights):
            h = np.asarray(history)
            n_components = h.shape[1]
            out = np.zeros(n_components)
            for j in range(n_components):
                out[j] = np.polyfit(np.arange(h.shape[0]), h[:, j], 1)[0] if h.shape[0] > 1 else 0.0
            return torch.as_tensor(-out, dtype=torch.float32)
    """,
}


ORDINARY_AUX = {
    "action penalty": """
        import torch

        def compute_aux_reward(obs):
            return -torch.square(obs["action"]).sum(dim=-1)
    """,
    "F.relu of a height margin": """
        import torch
        import torch.nn.functional as F

        def compute_aux_reward(obs):
            height = obs["observation"][:, 0]
            return -F.relu(0.5 - height)
    """,
    "numpy on the batch": """
        import numpy as np
        import torch

        def compute_aux_reward(obs):
            x = np.asarray(obs["observation"])
            return torch.as_tensor(-np.linalg.norm(x, axis=1), dtype=torch.float32)
    """,
    "loop over the batch size": """
        import torch

        def compute_aux_reward(obs):
            n = obs["action"].shape[0]
            reward = torch.zeros(n)
            for i in range(n):
                reward[i] = -obs["action"][i].abs().max()
            return reward
    """,
    "optional key with a default": """
        import torch

        def compute_aux_reward(obs):
            n = obs["observation"].shape[0]
            total = obs.get("reward.total", torch.zeros(n))
            bonus = torch.ones_like(total) * 0.1 if "info.success" not in obs else obs["info.success"]
            return bonus - 0.01 * total.abs()
    """,
    "gaussian kernel with math": """
        import math
        import torch

        SIGMA = 0.5

        def compute_aux_reward(obs):
            distance = torch.linalg.norm(obs["observation"][:, :3], dim=-1)
            return torch.exp(-distance**2 / (2 * SIGMA**2)) / math.sqrt(2 * math.pi)
    """,
    "helper and torch.where": """
        import torch

        def smoothness(action):
            return -(action[:, 1:] - action[:, :-1]).pow(2).sum(dim=-1)

        def compute_aux_reward(obs):
            a = obs["action"]
            penalty = smoothness(a) if a.shape[1] > 1 else torch.zeros(a.shape[0])
            return torch.where(penalty < -10.0, torch.full_like(penalty, -10.0), penalty)
    """,
}


AUX_INPUTS = {
    "observation": torch.randn(32, 9),
    "action": torch.randn(32, 4),
    "reward.total": torch.randn(32),
    "info.success": torch.zeros(32),
}


def _source(text: str) -> str:
    return textwrap.dedent(text).lstrip()


@pytest.mark.parametrize("label", sorted(ORDINARY_RULES))
def test_ordinary_rule_is_accepted_at_the_tasks_k(label):
    verdict = check(_source(ORDINARY_RULES[label]), "rule", num_components=TASK_K)
    assert verdict.ok, verdict.reasons


@pytest.mark.parametrize("label", sorted(ORDINARY_AUX))
def test_ordinary_aux_reward_is_accepted_on_the_tasks_inputs(label):
    verdict = check(_source(ORDINARY_AUX[label]), "aux", inputs=AUX_INPUTS)
    assert verdict.ok, verdict.reasons


def test_held_out_corpus_acceptance_and_time_per_check():
    corpus = [(text, "rule", {"num_components": TASK_K}) for text in ORDINARY_RULES.values()]
    corpus += [(text, "aux", {"inputs": AUX_INPUTS}) for text in ORDINARY_AUX.values()]
    assert len(corpus) >= 18
    check(_source(ORDINARY_AUX["action penalty"]), "aux")  # the worker's one-time start is not a check
    started = time.perf_counter()
    accepted = sum(check(_source(text), kind, **options).ok for text, kind, options in corpus)
    per_check = (time.perf_counter() - started) / len(corpus)
    print(f"held-out corpus: {accepted} of {len(corpus)} accepted, {per_check * 1000:.0f} ms per check")
    assert accepted == len(corpus)
    assert per_check < 1.0


def test_the_k1_rule_is_refused_when_k1_is_what_it_is_validated_at():
    source = _source(ORDINARY_RULES["NaN only at K=1 (unbiased std)"])
    verdict = check(source, "rule", num_components=1)
    assert not verdict.ok and "not finite" in verdict.reasons[0] and "K=1" in verdict.reasons[0]


def test_cli_validates_rules_at_the_given_k(tmp_path, capsys):
    path = tmp_path / "rule.py"
    path.write_text(_source(ORDINARY_RULES["NaN only at K=1 (unbiased std)"]))
    command = ["check", str(path), "--kind", "rule"]
    assert cli_main(command) == 1  # K = 1 is among the default sizes
    assert "not finite" in capsys.readouterr().out
    assert cli_main([*command, "--num-components", "11"]) == 0
