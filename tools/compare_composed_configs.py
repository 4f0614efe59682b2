"""Compares the composed config of every task x method between two checkouts of the repository (a config
refactor, such as moving task keys into ``conf/task/_*.yaml`` bases, must leave every composed value as it was).

Usage (each run composes from the ``torchrl_ahrs.conf`` package that the python of that checkout imports)::

    python tools/compare_composed_configs.py dump before.json     # on the old checkout
    python tools/compare_composed_configs.py dump after.json      # on the new one
    python tools/compare_composed_configs.py compare before.json after.json

``compare`` prints, for each distinct difference, how many configs have it and for which tasks
(``IDENTICAL`` when none); key order is reported separately (it does not change a value).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

MJX_TASKS = ("ant", "cassie", "quadcopter")


def dump(path: str) -> None:
    import torchrl_ahrs.conf
    from hydra import compose, initialize_config_module
    from omegaconf import OmegaConf

    conf = Path(torchrl_ahrs.conf.__file__).parent
    tasks = sorted(p.stem for p in (conf / "task").glob("*.yaml") if not p.stem.startswith("_"))
    methods = sorted(p.stem for p in (conf / "method").glob("*.yaml"))
    composed = {}
    with initialize_config_module(config_module="torchrl_ahrs.conf", version_base="1.3"):
        for task in tasks:
            for method in methods:
                for extra in [[], *([["task.backend=mjx"]] if task in MJX_TASKS else [])]:
                    cfg = compose(config_name="config", overrides=[f"task={task}", f"method={method}", *extra])
                    composed[" ".join([task, method, *extra])] = OmegaConf.to_container(cfg, resolve=True)
    Path(path).write_text(json.dumps(composed))
    print(f"{len(composed)} composed configs of {len(tasks)} tasks x {len(methods)} methods -> {path}")


def differences(before: Any, after: Any, prefix: str = "") -> list[str]:
    """``+key=value`` (added), ``-key`` (removed), ``~key: old -> new`` (changed), depth first."""
    if isinstance(before, dict) and isinstance(after, dict):
        found = []
        for key in sorted(set(before) | set(after)):
            if key not in before:
                found.append(f"+{prefix}{key}={after[key]!r}")
            elif key not in after:
                found.append(f"-{prefix}{key}")
            else:
                found += differences(before[key], after[key], f"{prefix}{key}.")
        return found
    return (
        [] if before == after and type(before) is type(after) else [f"~{prefix.rstrip('.')}: {before!r} -> {after!r}"]
    )


def compare(before_path: str, after_path: str) -> int:
    before, after = json.loads(Path(before_path).read_text()), json.loads(Path(after_path).read_text())
    if before.keys() != after.keys():
        print("configs only on one side:", sorted(set(before) ^ set(after)))
        return 1
    groups: dict[tuple[str, ...], list[str]] = {}
    reordered = 0
    for key in before:
        found = tuple(differences(before[key], after[key]))
        groups.setdefault(found, []).append(key)
        reordered += not found and list(before[key]["task"]) != list(after[key]["task"])
    for found, keys in groups.items():
        tasks = sorted({" ".join(k.split()[:1] + (["(mjx)"] if "mjx" in k else [])) for k in keys})
        print(f"{len(keys)} configs: {', '.join(found) or 'IDENTICAL'}; tasks: {', '.join(tasks)}")
    print(f"task keys in another order (values equal): {reordered}")
    return 0


if __name__ == "__main__":
    if sys.argv[1:2] == ["dump"] and len(sys.argv) == 3:
        dump(sys.argv[2])
    elif sys.argv[1:2] == ["compare"] and len(sys.argv) == 4:
        sys.exit(compare(sys.argv[2], sys.argv[3]))
    else:
        sys.exit(__doc__)
