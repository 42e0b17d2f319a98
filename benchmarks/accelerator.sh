#!/usr/bin/env bash
# The accelerator check, one prepared script (about 8 minutes on one GPU): the shipped
# models load, the geodesic solvers side by side on the accelerator, exploration and
# rollout throughput at a large batch (accelerator, and the CPU of the same machine), and
# the paper model's plan latency and batched throughput. Figures go to $OUT (default
# runs/accelerator) as logs and JSON; copy them into docs/benchmarks.md.
#
#   bash benchmarks/accelerator.sh                  # BATCH=1024 HOUSES=64 by default
#   BATCH=8 HOUSES=4 bash benchmarks/accelerator.sh # a quick dry run on a CPU
set -uo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-runs/accelerator}
BATCH=${BATCH:-1024}
HOUSES=${HOUSES:-64}
STEP_S=${STEP_S:-240}  # no step may take longer than this
mkdir -p "$OUT"
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
LOG="$OUT/accelerator.log"
: >"$LOG"
step() {  # step NAME COMMAND...: run, log, never stop the script
  echo "## $1  ($(date -u +%H:%M:%S))" | tee -a "$LOG"
  shift
  timeout "$STEP_S" "$@" 2>&1 | grep -v -e "^WARNING" -e "^I0000" | tee -a "$LOG"
  echo "## exit ${PIPESTATUS[0]}" | tee -a "$LOG"
}
step devices python3 -c "import jax; print(jax.__version__, jax.devices())"
step load python3 -c "
from bfsop_jax.policy import StrategicPolicy
for name in ('demo', 'paper'):
    p = StrategicPolicy.load(name)
    import jax; print(name, 'loads on', jax.tree.leaves(p.params)[0].devices())"
step distance-relax python3 -m benchmarks.bench_distance --preset demo --repeats 10
step distance-sweeps env BFSOP_GEODESICS=sweeps python3 -m benchmarks.bench_distance \
  --preset demo --repeats 3 --houses 1
step explore python3 -m benchmarks.bench_explore --presets demo --houses "$HOUSES" \
  --batch "$BATCH" --json "$OUT/explore.json"
step explore-cpu env JAX_PLATFORMS=cpu python3 -m benchmarks.bench_explore --presets demo \
  --houses 32 --json "$OUT/explore_cpu.json"
step rollout python3 -m benchmarks.bench_rollout --preset demo --batch "$BATCH" \
  --houses "$HOUSES" --methods fbe,bfsop_st --json "$OUT/rollout.json"
step policy python3 -m benchmarks.bench_policy --model paper --preset demo --houses 1 \
  --batch "$BATCH"
echo "done $(date -u +%H:%M:%S)" | tee -a "$LOG"
