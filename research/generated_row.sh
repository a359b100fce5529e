#!/usr/bin/env bash
# A row of the table from a generated depth source (issue 45, docs/table2.md), not the test sensor's. The ceiling's
# round 0 (research/sensor_dagger.sh: 80 expert episodes on the training kinds, seeds 50000..; the expert reads no
# depth, so its states are any source's) is copied and given the source's frames, made from its clean ones
# (`trainer ddg generate --generator G --steps STEPS`; SOURCE ddg: DDG (a) grafted, residual_edges: the residual
# diffusion kept near the depth edges). The shipped first readout is refitted 400 steps on them, with W > 0 the
# shipped clean-depth readout as its feature teacher on the clean frames of the same steps (`--teacher-loss W`),
# composed with M0 and exported as c{teachW|plain}. With ROUNDS > 0, DAgger on the source: round r's learner (the
# last readout composed with M0) drives EPISODES (40) episodes with the source as its sensor (`--sensor
# SOURCE:steps=STEPS`, beta 0.5^r, seeds 52000 + 1000 (r - 1)..), whose frames the store keeps, and the last readout
# is refitted 400 steps more on every round's source frames (c{name}r{r}). The gate then reads every readout on 20
# held-out expert episodes under stereo and on the source's frames of the same views (gate_c{name}.json: the bias
# near the object and over every frame, docs/table2.md), and CELL=1 runs a 180-episode seen-kind cell of the last
# one under stereo. With OFFCENTRE=N, N levels of off-centre descents follow the rounds: the expert aiming B cm off
# (`reactive:B`, beta 0.25, 40 episodes each; level 1: 1.0 and 2.0 cm, level 2: 1.5 and 3.0, OFFCENTRE_LEVELS in
# research/sensor_stages.sh) on clean depth, given the source's frames offline, and the last readout refitted 400
# steps more on every store and those (c{name}oc, then c{name}oc2): a row's readout reads its learner's hand beside
# the object as on target under stereo (docs/table2.md). Every stage is resumed
# (research/sensor_stages.sh); the ceiling's round 0 is collected if missing. With AIM=N the last learner then drives
# N approaches under the source (each ends once the grasp site is 12 cm over the object; beta 0.5^(ROUNDS+1), seeds
# 58000..), the ceiling's AIM=1 for the row, and the last readout is refitted 400 steps more with them (c{name}aim).
#
# STEPS (5) is the generator's DDIM steps; another count is another source, kept apart as row_SOURCE_sSTEPS. HOLES
# (residual sources) is the residual diffusion's hole threshold (research/hole_threshold.sh), another source again,
# row_SOURCE_sSTEPS_hHOLES (FLAT,EDGES: _hFLAT_eEDGES).
#
#   research/generated_row.sh SOURCE [W [ROUNDS]]   # env: CELL=1, WORKERS (2), EPISODES (40), STEPS (5), HOLES,
#                                                   #      OFFCENTRE (0, 1, 2), AIM (0: approaches)
set -euo pipefail
SOURCE=${1:?usage: research/generated_row.sh ddg|residual|residual_edges [W [ROUNDS]]}
W=${2:-0}
ROUNDS=${3:-0}
EPISODES=${EPISODES:-40}  # not 150: every frame the learner sees is generated (residual_edges: 1.4 a second)
STEPS=${STEPS:-5}
HOLES=${HOLES:-}
[[ ${AIM:-0} =~ ^[0-9]+$ ]] || { echo "error: AIM=$AIM: a number of approaches (0: none)" >&2; exit 2; }
NAME=row_$SOURCE
[[ $STEPS == 5 ]] || NAME=${NAME}_s$STEPS
if [[ -n $HOLES ]]; then
    [[ $SOURCE == residual* ]] || { echo "error: HOLES is the residual diffusion's, not $SOURCE's" >&2; exit 2; }
    TAG=h${HOLES/,/_e}  # FLAT,EDGES -> hFLAT_eEDGES: a comma would split the learner sensor's argument
    NAME=${NAME}_$TAG
fi
source "$(dirname "$0")/sensor_stages.sh"
MODEL=()  # the generator's model directory when it is not the shipped one
learner_sensor=$SOURCE:steps=$STEPS
if [[ -n $HOLES ]]; then
    model=$R/residual_holes/$TAG
    calibrated_residual "$HOLES" "$model"
    MODEL=(--model "$model")
    learner_sensor+=,model=$model
fi
C=$R/table2/ceiling
mkdir -p "$C"
generator=${SOURCE%_nograft}  # the DDG makes ddg and ddg_nograft together

# with_source FROM TO: a copy of the store FROM at TO, given the source's frames of its views.
with_source() {
    [[ -f $2.done ]] && return
    if [[ ! -d $2 ]]; then
        rm -rf "$2.part" && cp -r "$1" "$2.part" && mv "$2.part" "$2"
    fi
    log "$SOURCE frames of $2"
    python -m trainer ddg generate --generator "$generator" --demos "$2" --steps "$STEPS" --threads 2 "${MODEL[@]}"
    touch "$2.done"
}

recover_shipped
[[ -f $D/round0.zarr.done ]] || expert_round0 "$C/round0.zarr"  # the ceiling's, shared with sensor_dagger.sh
with_source "$C/round0.zarr" "$D/round0.zarr"
name=plain
if [[ $W != 0 ]]; then
    name=teach$W
    export TEACHER=$K/student.pt TEACHER_LOSS=$W
fi
fit "$name" "$K/student.pt" "$D/round0.zarr"  # fit reads the $SOURCE frames
stores=("$D/round0.zarr")
base=$name
readouts=("$name")
for ((r = 1; r <= ROUNDS; r++)); do
    prev=$name
    name=${base}r$r
    SENSOR=$learner_sensor dagger_round "$name" "$prev" $((52000 + 1000 * (r - 1))) "$(python -c "print(0.5 ** $r)")"
    readouts+=("$name")
done
# offcentre_store B SEED: the expert aiming B cm off, a hand beside the object, which the row's own learner seldom
# shows it; collected on clean depth (the expert reads none) and given the source's frames
offcentre_store() {
    SENSOR=clean collect "$D/offcentre$1.clean.zarr" 40 "$2" "reactive:$1" 0.25
    with_source "$D/offcentre$1.clean.zarr" "$D/offcentre$1.zarr"
    stores+=("$D/offcentre$1.zarr")
}
offcentre_levels "$name" offcentre_store
if ((${AIM:-0} > 0)); then  # more scenes where the aim is set, as the ceiling's AIM=1 (research/approach_readout.sh)
    SENSOR=$learner_sensor collect "$D/approach_$name.zarr" "$AIM" 58000 "student:$D/c$name/student.onnx" \
        "$(python -c "print(0.5 ** ($ROUNDS + 1))")" 12
    stores+=("$D/approach_$name.zarr")
    refit_as "${name}aim"
fi
# the gate: each readout on the 20 held-out gate episodes (research/hole_threshold.sh's), on their stereo frames and
# on this source's frames of the same views (research/stereo_errors.py)
gate=$R/table2/gate/stereo_seen20.zarr
SENSOR=stereo OBJECTS=seen collect "$gate" 20 30000
with_source "$gate" "$D/gate20.zarr"
for readout in "${readouts[@]}"; do
    out=$D/gate_c$readout.json
    gate_read "$out" "$D/c$readout/student.pt" "$D/gate20.zarr" --generated
done
[[ ${CELL:-0} == 1 ]] && cell "$name"
log "done: $D/c$name (gate: $D/gate_c*.json)"
