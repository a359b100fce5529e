#!/usr/bin/env bash
# Thousands of scenes where the aim is set (issue 45, docs/table2.md): under stereo the ceiling's readout reads
# scenes it trained on twice as well as new ones, and its error on a new scene is set by the scene, not by the
# sensor's draws (research/sensor_draw_readout.py), so more scenes may teach it. A glimpse (`trainer student
# readout --glimpse 3`) keeps 3 frames of one scene with the hand 12-30 cm over the object and renders only
# those: many times the scenes per hour of an approach.
#
#   research/glimpse_readout.sh [SCENES [REPEAT]]   # env as research/sensor_dagger.sh, and CELL=1
#
# SCENES glimpses into each of three stores, the expert aiming 0, 1 and 2 cm off (reactive:B) under $SENSOR;
# round 2's readout refitted 400 steps on rounds 0-3, the approaches and the glimpses, each glimpse store listed
# REPEAT times (a store listed twice is drawn twice as often), as "glimpse": round 3's readout with them added,
# on the same seeds, init and steps. The gate: the 40 held-out approaches of `research/approach_readout.sh 2`;
# then CELL=1 runs a 180-episode seen-kind cell under stereo. Every stage is resumed (research/sensor_stages.sh).
set -euo pipefail
SCENES=${1:-600}
REPEAT=${2:-4}
source "$(dirname "$0")/sensor_stages.sh"

recover_shipped
stores=()
for s in round0 round1 round2 round3 approach; do
    need "$D/$s.zarr" "research/approach_readout.sh 2"
done
seed=60000
for bias in 0.0 1.0 2.0; do
    store=$D/glimpse$bias.zarr
    driver=reactive:$bias
    [[ $bias == 0.0 ]] && driver=""
    collect "$store" "$SCENES" "$seed" "$driver" 0 12 3
    for ((i = 0; i < REPEAT; i++)); do stores+=("$store"); done
    seed=$((seed + 2000))
done
fit glimpse "$D/fit2/ckpt.pt" "${stores[@]}"
out=$R/table2/low_hand/cglimpse_approach_heldout.json
low_hand "$out" "$D/cglimpse/student.pt" "$D/approach_heldout.zarr"
[[ ${CELL:-0} == 1 ]] && cell glimpse
log "done: $D/cglimpse (gate: $out)"
