"""RuleScheduler, statistics and the non-LLM selectors, driven by synthetic batches."""

import logging
import time

import pytest
import torch
from omegaconf import OmegaConf
from tensordict import TensorDict

from torchrl_ahrs.app.shared.run_dir import DECISIONS
from torchrl_ahrs.app.shared.settings import scheduler_settings
from torchrl_ahrs.scheduling import (
    BanditSelector,
    ConstantSelector,
    Decision,
    FixedSelector,
    RandomSelector,
    ReturnStatistics,
    RuleScheduler,
    SchedulerSettings,
    Selector,
    build_scheduler,
    load_repository,
)

REPO = load_repository()
COMPONENTS = ["forward", "ctrl", "survive"]


class FakeEstimator:
    """The interface of WeightedMultiGAE the scheduler relies on."""

    def __init__(self, k, weight=0.5):
        self.weights = torch.full((k,), weight)  # the scheduler keeps these until its first decision
        self.calls = 0

    def set_weights(self, weights):
        assert weights.shape == self.weights.shape and torch.isfinite(weights).all()
        self.weights.copy_(weights)
        self.calls += 1


def make_batch(episode_returns, components=COMPONENTS, totals=None, num_envs=4, steps=8):
    """A collector-like batch [N, T] where the given episodes ([M, K]) finish at the last step."""
    episode_returns = torch.as_tensor(episode_returns, dtype=torch.float32).reshape(-1, len(components))
    done = torch.zeros(num_envs, steps, 1, dtype=torch.bool)
    rewards = {c: torch.full((num_envs, steps, 1), 123.0) for c in components}  # junk where not done
    for m, row in enumerate(episode_returns):
        done[m, -1] = True
        for k, c in enumerate(components):
            rewards[c][m, -1] = row[k]
    if totals is not None or "total" not in components:
        total = torch.full((num_envs, steps, 1), 123.0)
        for m in range(episode_returns.shape[0]):
            total[m, -1] = episode_returns[m].sum() if totals is None else totals[m]
        rewards["total"] = total
    return TensorDict({"next": {"done": done, "episode_reward": rewards}}, [num_envs, steps])


def run(scheduler, batches):
    """Feeds one batch per iteration, like the Trainer does; returns the weights after each step."""
    history = []
    for batch in batches:
        scheduler.observe_batch(batch)
        scheduler.step()
        history.append(scheduler.weights.clone())
    return history


def test_statistics_mean_and_population_variance():
    stats = ReturnStatistics(2, history_length=3)
    stats.add(torch.tensor([[1.0, 0.0], [3.0, 0.0]]))
    stats.add(torch.tensor([[5.0, 6.0], [float("nan"), 1.0]]))  # NaN row dropped
    summary = stats.summarise()
    assert summary.count == 3 and stats.dropped_non_finite == 1
    assert summary.mean == pytest.approx([3.0, 2.0])
    assert summary.var == pytest.approx([8 / 3, 8.0])  # (4+0+4)/3 and (4+4+16)/3
    assert stats.summarise().count == 0  # a new period starts empty


def test_history_pads_then_keeps_last_L_oldest_first():
    stats = ReturnStatistics(1, history_length=3)
    assert stats.history_tensor(torch.tensor([7.0])).flatten().tolist() == [7.0, 7.0, 7.0]
    for value in (1.0, 2.0, 3.0, 4.0):
        stats.add(torch.tensor([[value]]))
        stats.push(stats.summarise())
        if value == 2.0:
            assert stats.history_tensor(torch.tensor([0.0])).flatten().tolist() == [1.0, 1.0, 2.0]
    assert stats.history_tensor(torch.tensor([0.0])).flatten().tolist() == [2.0, 3.0, 4.0]


