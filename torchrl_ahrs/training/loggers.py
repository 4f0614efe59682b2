"""Where an iteration's numbers go: one TorchRL logger writing to several backends (CSV, TensorBoard, wandb,
mlflow), and what a person watching the run sees in the terminal.

The CSV files start with a ``step,value`` header (:class:`HeaderCSVLogger`; TorchRL's ``CSVLogger`` writes
none); :meth:`FanoutLogger.log_run_config` gives TensorBoard the run's hyperparameters (its HParams tab) and
its config as text, wandb and mlflow the hyperparameters.

:class:`ConsoleProgress` prints one short progress line per iteration and, now and then, a per-component table;
every other scalar (each component's reward, return and weight, the PPO diagnostics) goes to the logger only.
The line::

    1.23M/10.0M frames | 8.41k frames/s | ETA 17:32 | return 871.3 | rule 1 hdpg

frames/s is end to end (frames since the start over wall-clock time since the start, collection and
updates together). The table is printed at every decision the scheduler applied, and every
``table_interval`` iterations::

    it 40 | 1.23M frames | rule 1 hdpg
      component     return   weight   share
      forward        812.3    1.500   61.2%
      ctrl           -41.2    0.500   12.1%
"""

from __future__ import annotations

import importlib.util
import logging
import os
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, TextIO

import torch
import yaml
from tensordict import TensorDictBase
from torchrl.record.loggers import Logger, get_logger
from torchrl.record.loggers.csv import CSVExperiment, CSVLogger
from torchrl.record.loggers.tensorboard import TensorboardLogger
from torchrl.trainers import TrainerHookBase

from torchrl_ahrs.rewards.components import TOTAL, finished_episode_returns
from torchrl_ahrs.value.functional import effective_shares
from torchrl_ahrs.value.gae import ANCHOR

log = logging.getLogger(__name__)

BACKENDS = ("csv", "tensorboard", "wandb", "mlflow")
_PACKAGES = {"tensorboard": "tensorboard", "wandb": "wandb", "mlflow": "mlflow"}
CSV_HEADER = "step,value"
# the HParams tab compares runs on these scalars (logged every iteration under the same tags)
HPARAM_METRICS = ("return/total", "reward/total")


class _HeaderCSVExperiment(CSVExperiment):
    """TorchRL's CSV experiment, with a ``step,value`` header on every file it starts (a file that already has
    rows, a resumed run's, is appended to as it is)."""

    def add_scalar(self, name: str, value: float, global_step: int | None = None):
        path = os.path.join(self.log_dir, "scalars", f"{name}.csv")
        if path not in self.files:
            os.makedirs(os.path.dirname(path), exist_ok=True)
            starting = not os.path.isfile(path) or os.path.getsize(path) == 0
            self.files[path] = open(path, "a+")  # noqa: SIM115  (closed by CSVExperiment.__del__, as TorchRL's)
            if starting:
                self.files[path].write(CSV_HEADER + "\n")
        super().add_scalar(name, value, global_step)


class HeaderCSVLogger(CSVLogger):
    """TorchRL's :class:`~torchrl.record.loggers.CSVLogger` writing ``<log_dir>/<exp>/scalars/<name>.csv`` with a
    ``step,value`` header row.

    Example:
        >>> import tempfile
        >>> from pathlib import Path
        >>> logger = HeaderCSVLogger("metrics", log_dir=tempfile.mkdtemp())
        >>> logger.log_scalar("return/total", 1.5, step=64)
        >>> (Path(logger.log_dir) / "metrics/scalars/return/total.csv").read_text()
        'step,value\\n64,1.5\\n'
    """

    def _create_experiment(self) -> CSVExperiment:
        return _HeaderCSVExperiment(os.path.join(self.log_dir, self.exp_name), video_format=self.video_format)


def flat_hparams(config: Mapping[str, Any], prefix: str = "") -> dict[str, bool | int | float | str]:
    """``{"trainer.lr": 3e-4, ...}``: a nested config as the flat scalar values TensorBoard's HParams take
    (lists and None as their text).

    Example:
        >>> flat_hparams({"trainer": {"lr": 3e-4, "sizes": [64, 64]}, "seed": 1, "aux": None})
        {'trainer.lr': 0.0003, 'trainer.sizes': '[64, 64]', 'seed': 1, 'aux': 'None'}
    """
    flat: dict[str, bool | int | float | str] = {}
    for key, value in config.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(flat_hparams(value, f"{name}."))
        else:
            flat[name] = value if isinstance(value, bool | int | float | str) else str(value)
    return flat


