#!/usr/bin/env bash
# Trains and evaluates one arm on several seeds, one after another, resuming where an earlier call stopped.
#
#   benchmarks/learning/run_seeds.sh [--eval "<evaluate overrides>"] <results dir> <name> "<train overrides>" <seed> ...
#
# e.g. one lane of RESULTS round 37 (start several lanes with & for runs side by side, each with
# trainer.torch_threads=1 among its overrides: Cassie's preset gives a lone run both cores' threads):
#   benchmarks/learning/run_seeds.sh benchmarks/results/issue26_probes \
#       cassie_r37_ahrs_anchored_mirror_kl004_progress_half_klactor \
#       "method=ahrs ppo.mix=anchored ppo.mirror=true ppo.kl_target=0.04 trainer.total_frames=2500000
#        trainer.num_envs=128 ppo.kl_adapts=actor aux.path=benchmarks/pilots/aux/cassie_progress.py aux.scale=0.5" \
#       4 5 9
#
# Per seed s, the run directory is <results dir>/<name>_s<s>:
#   - evaluated at both evaluation seeds (evaluation.json and evaluation_seed2027.json): skipped;
#   - finished (finished.json): evaluated only;
#   - with a checkpoint.pt: continued with `train resume=<dir>`, then evaluated;
#   - otherwise: trained from scratch (a directory left without a checkpoint is removed first), then evaluated.
# Evaluations: `python -m torchrl_ahrs.evaluate run=<dir>` (seed 12345) and the held-out seed 2027, each with the
# --eval overrides (e.g. `+task.commands.resampling_time_s=10.0` to score a run trained on another command schedule
# on the task as defined). Console output
# goes to <dir>.err (training) and <dir>/evaluate*.txt; run from the repository root with the package installed.
# A command that fails stops the lane there (set -e), its output in those files; calling again retries that seed.
set -euo pipefail
evaluate_overrides=""
if [ "${1:-}" = "--eval" ] && [ $# -ge 2 ]; then
  evaluate_overrides=$2
  shift 2
fi
if [ $# -lt 4 ]; then
  echo "usage: $0 [--eval \"<evaluate overrides>\"] <results dir> <name> \"<train overrides>\" <seed> [<seed> ...]" >&2
  exit 2
fi
results=$1 name=$2 overrides=$3
shift 3
mkdir -p "$results"
for seed in "$@"; do
  run="$results/${name}_s$seed"
  if [ -f "$run/evaluation.json" ] && [ -f "$run/evaluation_seed2027.json" ]; then
    continue
  fi
  if [ ! -f "$run/finished.json" ]; then
    if [ -f "$run/checkpoint.pt" ]; then
      python -m torchrl_ahrs.train resume="$run" trainer.progress_bar=false >>"$run.err" 2>&1
    else
      rm -rf "$run"
      # shellcheck disable=SC2086  # the overrides are words on purpose
      python -m torchrl_ahrs.train $overrides seed="$seed" trainer.progress_bar=false hydra.run.dir="$run" >"$run.err" 2>&1
    fi
  fi
  # shellcheck disable=SC2086  # as above
  [ -f "$run/evaluation.json" ] || python -m torchrl_ahrs.evaluate run="$run" $evaluate_overrides >"$run/evaluate.txt" 2>&1
  # shellcheck disable=SC2086
  [ -f "$run/evaluation_seed2027.json" ] ||
    python -m torchrl_ahrs.evaluate run="$run" seed=2027 output=evaluation_seed2027.json $evaluate_overrides \
      >"$run/evaluate_seed2027.txt" 2>&1
done