def test_fixed_rule_installs_hand_computed_weights_every_interval(tmp_path):
    estimator = FakeEstimator(3)
    scheduler = RuleScheduler(
        estimator,
        COMPONENTS,
        REPO,
        FixedSelector(REPO, "mean_returns_only"),
        interval=2,
        decisions_path=tmp_path / DECISIONS,
    )
    assert estimator.weights.tolist() == [0.5, 0.5, 0.5]  # base weight before the first decision
    weights = run(scheduler, [make_batch([[1.0, 2.0, 0.0]]), make_batch([[3.0, 2.0, 8.0]])])
    assert weights[0].tolist() == [0.5, 0.5, 0.5]  # iteration 1: no decision yet
    # means over both batches: [2, 2, 4] -> n = [0, 0, 1]
    assert weights[1].tolist() == [0.5, 0.5, 1.5] and estimator.weights.tolist() == [0.5, 0.5, 1.5]
    assert scheduler.scalars()["scheduler/rule"] == 1.0
    assert scheduler.scalars()["weight/survive"] == 1.5
    lines = (tmp_path / DECISIONS).read_text().splitlines()
    assert len(lines) == 1 and '"rule": "mean_returns_only"' in lines[0]


def test_no_finished_episode_keeps_weights_and_says_so(caplog):
    estimator = FakeEstimator(3)
    scheduler = RuleScheduler(estimator, COMPONENTS, REPO, RandomSelector(REPO, seed=1), interval=1)
    with caplog.at_level(logging.INFO, logger="torchrl_ahrs.scheduling.scheduler"):
        run(scheduler, [make_batch(torch.zeros(0, 3)), make_batch([[float("nan"), 1.0, 1.0]])])
    assert estimator.weights.tolist() == [0.5, 0.5, 0.5] and scheduler.rule_id is None
    assert caplog.text.count("no finished episodes since the last decision; weights kept") == 2


def test_constant_selector_never_changes_weights():
    estimator = FakeEstimator(1)
    scheduler = RuleScheduler(estimator, ["total"], REPO, ConstantSelector(), interval=1, initial_weights=[1.0])
    run(scheduler, [make_batch([[float(i)]], components=["total"]) for i in range(5)])
    assert estimator.weights.tolist() == [1.0] and estimator.calls == 1


def test_random_selector_is_seeded_and_varies():
    def schedule(seed):
        scheduler = RuleScheduler(FakeEstimator(3), COMPONENTS, REPO, RandomSelector(REPO, seed=seed), interval=1)
        ids = []
        for i in range(12):
            run(scheduler, [make_batch([[i, 1.0, 2.0]])])
            ids.append(scheduler.rule_id)
        return ids

    assert schedule(0) == schedule(0)
    assert len(set(schedule(0))) > 3 and schedule(0) != schedule(1)


def test_bandit_learns_which_rule_raises_the_total_return():
    bandit = BanditSelector(REPO, seed=0, discount=0.95, exploration=0.3)
    scheduler = RuleScheduler(FakeEstimator(3), COMPONENTS, REPO, bandit, interval=1)
    total, chosen = 0.0, []
    for _ in range(60):
        # environment oracle: the total return grows only while rule 5 is in force
        total += 10.0 if scheduler.rule_id == 5 else -1.0
        run(scheduler, [make_batch([[1.0, 2.0, 3.0]], totals=[total])])
        chosen.append(scheduler.rule_id)
    assert sorted(chosen[:8]) == list(range(1, 9))  # every rule tried once first
    assert chosen[-20:].count(5) >= 10  # uniform choice would give about 2 of 20


class SlowSelector(Selector):
    name = "slow"

    def select(self, context):
        time.sleep(0.3)
        return Decision(self.name, rule_id=1)


def test_non_blocking_selector_applies_rule_when_it_arrives():
    scheduler = RuleScheduler(FakeEstimator(3), COMPONENTS, REPO, SlowSelector(), interval=1, blocking=False)
    run(scheduler, [make_batch([[1.0, 2.0, 4.0]])])
    assert scheduler.rule_id is None  # still asking
    time.sleep(0.5)
    run(scheduler, [make_batch([[1.0, 2.0, 4.0]])])
    assert scheduler.rule_id == 1 and scheduler.weights.tolist() == pytest.approx([0.5, 0.75, 1.25])
    scheduler.close()


