"""Finding and reading the run directories of a sweep into :class:`~torchrl_ahrs.reporting.records.Run`
records (no statistics, no plotting); file names from :mod:`torchrl_ahrs.app.shared.run_dir`.

A sweep directory holds one run directory per job, anywhere below it (``python -m torchrl_ahrs.sweep``
puts them at ``<task>/<method>/seed_<seed>``). A run directory is recognised by ``config.yaml`` (written by
``train`` at start) or ``.hydra/config.yaml`` (written by Hydra before the job runs, so a job that crashed
before training is still found). Each run gets a status:

- ``ok``: ``checkpoint.pt`` holds ``collected_frames >= trainer.total_frames`` and ``return/total`` has at
  least one row in the final window (the last 10 % of the frame budget);
- ``incomplete``: no checkpoint, or one from before the end of the budget (crashed, killed, still running);
- ``too few metric rows``: finished, but no ``return/total`` row in the final window (no episode ended);
- ``missing``: a seed of the sweep's grid with no run directory at all.
"""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from torchrl_ahrs.app.shared.run_dir import CONFIG, HYDRA, MULTIRUN, PLAN, RunDirectory
from torchrl_ahrs.app.train.checkpoint import collected_frames
from torchrl_ahrs.reporting.records import Run, method_label, method_rank
from torchrl_ahrs.reporting.stats import final_return, final_window_mask


