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

# cache_drive WORK VCR SPEC COPIES POINTS: make_drive, then its frame cache WORK/cache_SEED.npz at an
# 80 m crop with COPIES down-samplings of POINTS points (every frame of a keyframe set or of a drive
# recorded below 10 Hz, every fourth of a 10 Hz one: its neighbours are near-copies), unless the cache
# is there already; prints the cache's path.
cache_drive() {  # WORK VCR SPEC COPIES POINTS
  local work=$1 vcr=$2 spec=$3 copies=$4 points=$5 seed stride=4
  make_drive "$work" "$vcr" "$spec" >/dev/null
  seed=${spec%% *}
  case "$spec" in *--keyframes* | *--rate-hz*) stride=1 ;; esac
  [ -f "$work/cache_$seed.npz" ] || "$vcr" cache --data-root "$work/synth" --seq "$seed" --stride "$stride" \
    --copies "$copies" --input-max-range 80 --num-points "$points" --out "$work/cache_$seed.npz" >&2
  echo "$work/cache_$seed.npz"
}
