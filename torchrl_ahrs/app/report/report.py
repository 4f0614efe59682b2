"""The paper-style report of a sweep behind ``python -m torchrl_ahrs.report <sweep dir> [...] [--out DIR]``.

Reads every run directory below the sweep directories (several are pooled) (see :mod:`torchrl_ahrs.app.train.runs`) and writes
to ``--out`` (default ``<sweep dir>/report``):

- ``report.md``: the method x task table of the paper's Tables I-II (final return mean ± std over seeds,
  change against PPO in %), bootstrap 95 % CIs and interquartile means, runs that are not ``ok`` (missing,
  incomplete, too few metric rows: listed, never dropped silently), per-component returns, the rules the
  schedulers applied, the LLM summary and the figures;
- ``summary.csv``, ``runs.csv``, ``components.csv``, ``rules.csv``, ``llm.csv``: the same numbers;
- ``curves_<task>.png`` (mean ± std learning curves), ``weights_<task>.png`` (weight and rule timelines of
  scheduled runs), ``components_<task>.png`` (final return per reward component).

Final return of a run = mean of its ``return/total`` rows logged after 90 % of ``trainer.total_frames``
(each row is the mean native return of the episodes finished in one iteration).

Example::

    python -m torchrl_ahrs.sweep +sweep=smoke hydra.sweep.dir=outputs/sweeps/smoke
    python -m torchrl_ahrs.report outputs/sweeps/smoke
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

from torchrl_ahrs.app.train.runs import load_sweep
from torchrl_ahrs.reporting import figures
from torchrl_ahrs.reporting.records import Run
from torchrl_ahrs.reporting.stats import FINAL_WINDOW
from torchrl_ahrs.reporting.tables import (
    component_rows,
    contrast_rows,
    llm_rows,
    markdown_table,
    paper_table,
    rule_rows,
    run_rows,
    share_rows,
    summary_rows,
)


def write_csv(rows: list[dict[str, Any]], path: Path) -> Path:
    """``rows`` as CSV with a header (the union of the rows' keys, in first-seen order)."""
    columns = list(dict.fromkeys(key for row in rows for key in row))
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns, restval="")
        writer.writeheader()
        writer.writerows(rows)
    return path


def write_report(sweep_dir: Path | list[Path], out_dir: Path, title: str | None = None) -> dict[str, Any]:
    """Writes the report of ``sweep_dir`` (or of several sweep directories pooled, e.g. a sweep extended
    with more seeds) into ``out_dir``; returns its tables (lists of row dicts).

    Example:
        >>> tables = write_report(Path("outputs/sweeps/smoke"), Path("/tmp/report"))  # doctest: +SKIP
        >>> tables["summary"][0]["mean"]  # doctest: +SKIP
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    runs = load_sweep(sweep_dir)
    tables = {
        "summary": summary_rows(runs),
        "runs": run_rows(runs),
        "components": component_rows(runs),
        "rules": rule_rows(runs),
        "llm": llm_rows(runs),
        "shares": share_rows(runs),
        "contrasts": contrast_rows(runs),
    }
    for name, rows in tables.items():
        write_csv(rows, out_dir / f"{name}.csv")
    images = draw_figures(runs, out_dir)
    names = [Path(d).name for d in (sweep_dir if isinstance(sweep_dir, list) else [sweep_dir])]
    (out_dir / "report.md").write_text(render_markdown(runs, tables, images, title or " + ".join(names)))
    return tables


def draw_figures(runs: list[Run], out_dir: Path) -> dict[str, list[Path]]:
    """All PNGs, grouped by kind."""
    images: dict[str, list[Path]] = {"curves": [], "profiles": [], "weights": [], "shares": [], "components": []}
    for task in sorted({run.task for run in runs}):
        task_runs = [run for run in runs if run.task == task]
        for kind, draw in (
            ("curves", figures.learning_curves),
            ("profiles", figures.performance_profile),
            ("weights", figures.weight_timelines),
            ("shares", figures.share_timelines),
            ("components", figures.component_returns),
        ):
            path = draw(task, task_runs, out_dir / f"{kind}_{task}.png")
            if path is not None:
                images[kind].append(path)
    return images


def who_chose(runs: list[Run]) -> str:
    """One paragraph saying who chose the weights: an arm labelled ``[bandit]`` had its LLM selector replaced by
    the offline bandit (no LLM was called); the rules are hand-written readings of the paper's."""
    stand_ins = sorted({run.method for run in runs if run.method.endswith("[bandit]")})
    llm_arms = sorted({run.method for run in runs if "[" in run.method and not run.method.endswith("[bandit]")})
    text = "**Who chose the weights.** "
    if stand_ins:
        text += (
            f"In {', '.join(stand_ins)} the discounted-UCB bandit chose among the rules: no LLM was reachable, so no "
            "LLM made any decision in these runs. "
        )
    if llm_arms:
        text += f"In {', '.join(llm_arms)} an LLM chose (the backend is in brackets). "
    return text + (
        "The rules are hand-written (scheduling/default_rules.py: rules 1-6 are readings of the paper's, 7-8 ours); "
        "an auxiliary reward, where an arm has one, is the shipped hand-written one unless `aux.path` names another.\n"
    )


