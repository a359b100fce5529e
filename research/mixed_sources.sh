#!/usr/bin/env bash
# One readout fitted on several generated sources of the same states (issue 45, docs/table2.md): each row of
# research/generated_row.sh gives the ceiling's 80 expert episodes its own source's frames (round0.zarr), and a
# readout fitted on one source reads that source better than the stereo sensor it stands in for. Refitted on every
# named row's round 0 at once (the same 400 steps, the shipped readout as feature teacher at W), it sees each state
# under every source: what the sources share is what it can rely on. With ROUND=N, it starts from the first row's
# round-N readout instead (c{teachW}rN) and adds that row's DAgger rounds 1..N to the stores. With OFFCENTRE=L,
# that readout is refitted 400 steps more per level with the first row's off-centre descents of levels 1..L added
# (its offcentre*.zarr from research/generated_row.sh OFFCENTRE=L, in that row's source only): c{name}oc, c{name}oc2.
# The gate (research/stereo_errors.py on the first row's gate20.zarr: its stereo frames and that row's source) is
# written to gate_cNAME.json, and research/low_hand_readout.py pairs it with the first row's readout of the same
# round, episode by episode, on the stereo frames (versus_FIRST_NAME.json); CELL=1 then runs a 180-episode
# seen-kind cell under stereo. Every stage is resumed (research/sensor_stages.sh).
#
#   research/mixed_sources.sh W ROW [ROW ...]   # ROW: a residual_edges row's folder under $R/table2, e.g.
#                                               # row_residual_edges_s2_h-0.7; env: ROUND (0), CELL=1,
#                                               # OFFCENTRE (0, 1, 2)
set -euo pipefail
W=${1:?usage: research/mixed_sources.sh W ROW [ROW ...]}
shift
(($# > 1)) || { echo "error: name at least two rows (folders under \$R/table2) to mix" >&2; exit 2; }
for row in "$@"; do
    [[ $row == row_residual_edges* ]] || { echo "error: $row is not a residual_edges row" >&2; exit 2; }
done
NAME=mix_$(IFS=+; echo "${*#row_residual_edges_}")
source "$(dirname "$0")/sensor_stages.sh"
recover_shipped
stores=()
for row in "$@"; do
    need "$R/table2/$row/round0.zarr" "research/generated_row.sh (the row $row)"
done
first=$R/table2/$1
name=teach$W init=$K/student.pt
for ((r = 1; r <= ${ROUND:-0}; r++)); do
    need "$first/roundteach${W}r$r.zarr" "research/generated_row.sh ... $W ${ROUND} (the row $1)"
    name=teach${W}r$r init=$first/fitteach${W}r$r/ckpt.pt
done
export SOURCE=residual_edges TEACHER=$K/student.pt TEACHER_LOSS=$W
fit "$name" "$init" "${stores[@]}"
first_offcentre() {  # first_offcentre B SEED: the first row's descents aiming B cm off (their seeds are its own)
    need "$first/offcentre$1.zarr" "OFFCENTRE=$OFFCENTRE research/generated_row.sh ... (the row ${first##*/})"
}
offcentre_levels "$name" first_offcentre
gate=$D/gate_c$name.json
gate_read "$gate" "$D/c$name/student.pt" "$first/gate20.zarr" --generated
out=$D/versus_$1_c$name.json
low_hand "$out" "$first/c$name/student.pt" "$first/gate20.zarr" "$D/c$name/student.pt"
[[ ${CELL:-0} == 1 ]] && cell "$name"
log "done: $D/c$name (gate: $gate, paired: $out)"
