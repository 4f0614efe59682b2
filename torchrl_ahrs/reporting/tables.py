"""Rows of the report's tables (plain dicts, one per CSV line) and their Markdown rendering."""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from typing import Any

import numpy as np

from torchrl_ahrs.reporting.records import Run, method_rank
from torchrl_ahrs.reporting.stats import bootstrap_ci, change_percent, interquartile_mean, mean_std

BASELINE = "ppo"


def cells(runs: list[Run]) -> dict[tuple[str, str], list[Run]]:
    """Runs grouped by (task, method), tasks alphabetically, methods in the paper's order."""
    grouped: dict[tuple[str, str], list[Run]] = defaultdict(list)
    for run in runs:
        grouped[(run.task, run.method)].append(run)
    return dict(sorted(grouped.items(), key=lambda item: (item[0][0], method_rank(item[0][1]))))


def summary_rows(runs: list[Run]) -> list[dict[str, Any]]:
    """One row per (task, method): final return over the finished seeds (mean, sample std, bootstrap
    95 % CI of the mean, IQM) and its change against PPO's mean on the same task in % of |PPO|."""
    rows: list[dict[str, Any]] = []
    for (task, method), group in cells(runs).items():
        finals = [r.final_return for r in group if r.ok]
        mean, std = mean_std(finals)
        low, high = bootstrap_ci(finals)
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
                "iqm": interquartile_mean(finals),
                "seeds": " ".join(str(r.seed) for r in group if r.ok),
                "total_frames": " ".join(str(f) for f in sorted({r.total_frames for r in group if r.ok})),
            }
        )
    baselines = {row["task"]: row["mean"] for row in rows if row["method"] == BASELINE}
    for row in rows:
        row["change_vs_ppo_pct"] = change_percent(row["mean"], baselines.get(row["task"], math.nan))
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


def paper_table(summary: list[dict[str, Any]]) -> str:
    """Tables I-II of the paper: tasks as rows, methods as columns, cells "mean ± std (Δ% vs PPO)"."""
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
            text = f"{fmt(row['mean'])} ± {fmt(row['std'])}"
            if method != BASELINE and math.isfinite(row["change_vs_ppo_pct"]):
                text += f" ({row['change_vs_ppo_pct']:+.1f} %)"
            if row["seeds_not_ok"]:
                text += f" [{row['seeds_ok']} seeds]"
            entries.append(text)
        lines.append(f"| {task} | " + " | ".join(entries) + " |")
    return "\n".join(lines) + "\n"
