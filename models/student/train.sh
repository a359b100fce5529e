#!/usr/bin/env bash
# The recorded commands that produced models/student.onnx (the DDG student: step 2's GT student fine-tuned on
# DDG depth in step 4) and the runs measured beside it: the GT student (step 2) and a control without the object loss.
# Run from the repository root; everything lands in runs/ (git-ignored) except the shipped files.
set -euo pipefail
export OMP_NUM_THREADS=1

# 1. Demos: 1000 scripted-expert episodes over the six seen kinds (seeds 0..1001; 2 failed, counted, not stored).
python -m trainer collect --episodes 1000 --objects seen --workers 2 --out runs/sim/demos_seen.zarr
# 2. The student on GT depth with the auxiliary object loss (the default --object-loss 1): 16000 steps, then
#    resumed to 26000 (the cosine schedule restarts from its value at 16000/26000 of the longer run).
for steps in 16000 26000; do
    python -m trainer student fit --demos runs/sim/demos_seen.zarr --depth-source gt --out runs/student/gt_1000_obj1 \
        --object-loss 1 --steps "$steps" --batch 32 --lr 3e-4 --warmup 200 --width 16 --head-dims 32 64 128 \
        --threads 1 --ckpt-every 1000
done
python -m export runs/student/gt_1000_obj1/ckpt.pt --ddim-steps 4 --out runs/student/gt_1000_obj1.onnx
# 3. DDG depth for every demo frame (the shipped DDG, models/ddg, at DDIM 5; resumes by chunk if interrupted).
python -m trainer ddg generate --demos runs/sim/demos_seen.zarr --steps 5 --threads 2 --batch 16
# 4. The DDG student: the GT student fine-tuned on DDG depth (--init: its EMA weights and normalisers, a fresh
#    optimiser and schedule), 8000 steps at lr 1e-4 on 2 threads, then resumed to 20000 on one thread.
for run in "8000 2" "20000 1"; do
    set -- $run
    python -m trainer student fit --demos runs/sim/demos_seen.zarr --depth-source ddg --out runs/student/ddg2_ft_20k \
        --init runs/student/gt_1000_obj1/ckpt.pt --object-loss 1 --steps "$1" --batch 32 --lr 1e-4 --warmup 200 \
        --width 16 --head-dims 32 64 128 --threads "$2" --ckpt-every 1000
done
python -m export runs/student/ddg2_ft_20k/ckpt.pt --ddim-steps 4 --out runs/student/ddg2_ft_20k.onnx
cp runs/student/ddg2_ft_20k.onnx models/student.onnx
# 5. Control: the same data and the same first 16000 steps on GT depth without the object loss.
python -m trainer student fit --demos runs/sim/demos_seen.zarr --depth-source gt --out runs/student/gt_1000_obj0 \
    --object-loss 0 --steps 16000 --batch 32 --lr 3e-4 --warmup 200 --width 16 --head-dims 32 64 128 \
    --threads 1 --ckpt-every 1000
python -m export runs/student/gt_1000_obj0/ckpt.pt --ddim-steps 4 --out runs/student/gt_1000_obj0.onnx
