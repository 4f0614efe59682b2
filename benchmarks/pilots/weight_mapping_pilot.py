"""Pilot for issue 13's defaults: which weight mapping / component scale lets the schedule move the
effective shares without hurting learning. Reads run directories ``<grid>/<variant>/seed_<s>`` (written by
``python -m torchrl_ahrs.train ... hydra.run.dir=<grid>/<variant>/seed_<s>``) and prints one Markdown row per
variant: final return and normalised AUC (mean over seeds), the shares' movement between decisions (max and
mean over components, mean over seeds) and their seed-to-seed noise.

    python benchmarks/pilots/weight_mapping_pilot.py /tmp/ahrs_meas/grid
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from torchrl_ahrs.app.train.runs import load_run
from torchrl_ahrs.reporting.stats import movement_and_noise, normalised_auc


def main(grid: Path) -> None:
    print("| variant | seeds | final return | AUC | share movement max / mean | share seed noise | decisions |")
    print("|---|---|---|---|---|---|---|")
    for variant in sorted(p for p in grid.iterdir() if p.is_dir()):
        runs = [load_run(p) for p in sorted(variant.glob("seed_*")) if (p / "checkpoint.pt").is_file()]
        runs = [r for r in runs if r.ok or r.status == "too few metric rows"]
        if not runs:
            continue
        finals = [r.final_return for r in runs]
        aucs = [normalised_auc(*r.curves["return/total"]) for r in runs]
        components = [n.split("/", 1)[1] for n in runs[0].curves if n.startswith("share/")]
        moves, noises = [], []
        for component in components:
            entries = [
                (*r.curves[f"share/{component}"], [d["frames"] for d in r.decisions if d.get("applied")]) for r in runs
            ]
            move, noise = movement_and_noise(entries)
            moves.append(move)
            noises.append(noise)
        decisions = np.mean([sum(bool(d.get("applied")) for d in r.decisions) for r in runs])
        move_text = f"{np.nanmax(moves):.3f} / {np.nanmean(moves):.3f}" if len(components) > 1 else "–"
        noise_text = f"{np.nanmean(noises):.3f}" if len(runs) > 1 and len(components) > 1 else "–"
        print(
            f"| {variant.name} | {' '.join(str(r.seed) for r in runs)} | {np.mean(finals):.1f} "
            f"({' '.join(f'{f:.0f}' for f in finals)}) | {np.mean(aucs):.1f} | {move_text} | {noise_text} | {decisions:.0f} |"
        )


if __name__ == "__main__":
    main(Path(sys.argv[1]))
