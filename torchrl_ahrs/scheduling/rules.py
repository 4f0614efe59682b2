"""Weight rules and rule repositories.

A rule maps per-component statistics to raw scores ``s [K]``; the scheduler turns them into weights
with a :class:`~torchrl_ahrs.scheduling.mapping.WeightMapping` (``scheduler.weight_mapping``:
``minshift_sum``, ``softmax`` or the paper's ``w = base + s`` with a clamp). ``normalise_scores`` is
the min-shift sum normalisation ``n_k = (s_k - min_j s_j) / sum_i (s_i - min_j s_j)``.

A repository is a Python file in the sandbox's subset (see ``default_rules.py`` for the format). It is
loaded with :func:`load_repository` through the sandbox's restricted execution, so a file written by
an LLM and the shipped one follow one path.
"""

from __future__ import annotations

import ast
import hashlib
import inspect
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch

from torchrl_ahrs.sandbox import check_file, load_functions, output_contract
from torchrl_ahrs.sandbox.session import SandboxSession, isolated_functions
from torchrl_ahrs.scheduling.mapping import WeightMapping, minshift_sum

DEFAULT_REPOSITORY = Path(__file__).with_name("default_rules.py")
HDPG_REPOSITORY = Path(__file__).with_name("hdpg_rule.py")
SHIPPED_REPOSITORIES = {"ahrs": DEFAULT_REPOSITORY, "hdpg": HDPG_REPOSITORY}
RULE_ARITY = 4

