"""Shipped rules on hand-computed inputs, the normalisation, and repository loading."""

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from torchrl_ahrs.scheduling.rules import DEFAULT_REPOSITORY, load_repository, normalise_scores

REPO = load_repository()
HDPG = load_repository("hdpg")
ONES = torch.ones(3)
E = math.e


def hist(first, last):
    """History [5, 3] whose oldest row is ``first`` and newest row ``last`` (middle rows: junk)."""
    rows = [first] + [[100.0, -50.0, 7.0]] * 3 + [last]
    return torch.tensor(rows)


# (rule key, mean, var, history, expected normalised shares n = w - 0.5), all worked out by hand
CASES = [
    ("mean_returns_only", [1, 2, 4], [3, 1, 0], hist([0, 0, 0], [1, 1, 1]), [0, 1 / 4, 3 / 4]),
    ("variance_returns_only", [1, 2, 4], [3, 1, 0], hist([0, 0, 0], [1, 1, 1]), [3 / 4, 1 / 4, 0]),
    ("combined_mean_variance", [1, 2, 4], [3, 1, 0], hist([0, 0, 0], [1, 1, 1]), [1 / 2, 0, 1 / 2]),
    # (mu - H_0) / 5 = [1, 2, 4] / 5
    ("improvement_rate_only", [1, 2, 4], [3, 1, 0], hist([0, 0, 0], [1, 1, 1]), [0, 1 / 4, 3 / 4]),
    # log(1+|mu|) = [0, 1, 2]; sigma/(1+|mu|) = [3, 0, 0] -> s = [3, 1, 2]
    ("log_mean_adjusted_variance", [0, E - 1, E * E - 1], [9, 0, 0], hist([0, 0, 0], [1, 1, 1]), [2 / 3, 0, 1 / 3]),
    # 0.7 * [1,2,4]/7 + 0.3 * [3,1,0]/4 = [0.325, 0.275, 0.4]
    ("balanced_mean_variance", [1, 2, 4], [3, 1, 0], hist([0, 0, 0], [1, 1, 1]), [2 / 7, 0, 5 / 7]),
    ("lagging_components_first", [1, 2, 4], [3, 1, 0], hist([0, 0, 0], [1, 1, 1]), [3 / 5, 2 / 5, 0]),
    # (mu - H_-1) / sqrt(1 + var) = [0, 1, 3] / [2, 2, 1] = [0, 0.5, 3]
    ("noise_adjusted_improvement", [1, 2, 4], [3, 3, 0], hist([9, 9, 9], [1, 1, 1]), [0, 1 / 7, 6 / 7]),
    # (mu - H_-1) / |H_-1| = [0, 1, 3] with H_-1 = 1
    ("hdpg", [1, 2, 4], [3, 1, 0], hist([9, 9, 9], [1, 1, 1]), [0, 1 / 4, 3 / 4]),
]


PAPER_NAMES = {  # the names the paper's rule-selection prompt (appendix A) and figure 4 give
    1: "Mean Returns Only",
    2: "Variance Returns Only",
    3: "Combined Mean and Variance Returns",
    4: "Improvement Rate Only",
    5: "Formula 1",
    6: "Formula 2",
}


def test_default_repository_has_the_papers_eight_rules_and_hdpg_lives_apart():
    assert len(REPO) == 8 and [rule.id for rule in REPO] == list(range(1, 9))
    for rule_id, name in PAPER_NAMES.items():
        assert name in REPO[rule_id].name, (rule_id, REPO[rule_id].name)
    assert all(rule.text and rule.math for rule in REPO)
    assert [rule.key for rule in HDPG] == ["hdpg"]
    assert {case[0] for case in CASES} == {rule.key for rule in REPO} | {"hdpg"}


