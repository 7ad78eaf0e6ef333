# Sourced by the benchmark and training scripts that describe synthetic drives as
# "SEED FRAMES|synth options": make_drive writes one under WORK/synth unless its poses are there
# already (so a rerun reuses it), its progress on stderr, and prints the sequence folder.
make_drive() {  # WORK VCR SPEC
  local work=$1 vcr=$2 spec=$3 seed frames
  read -r seed frames <<<"${spec%%|*}"
  # shellcheck disable=SC2086  # the options are words
  [ -f "$work/synth/poses/$seed.txt" ] || "$vcr" synth --out "$work/synth" --seq "$seed" --frames "$frames" \
    --seed "$seed" ${spec#*|} >&2
  echo "$work/synth/sequences/$seed"
}
