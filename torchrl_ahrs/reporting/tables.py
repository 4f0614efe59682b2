"""Rows of the report's tables (plain dicts, one per CSV line) and their Markdown rendering."""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from typing import Any

import numpy as np

from torchrl_ahrs.reporting.intervals import improvement_probability, iqm_interval, mean_interval
from torchrl_ahrs.reporting.records import Run, method_rank
from torchrl_ahrs.reporting.stats import (
    change_percent,
    frames_to_threshold,
    mean_std,
    movement_and_noise,
    normalised_auc,
)

SPEED_FRACTION = 0.9  # "frames to 90 % of PPO's plateau"

BASELINE = "ppo"
CRITIC_CONTROL = "mcppo"  # K heads, equal weights, no schedule: the critic alone
# the contrasts named before the experiment ran (benchmarks/RESULTS.md, "Faithful defaults"): (X, Y, what X - Y tests)
CONTRASTS = (
    ("mcppo", "ppo", "the critic"),
    ("hdppo", "mcppo", "a fixed rule"),
    ("ahrs_wo_a[bandit]", "mcppo", "selection (by the bandit)"),
    ("ahrs_wo_a[bandit]", "ahrs_r", "informed vs random choice"),
)


def cells(runs: list[Run]) -> dict[tuple[str, str], list[Run]]:
    """Runs grouped by (task, method), tasks alphabetically, methods in the paper's order."""
    grouped: dict[tuple[str, str], list[Run]] = defaultdict(list)
    for run in runs:
        grouped[(run.task, run.method)].append(run)
    return dict(sorted(grouped.items(), key=lambda item: (item[0][0], method_rank(item[0][1]))))


def summary_rows(runs: list[Run]) -> list[dict[str, Any]]:
    """One row per (task, method): final return over the finished seeds (mean, sample std, the mean's and the
    IQM's stratified-bootstrap 95 % intervals from rliable) and its change against PPO's mean on the same task
    in % of |PPO|; the same
    mean, std and change for the final native reward per step (``reward_per_step_*``), which counts every
    frame where a return counts only the episodes that ended."""
    rows: list[dict[str, Any]] = []
    for (task, method), group in cells(runs).items():
        finals = [r.final_return for r in group if r.ok]
        per_step = [r.final.get("reward/total", math.nan) for r in group if r.ok]
        mean, std = mean_std(finals)
        per_step_mean, per_step_std = mean_std(per_step)
        _, low, high = mean_interval(finals)
        iqm, iqm_low, iqm_high = iqm_interval(finals)
        rows.append(
            {
                "task": task,
                "method": method,
                "seeds_ok": len(finals),
                "seeds_not_ok": sum(not r.ok for r in group),
                "mean": mean,
                "std": std,
                "ci95_low": low,
                "ci95_high": high,
                "iqm": iqm,
                "iqm_ci95_low": iqm_low,
                "iqm_ci95_high": iqm_high,
                "reward_per_step_mean": per_step_mean,
                "reward_per_step_std": per_step_std,
                "seeds": " ".join(str(r.seed) for r in group if r.ok),
                "total_frames": " ".join(str(f) for f in sorted({r.total_frames for r in group if r.ok})),
            }
        )
    for metric in ("", "reward_per_step_"):  # the final return, the final reward per step
        baselines = {row["task"]: row[metric + "mean"] for row in rows if row["method"] == BASELINE}
        for row in rows:
            row[metric + "change_vs_ppo_pct"] = change_percent(
                row[metric + "mean"], baselines.get(row["task"], math.nan)
            )
    _add_speed(rows, runs, {row["task"]: row["mean"] for row in rows if row["method"] == BASELINE})
    return rows


