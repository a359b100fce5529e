#!/usr/bin/env bash
# A clean-depth feature teacher for the ceiling's readout (issue 45, docs/table2.md): every store keeps the clean
# frame of each step beside the sensor's, and the shipped clean-depth readout reads the clean ones 0.38 cm off
# where the ceiling's reads the stereo ones 0.73-0.83. Round 2's readout is refitted as round 3's was (400 steps on
# rounds 0-3), its features of the stereo frames pulled toward the shipped readout's of the clean frames of the
# same steps with weight W (`trainer student refit --teacher --teacher-loss W`), as "teachW"; AIM=1 adds the 300
# learner approaches of `research/approach_readout.sh 2 300` ("teachWaim"); REPEAT=N refits it N times, each
# 400 steps warm-started from the last ("teachWaimxN", the teacher's loss still falls at 400). The gate: paired
# against round 3's readout on the 40 held-out approaches of `research/approach_readout.sh 2`; then CELL=1 runs a
# 180-episode seen-kind cell under stereo. Every stage is resumed (research/sensor_stages.sh).
#
#   research/teacher_readout.sh [W]   # env as research/sensor_dagger.sh, and AIM=1, REPEAT=N, CELL=1
set -euo pipefail
W=${1:-0.5}
source "$(dirname "$0")/sensor_stages.sh"

recover_shipped
need "$D/approach_heldout.zarr" "research/approach_readout.sh 2"  # the gate's store, not fitted on
stores=()
for r in 0 1 2 3; do
    need "$D/round$r.zarr" "research/sensor_dagger.sh 3"
done
name=teach$W
if [[ ${AIM:-0} == 1 ]]; then
    need "$D/approach.zarr" "research/approach_readout.sh 2 300"
    name=teach${W}aim
fi
init=$D/fit2/ckpt.pt first=$name
for ((k = 1; k <= ${REPEAT:-1}; k++)); do
    ((k > 1)) && name=${first}x$k
    TEACHER=$K/student.pt TEACHER_LOSS=$W fit "$name" "$init" "${stores[@]}"
    init=$D/fit$name/ckpt.pt
done
out=$R/table2/low_hand/c3_vs_c${name}_approach_heldout.json
low_hand "$out" "$D/c3/student.pt" "$D/approach_heldout.zarr" "$D/c$name/student.pt"
[[ ${CELL:-0} == 1 ]] && cell "$name"
log "done: $D/c$name (gate: $out)"
