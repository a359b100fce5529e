#!/usr/bin/env bash
# The recorded evaluation behind models/student/README.md: closed-loop success in the simulated world through
# the runtime's own preprocessing and onnxruntime path (`trainer evaluate`, never torch). Seeds 10000+ (the
# evaluator's default), disjoint from the demo seeds 0..1001.
# Usage: [SENSOR=spec] [WORKERS=n] evaluate.sh ONNX EPISODES OBJECTS...   e.g. evaluate.sh models/student.onnx 200 seen unseen
# SENSOR is any `trainer evaluate --sensor` spec (default clean; the DDG cells use SENSOR=ddg:steps=5, the
# DDIM steps of the generated training depth).
set -euo pipefail
export OMP_NUM_THREADS=1
model=$1; episodes=$2; shift 2
sensor=${SENSOR:-clean}
out=runs/student/eval; mkdir -p "$out"
for objects in "$@"; do
    name="$(basename "${model%.onnx}")_${sensor%%:*}_${objects}_${episodes}"
    python -m trainer evaluate --policy "student:$model" --objects "$objects" --sensor "$sensor" \
        --episodes "$episodes" --workers "${WORKERS:-2}" --json "$out/$name.json" > "$out/$name.log" 2>&1
    tail -1 "$out/$name.log"
done