def read_scalar(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """A metric CSV file (rows ``step,value``; the ``step,value`` header of current runs, or none as in runs
    written before it, e.g. under ``benchmarks/results``) as (steps [R], values [R]), sorted by step.

    Example:
        >>> import tempfile
        >>> path = Path(tempfile.mkdtemp()) / "total.csv"
        >>> _ = path.write_text("step,value\\n200,2.0\\n100,1.0\\n")
        >>> read_scalar(path)
        (array([100., 200.]), array([1., 2.]))
    """
    steps, values = [], []
    with open(path) as handle:
        for row in csv.reader(handle):
            if len(row) >= 2 and row[0] != "step":
                steps.append(float(row[0]))
                values.append(float(row[1]))
    order = np.argsort(steps, kind="stable")
    return np.asarray(steps)[order], np.asarray(values)[order]


def read_jsonl(path: Path) -> list[dict[str, Any]]:
    """Every parsable JSON line of ``path`` (a truncated last line from a killed run is skipped)."""
    if not path.is_file():
        return []
    entries = []
    for line in path.read_text().splitlines():
        try:
            entries.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return entries


def load_run(path: Path) -> Run:
    """Reads one run directory (config, scalars, decisions, LLM calls) and decides its status."""
    directory = RunDirectory(path)
    config = yaml.safe_load(directory.saved_config.read_text()) or {}
    run = Run(
        path=path,
        task=str(config.get("task", {}).get("name", "?")),
        method=method_label(config),
        seed=int(config.get("seed", 0)),
        status="ok",
        total_frames=int(config.get("trainer", {}).get("total_frames", 0)),
        llm_name=str((config.get("llm", {}) or {}).get("name", "offline")),
    )
    scalars = directory.scalars
    for group in ("return", "weight", "share"):
        for csv_path in sorted((scalars / group).glob("*.csv")):
            run.curves[f"{group}/{csv_path.stem}"] = read_scalar(csv_path)
    reward_per_step = scalars / "reward" / "total.csv"  # the native reward per step over every frame of each batch
    if reward_per_step.is_file():
        run.curves["reward/total"] = read_scalar(reward_per_step)
    logged = [name.split("/", 1)[1] for name in run.curves if name.startswith("return/")]
    task_order = list(config.get("task", {}).get("components") or [])  # the task's K axis order first
    run.components = [c for c in task_order if c in logged] + [c for c in logged if c not in task_order]
    run.components = [c for c in run.components if c != "total"]
    for name, (steps, values) in run.curves.items():
        if name.startswith("return/") or name == "reward/total":
            run.final[name] = final_return(steps, values, run.total_frames)  # mean over the last 10 % of frames
    run.decisions = read_jsonl(directory.decisions)
    run.llm_calls = read_jsonl(directory.llm_calls)

    try:
        frames = collected_frames(path)  # finished.json, else the checkpoint
    except Exception as error:  # a torn or foreign checkpoint: the run cannot be trusted
        run.status, run.reason = "incomplete", f"unreadable checkpoint ({type(error).__name__})"
        return run
    run.collected_frames = frames or 0
    if frames is None:
        run.status, run.reason = "incomplete", f"no {directory.checkpoint.name} (crashed, killed or still running)"
    elif run.collected_frames < run.total_frames:
        run.status = "incomplete"
        run.reason = f"checkpoint at {run.collected_frames} of {run.total_frames} frames"
    else:
        steps = run.curves.get("return/total", (np.array([]), np.array([])))[0]
        rows = int(final_window_mask(steps, run.total_frames).sum())
        if rows == 0:
            run.status = "too few metric rows"
            run.reason = f"no return/total row after {0.9 * run.total_frames:.0f} frames ({len(steps)} rows in all)"
    return run


def find_run_dirs(sweep_dir: Path) -> list[Path]:
    """Every run directory below ``sweep_dir`` (:meth:`RunDirectory.is_run`); symbolic links are followed,
    so a sweep can be assembled from runs of other sweeps."""
    found = set()
    for root, _, files in os.walk(sweep_dir, followlinks=True):
        here = Path(root)
        if CONFIG in files:
            found.add(here.parent if here.name == HYDRA else here)
    return sorted(found)


def seed_list(spec: Any) -> list[int] | None:
    """Seeds written as Hydra sweeps them: ``1,2,3``, ``range(1,11)`` (stop excluded) or a YAML list; None
    when ``spec`` is none of these.

    Example:
        >>> seed_list("range(1,4)"), seed_list("7,8"), seed_list([2, 1])
        ([1, 2, 3], [7, 8], [1, 2])
    """
    if isinstance(spec, list):
        return sorted(int(seed) for seed in spec)
    text = str(spec).replace(" ", "")
    try:
        if text.startswith("range(") and text.endswith(")"):  # Hydra's range(start,stop[,step]) sweep
            return list(range(*(int(part) for part in text[6:-1].split(","))))
        return sorted(int(part) for part in text.split(","))
    except (TypeError, ValueError):
        return None


def expected_seeds(sweep_dir: Path) -> list[int] | None:
    """The seeds the sweep asked for, from Hydra's ``multirun.yaml`` (``hydra.sweeper.params.seed`` or a
    ``seed=a,b,c`` override); None when the file or the parameter is absent or not a plain list."""
    path = sweep_dir / MULTIRUN
    if not path.is_file():
        return None
    hydra = (yaml.safe_load(path.read_text()) or {}).get("hydra", {}) or {}
    spec = ((hydra.get("sweeper") or {}).get("params") or {}).get("seed")
    for override in (hydra.get("overrides") or {}).get("task") or []:
        if str(override).startswith("seed="):
            spec = str(override).split("=", 1)[1]
    return None if spec is None else seed_list(spec)


def planned_cells(sweep_dir: Path) -> set[tuple[str, str, int]] | None:
    """The (task, method, seed) cells of ``plan.yaml`` in the sweep directory, None without one.

    Hydra's ``multirun.yaml`` records only the last invocation, so a sweep directory filled by several
    (arms on 10 seeds, fixed rules on 5, later seeds added) cannot say which runs are missing; a plan can.
    Its format: ``cells:`` a list of ``{task, methods: [...], seeds: <a Hydra seed sweep or a list>}`` (quote a
    ``range(a,b)`` inside a YAML flow mapping, whose commas would split it).

    Example:
        >>> import tempfile
        >>> sweep = Path(tempfile.mkdtemp())
        >>> _ = (sweep / "plan.yaml").write_text("cells: [{task: ant, methods: [ppo], seeds: 'range(1,3)'}]")
        >>> sorted(planned_cells(sweep))
        [('ant', 'ppo', 1), ('ant', 'ppo', 2)]
    """
    path = sweep_dir / PLAN
    if not path.is_file():
        return None
    cells = set()
    for number, cell in enumerate((yaml.safe_load(path.read_text()) or {}).get("cells") or []):
        seeds = seed_list(cell.get("seeds")) if isinstance(cell, dict) else None
        if seeds is None or not cell.get("task") or not cell.get("methods"):
            raise ValueError(f"{path}: cell {number} needs task, methods and seeds (e.g. range(1,11)), got {cell!r}")
        cells |= {(str(cell["task"]), str(method), seed) for method in cell["methods"] for seed in seeds}
    return cells


def load_sweep(sweep_dirs: Path | list[Path]) -> list[Run]:
    """All runs of one sweep (or of several pooled, e.g. a sweep extended later with more seeds), plus a
    ``missing`` placeholder for every planned cell that no pooled sweep holds: the cells of the sweep's
    ``plan.yaml`` (:func:`planned_cells`) or, without one, every seed the sweep asked for (``multirun.yaml``;
    without it, the seeds its other cells have) in every (task, method) cell of that sweep."""
    sweep_dirs = [Path(sweep_dirs)] if isinstance(sweep_dirs, str | Path) else [Path(d) for d in sweep_dirs]
    runs, wanted = [], set()
    for sweep_dir in sweep_dirs:
        found = []
        for path in find_run_dirs(sweep_dir):
            found.append(load_run(path))
            found[-1].where = f"{sweep_dir.name}/{path.relative_to(sweep_dir)}"
        plan = planned_cells(sweep_dir)
        if plan is not None:
            wanted |= plan
        else:
            seeds = expected_seeds(sweep_dir) or sorted({run.seed for run in found})
            wanted |= {(run.task, run.method, seed) for run in found for seed in seeds}
        runs += found
    # a plan names methods as their configs do (ahrs_wo_a); a run's label may add who chose (ahrs_wo_a[bandit])
    present = {(run.task, name, run.seed) for run in runs for name in (run.method, run.method.split("[")[0])}
    for task, method, seed in sorted(wanted - present):
        runs.append(Run(None, task, method, seed, "missing", "no run directory for this seed"))
    return sorted(runs, key=lambda r: (r.task, method_rank(r.method), r.seed))