def contrast_rows(runs: list[Run]) -> list[dict[str, Any]]:
    """Per task: the named :data:`CONTRASTS`, then every arm against PPO and against the critic-alone control:
    the probability of improvement ``P(X > Y)`` of the final return with its 95 % interval (rliable), the IQM
    difference, and the verdict: an effect when the interval excludes 0.5, else no measurable difference."""
    rows: list[dict[str, Any]] = []
    finals: dict[tuple[str, str], list[float]] = defaultdict(list)
    for run in runs:
        if run.ok:
            finals[(run.task, run.method)].append(run.final_return)
    for task in sorted({task for task, _ in finals}):
        methods = sorted({m for t, m in finals if t == task}, key=method_rank)
        pairs = [(x, y, why) for x, y, why in CONTRASTS if x in methods and y in methods]
        for control in (BASELINE, CRITIC_CONTROL):
            for method in methods:
                seen = {frozenset((x, y)) for x, y, _ in pairs}  # a contrast and its mirror are one question
                if control in methods and method != control and frozenset((method, control)) not in seen:
                    pairs.append((method, control, f"{method} against {control}"))
        for x, y, why in pairs:
            p, low, high = improvement_probability(np.array(finals[(task, x)]), np.array(finals[(task, y)]))
            verdict = "X better" if low > 0.5 else "Y better" if high < 0.5 else "no measurable difference"
            rows.append(
                {
                    "task": task,
                    "x": x,
                    "y": y,
                    "tests": why,
                    "seeds_x": len(finals[(task, x)]),
                    "seeds_y": len(finals[(task, y)]),
                    "iqm_x_minus_y": iqm_interval(np.array(finals[(task, x)]))[0]
                    - iqm_interval(np.array(finals[(task, y)]))[0],
                    "p_x_better": p,
                    "p_ci95_low": low,
                    "p_ci95_high": high,
                    "verdict": verdict if math.isfinite(p) else "",
                }
            )
    return rows


def speed_threshold(runs: list[Run], task: str, plateau: float) -> float:
    """``r0 + 0.9 (P - r0)``: r0 = mean first logged ``return/total`` of the task's finished runs (the
    random-policy level), P = PPO's mean final return on the task (its plateau)."""
    firsts = [r.curves["return/total"][1][0] for r in runs if r.ok and r.task == task and "return/total" in r.curves]
    if not firsts or not math.isfinite(plateau):
        return math.nan
    start = float(np.mean(firsts))
    return start + SPEED_FRACTION * (plateau - start)  # r0 + 0.9 (P - r0)


def _add_speed(rows: list[dict[str, Any]], runs: list[Run], baselines: dict[Any, Any]) -> None:
    """Early-learning speed per (task, method): normalised AUC (mean ± std over seeds) and frames to
    90 % of PPO's plateau (mean over the seeds that reached it, and how many did)."""
    for row in rows:
        group = [r for r in runs if r.ok and r.task == row["task"] and r.method == row["method"]]
        curves = [r.curves["return/total"] for r in group if "return/total" in r.curves]
        aucs = [normalised_auc(steps, values) for steps, values in curves]
        row["auc_mean"], row["auc_std"] = mean_std(aucs)
        threshold = speed_threshold(runs, row["task"], baselines.get(row["task"], math.nan))
        reached = [f for f in (frames_to_threshold(s, v, threshold) for s, v in curves) if math.isfinite(f)]
        row["frames_to_90pct_ppo"] = float(np.mean(reached)) if reached else math.nan
        row["reached_90pct_ppo"] = f"{len(reached)}/{len(curves)}"


