#!/usr/bin/env bash
# The recorded commands that produced models/student.onnx (step 6: the best recipe's GT student fine-tuned on
# DDG depth) and the first recipe before it (steps 2-5: the GT student that research/student_v1/table2.sh starts
# from, the first DDG student, a control without the object loss).
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
# 5. Control: the same data and the same first 16000 steps on GT depth without the object loss.
python -m trainer student fit --demos runs/sim/demos_seen.zarr --depth-source gt --out runs/student/gt_1000_obj0 \
    --object-loss 0 --steps 16000 --batch 32 --lr 3e-4 --warmup 200 --width 16 --head-dims 32 64 128 \
    --threads 1 --ckpt-every 1000
python -m export runs/student/gt_1000_obj0/ckpt.pt --ddim-steps 4 --out runs/student/gt_1000_obj0.onnx
# 6. The shipped student, the best recipe (docs/student.md from "The oracle" on): the demos grown to 6000, a GT
#    student given the hand's pose and the object's offset from it, 36000 + 12000 steps (`sixk`); then 8000 +
#    12000 steps from it on the shipped DDG's depth of the first 1000 demos (DDIM 5), executing 4 of each
#    chunk, and its measures (`ddga6k`).
research/student_v1/table2.sh sixk
research/student_v1/table2.sh ddga6k
cp runs/student/ddga6k_hpos_more_12k_x4.onnx models/student.onnx
