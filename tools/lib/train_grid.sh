# Sourced by the study scripts in tools/: trains every (w1, trial) run of a
# grid that has no samples yet, JOBS at a time, as `irlgrid train` runs under
# OUT/runs/w1_<w1>_t<trial> with seed 1000 + trial. Re-running skips the
# finished runs, so a study that was stopped resumes where it was.
#
#   train_grid BIN GRID TRIALS STEPS JOBS OUT [EXTRA]
#
# EXTRA: more `irlgrid train` arguments as one word-split string, e.g.
# "--preset power".

train_grid() {
  local bin=$1 grid=$2 trials=$3 steps=$4 jobs=$5 out=$6 extra=${7:-}
  mkdir -p "$out/runs"
  local w t dir
  for w in ${grid//,/ }; do
    for t in $(seq 1 "$trials"); do
      dir="$out/runs/w1_${w}_t$t"
      [ -f "$dir/samples.json" ] || echo "$w $t $dir"
    done
  done | xargs -r -P "$jobs" -n 3 sh -c \
    '"$0" train --w1 "$3" --seed "$((1000 + $4))" --steps "$1" --quiet --out "$5" $2 >/dev/null &&
       echo "  done w1=$3 trial $4"' "$bin" "$steps" "$extra"
}
