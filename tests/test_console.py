"""The console: one short line per iteration, a per-component table at decisions."""

import io

import torch
from tensordict import TensorDict

from torchrl_ahrs import FixedSelector, RuleScheduler, load_repository
from torchrl_ahrs.training.console import LINE_WIDTH, ConsoleProgress, effective_shares

NAMES = ["forward_velocity_tracking", "ctrl", "survive"]  # a long name must not widen the line


class Gae:
    components = NAMES
    normalize_components = False

    def __init__(self):
        self.weights = torch.full((3,), 0.5)

    def set_weights(self, weights):
        self.weights = weights.clone()


def batch(total):
    done = torch.zeros(4, 5, 1, dtype=torch.bool)
    done[:, -1] = True
    rewards = {c: torch.randn(4, 5, 1) * (k + 1) for k, c in enumerate(NAMES)}
    returns = {c: torch.full((4, 5, 1), float(k)) for k, c in enumerate(NAMES)}
    returns["total"] = torch.full((4, 5, 1), total)
    return TensorDict({"next": {"done": done, "reward": rewards, "episode_reward": returns}}, [4, 5])


def test_one_short_line_per_iteration_and_a_table_at_each_decision():
    gae, out = Gae(), io.StringIO()
    repo = load_repository()
    scheduler = RuleScheduler(gae, selector=FixedSelector(repo, "combined_mean_variance"), interval=2)
    now = [0.0]
    console = ConsoleProgress(10_000_000, NAMES, gae, scheduler, table_interval=0, stream=out, clock=lambda: now[0])
    for it in range(4):
        now[0] += 0.01  # 20 frames per 10 ms: 2k frames/s
        console(batch(100.0 + it))
        scheduler.observe_batch(batch(100.0 + it))
        scheduler.step()
    lines = out.getvalue().splitlines()
    progress = [line for line in lines if "frames/s" in line]
    assert len(progress) == 4 and all(len(line) <= LINE_WIDTH for line in progress)
    assert progress[0] == "20/10M frames | 2k frames/s | ETA 1:23:19 | return 100 | no rule yet"
    assert (
        progress[3] == "80/10M frames | 2k frames/s | ETA 1:23:19 | return 103 | rule 3 combined_mean_v…"
    )  # cut at 80
    tables = [i for i, line in enumerate(lines) if line.startswith("it ")]
    assert len(tables) == 1  # the decision after iteration 2, shown at iteration 3
    rows = lines[tables[0] + 2 : tables[0] + 5]
    shares = [float(row.split()[-1].rstrip("%")) for row in rows]
    assert abs(sum(shares) - 100.0) < 0.5 and [row.split()[0] for row in rows] == NAMES


def test_effective_share_is_weight_times_spread():
    shares = effective_shares(torch.tensor([2.0, 1.0, 1.0]), torch.tensor([1.0, 2.0, 0.0]))
    torch.testing.assert_close(shares, torch.tensor([0.5, 0.5, 0.0]))
