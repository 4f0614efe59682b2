"""Short training rounds for auxiliary-reward candidates (the paper's "I will use the reward function to
train an RL agent and test it", as Eureka does): train with the candidate, read each component's
statistics back, tell the LLM, keep every candidate with its code and scores, choose the best.

Output directory layout (``generate_aux``)::

    candidates/attempt_<i>/aux_reward.py    every accepted candidate's code (with provenance)
    candidates/attempt_<i>/answer.md        the LLM's whole answer (refused ones too)
    candidates/attempt_<i>/run/             its training round (metrics/, scheduler_decisions.jsonl)
    candidates.json                         every attempt: refusal reasons or scores, and the chosen one
    aux_reward.py                           the chosen candidate (highest final return/total)
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from torchrl_ahrs.app.shared.run_dir import RunDirectory
from torchrl_ahrs.app.train.runs import read_scalar
from torchrl_ahrs.reporting.stats import final_return

WINDOW = 0.25  # the first / last quarter of a round are compared in the feedback
SCORE = "return/total"  # the task's own reward: what a candidate is chosen by


@dataclass
class Candidate:
    """One LLM answer: its code file (None when refused), refusal reasons, and the round's scores."""

    attempt: int
    path: str | None = None
    reasons: list[str] = field(default_factory=list)
    scores: dict[str, float] = field(default_factory=dict)

    @property
    def score(self) -> float:
        """Final ``return/total`` of its round (NaN when it was not trained or no episode ended)."""
        return self.scores.get(f"final {SCORE}", math.nan)


def round_config(cfg: DictConfig, aux_path: Path, frames: int) -> DictConfig:
    """The run's config for one round: the composed method (with an auxiliary branch) on ``aux_path``,
    ``frames`` frames, CSV metrics only, no progress bar, a checkpoint only at the end, and no LLM
    during the round (``llm=offline``: the bandit stands in for rule selection, so the generator's
    model is asked only for reward functions)."""
    round_cfg = OmegaConf.create(OmegaConf.to_container(cfg, resolve=True))
    assert isinstance(round_cfg, DictConfig)
    round_cfg.aux.path = str(aux_path)
    round_cfg.trainer.total_frames = int(frames)
    round_cfg.trainer.progress_bar = False
    round_cfg.checkpoint.interval = 0
    round_cfg.logger.backends = ["csv"]
    round_cfg.logger.video_interval = 0
    round_cfg.resume = None
    round_cfg.llm = {"name": "offline", "model": None}
    if round_cfg.method.get("auxiliary") != "branch":
        raise ValueError(
            f"training rounds need a method with an auxiliary branch (ahrs, ahrs_r, ahrs_d, hdppo_a), "
            f"got method={round_cfg.method.name}"
        )
    return round_cfg


def round_scores(run_dir: Path, components: list[str], total_frames: int) -> dict[str, float]:
    """Per component: ``return/<c>`` over the first and the last quarter of the round, the final
    ``return/total``, and the mean ``weight/<c>`` and ``share/<c>`` of the last quarter.

    Example:
        >>> import tempfile
        >>> run = Path(tempfile.mkdtemp())
        >>> (RunDirectory(run).scalars / "return").mkdir(parents=True)
        >>> _ = RunDirectory(run).scalar("return/total").write_text("100,1.0\\n900,3.0\\n1000,5.0\\n")
        >>> round_scores(run, ["total"], 1000)["final return/total"]
        4.0
    """
    scores: dict[str, float] = {}
    for name in [*components, "total"]:
        for kind in ("return", "weight", "share"):
            path = RunDirectory(run_dir).scalar(f"{kind}/{name}")
            if not path.is_file():
                continue
            steps, values = read_scalar(path)
            final = final_return(steps, values, total_frames, WINDOW)  # mean over the last quarter
            if kind == "return":
                early = steps <= WINDOW * total_frames  # the first quarter
                scores[f"first {kind}/{name}"] = float(values[early].mean()) if early.any() else math.nan
            scores[f"final {kind}/{name}"] = final
    return scores


def scores_text(scores: dict[str, float], components: list[str], frames: int) -> str:
    """The feedback lines for the LLM: one per component, returns early -> late, weight and share.

    Example:
        >>> print(scores_text({"first return/a": 1.0, "final return/a": 2.0, "final return/total": 2.0}, ["a"], 100))
        Training round: 100 frames. Mean episode return per component, first quarter -> last quarter:
        - a: 1 -> 2
        - total (the task's own reward): nan -> 2
    """
    lines = [f"Training round: {frames} frames. Mean episode return per component, first quarter -> last quarter:"]
    for name in [*components, "total"]:
        label = "total (the task's own reward)" if name == "total" else name
        line = f"- {label}: {scores.get(f'first return/{name}', math.nan):.4g} -> "
        line += f"{scores.get(f'final return/{name}', math.nan):.4g}"
        if f"final weight/{name}" in scores:
            line += f", weight {scores[f'final weight/{name}']:.3g}"
        if f"final share/{name}" in scores:
            line += f", share of the policy update {scores[f'final share/{name}']:.3g}"
        lines.append(line)
    return "\n".join(lines)


def train_round(cfg: DictConfig, aux_path: Path, run_dir: Path, frames: int) -> dict[str, float]:
    """Trains with candidate ``aux_path`` for ``frames`` frames in ``run_dir``; returns its scores."""
    from torchrl_ahrs.app.shared.config import resolve_components
    from torchrl_ahrs.app.train.iteration import train

    round_cfg = round_config(cfg, aux_path, frames)
    train(round_cfg, run_dir)
    return round_scores(run_dir, resolve_components(round_cfg), frames)


def choose(candidates: list[Candidate]) -> Candidate | None:
    """The trained candidate with the highest final ``return/total``; without any trained one, the
    last accepted candidate; None when every answer was refused."""
    accepted = [candidate for candidate in candidates if candidate.path is not None]
    trained = [candidate for candidate in accepted if not math.isnan(candidate.score)]
    if trained:
        return max(trained, key=lambda candidate: candidate.score)
    return accepted[-1] if accepted else None


def write_index(output_dir: Path, candidates: list[Candidate], chosen: Candidate | None, extra: dict[str, Any]) -> Path:
    """``candidates.json``: every attempt (code path, refusal reasons, scores) and the chosen attempt."""
    index = {
        "chosen_attempt": chosen.attempt if chosen else None,
        "chosen_by": f"final {SCORE} (mean over the last quarter of each training round)",
        **extra,
        "candidates": [asdict(candidate) for candidate in candidates],
    }
    path = output_dir / "candidates.json"
    path.write_text(json.dumps(index, indent=2, default=str))
    return path
