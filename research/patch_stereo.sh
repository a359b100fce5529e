#!/usr/bin/env bash
# Would the stream's native pixels read the object better under stereo, where the aim is set? (issue 45,
# docs/table2.md) 1200 expert glimpses aiming 0, 1, 2 cm off, each with a 96 x 96 patch of the sensor's own stream
# around the object and the same patch as the policy image shows it (research/patch_ceiling.py glimpse); held out:
# 200 expert glimpses, 100 M0 drove, and the gate's 40 learner approaches (research/approach_readout.sh 2's
# episodes, re-run bit for bit); one small CNN fitted on each patch, round 3's readout as the bar, paired by
# episode. Each store is resumed where it stopped.
#
#   research/patch_stereo.sh
set -euo pipefail
source "$(dirname "$0")/sensor_stages.sh"
P=$R/table2/patch
recover_shipped
glimpse() { PYTHONPATH=. python research/patch_ceiling.py glimpse "$P/$1" --episodes "$2" --seed "$3" --workers "$WORKERS" "${@:4}"; }
glimpse train0 400 80000 --driver reactive:0.0
glimpse train1 400 81000 --driver reactive:1.0
glimpse train2 400 82000 --driver reactive:2.0
glimpse test_expert 200 83000 --driver reactive:1.0
glimpse test_m0 100 84000 --driver "oracle:$K/head.pt@1.0"
glimpse test_learner 40 59000 --approach --driver "student:$D/c2/student.onnx" --beta 0.125
out=$P/fit_low_native_c3.json
[[ -f $out ]] || PYTHONPATH=. python research/patch_ceiling.py fit --train "$P"/train{0,1,2} \
    --test expert="$P/test_expert" m0="$P/test_m0" learner="$P/test_learner" --variant low native readout \
    --ckpt "$D/c3/student.pt" --out "$out" > /dev/null
log "done: $out"
