#!/usr/bin/env bash
# Training cost of the shipped student's recipe on 2 cores, run back to back on an otherwise idle machine:
# 300 steps of global batch 32 on the DDG depth of the 1000 demos, as one process with 2 intra-op threads and
# as `torchrun --nproc_per_node 2` with 1 thread per rank. Prints seconds, steps/s and peak RSS per rank.
set -euo pipefail
demos=${1:-runs/sim/demos_seen.zarr}
recipe=(--demos "$demos" --depth-source ddg --steps 300 --batch 32 --lr 1e-4 --warmup 200 --width 16
        --head-dims 32 64 128 --ckpt-every 1000)
rm -rf runs/student/cost_single runs/student/cost_ddp
OMP_NUM_THREADS=2 python -m trainer student fit "${recipe[@]}" --out runs/student/cost_single --threads 2 > /dev/null 2>&1
OMP_NUM_THREADS=1 python -m torch.distributed.run --standalone --nproc_per_node 2 -m trainer student fit \
    "${recipe[@]}" --out runs/student/cost_ddp --threads 1 > /dev/null 2>&1
for run in cost_single cost_ddp; do
    python - "runs/student/$run/summary.json" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
print(f"{sys.argv[1]}: {s['world_size']} process(es), {s['seconds']:.1f} s for {s['steps_this_run']} steps "
      f"({s['steps_this_run'] / s['seconds']:.2f} steps/s), peak RSS per rank {s['peak_rss_mb_per_rank']} MB, "
      f"ranks in sync {s['ranks_in_sync']}")
PY
done
