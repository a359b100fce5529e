#!/usr/bin/env bash
# DAgger rounds for the depth readout under one depth source (issue 45, docs/table2.md), from nothing or resumed.
#
#   research/sensor_dagger.sh [ROUNDS]   # env: SENSOR (stereo), NAME (ceiling), CELLS ("2 3": rounds to judge),
#                                        #      WORKERS (2: simulation processes; 15 on a lent 16-core machine)
#
# Round 0: the expert drives 80 episodes under $SENSOR on the training kinds; the shipped file's first readout is
# refitted 400 steps on those frames. Round r >= 1: the composed learner of round r-1 drives 150 episodes under
# $SENSOR (DAgger's beta 0.5^r: the expert's share shrinks as the learner improves) and round r-1's readout is
# refitted 400 more steps on every round so far (warm-started: a fresh refit from the shipped weights took 800 steps
# for one learner round and 1200 for more, and a step takes ~5 s on a CPU without bf16). Each readout is
# composed with the shipped head (M0) and exported; the rounds in $CELLS get a 180-episode seen-kind cell under
# stereo. Under SENSOR=stereo this is the ceiling of a source faithful to the test sensor (not a row of the table);
# any other source (ddg:..., residual) is a row.
#
# Every stage leaves its output under $DIFFUDEPGRASP_HOME/table2/$NAME (the project's home for long-lived artifacts,
# default ~/.cache/diffudepgrasp, as trainer.student.recipe.default_home) and is skipped when that output is there:
# a killed run resumes where it stopped (a half-collected store or a half-done refit from where it was cut off).
set -euo pipefail
ROUNDS=${1:-3}
SENSOR=${SENSOR:-stereo}
NAME=${NAME:-ceiling}
CELLS=${CELLS:-"2 3"}
WORKERS=${WORKERS:-2}
R=${DIFFUDEPGRASP_HOME:-$HOME/.cache/diffudepgrasp}
K=$R/recovered/shipped
D=$R/table2/$NAME
TRAIN_KINDS=seen,squares,shapes
# bf16 fits run ~2x faster where the CPU has bf16 arithmetic and ~13x slower where it has none
PRECISION=$(grep -q -w -e avx512_bf16 -e amx_bf16 /proc/cpuinfo && echo bf16 || echo fp32)
mkdir -p "$D" "$R/table2/cells"

log() { echo "[$(date +%H:%M:%S)] $*"; }

recover_shipped() {
    [[ -f $K/head.pt ]] || python -m export.recover models/student.onnx --out "$K"
}

# collect STORE EPISODES SEED [LEARNER BETA]: a labelled store of frames under $SENSOR, marked done when complete.
collect() {
    local store=$1 episodes=$2 seed=$3 learner=${4:-} beta=${5:-}
    [[ -f $store.done ]] && return
    log "collect $store ($episodes episodes${learner:+, learner $learner beta $beta})"
    python -m trainer student readout "$K/student.pt" --store "$store" --episodes "$episodes" --no-chunks \
        --sensor "$SENSOR" --objects "$TRAIN_KINDS" --seed "$seed" --workers "$WORKERS" --collect-only \
        ${learner:+--learner student:$learner --beta $beta}
    touch "$store.done"
}

# fit ROUND INIT STORES...: INIT's first readout refitted 400 steps, composed with M0, exported.
fit() {
    local round=$1 init=$2 steps=400; shift 2
    local out=$D/fit$round onnx=$D/c$round/student.onnx
    [[ -f $onnx ]] && return
    log "fit round $round ($steps steps on $*)"
    python -m trainer student refit --init "$init" --stores "$@" --depth-source sensor --perception-only \
        --shares seen=0.45 squares=0.2 --steps "$steps" --batch 128 --lr 3e-4 --shift-px 6 --near-loss 1 \
        --precision $PRECISION --threads 2 --ckpt-every 50 --out "$out"
    python -m trainer student compose --perception "$out/ckpt.pt" --head "$K/head.pt" --out "$D/c$round/student.pt"
    python -m export "$D/c$round/student.pt" --ddim-steps 4 --out "$onnx"
}

# cell ROUND: 180 seen-kind episodes under stereo, seeds 10000.., the table's cell.
cell() {
    local json=$R/table2/cells/${NAME}_r$1_stereo_seen.json
    [[ -f $json ]] && return
    log "cell round $1"
    python -m trainer evaluate --policy "student:$D/c$1/student.onnx" --sensor stereo --objects seen \
        --episodes 180 --workers "$WORKERS" --json "$json.part"
    mv "$json.part" "$json"
}

recover_shipped
collect "$D/round0.zarr" 80 50000
stores=("$D/round0.zarr")
fit 0 "$K/student.pt" "${stores[@]}"
for ((r = 1; r <= ROUNDS; r++)); do
    beta=$(python -c "print(0.5 ** $r)")
    collect "$D/round$r.zarr" 150 $((52000 + 1000 * (r - 1))) "$D/c$((r - 1))/student.onnx" "$beta"
    stores+=("$D/round$r.zarr")
    fit "$r" "$D/fit$((r - 1))/ckpt.pt" "${stores[@]}"
    [[ " $CELLS " == *" $r "* ]] && cell "$r"
done
log "done: $D"
