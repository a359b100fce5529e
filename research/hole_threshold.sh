#!/usr/bin/env bash
# The residual diffusion's hole threshold against the stereo sensor's hole rates (issue 45, docs/table2.md): at a
# few DDIM steps the hole channel stays blurred and the shipped threshold (0, half way) makes fewer holes than the
# sensor has. Each threshold T gets a copy of models/residual calibrated so ($R/residual_holes/hT), and `ddg
# vs-sensor` judges them all on the gate store's 20 held-out expert episodes under stereo (seeds 30000..; collected
# here if missing): holes at edges / flat, wrong depth, FID. The report: $R/table2/vs_sensor/holes_sSTEPS_T1_T2...json.
#
# T may be FLAT,EDGES: one threshold off the simulated frame's depth edges, one within their band.
#
#   research/hole_threshold.sh STEPS T [T ...]    # e.g. research/hole_threshold.sh 2 0 -0.3 -0.6,-0.9
set -euo pipefail
STEPS=${1:?usage: research/hole_threshold.sh STEPS T [T ...]}
shift
(($# > 0)) || { echo "error: name at least one threshold T (the hole channel's, in [-1, 1])" >&2; exit 2; }
NAME=gate
source "$(dirname "$0")/sensor_stages.sh"
recover_shipped
store=$D/stereo_seen20.zarr
SENSOR=stereo OBJECTS=seen collect "$store" 20 30000
dirs=()
for t in "$@"; do
    dirs+=("$R/residual_holes/h${t/,/_e}")  # as research/generated_row.sh names it
    calibrated_residual "$t" "${dirs[-1]}"
done
python -m trainer ddg vs-sensor --store "$store" --residual "${dirs[@]}" --steps "$STEPS" --every 4 --bootstrap 10 \
    --json "$R/table2/vs_sensor/holes_s${STEPS}_$(IFS=_; echo "$*").json"
