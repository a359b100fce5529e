#!/usr/bin/env bash
# DAgger rounds for the depth readout under one depth source (issue 45, docs/table2.md), from nothing or resumed.
#
#   research/sensor_dagger.sh [ROUNDS]   # env: SENSOR (stereo), NAME (ceiling), CELLS ("2 3": rounds to judge; "" none),
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
# Every stage is resumed (research/sensor_stages.sh).
set -euo pipefail
ROUNDS=${1:-3}
CELLS=${CELLS-"2 3"}
source "$(dirname "$0")/sensor_stages.sh"

recover_shipped
expert_round0 "$D/round0.zarr"
stores=("$D/round0.zarr")
fit 0 "$K/student.pt" "${stores[@]}"
for ((r = 1; r <= ROUNDS; r++)); do
    beta=$(python -c "print(0.5 ** $r)")
    dagger_round "$r" $((r - 1)) $((52000 + 1000 * (r - 1))) "$beta"
    [[ " $CELLS " == *" $r "* ]] && cell "$r"
done
log "done: $D"
