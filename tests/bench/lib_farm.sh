# shellcheck shell=bash
# lib_farm.sh - what the farm benchmarks (farm_scale.sh, job_end.sh) share.
# Source it after the script's settings; the functions read the globals
# bin, workers, threads, pace and work, and add to the arrays pids and wpids.
#
#   usage                      the script's header comment, as --help text
#   median                     the median of the numbers on stdin (one a line)
#   start_workers PORT DIR     $workers ptworker-null processes of $threads
#                              threads, paced at $pace samples/s each, against
#                              127.0.0.1:PORT; logs DIR/wI.log, cache $work/cache
#   wait_joined LOG            0 once ptserve's LOG says $workers workers
#                              joined; 1 after a minute
# shellcheck disable=SC2154 # the globals above are the sourcing script's

usage() { sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'; }

median() { sort -g | awk '{a[NR]=$1} END {if (NR) print (NR % 2) ? a[(NR+1)/2] : (a[NR/2] + a[NR/2+1]) / 2}'; }

start_workers() {
  local port=$1 dir=$2 i
  for ((i = 0; i < workers; i++)); do
    PTWORKER_NULL_RATE=$pace "$bin/ptworker-null" --server "127.0.0.1:$port" --threads "$threads" \
      --cache-dir "$work/cache" --name "null$i" 2> "$dir/w$i.log" &
    pids+=($!)
    wpids+=($!)
  done
}

wait_joined() {
  local t=0
  while (($(grep -c 'worker .* joined' "$1") < workers)); do
    sleep 0.05
    t=$((t + 1))
    ((t < 1200)) || return 1
  done
}
