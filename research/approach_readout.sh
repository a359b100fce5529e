#!/usr/bin/env bash
# More scenes where the aim is set (issue 45, docs/table2.md): under stereo the ceiling's readout reads
# its training scenes' high frames 0.56 cm off and new scenes' 1.30 cm (hand 18-30 cm over the object, one
# constant per episode): it memorises scenes. An approach ends once the grasp site is 12 cm over the object,
# a quarter of a learner episode's frames, so the same time collects ~3x the scenes of the frames that set
# the aim.
#
#   research/approach_readout.sh [FROM [EPISODES]]   # env as research/sensor_dagger.sh, and CELL=1
#
# Round FROM's learner drives EPISODES approaches under $SENSOR (beta 0.5^(FROM+1), as round FROM+1's);
# round FROM's readout is refitted 400 steps on rounds 0..FROM+1 and the approaches ("aim"): round FROM+1's
# readout (`sensor_dagger.sh`) with the approaches added, on the same seeds, init and steps. The gate: both
# readouts and round FROM's on 40 held-out approaches (the same learner, other seeds); read it, then CELL=1
# runs a 180-episode seen-kind cell under stereo.
# Every stage is resumed (research/sensor_stages.sh).
set -euo pipefail
FROM=${1:-2}
EPISODES=${2:-300}
source "$(dirname "$0")/sensor_stages.sh"

recover_shipped
stores=()
for ((r = 0; r <= FROM + 1; r++)); do
    need "$D/round$r.zarr" "research/sensor_dagger.sh $((FROM + 1))"
done
beta=$(python -c "print(0.5 ** ($FROM + 1))")
collect "$D/approach.zarr" "$EPISODES" 58000 "student:$D/c$FROM/student.onnx" "$beta" 12
collect "$D/approach_heldout.zarr" 40 59000 "student:$D/c$FROM/student.onnx" "$beta" 12
fit aim "$D/fit$FROM/ckpt.pt" "${stores[@]}" "$D/approach.zarr"
for c in "c$FROM" "c$((FROM + 1))" caim; do
    out=$R/table2/low_hand/${c}_approach_heldout.json
    low_hand "$out" "$D/$c/student.pt" "$D/approach_heldout.zarr"
done
[[ ${CELL:-0} == 1 ]] && cell aim
log "done: $D/caim (gate: $R/table2/low_hand/*_approach_heldout.json)"
