#!/usr/bin/env bash
# Off-centre descents for the depth readout under one depth source (issue 45, docs/table2.md).
#
#   research/offcentre_readout.sh [FROM [ROUNDS]]   # env: SENSOR, NAME, WORKERS (research/sensor_stages.sh),
#                                                   #      OFFCENTRE_CM ("1.0 2.0": the aim errors of the drivers)
#
# Why: on the learner's own stereo frames the ceiling's readout reads the hand on target once it is below ~12 cm
# over the object, whatever the true offset (round 2's frames, c1's readout: the read offset's slope on the true
# one 0.0-0.1 there, 0.9-1.0 above 18 cm), so the hand closes where it was aimed while the readout could still see.
# The expert's episodes it learnt from never hold a low hand beside the object. Here the expert aiming B cm off
# (`reactive:B`, BiasedExpert; at beta 0.25 a step executes the true expert's action) drives 40 episodes per B, so
# the hand descends 0-B cm beside the object, and every frame is labelled with the true offset.
# FROM: the round of research/sensor_dagger.sh whose readout is warm-started and whose stores are kept. Its
# readout is refitted 400 steps on those and the off-centre stores (round "oc"), composed with M0 and exported;
# both readouts are measured on 20 held-out off-centre episodes (B 1.5 cm); then a 180-episode cell under stereo.
# ROUNDS (0) more DAgger rounds follow as research/sensor_dagger.sh's do (the last readout drives 150 episodes at
# beta 0.5^(FROM + k), every store so far refitted 400 steps, a cell each), the off-centre stores kept: oc1, oc2 ...
set -euo pipefail
FROM=${1:-2}
ROUNDS=${2:-0}
OFFCENTRE_CM=${OFFCENTRE_CM:-"1.0 2.0"}
source "$(dirname "$0")/sensor_stages.sh"

# measure ROUND STORE: the readout of round ROUND on STORE's sensor frames (trainer student readout's JSON).
measure() {
    local json=$D/measure_c$1_$(basename "$2" .zarr).json
    [[ -f $json ]] && return
    log "measure c$1 on $2"
    python -m trainer student readout "$D/c$1/student.pt" --store "$2" > "$json.part"
    mv "$json.part" "$json"
}

recover_shipped
stores=()
for ((r = 0; r <= FROM; r++)); do stores+=("$D/round$r.zarr"); done
seed=60000
for b in $OFFCENTRE_CM; do
    collect "$D/offcentre$b.zarr" 40 $seed "reactive:$b" 0.25
    stores+=("$D/offcentre$b.zarr")
    seed=$((seed + 1000))
done
heldout=$D/offcentre_heldout.zarr
collect "$heldout" 20 69000 reactive:1.5 0.25
measure "$FROM" "$heldout"
fit oc "$D/fit$FROM/ckpt.pt" "${stores[@]}"
measure oc "$heldout"
cell oc
prev=oc
for ((k = 1; k <= ROUNDS; k++)); do
    beta=$(python -c "print(0.5 ** ($FROM + $k))")
    dagger_round "oc$k" "$prev" $((70000 + 1000 * k)) "$beta"
    cell "oc$k"
    prev=oc$k
done
log "done: $D/c$prev"
