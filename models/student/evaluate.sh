#!/usr/bin/env bash
# The recorded evaluation behind models/student/README.md: closed-loop success in the simulated world through
# the runtime's own preprocessing and onnxruntime path (`trainer evaluate`, never torch). Seeds 10000+ (the
# evaluator's default), disjoint from the demo seeds 0..119. Usage: evaluate.sh STUDENT(gt|ddg) CELL...
# where CELL is clean_seen | clean_unseen | ddg_seen | ddg_unseen | k<K>_seen.
set -euo pipefail
export OMP_NUM_THREADS=1
student=$1; shift
out=runs/student/eval; mkdir -p "$out"
for cell in "$@"; do
    sensor=${cell%_*}; objects=${cell#*_}; model="runs/student/${student}_120.onnx"; episodes=200
    case $sensor in
        ddg) episodes=24 ;;                                  # DDG sensor: ~0.27 s per frame on one core
        k*) model="runs/student/${student}_120_${sensor}.onnx"; episodes=60
            [ -f "$model" ] || python -m export "runs/student/${student}_120/ckpt.pt" --ddim-steps "${sensor#k}" --out "$model"
            sensor=clean ;;
    esac
    python -m trainer evaluate --policy "student:$model" --objects "$objects" --sensor "$sensor" \
        --episodes "$episodes" --workers 1 --json "$out/${student}_${cell}.json" > "$out/${student}_${cell}.log" 2>&1
    tail -1 "$out/${student}_${cell}.log"
done