class FanoutLogger(Logger):
    """Forwards every call to each wrapped TorchRL logger.

    Example:
        >>> import tempfile
        >>> logger = build_logger(["csv"], tempfile.mkdtemp(), "demo")
        >>> logger.log_scalar("return/total", 1.5, step=0)
    """

    def __init__(self, loggers: Sequence[Logger], exp_name: str = "torchrl_ahrs"):
        self.loggers = list(loggers)
        super().__init__(exp_name=exp_name, log_dir="")

    def _create_experiment(self):
        return None

    def log_scalar(self, name: str, value: float, step: int | None = None) -> None:
        for logger in self.loggers:
            logger.log_scalar(name, value, step=step)

    def close(self) -> None:
        """Flushes and closes every backend that holds a writer (TensorBoard's event file thread)."""
        for logger in self.loggers:
            close = getattr(getattr(logger, "experiment", None), "close", None)
            if callable(close):
                close()

    def log_video(self, name: str, video, step: int | None = None, **kwargs) -> None:
        for logger in self.loggers:
            logger.log_video(name, video, step=step, **kwargs)

    def log_hparams(self, cfg) -> None:
        for logger in self.loggers:
            logger.log_hparams(cfg)

    def log_histogram(self, name: str, data, **kwargs) -> None:
        for logger in self.loggers:
            logger.log_histogram(name, data, **kwargs)

    def log_run_config(self, config_text: str) -> None:
        """The run's config, ``config_text`` (the YAML of ``config.yaml``, secrets redacted): TensorBoard gets its
        flat hyperparameters, compared on :data:`HPARAM_METRICS`, and the text under the tag ``config``; wandb
        and mlflow get the hyperparameters; CSV nothing (``config.yaml`` is in the run directory)."""
        hparams = flat_hparams(yaml.safe_load(config_text) or {})
        for logger in self.loggers:
            if isinstance(logger, TensorboardLogger):
                from torch.utils.tensorboard.summary import hparams as hparam_summaries

                writer = logger.experiment
                # written into the run's own event file (SummaryWriter.add_hparams would open a new one per call)
                for summary in hparam_summaries(hparams, {name: 0.0 for name in HPARAM_METRICS}):
                    writer.file_writer.add_summary(summary)
                indented = "\n".join("    " + line for line in config_text.splitlines())  # Markdown code block
                writer.add_text("config", indented, global_step=0)
                writer.flush()
            elif not isinstance(logger, CSVLogger):
                logger.log_hparams(hparams)

    def __repr__(self) -> str:
        return f"FanoutLogger({self.loggers})"


def build_logger(backends: Sequence[str], run_dir: str | Path, exp_name: str) -> FanoutLogger:
    """Loggers writing under ``run_dir``: ``csv`` → ``run_dir/<exp>/scalars/*.csv``, ``tensorboard`` →
    ``run_dir/<exp>/events*``. wandb and mlflow are used when installed and skipped with a warning
    otherwise; an unknown name is an error listing the accepted ones."""
    unknown = [name for name in backends if name not in BACKENDS]
    if unknown:
        raise ValueError(f"unknown logger backend(s) {unknown}; accepted: {', '.join(BACKENDS)}")
    loggers = []
    for name in backends:
        package = _PACKAGES.get(name)
        if package and importlib.util.find_spec(package) is None:
            log.warning("logger %s skipped: package %r is not installed", name, package)
            continue
        if name == "csv":
            loggers.append(HeaderCSVLogger(exp_name, log_dir=str(run_dir)))
        else:
            loggers.append(get_logger(name, logger_name=str(run_dir), experiment_name=exp_name))
    return FanoutLogger(loggers, exp_name=exp_name)


# ---- the terminal ----------------------------------------------------------------------------------------

LINE_WIDTH = 80  # a standard terminal


def _si(value: float) -> str:
    for unit, size in (("G", 1e9), ("M", 1e6), ("k", 1e3)):
        if abs(value) >= size:
            return f"{value / size:.3g}{unit}"
    return f"{value:.3g}"