class BrokenSelector(Selector):
    name = "broken"

    def select(self, context):
        raise RuntimeError("boom")


def test_selector_or_rule_failure_keeps_weights(caplog):
    caplog.set_level(logging.INFO)
    scheduler = RuleScheduler(FakeEstimator(3), COMPONENTS, REPO, BrokenSelector(), interval=1)
    run(scheduler, [make_batch([[1.0, 2.0, 4.0]])])
    assert scheduler.weights.tolist() == [0.5, 0.5, 0.5] and "selector failed: RuntimeError: boom" in caplog.text
    # a rule that overflows to inf is caught by the output guard
    scheduler = RuleScheduler(
        FakeEstimator(3), COMPONENTS, REPO, FixedSelector(REPO, "variance_returns_only"), interval=1
    )
    run(scheduler, [make_batch([[1e30, 0.0, 0.0], [-1e30, 0.0, 0.0]])])
    assert scheduler.weights.tolist() == [0.5, 0.5, 0.5]


def test_state_dict_resumes_exactly():
    batches = [make_batch([[i % 3, 2.0 - i, i * i / 10]], totals=[float(i % 4)]) for i in range(16)]
    reference = RuleScheduler(FakeEstimator(3), COMPONENTS, REPO, BanditSelector(REPO, seed=2), interval=2)
    expected = run(reference, batches)
    first = RuleScheduler(FakeEstimator(3), COMPONENTS, REPO, BanditSelector(REPO, seed=2), interval=2)
    run(first, batches[:7])
    state = first.state_dict()
    resumed = RuleScheduler(FakeEstimator(3), COMPONENTS, REPO, BanditSelector(REPO, seed=99), interval=2)
    resumed.estimator.set_weights(first.estimator.weights.clone())  # the weights are the estimator's state
    resumed.load_state_dict(state)
    assert "weights" not in state
    assert [w.tolist() for w in run(resumed, batches[7:])] == [w.tolist() for w in expected[7:]]


def config(method, llm="offline", **scheduler):
    return scheduler_settings(
        OmegaConf.create(
            {
                "seed": 0,
                "method": method,
                "llm": {"name": llm, "model": None},
                "scheduler": {
                    "interval": 3,
                    "history_length": 5,
                    "base_weight": 0.5,
                    "rules": None,
                    "blocking": True,
                    **scheduler,
                },
            }
        )
    )


def test_build_scheduler_for_the_shipped_methods(tmp_path, caplog):
    ppo = build_scheduler(
        config({"selector": "constant", "initial_weights": [1.0]}), FakeEstimator(1), ["total"], tmp_path / DECISIONS
    )
    assert ppo.selector.name == "constant" and ppo.weights.tolist() == [1.0]
    hdppo = build_scheduler(
        config({"selector": "fixed", "rule": "hdpg", "initial_weights": None}),
        FakeEstimator(3),
        COMPONENTS,
        tmp_path / DECISIONS,
    )
    assert hdppo.selector.name == "fixed" and [rule.key for rule in hdppo.repository] == ["hdpg"]
    with caplog.at_level(logging.INFO):
        offline = build_scheduler(
            config({"selector": "llm", "initial_weights": None}), FakeEstimator(3), COMPONENTS, tmp_path / DECISIONS
        )
        run(offline, [make_batch([[1.0, 2.0, 3.0]])] * 3)
    assert offline.selector.name == "bandit" and "bandit selector stands in" in offline.note
    assert caplog.text.count("bandit selector stands in") == 1  # once, at start (the decisions file: every time)


class FakeTrainer:
    def __init__(self):
        self.ops, self.modules = [], {}

    def register_op(self, dest, op, **kwargs):
        self.ops.append(dest)

    def register_module(self, name, module):
        self.modules[name] = module