def render_markdown(runs: list[Run], tables: dict[str, Any], images: dict[str, list[Path]], title: str) -> str:
    """The Markdown report."""
    not_ok = [row for row in tables["runs"] if row["status"] != "ok"]
    ok_count = len(tables["runs"]) - len(not_ok)
    budgets = sorted({run.total_frames for run in runs if run.path})
    llms = sorted({run.llm_name for run in runs if run.path})
    parts = [
        f"# Sweep report: {title}\n",
        f"{len(tables['runs'])} runs ({ok_count} ok, {len(not_ok)} not ok); frame budget per run "
        f"{', '.join(f'{b:,}' for b in budgets)}; llm backend(s): {', '.join(llms)}.\n",
        who_chose(runs),
        f"**Final return** of a run = mean of its `return/total` rows (each the mean native return of the "
        f"episodes finished in one iteration) logged after {100 * (1 - FINAL_WINDOW):.0f} % of the frame "
        "budget. Cells: mean ± sample std (ddof = 1) over the finished seeds, and the change of the mean "
        "against PPO on the same task in % of |PPO| (positive = higher return).\n",
        "## Final return (paper Tables I-II layout)\n",
        paper_table(tables["summary"]),
        "\n**Final reward per step**: mean of a run's `reward/total` rows (the native reward per step over every "
        "frame of one iteration's batch) in the same final window. Unlike a return it counts the frames of the "
        "episodes still running, so it is the steadier measure where few episodes end per iteration (Cassie).\n",
        paper_table(tables["summary"], metric="reward_per_step_", digits=4),
        "\n## Statistics per method and task\n",
        "Bootstrap: percentile 95 % interval of the mean over seeds (10 000 resamples, fixed seed); with a "
        "handful of seeds it is a spread, not a significance test. IQM: mean of the middle half of the seeds (the mean "
        "for fewer than 4 seeds).\n",
        markdown_table(
            tables["summary"],
            [
                "task",
                "method",
                "seeds_ok",
                "seeds_not_ok",
                "iqm",
                "iqm_ci95_low",
                "iqm_ci95_high",
                "mean",
                "ci95_low",
                "ci95_high",
                "std",
                "change_vs_ppo_pct",
            ],
        ),
        "\n## Contrasts: probability of improvement\n",
        "P(X > Y): the probability that a run of X ends above a run of Y (ties count half; rliable's probability of "
        "improvement, stratified-bootstrap 95 % interval). Named contrasts first, then every arm against `ppo` and "
        "against `mcppo` (the critic alone). Verdict: an effect when the interval excludes 0.5, otherwise no "
        "measurable difference.\n",
        markdown_table(
            tables["contrasts"],
            [
                "task",
                "x",
                "y",
                "tests",
                "seeds_x",
                "seeds_y",
                "iqm_x_minus_y",
                "p_x_better",
                "p_ci95_low",
                "p_ci95_high",
                "verdict",
            ],
        )
        if tables["contrasts"]
        else "No pair of arms on a common task.\n",
        *[f"![{p.stem}]({p.name})\n" for p in images["profiles"]],
        "\n## Early-learning speed\n",
        "AUC: the area under a run's `return/total` curve divided by the frames it spans (its average return "
        "over training; higher = learnt sooner and/or better), mean ± std over seeds. Frames to 90 %: first frame "
        "at which the running mean of 5 rows reaches r0 + 0.9 (P - r0), with r0 the task's mean first logged "
        "return (random-policy level) and P PPO's mean final return; averaged over the seeds that reached it.\n",
        markdown_table(
            tables["summary"],
            ["task", "method", "auc_mean", "auc_std", "frames_to_90pct_ppo", "reached_90pct_ppo"],
        ),
        "\n## Runs not ok (missing, incomplete, too few metric rows)\n",
        markdown_table(not_ok, ["task", "method", "seed", "status", "reason", "path"]) if not_ok else "None.\n",
        "\n## Learning curves\n",
        *[f"![{p.stem}]({p.name})\n" for p in images["curves"]],
        "\n## Per-component final returns\n",
        "PPO learns the total reward with one head and logs no component returns (–).\n",
        markdown_table(tables["components"], ["task", "method", "component", "mean", "std"]),
        *[f"![{p.stem}]({p.name})\n" for p in images["components"]],
        "\n## Weight and rule timelines of scheduled runs\n",
        markdown_table(tables["rules"], ["task", "method", "rule", "decisions", "selector"]),
        *[f"![{p.stem}]({p.name})\n" for p in images["weights"]],
        "\n## Effective shares of scheduled runs\n",
        "share_k = w_k std(A_k) / sum_j w_j std(A_j), with A_k as mixed (after `ppo.component_scale`), logged every "
        "iteration. Movement: mean over seeds of the range of a component's per-period mean share (periods between "
        "decisions); seed noise: mean over frames of the share's std across seeds.\n",
        markdown_table(tables["shares"]) if tables["shares"] else "No run logged shares.\n",
        *[f"![{p.stem}]({p.name})\n" for p in images["shares"]],
        "\n## LLM calls\n",
        markdown_table(tables["llm"])
        if tables["llm"]
        else "No LLM calls in this sweep (llm=offline: the bandit stood in for the LLM selector).\n",
    ]
    return "\n".join(parts)
