#!/usr/bin/env bash
# The gate on a learner's own states under stereo (issue 45, docs/table2.md): the offline gate
# (research/stereo_errors.py on $R/table2/gate/stereo_seen20.zarr) reads the expert's states, and a readout that
# reads them 0.2 cm better did not grasp better. Here one composed learner (DRIVER: a row's student.onnx) drives
# 40 held-out seen-kind episodes under stereo on its own (beta 0, seeds 33000..; never fitted on), labelled, and
# every readout named is read on those frames (gate_NAME.json beside the store) and paired with the first, episode
# by episode, by the hand's height (research/low_hand_readout.py --versus: versus_NAME.json). Resumed: the store and
# each readout's files are kept.
#
#   research/learner_gate.sh DRIVER.onnx TAG CKPT [CKPT ...]   # CKPT: a composed student.pt; TAG names the store
set -euo pipefail
DRIVER=${1:?usage: research/learner_gate.sh DRIVER.onnx TAG CKPT [CKPT ...]}
TAG=${2:?usage: research/learner_gate.sh DRIVER.onnx TAG CKPT [CKPT ...]}
shift 2
(($# > 0)) || { echo "error: name at least one readout (a composed student.pt) to read" >&2; exit 2; }
[[ -f $DRIVER ]] || { echo "error: no driver policy at $DRIVER" >&2; exit 2; }
NAME=gate
source "$(dirname "$0")/sensor_stages.sh"
recover_shipped
store=$D/learner_$TAG.zarr
SENSOR=stereo OBJECTS=seen collect "$store" 40 33000 "student:$DRIVER" 0
first=$1
for ckpt in "$@"; do
    name=$(basename "$(dirname "$(dirname "$ckpt")")")_$(basename "$(dirname "$ckpt")")  # row folder _ readout
    gate_read "$store.gate_$name.json" "$ckpt" "$store"
    [[ $ckpt == "$first" ]] || low_hand "$store.versus_$name.json" "$first" "$store" "$ckpt"
done
log "done: $store.gate_*.json, $store.versus_*.json"