@pytest.mark.parametrize("key, mean, var, history, expected", CASES, ids=[case[0] for case in CASES])
def test_shipped_rule_on_hand_computed_input(key, mean, var, history, expected):
    rule = (HDPG if key == "hdpg" else REPO).get(key)
    weights = rule.weights(
        torch.tensor(mean, dtype=torch.float32), torch.tensor(var, dtype=torch.float32), history, ONES, 0.5
    )
    assert weights.shape == (3,)
    assert torch.allclose(weights - 0.5, torch.tensor(expected, dtype=torch.float32), atol=1e-4), weights


def test_first_decision_without_history_gives_uniform_improvement_rules():
    mean = torch.tensor([5.0, -3.0, 2.0])
    for key in ("improvement_rate_only", "noise_adjusted_improvement", "hdpg"):
        weights = (HDPG if key == "hdpg" else REPO).get(key).weights(mean, torch.ones(3), mean.expand(5, 3), ONES, 0.5)
        assert torch.allclose(weights, torch.full((3,), 0.5 + 1 / 3)), key


def test_normalise_hand_values_and_ties():
    assert normalise_scores(torch.tensor([1.0, 2.0, 4.0])).tolist() == [0.0, 0.25, 0.75]
    assert normalise_scores(torch.tensor([-2.0, -2.0, -2.0, -2.0])).tolist() == [0.25] * 4
    assert normalise_scores(torch.tensor([3.0])).tolist() == [1.0]


finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, width=32)


@settings(max_examples=200, deadline=None)
@given(st.lists(finite, min_size=1, max_size=12), st.floats(0.01, 100), st.floats(-1e3, 1e3))
def test_normalise_is_a_distribution_invariant_to_scale_and_shift(values, scale, shift):
    scores = torch.tensor(values, dtype=torch.float64)
    shares = normalise_scores(scores)
    assert torch.isfinite(shares).all() and (shares >= 0).all()
    assert abs(float(shares.sum()) - 1.0) < 1e-5
    if float(scores.max() - scores.min()) > 1e-3 * max(1.0, float(scores.abs().max())):
        assert torch.allclose(normalise_scores(scores * scale + shift), shares, atol=1e-4)
        assert float(shares[int(torch.argmax(scores))]) == pytest.approx(float(shares.max()), abs=1e-6)
        assert float(shares[int(torch.argmin(scores))]) == pytest.approx(0.0, abs=1e-6)


def test_rule_output_is_validated():
    rule = REPO.get("mean_returns_only")
    with pytest.raises(ValueError, match="not finite"):
        rule.scores(torch.tensor([1.0, float("nan")]), torch.zeros(2), torch.zeros(5, 2), torch.ones(2))


def test_repository_loads_from_a_path_and_refuses_hostile_files(tmp_path):
    good = tmp_path / "rules.py"
    good.write_text(
        '"""provenance: test"""\nimport torch\n\n'
        "def squared(mean_returns, var_returns, history, previous_weights):\n"
        '    """Squared Means\n\n    Square them.\n\n    math: s_k = mu_k^2\n    """\n'
        "    return mean_returns * mean_returns\n"
    )
    repo = load_repository(good)
    assert len(repo) == 1 and repo[1].name == "Squared Means" and repo[1].math == "s_k = mu_k^2"
    assert repo.provenance == "provenance: test"
    weights = repo[1].weights(torch.tensor([1.0, -2.0, 3.0]), torch.zeros(3), torch.zeros(5, 3), ONES, 0.5)
    assert weights.tolist() == pytest.approx([0.5, 0.5 + 3 / 11, 0.5 + 8 / 11])  # squares [1, 4, 9]
    bad = tmp_path / "bad.py"
    bad.write_text("import os\ndef r(a, b, c, d):\n    return os.system('true')\n")
    with pytest.raises(ValueError, match="import of 'os'"):
        load_repository(bad)


def test_default_repository_path_is_the_shipped_file():
    assert DEFAULT_REPOSITORY.name == "default_rules.py" and DEFAULT_REPOSITORY.exists()
