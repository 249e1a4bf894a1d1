#!/usr/bin/env bash
# Copyright 2026 valve_sim developers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.
#
# Run the test suite RUNS times in a row while a busy loop loads every core (issue 8).
#
#     bench/stress_suite.sh [RUNS] [pytest arguments...]      RUNS defaults to 3
#
# Each run is `python3 run.py test -q` (plus the arguments); its output goes to
# out/stress/run<k>.log, and one line per run says passed or FAILED, its time and
# the load average. The busy loops (one per core, `nproc`) are this script's own
# children and are ended by their process ids on exit. Exit code 0 only if every
# run passed.
set -uo pipefail
cd "$(dirname "$0")/.."
runs=${1:-3}
shift || true
cores=$(nproc)
logs=out/stress
mkdir -p "$logs"

busy=()
for _ in $(seq "$cores"); do
    ( while :; do :; done ) &
    busy+=($!)
done
trap 'kill "${busy[@]}" 2>/dev/null' EXIT
echo "stress: $runs suite runs with $cores busy loops (pids ${busy[*]}); logs in $logs/"

passed=0
for k in $(seq "$runs"); do
    start=$(date +%s)
    if python3 run.py test -q -p no:cacheprovider "$@" > "$logs/run$k.log" 2>&1; then
        result=passed
        passed=$((passed + 1))
    else
        result=FAILED
    fi
    summary=$(grep -E '^[0-9]+ (passed|failed)|^=+ .*(passed|failed)' "$logs/run$k.log" | tail -1)
    echo "stress run $k/$runs: $result in $(( $(date +%s) - start )) s," \
        "load $(cut -d' ' -f1 /proc/loadavg): ${summary:-see $logs/run$k.log}"
done
echo "stress: $passed of $runs runs passed"
[ "$passed" -eq "$runs" ]
