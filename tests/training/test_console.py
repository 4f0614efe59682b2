"""The console: one short line per iteration, a per-component table at decisions."""

import io

import pytest
import torch
from tensordict import TensorDict

from torchrl_ahrs import ConstantSelector, FixedSelector, RuleScheduler, load_repository
from torchrl_ahrs.training.loggers import LINE_WIDTH, ConsoleProgress
from torchrl_ahrs.value.functional import effective_shares

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


def test_the_eta_is_zero_once_the_last_batch_overshoots_the_budget():
    # 2.5M frames in batches of 1 536 end at 2 500 608: the line said "ETA -1:59:59"
    now, out = [0.0], io.StringIO()
    console = ConsoleProgress(30, NAMES, Gae(), table_interval=0, stream=out, clock=lambda: now[0])
    for _ in range(2):
        now[0] += 10.0
        console(batch(1.0))  # 20 frames in 10 s each: 40 of a budget of 30, 5 s past it at 2 frames/s
    assert out.getvalue().splitlines()[-1].split(" | ")[:3] == ["40/30 frames", "2 frames/s", "ETA 0:00"]


def test_effective_share_is_weight_times_spread():
    spread = torch.tensor([1.0, 2.0, 0.0])  # std over the batch of each component's advantage
    advantages = torch.stack([spread, -spread]) / 2**0.5  # [2, K] with std(A_k) = spread_k
    shares = effective_shares(advantages, torch.tensor([2.0, 1.0, 1.0]))
    torch.testing.assert_close(shares, torch.tensor([0.5, 0.5, 0.0]))


def test_table_rows_are_one_update_and_the_next_weights_stand_beside_them():
    """Weights and shares of a row come from one update (the iteration's metrics); a decision taken after it shows as
    the "next" column, not as the row's weight (which used to pair decision n's weights with update n-1's shares)."""
    gae, out = Gae(), io.StringIO()
    repo = load_repository()
    scheduler = RuleScheduler(gae, selector=FixedSelector(repo, "combined_mean_variance"), interval=1)
    console = ConsoleProgress(1000, NAMES, gae, scheduler, table_interval=1, stream=out)
    used = scheduler.scalars()  # what observe_batch returns: the weights this update trains with
    scheduler.observe_batch(batch(10.0))
    scheduler.step()  # the decision after the update installs new weights
    metrics = {**used, **{f"share/{c}": s for c, s in zip(NAMES, [0.5, 0.3, 0.2], strict=True)}}
    console(batch(10.0), metrics)
    table = out.getvalue().splitlines()[1:]
    assert table[0].endswith("| no rule yet -> next rule 3 combined_mean_variance"), table[0]
    assert table[1].split() == ["component", "return", "weight", "share", "next"]
    rows = [row.split() for row in table[2:]]
    assert [row[2] for row in rows] == ["0.500"] * 3  # the update's weights
    assert [row[3] for row in rows] == ["50.0%", "30.0%", "20.0%"]  # its shares
    assert [float(row[4]) for row in rows] == [round(w, 3) for w in gae.weights.tolist()]  # what comes next
    assert gae.weights.tolist() != [0.5] * 3


def test_decision_lines_are_short_and_methods_without_a_schedule_have_none(caplog):
    gae = Gae()
    repo = load_repository()
    note = "llm=offline: the bandit selector stands in for the 'llm' selector (no LLM is called)"
    with caplog.at_level("INFO", logger="torchrl_ahrs.scheduling.scheduler"):
        scheduler = RuleScheduler(gae, selector=FixedSelector(repo, "combined_mean_variance"), interval=1, note=note)
        constant = RuleScheduler(Gae(), selector=ConstantSelector(), interval=1)
        for _ in range(3):
            for each in (scheduler, constant):
                each.observe_batch(batch(10.0))
                each.step()
    decisions = [r.getMessage() for r in caplog.records if r.getMessage().startswith("decision")]
    assert len(decisions) == 3  # the fixed rule's three; the constant selector's none
    assert all(len(line) <= 120 and "stands in" not in line for line in decisions), decisions
    assert decisions[0].startswith("decision it 1 (fixed): rule 3 combined_mean_variance -> "), decisions[0]
    assert decisions[-1].endswith(" -> " + " ".join(f"{w:.2f}" for w in gae.weights.tolist()))
    assert sum(note in r.getMessage() for r in caplog.records) == 1  # the stand-in note: once, at start


