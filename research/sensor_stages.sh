# The stages of a depth readout's rounds under one depth source (issue 45), sourced by research/sensor_dagger.sh
# and the other research/*_readout.sh. Env: SENSOR (stereo), NAME (ceiling), WORKERS (2: simulation processes),
# EPISODES (150: a DAgger round's).
#
# Every stage leaves its output under $DIFFUDEPGRASP_HOME/table2/$NAME (the project's home for long-lived artifacts,
# default ~/.cache/diffudepgrasp, as trainer.student.recipe.default_home) and is skipped when that output is there:
# a killed run resumes where it stopped (a half-collected store or a half-done refit from where it was cut off).
SENSOR=${SENSOR:-stereo}
NAME=${NAME:-ceiling}
WORKERS=${WORKERS:-2}
R=${DIFFUDEPGRASP_HOME:-$HOME/.cache/diffudepgrasp}
K=$R/recovered/shipped
D=$R/table2/$NAME
TRAIN_KINDS=seen,squares,shapes
# OFFCENTRE_LEVELS[L - 1]: the aim biases (cm) of level L of off-centre descents (generated_row.sh, mixed_sources.sh)
OFFCENTRE_LEVELS=("1.0 2.0" "1.5 3.0")
if ! [[ ${OFFCENTRE:-0} =~ ^[0-9]+$ ]] || ((${OFFCENTRE:-0} > ${#OFFCENTRE_LEVELS[@]})); then
    echo "error: OFFCENTRE=$OFFCENTRE: a level 0..${#OFFCENTRE_LEVELS[@]} (OFFCENTRE_LEVELS, research/sensor_stages.sh)" >&2
    exit 2
fi
# bf16 fits run ~2x faster where the CPU has bf16 arithmetic and ~13x slower where it has none
PRECISION=$(grep -q -w -e avx512_bf16 -e amx_bf16 /proc/cpuinfo && echo bf16 || echo fp32)
mkdir -p "$D" "$R/table2/cells"

log() { echo "[$(date +%H:%M:%S)] $*"; }

recover_shipped() {
    [[ -f $K/head.pt ]] || python -m export.recover models/student.onnx --out "$K"
}

# calibrated_residual T DIR: the shipped residual diffusion (models/residual) at DIR, its last stage's hole threshold
# set to T (trainer/ddg/residual.py: HOLE_THRESHOLD; a lower one makes more holes). T may be FLAT,EDGES: FLAT off
# the simulated frame's depth edges, EDGES within their band.
calibrated_residual() {
    [[ -f $2/done ]] && return
    rm -rf "$2" && mkdir -p "$(dirname "$2")" && cp -r models/residual "$2"
    python - "$1" "$2" <<'EOF'
import json, pathlib, sys
flat, *edges = (float(t) for t in sys.argv[1].split(","))
cfg = sorted(pathlib.Path(sys.argv[2]).glob("stage*/config.json"))[-1]
set_ = {"hole_threshold": flat, **({"hole_threshold_edges": edges[0]} if edges else {})}
cfg.write_text(json.dumps({**json.loads(cfg.read_text()), **set_}, indent=1) + "\n")
EOF
    touch "$2/done"
}

# need STORE MAKER: STORE appended to the array `stores` if it is complete, else exit 2 naming the command MAKER
# that makes it.
need() {
    if [[ ! -f $1.done ]]; then
        echo "error: $1 is incomplete: run $2" >&2
        exit 2
    fi
    stores+=("$1")
}

# collect STORE EPISODES SEED [DRIVER BETA [END_CM [GLIMPSE]]]: a labelled store of frames under $SENSOR (of the
# kinds OBJECTS names, default the training kinds), marked
# done when complete; DRIVER is a policy spec (student:ONNX, reactive:BIAS_CM), else the expert drives; with END_CM
# each episode ends once the grasp site is that low over the object (the approach alone); with GLIMPSE frames,
# at a height drawn between END_CM and 30 cm, keeping only its last GLIMPSE frames.
collect() {
    local store=$1 episodes=$2 seed=$3 driver=${4:-} beta=${5:-} end_cm=${6:-0} glimpse=${7:-0}
    [[ -f $store.done ]] && return
    log "collect $store ($episodes episodes${driver:+, $driver driving, beta $beta})"
    python -m trainer student readout "$K/student.pt" --store "$store" --episodes "$episodes" --no-chunks \
        --sensor "$SENSOR" --objects "${OBJECTS:-$TRAIN_KINDS}" --seed "$seed" --workers "$WORKERS" --collect-only \
        --end-height-cm "$end_cm" --glimpse "$glimpse" ${driver:+--learner $driver --beta $beta}
    touch "$store.done"
}

# expert_round0 STORE: round 0 of every chain, the expert's 80 episodes on the training kinds, seeds 50000...
expert_round0() {
    collect "$1" 80 50000
}

# fit ROUND INIT STORES...: INIT's first readout refitted 400 steps on the stores' SOURCE frames (default sensor: what
# the learner saw; ddg: `trainer ddg generate`'s), composed with M0, exported; with TEACHER (a clean-depth student) and
# TEACHER_LOSS (its weight), its features of the clean frames teach the readout's.
fit() {
    local round=$1 init=$2 steps=400; shift 2
    local out=$D/fit$round onnx=$D/c$round/student.onnx
    [[ -f $onnx ]] && return
    log "fit round $round ($steps steps on $*)"
    python -m trainer student refit --init "$init" --stores "$@" --depth-source "${SOURCE:-sensor}" --perception-only \
        --shares seen=0.45 squares=0.2 --steps "$steps" --batch 128 --lr 3e-4 --shift-px 6 --near-loss 1 \
        --precision $PRECISION --threads 2 --ckpt-every 50 --out "$out" \
        ${TEACHER:+--teacher "$TEACHER" --teacher-loss "$TEACHER_LOSS"}
    python -m trainer student compose --perception "$out/ckpt.pt" --head "$K/head.pt" --out "$D/c$round/student.pt"
    python -m export "$D/c$round/student.pt" --ddim-steps 4 --out "$onnx"
}

# dagger_round ROUND PREV SEED BETA: round PREV's composed learner drives $EPISODES under $SENSOR (DAgger: a
# step executes the expert's action with probability BETA) into round ROUND's store, added to the array `stores`;
# PREV's readout is refitted on all of them.
dagger_round() {
    local round=$1 prev=$2 seed=$3 beta=$4
    collect "$D/round$round.zarr" "${EPISODES:-150}" "$seed" "student:$D/c$prev/student.onnx" "$beta"
    stores+=("$D/round$round.zarr")
    fit "$round" "$D/fit$prev/ckpt.pt" "${stores[@]}"
}

# gate_read OUT CKPT STORE [--generated]: research/stereo_errors.py's readout of CKPT on STORE's frames (the gate's
# figures), kept at OUT.
gate_read() {
    local out=$1; shift
    [[ -f $out ]] || PYTHONPATH=. python research/stereo_errors.py "$@" --json "$out"
}

# low_hand OUT CKPT STORE [OTHER]: research/low_hand_readout.py's reading of CKPT on STORE's frames by the hand's
# height, with OTHER paired against it episode by episode, kept at OUT.
low_hand() {
    local out=$1 ckpt=$2 store=$3 other=${4:-}
    [[ -f $out ]] || PYTHONPATH=. python research/low_hand_readout.py "$ckpt" "$store" ${other:+--versus "$other"} \
        --out "$out" > /dev/null
}

# offcentre_levels LAST STORE: levels 1..$OFFCENTRE of off-centre descents after readout LAST. For each of a level's
# aim biases B (OFFCENTRE_LEVELS, cm), `STORE B SEED` appends that level's store to the array `stores` (seeds 60000,
# 61000, ..); then the last readout is refitted 400 steps more on every store: c{LAST}oc, then c{LAST}oc2, .., the
# last name left in `name` and each appended to the array `readouts`.
offcentre_levels() {
    local last=$1 store=$2 seed=60000 o b new
    name=$last
    for ((o = 1; o <= ${OFFCENTRE:-0}; o++)); do
        for b in ${OFFCENTRE_LEVELS[o - 1]}; do
            "$store" "$b" $seed
            seed=$((seed + 1000))
        done
        new=${last}oc
        ((o == 1)) || new+=$o
        refit_as "$new"
    done
}

# refit_as NEW: the last readout ($name) refitted 400 steps more on every store as NEW, which becomes the last
# (`name`) and is appended to the array `readouts`.
refit_as() {
    local prev=$name
    name=$1
    fit "$name" "$D/fit$prev/ckpt.pt" "${stores[@]}"
    readouts+=("$name")
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