def share_rows(runs: list[Run]) -> list[dict[str, Any]]:
    """Per scheduled (task, method, component): the effective share's movement between decisions
    against its seed-to-seed noise (see :func:`~torchrl_ahrs.reporting.stats.movement_and_noise`)."""
    rows = []
    for (task, method), group in cells([r for r in runs if r.ok and r.scheduled]).items():
        components = [name.split("/", 1)[1] for name in group[0].curves if name.startswith("share/")]
        for component in components:
            entries = [
                (*r.curves[f"share/{component}"], [d["frames"] for d in r.decisions if d.get("applied")])
                for r in group
                if f"share/{component}" in r.curves
            ]
            movement, noise = movement_and_noise(entries)
            final = [float(np.mean(values[-max(1, len(values) // 10) :])) for _, values, _ in entries]
            rows.append(
                {
                    "task": task,
                    "method": method,
                    "component": component,
                    "final_share": float(np.mean(final)) if final else math.nan,
                    "movement": movement,
                    "seed_noise": noise,
                    "moves_beyond_noise": bool(movement > noise) if math.isfinite(noise) else "",
                    "decisions_per_run": float(np.mean([len(e[2]) for e in entries])) if entries else 0.0,
                }
            )
    return rows


def run_rows(runs: list[Run]) -> list[dict[str, Any]]:
    """One row per run (or missing seed): status, reason, frames, final return and its components."""
    rows = []
    for run in runs:
        row = {
            "task": run.task,
            "method": run.method,
            "seed": run.seed,
            "status": run.status,
            "reason": run.reason,
            "collected_frames": run.collected_frames,
            "total_frames": run.total_frames,
            "final_return": run.final_return,
            "path": run.where,
        }
        for component in run.components:
            row[f"final_return/{component}"] = run.final.get(f"return/{component}", math.nan)
        rows.append(row)
    return rows


def component_rows(runs: list[Run]) -> list[dict[str, Any]]:
    """One row per (task, method, component): the component's final return over finished seeds."""
    rows = []
    for (task, method), group in cells(runs).items():
        finished = [r for r in group if r.ok]
        for component in dict.fromkeys(c for r in finished for c in r.components):
            mean, std = mean_std([r.final.get(f"return/{component}", math.nan) for r in finished])
            rows.append({"task": task, "method": method, "component": component, "mean": mean, "std": std})
    return rows


def rule_rows(runs: list[Run]) -> list[dict[str, Any]]:
    """One row per (task, method, rule): how often the scheduler applied it, over all seeds, and which
    selector decided (``selector`` and ``note`` of the decisions, e.g. the offline bandit standing in)."""
    rows = []
    for (task, method), group in cells(runs).items():
        decisions = [d for r in group if r.scheduled for d in r.decisions]
        if not decisions:
            continue
        counts = Counter(d.get("rule") or "(no change)" for d in decisions)
        selectors = sorted({str(d.get("selector")) for d in decisions})
        for rule, count in counts.most_common():
            rows.append(
                {"task": task, "method": method, "rule": rule, "decisions": count, "selector": " ".join(selectors)}
            )
    return rows


def llm_rows(runs: list[Run]) -> list[dict[str, Any]]:
    """One row per (task, method) that made LLM calls: calls, failures (no answer or an unparsable one),
    latency, tokens and cost summed over seeds."""
    rows = []
    for (task, method), group in cells(runs).items():
        calls = [c for r in group for c in r.llm_calls]
        if not calls:
            continue
        latency = np.asarray([float(c.get("latency") or 0.0) for c in calls])
        costs = [c["cost"] for c in calls if c.get("cost") is not None]
        rows.append(
            {
                "task": task,
                "method": method,
                "calls": len(calls),
                "failures": sum(bool(c.get("error") or c.get("parse_error")) for c in calls),
                "latency_mean_s": float(latency.mean()),
                "latency_max_s": float(latency.max()),
                "prompt_tokens": sum(int((c.get("tokens") or {}).get("prompt_tokens", 0)) for c in calls),
                "completion_tokens": sum(int((c.get("tokens") or {}).get("completion_tokens", 0)) for c in calls),
                "cost_usd": float(sum(costs)) if costs else math.nan,
            }
        )
    return rows


def fmt(value: Any, digits: int = 2) -> str:
    """A number for a Markdown cell ("–" for NaN)."""
    if isinstance(value, float):
        return "–" if not math.isfinite(value) else f"{value:.{digits}f}"
    return str(value)


def markdown_table(rows: list[dict[str, Any]], columns: list[str] | None = None) -> str:
    """``rows`` as a GitHub Markdown table (columns default to the first row's keys)."""
    if not rows:
        return "(none)\n"
    columns = columns or list(rows[0])
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(fmt(row.get(c, "")) for c in columns) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def paper_table(summary: list[dict[str, Any]], metric: str = "", digits: int = 2) -> str:
    """Tables I-II of the paper: tasks as rows, methods as columns, cells "mean ± std (Δ% vs PPO)" of the
    summary's ``{metric}mean``, ``{metric}std`` and ``{metric}change_vs_ppo_pct`` (``metric=""``: the final
    return; ``"reward_per_step_"``: the final reward per step)."""
    tasks = sorted({row["task"] for row in summary})
    methods = sorted({row["method"] for row in summary}, key=method_rank)
    cell = {(row["task"], row["method"]): row for row in summary}
    lines = ["| task | " + " | ".join(methods) + " |", "|---|" + "---|" * len(methods)]
    for task in tasks:
        entries = []
        for method in methods:
            row = cell.get((task, method))
            if row is None or row["seeds_ok"] == 0:
                entries.append("–")
                continue
            text = f"{fmt(row[metric + 'mean'], digits)} ± {fmt(row[metric + 'std'], digits)}"
            change = row[metric + "change_vs_ppo_pct"]
            if method != BASELINE and math.isfinite(change):
                text += f" ({change:+.1f} %)"
            if row["seeds_not_ok"]:
                text += f" [{row['seeds_ok']} seeds]"
            entries.append(text)
        lines.append(f"| {task} | " + " | ".join(entries) + " |")
    return "\n".join(lines) + "\n"
