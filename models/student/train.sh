#!/usr/bin/env bash
# The recorded commands that produced models/student.onnx (the `ddg` student) and the `gt` student
# measured beside it. Run from the repository root; everything lands in runs/student/ (git-ignored) except
# the shipped files. Both students: same 120 demos, same seed, same architecture, same 5000-step budget.
set -euo pipefail
export OMP_NUM_THREADS=1

# 1. Demos: 120 scripted-expert episodes over the six seen kinds (seeds 0..119).
python -m trainer collect --episodes 120 --objects seen --workers 1 --out runs/student/demos_120.zarr
# 2. DDG depth for every demo frame (shipped DDG, models/ddg; DDIM 5; grafted and ungrafted).
python -m trainer ddg generate --demos runs/student/demos_120.zarr --steps 5 --threads 1 --batch 8
# 3. The two students (1 thread each; they were trained side by side on the 2 cores).
# Trained to 5000 steps, evaluated, then resumed to 10000 (the cosine schedule restarts from its value
# at 5000/10000 of the longer run: a warm restart), exactly as the two commands below do.
for source in gt ddg; do
    for steps in 5000 10000; do
        python -m trainer student fit --demos runs/student/demos_120.zarr --depth-source "$source" \
            --out "runs/student/${source}_120" --steps "$steps" --batch 32 --lr 3e-4 --warmup 200 --width 16 \
            --head-dims 32 64 128 --threads 1 --ckpt-every 500
    done
    python -m export "runs/student/${source}_120/ckpt.pt" --ddim-steps 4 --out "runs/student/${source}_120.onnx"
done
cp runs/student/ddg_120.onnx models/student.onnx