def test_register_hooks_on_trainer():
    trainer = FakeTrainer()
    scheduler = RuleScheduler(FakeEstimator(3), COMPONENTS, REPO, ConstantSelector(), interval=1)
    scheduler.register(trainer, "rule_scheduler")
    assert {"pre_steps_log", "post_steps"} <= set(trainer.ops) and trainer.modules["rule_scheduler"] is scheduler


class NamedEstimator(FakeEstimator):
    """Like WeightedMultiGAE: knows its components."""

    def __init__(self, components, weights):
        super().__init__(len(components))
        self.components = list(components)
        self.weights = torch.tensor(weights)


def test_estimator_weights_and_components_are_kept_unless_given():
    estimator = NamedEstimator(COMPONENTS, [1.0, 0.5, 0.5])
    scheduler = RuleScheduler(estimator, selector=FixedSelector(REPO, "mean_returns_only"), interval=1)
    assert scheduler.components == COMPONENTS and scheduler.selector.name == "fixed"
    assert estimator.weights.tolist() == [1.0, 0.5, 0.5] and estimator.calls == 0
    assert RuleScheduler(estimator).selector.name == "bandit"  # the default selector
    RuleScheduler(estimator, initial_weights=[0.2, 0.2, 0.2])
    assert estimator.weights.tolist() == pytest.approx([0.2, 0.2, 0.2])
    with pytest.raises(ValueError, match=r"differ from the estimator's"):
        RuleScheduler(estimator, ["a", "b", "c"])


def test_episode_return_key_is_configurable_and_a_missing_one_is_named():
    batch = make_batch([[1.0, 2.0, 0.0]]).rename_key_(("next", "episode_reward"), ("next", "episode"))
    scheduler = RuleScheduler(NamedEstimator(COMPONENTS, [0.5] * 3), selector=ConstantSelector())
    with pytest.raises(KeyError, match=r"no episode returns at \('next', 'episode_reward', 'forward'\)"):
        scheduler.observe_batch(batch)
    scheduler.set_keys(episode_reward="episode").observe_batch(batch)
    assert scheduler.statistics.summarise().mean == pytest.approx([1.0, 2.0, 0.0])


def test_build_scheduler_has_a_default_for_every_key():
    scheduler = build_scheduler(SchedulerSettings(), NamedEstimator(COMPONENTS, [1.0, 1.0, 1.0]))
    assert scheduler.selector.name == "constant" and scheduler.interval == 100
    assert scheduler.weights.tolist() == [0.5, 0.5, 0.5]  # initial_weights: null = base_weight


class SilentSelector(Selector):
    name = "silent"

    def select(self, context):
        time.sleep(30)  # a server that never answers within the run
        return Decision(self.name, rule_id=1)


def test_shutdown_does_not_wait_for_a_silent_background_decision():
    scheduler = RuleScheduler(FakeEstimator(3), COMPONENTS, REPO, SilentSelector(), interval=1, blocking=False)
    run(scheduler, [make_batch([[1.0, 2.0, 4.0]])])
    started = time.monotonic()
    scheduler.close(wait_seconds=0.5)
    assert time.monotonic() - started < 3 and scheduler.rule_id is None


def test_a_rule_raising_a_huge_message_is_recorded_in_one_capped_line(tmp_path, caplog):
    from torchrl_ahrs.scheduling.rules import RuleRepository, rules_from_source

    source = "def loud(m, v, h, w):\n    k = {}\n    return k['x' * 1000000]\n"  # KeyError of a 1 MB key
    repository = RuleRepository(rules_from_source(source))
    decisions = tmp_path / "decisions.jsonl"
    scheduler = RuleScheduler(
        FakeEstimator(3),
        COMPONENTS,
        repository,
        FixedSelector(repository, "loud"),
        interval=1,
        decisions_path=decisions,
    )
    caplog.set_level(logging.INFO)
    run(scheduler, [make_batch([[1.0, 2.0, 4.0]])])
    assert scheduler.weights.tolist() == [0.5, 0.5, 0.5]  # fell back: weights kept
    assert "rule failed (KeyError" in decisions.read_text() and decisions.stat().st_size < 5000
    assert len(caplog.text) < 5000
