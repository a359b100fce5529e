#!/usr/bin/env bash
# Readouts averaged (issue 45, docs/table2.md): the shipped file averages two readouts' facts (`trainer student
# compose --also`). Readouts fitted on different stores (the -0.7 row's off-centre one and the five-source one)
# fail on different episodes under stereo (14 won / 19 lost, paired); here the named readouts' facts are averaged,
# composed with M0's head, exported as $R/table2/NAME/cavg, read on the gate (research/stereo_errors.py on
# the 20 held-out stereo episodes: gate_cavg.json) and with CELL=1 given a 180-episode seen-kind cell under stereo.
# Every stage is resumed (research/sensor_stages.sh).
#
#   research/averaged_readouts.sh NAME FIT [FIT ...]   # FIT: a refit's ckpt.pt (.../fitX/ckpt.pt); env CELL=1
set -euo pipefail
NAME=${1:?usage: research/averaged_readouts.sh NAME FIT [FIT ...]}
shift
(($# > 1)) || { echo "error: name at least two readouts (a refit's ckpt.pt) to average" >&2; exit 2; }
for fit in "$@"; do
    [[ -f $fit ]] || { echo "error: no readout at $fit" >&2; exit 2; }
done
source "$(dirname "$0")/sensor_stages.sh"
recover_shipped
onnx=$D/cavg/student.onnx
if [[ ! -f $onnx ]]; then
    log "compose $# readouts averaged"
    python -m trainer student compose --perception "$1" --also "${@:2}" --head "$K/head.pt" --out "$D/cavg/student.pt"
    python -m export "$D/cavg/student.pt" --ddim-steps 4 --out "$onnx"
fi
gate_read "$D/gate_cavg.json" "$D/cavg/student.pt" "$R/table2/gate/stereo_seen20.zarr"
[[ ${CELL:-0} == 1 ]] && cell avg
log "done: $onnx (gate: $D/gate_cavg.json)"