# point_reach with the bandit deciding, and a table printed, after every iteration of 1 024 frames
TABLE_EVERY_ITERATION = [
    "task=point_reach",
    "method=ahrs_wo_a",
    "trainer.num_envs=16",
    "trainer.frames_per_batch=1024",
    "trainer.mini_batch_size=512",
    "trainer.num_epochs=1",
    "trainer.table_interval=1",
    "scheduler.interval=1",
    "model.hidden_sizes=[16]",
]


def test_a_real_run_prints_tables_that_match_its_logged_metrics(tmp_path, capsys, caplog):
    """point_reach with the bandit deciding after every iteration: each table row's weight and share are the CSV's
    weight/<c> and share/<c> of that iteration, its "next" column the following row's weight; the run ends with one
    ``done:`` line; no FutureWarning comes from our calls into TorchRL."""
    import warnings

    from conftest import make_cfg

    from torchrl_ahrs.app.train.runs import read_scalar
    from torchrl_ahrs.train import train

    cfg = make_cfg(*TABLE_EVERY_ITERATION, "trainer.total_frames=3072")
    with warnings.catch_warnings(record=True) as caught, caplog.at_level("INFO", logger="torchrl_ahrs.train"):
        warnings.simplefilter("always", FutureWarning)
        train(cfg, tmp_path)
    assert [str(w.message) for w in caught if issubclass(w.category, FutureWarning)] == []
    lines = capsys.readouterr().err.splitlines()
    starts = [i for i, line in enumerate(lines) if line.startswith("it ")]
    assert len(starts) == 3
    components = ["distance", "arrival", "ctrl"]

    def logged(name):
        steps, values = read_scalar(tmp_path / "metrics" / "scalars" / f"{name}.csv")
        return {int(step): float(value) for step, value in zip(steps, values, strict=True)}

    tables = []
    for start in starts:
        rows = {row.split()[0]: row.split() for row in lines[start + 2 : start + 2 + len(components)]}
        tables.append(rows)
    for iteration, rows in enumerate(tables, start=1):
        step = 1024 * iteration
        for name in components:
            assert float(rows[name][2]) == pytest.approx(logged(f"weight/{name}")[step], abs=5e-4)
            assert float(rows[name][3].rstrip("%")) == pytest.approx(100 * logged(f"share/{name}")[step], abs=0.05)
    for before, after in zip(tables[:-1], tables[1:], strict=True):  # a table's "next" is what the next update used
        for name in components:
            if len(before[name]) == 5:
                assert before[name][4] == after[name][2]
    done = [r.getMessage() for r in caplog.records if r.getMessage().startswith("done: ")]
    assert len(done) == 1 and done[0].startswith("done: 3072 frames in ") and f"run directory {tmp_path}" in done[0]
    assert "final return -" in done[0]  # point_reach's return is a negative distance


def test_an_anchored_run_prints_the_anchors_row_whose_share_completes_the_components(tmp_path, capsys):
    """``ppo.mix=anchored``: below the components, an ``anchor`` row with the mean weight and the logged
    share/anchor; the shares of a table add up to 100 % only with it."""
    from conftest import make_cfg

    from torchrl_ahrs.app.train.runs import read_scalar
    from torchrl_ahrs.train import train

    cfg = make_cfg(*TABLE_EVERY_ITERATION, "ppo.mix=anchored", "trainer.total_frames=2048", "logger.backends=[csv]")
    train(cfg, tmp_path)
    lines = capsys.readouterr().err.splitlines()
    starts = [i for i, line in enumerate(lines) if line.startswith("it ")]
    anchor_shares = read_scalar(tmp_path / "metrics" / "scalars" / "share" / "anchor.csv")[1]
    assert len(starts) == 2 == len(anchor_shares)
    for start, logged in zip(starts, anchor_shares, strict=True):
        rows = [line.split() for line in lines[start + 2 : start + 6]]  # three components, then the anchor
        assert [row[0] for row in rows] == ["distance", "arrival", "ctrl", "anchor"]
        assert float(rows[3][2]) == pytest.approx(sum(float(row[2]) for row in rows[:3]) / 3, abs=2e-3)  # w̄
        assert float(rows[3][3].rstrip("%")) == pytest.approx(100 * logged, abs=0.05)
        assert sum(float(row[3].rstrip("%")) for row in rows) == pytest.approx(100.0, abs=0.3)