def _clock(seconds: float) -> str:
    minutes, secs = divmod(int(seconds), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


class ConsoleProgress(TrainerHookBase):
    """Trainer hook (``pre_steps_log``) printing one progress line and a compact per-component table.

    Args:
        total_frames: the run's frame budget (for the ETA).
        components: the K components (the estimator's order).
        estimator: has ``weights [K]`` and ``shares [K]`` (a ``WeightedMultiGAE``: the shares of its last
            call, i.e. of the last update, the numbers logged as ``share/<c>``; after a decision the weight
            column is already the new one); without ``shares`` the table estimates them from the batch's
            reward spreads with the same formula.
        scheduler: optional ``RuleScheduler`` (``rule_id``, ``decision_index``, ``repository``).
        table_interval: iterations between tables besides the decisions (0 = at decisions only).
        stream: where to write (default ``sys.stderr``).
        start_frames: frames already done (a resumed run).
        clock: seconds for the rate and ETA (default ``time.monotonic``; tests pass a fake one).

    Example:
        >>> import io, torch
        >>> from tensordict import TensorDict
        >>> class Gae:
        ...     weights = torch.tensor([1.0, 0.5])  # no shares: estimated from the batch's rewards
        >>> out = io.StringIO()
        >>> console = ConsoleProgress(1000, ["a", "b"], Gae(), table_interval=1, stream=out)
        >>> batch = TensorDict({"next": {"done": torch.ones(4, 1, dtype=torch.bool),
        ...     "reward": {"a": torch.arange(4.0)[:, None], "b": 2 * torch.arange(4.0)[:, None], "total": torch.ones(4, 1)},
        ...     "episode_reward": {"a": torch.ones(4, 1), "b": torch.ones(4, 1), "total": torch.full((4, 1), 9.0)}}}, [4])
        >>> console(batch)
        {}
        >>> line, *table = out.getvalue().splitlines()
        >>> line.split(" | ")[0], line.split(" | ")[3]
        ('4/1k frames', 'return 9')
        >>> table[2].split(), table[3].split()  # b: half the weight, twice the spread: the same share
        (['a', '1', '1.000', '50.0%'], ['b', '1', '0.500', '50.0%'])
    """

    def __init__(
        self,
        total_frames: int,
        components: Sequence[str],
        estimator: Any,
        scheduler: Any = None,
        table_interval: int = 10,
        stream: TextIO | None = None,
        start_frames: int = 0,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.total_frames = int(total_frames)
        self.components = list(components)
        self.estimator = estimator
        self.scheduler = scheduler
        self.table_interval = int(table_interval)
        self.stream = stream if stream is not None else sys.stderr
        self.frames = int(start_frames)
        self.start_frames = self.frames
        self.clock = clock
        self.started = clock()
        self.iteration = 0
        self.last_return: float | None = None
        self.last_component_returns: list[float] | None = None
        self.seen_decisions = getattr(scheduler, "decision_index", 0)

    def decision_text(self, rule_id: int | None = None, decided: bool | None = None) -> str:
        """``rule 1 hdpg``, ``direct weights`` or ``no rule yet``: the rule in force now, or ``rule_id`` (0 or
        None: no rule) when given."""
        scheduler = self.scheduler
        if rule_id is None and decided is None:
            rule_id = getattr(scheduler, "rule_id", None)
            decided = scheduler is not None and int(getattr(scheduler, "decision_index", 0)) > 0
        if getattr(getattr(scheduler, "selector", None), "name", None) == "constant":
            return "no schedule"  # ppo, mcppo: the weights never change
        if scheduler is None or not rule_id:
            return "direct weights" if decided else "no rule yet"
        rule = scheduler.repository[int(rule_id)]
        return f"rule {rule.id} {rule.key}"

    def line(self) -> str:
        """One line of at most 80 characters: frames, frames/s, ETA, total return, the rule in force."""
        elapsed = max(self.clock() - self.started, 1e-9)
        rate = (self.frames - self.start_frames) / elapsed  # end to end: collection + update
        # the last batch overshoots a budget that is not a multiple of it: nothing is left, not a negative time
        eta = max(self.total_frames - self.frames, 0) / rate if rate > 0 else float("inf")
        parts = [
            f"{_si(self.frames)}/{_si(self.total_frames)} frames",
            f"{_si(rate)} frames/s",
            f"ETA {_clock(eta) if eta != float('inf') else '?'}",
            f"return {'?' if self.last_return is None else f'{self.last_return:.4g}'}",
            self.decision_text(),
        ]
        text = " | ".join(parts)
        return text if len(text) <= LINE_WIDTH else text[: LINE_WIDTH - 1] + "…"  # one terminal line

    def table(self, batch: TensorDictBase, metrics: Mapping[str, float] | None = None) -> str:
        """Per-component last mean return, weight and effective share of one update.

        With the iteration's ``metrics`` (``weight/<c>``: the weights the update used, ``share/<c>``: their
        shares in it, ``scheduler/rule``: the rule they came from) the row's numbers belong to one update, and a
        ``next`` column shows the weights a decision installed after it. Without them, the estimator's
        ``weights`` and ``shares`` (or shares estimated from the batch's reward spreads)."""
        current = self.estimator.weights.detach().float().cpu()
        names = self.components
        header = self.decision_text()
        if metrics is not None and all(f"weight/{c}" in metrics and f"share/{c}" in metrics for c in names):
            weights = torch.tensor([metrics[f"weight/{c}"] for c in names])
            shares = torch.tensor([metrics[f"share/{c}"] for c in names])
            if "scheduler/rule" in metrics:  # the rule of this update; a decision after it is the "next" one
                later = int(not torch.allclose(weights, current))
                decided = int(getattr(self.scheduler, "decision_index", 0)) - later > 0
                header = self.decision_text(int(metrics["scheduler/rule"]), decided)
        else:
            weights = current
            recorded = getattr(self.estimator, "shares", None)
            if recorded is None:  # an estimator that does not record its shares: the reward spreads stand in
                rewards = torch.cat(
                    [batch.get(("next", "reward", c)).float().reshape(-1, 1) for c in names], dim=-1
                ).cpu()  # [N, K], beside the CPU weights
                recorded = effective_shares(rewards, weights)
            # [K]: an anchored estimator's last share is its anchor's, shown only with the metrics (the row below)
            shares = recorded.detach().float().cpu()[: len(names)]
        changed = not torch.allclose(weights, current)  # a decision after this update: its weights come next
        returns = self.last_component_returns or [float("nan")] * len(names)
        width = max(9, *(len(c) for c in names))
        rows = [
            f"it {self.iteration} | {_si(self.frames)} frames | {header}"
            + (f" -> next {self.decision_text()}" if changed else ""),
            f"  {'component':<{width}} {'return':>9} {'weight':>8} {'share':>7}" + (f" {'next':>8}" if changed else ""),
        ]
        columns = zip(names, returns, weights.tolist(), shares.tolist(), current.tolist(), strict=True)
        for name, ret, weight, share, upcoming in columns:
            row = f"  {name:<{width}} {ret:>9.4g} {weight:>8.3f} {share:>7.1%}"
            rows.append(row + (f" {upcoming:>8.3f}" if changed else ""))
        anchor_share = (metrics or {}).get(f"share/{ANCHOR}")
        if anchor_share is not None:  # the anchored mix: the summed reward's advantage at the mean weight w̄
            total = float("nan") if self.last_return is None else self.last_return
            rows.append(f"  {ANCHOR:<{width}} {total:>9.4g} {weights.mean().item():>8.3f} {anchor_share:>7.1%}")
        return "\n".join(rows)

    def __call__(self, batch: TensorDictBase, metrics: Mapping[str, float] | None = None) -> dict[str, float]:
        self.iteration += 1
        self.frames += batch.numel()
        tracked = self.components + ([TOTAL] if TOTAL not in self.components else [])
        returns = finished_episode_returns(batch, tracked)  # [M, K+1]
        if returns.shape[0]:
            means = returns.mean(0).tolist()
            self.last_component_returns, self.last_return = means[: len(self.components)], means[-1]
            if TOTAL in self.components:
                self.last_return = means[self.components.index(TOTAL)]
        print(self.line(), file=self.stream, flush=True)
        decisions = getattr(self.scheduler, "decision_index", 0)
        periodic = self.table_interval > 0 and self.iteration % self.table_interval == 0
        if decisions != self.seen_decisions or periodic:
            self.seen_decisions = decisions
            print(self.table(batch, metrics), file=self.stream, flush=True)
        return {}  # nothing for the logger: learn() logs the numbers

    def state_dict(self) -> dict[str, Any]:
        return {}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        pass

    def register(self, trainer, name: str = "console") -> None:
        trainer.register_op("pre_steps_log", self)