RuleFn = Callable[[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]


@dataclass(frozen=True)
class Rule:
    """One weight rule: ``fn(mean_returns [K], var_returns [K], history [L, K], previous_weights [K]) -> [K]``.

    Attributes:
        id: 1-based position in its repository (the number an LLM answers with).
        key: the function's name, stable across repositories (e.g. ``"hdpg"``).
        name: display name (first docstring line).
        text: one-paragraph description for prompts.
        math: the formula as one line of text for prompts.
        fn: the pure tensor function returning raw scores.

    Example:
        >>> import torch
        >>> rule = load_repository().get("mean_returns_only")
        >>> rule.id, rule.math
        (1, 's_k = mu_k')
        >>> rule.weights(torch.tensor([1.0, 3.0]), torch.zeros(2), torch.zeros(5, 2), torch.ones(2), 0.5).tolist()
        [0.5, 1.5]
    """

    id: int
    key: str
    name: str
    text: str
    math: str
    fn: RuleFn

    def scores(self, mean_returns, var_returns, history, previous_weights) -> torch.Tensor:
        """Raw scores ``[K]`` (float32), checked by the sandbox's output contract (the check's own).

        Raises:
            ValueError: wrong shape or a non-finite score.
            SandboxCallError: an isolated rule failed in its worker (the message names the file).
        """
        raw = self.fn(mean_returns, var_returns, history, previous_weights)
        scores, problem = output_contract(raw, tuple(mean_returns.shape))
        if scores is None:
            raise ValueError(f"rule {self.key!r}: {problem}")
        return scores

    def weights(
        self, mean_returns, var_returns, history, previous_weights, base_weight: float = 0.5, mapping=None
    ) -> torch.Tensor:
        """Final weights ``[K]``: ``mapping(scores)`` (default: ``base_weight + normalise_scores(scores)``)."""
        mapping = mapping if mapping is not None else WeightMapping("minshift_sum", base_weight)
        return mapping(self.scores(mean_returns, var_returns, history, previous_weights))

    def describe(self) -> str:
        """The rule as it appears in prompts: ``"3. Name: text (math)"``."""
        return f"{self.id}. {self.name}: {self.text} Formula: {self.math}"


def normalise_scores(scores: torch.Tensor) -> torch.Tensor:
    """Min-shift sum normalisation of raw scores ``[K]`` → non-negative ``[K]`` summing to 1.

    Example:
        >>> normalise_scores(torch.tensor([1.0, 2.0, 4.0])).tolist()
        [0.0, 0.25, 0.75]
        >>> normalise_scores(torch.tensor([7.0, 7.0])).tolist()
        [0.5, 0.5]
    """
    return minshift_sum(scores.to(torch.float64)).float()  # n_k = (s_k - min s) / sum (s - min s)


class RuleRepository:
    """An ordered set of rules with 1-based ids, loaded from a sandbox-accepted Python file.

    Args:
        rules: the rules in id order.
        source_path: where they came from (for logs and provenance).
        provenance: the file's docstring (model, date, prompt hash for generated repositories).

    Example:
        >>> repo = load_repository()
        >>> len(repo), repo[8].key, load_repository("hdpg")[1].key
        (8, 'noise_adjusted_improvement', 'hdpg')
    """

    def __init__(self, rules: list[Rule], source_path: Path | None = None, provenance: str = ""):
        if not rules:
            raise ValueError("a rule repository needs at least one rule")
        self.rules = list(rules)
        self.source_path = source_path
        self.provenance = provenance

    def __len__(self) -> int:
        return len(self.rules)

    def __iter__(self):
        return iter(self.rules)

    def __getitem__(self, rule_id: int) -> Rule:
        if not 1 <= rule_id <= len(self.rules):
            raise KeyError(f"rule id {rule_id} out of range 1..{len(self.rules)}")
        return self.rules[rule_id - 1]

    @property
    def ids(self) -> list[int]:
        return [rule.id for rule in self.rules]

    def get(self, key_or_id: str | int) -> Rule:
        """A rule by function name (``"hdpg"``) or id (``3`` or ``"3"``)."""
        if isinstance(key_or_id, int) or str(key_or_id).isdigit():
            return self[int(key_or_id)]
        for rule in self.rules:
            if rule.key == key_or_id:
                return rule
        raise KeyError(f"no rule {key_or_id!r}; rules: {[rule.key for rule in self.rules]}")

    def describe(self) -> str:
        """All rules, one numbered paragraph each, for prompts."""
        return "\n".join(rule.describe() for rule in self.rules)

    def digest(self) -> str:
        """Short hash of the rules' names and formulas (identifies a repository in logs)."""
        text = "\n".join(f"{rule.key}|{rule.math}" for rule in self.rules)
        return hashlib.sha256(text.encode()).hexdigest()[:12]


def _parse_docstring(key: str, docstring: str | None) -> tuple[str, str, str]:
    lines = [line.strip() for line in (docstring or key).strip().splitlines()]
    name = lines[0].rstrip(".") or key
    math_lines = [line[len("math:") :].strip() for line in lines if line.lower().startswith("math:")]
    text = " ".join(line for line in lines[1:] if line and not line.lower().startswith("math:"))
    return name, text or name, math_lines[0] if math_lines else ""


def rules_from_source(source: str, filename: str = "<rules>", isolated: bool = False) -> list[Rule]:
    """Rules of a repository source text (static sandbox check + restricted execution).

    ``isolated``: the rules run in a :class:`~torchrl_ahrs.sandbox.session.SandboxSession` (a key-free worker
    with the check's limits) instead of in this process; the file's text is checked statically here first.

    Example:
        >>> (rule,) = rules_from_source("def twice(m, v, h, w):\\n    return m * 2\\n", isolated=True)
        >>> rule.key, rule.fn(torch.ones(2), None, None, None).tolist()
        ('twice', [2.0, 2.0])
        >>> rule.fn.session.close()
    """
    functions: dict[str, Callable]
    if isolated:
        load_functions(source, filename)  # the static gate's reasons, here, before a worker starts
        functions = dict(isolated_functions(SandboxSession(source, filename), "rule"))
    else:
        functions = load_functions(source, filename)
    rules: list[Rule] = []
    for key, fn in functions.items():
        if len(inspect.signature(fn).parameters) != RULE_ARITY:
            continue  # a helper, not a rule
        name, text, math = _parse_docstring(key, fn.__doc__)
        rules.append(Rule(len(rules) + 1, key, name, text, math, fn))
    if not rules:
        raise ValueError(f"{filename}: no rule function with {RULE_ARITY} arguments")
    return rules


def load_repository(
    path: str | Path | None = None,
    validate: bool = False,
    num_components: int | None = None,
    isolated: bool | None = None,
) -> RuleRepository:
    """Loads a repository file (default: the shipped ``default_rules.py``).

    Args:
        path: a Python file in the sandbox's subset, or the name of a shipped repository (``"ahrs"``:
            the paper's 8 rules, ``"hdpg"``: HD-PPO's rule alone); ``None`` = ``"ahrs"``.
        validate: also run the sandbox's child-process validation (~1 s for the sandbox worker's
            first start, milliseconds after; do it for files written by an LLM that were not
            checked when generated).
        num_components: the task's K, so validation calls the rules at the K they will serve
            (None: K = 1, 4 and 12).
        isolated: call the rules in an isolated worker (:func:`rules_from_source`); None: every file but
            the shipped repositories (hand-written, part of the package's reviewed code).

    Raises:
        ValueError: the sandbox refused the file (every reason is in the message).
    """
    if path is None or str(path) in SHIPPED_REPOSITORIES:
        path = SHIPPED_REPOSITORIES[str(path or "ahrs")]
    path = Path(path)
    if isolated is None:
        isolated = path.resolve() not in {shipped.resolve() for shipped in SHIPPED_REPOSITORIES.values()}
    if validate:
        verdict = check_file(path, "rule", num_components=num_components)
        if not verdict.ok:
            raise ValueError(f"sandbox refused {path}:\n" + "\n".join(verdict.reasons))
    source = path.read_text()
    provenance = ast.get_docstring(ast.parse(source)) or ""
    return RuleRepository(rules_from_source(source, str(path), isolated=isolated), path, provenance)
