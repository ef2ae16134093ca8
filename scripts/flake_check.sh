#!/usr/bin/env bash
# Flake check: the whole test suite N times in a row (default 3) while a CPU hog keeps every
# core busy, so that a test that leans on timing or on a lucky schedule fails here and not in
# CI. Every run must pass; a crash (segfault, abort) in any test's output fails the run even
# when pytest itself passed (a subprocess's crash can hide behind its exit status).
# Usage: scripts/flake_check.sh [N] [pytest args...]   (run from anywhere; needs a built tree)
# Writes log/flake_check/run<i>.log and prints one line per run and a summary line.
set -uo pipefail
top=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$top"
runs=${1:-3}
shift || true
case "$runs" in
  '' | *[!0-9]* | 0) echo "flake_check: N must be a positive integer, got '$runs'" >&2; exit 2 ;;
esac
if [ ! -f env.sh ]; then
  echo 'flake_check: no env.sh: build first (make build)' >&2
  exit 2
fi
set +u
# shellcheck disable=SC1091
. ./env.sh
set -u

hogs=()
stop_hogs() {
  local pid
  for pid in "${hogs[@]}"; do
    kill "$pid" 2>/dev/null
  done
  for pid in "${hogs[@]}"; do
    wait "$pid" 2>/dev/null
  done
  hogs=()
}
trap stop_hogs EXIT
trap 'stop_hogs; exit 130' INT
trap 'stop_hogs; exit 143' TERM

cores=$(nproc)
for _ in $(seq "$cores"); do
  # A busy loop per core at normal priority: the tests get about half of each core.
  yes > /dev/null &
  hogs+=("$!")
done
echo "flake_check: $runs run(s) of the test suite with $cores CPU hog(s) (pids ${hogs[*]})"

logs="$top/log/flake_check"
mkdir -p "$logs"
# What a crashed process leaves in a log: the kernel's and Python's words for it.
crash='Segmentation fault|core dumped|Fatal Python error|SIGSEGV|Aborted|terminate called'
passed=0
for i in $(seq "$runs"); do
  log="$logs/run$i.log"
  start=$(date +%s)
  scripts/run_pytest.sh -q -p no:cacheprovider "$@" > "$log" 2>&1
  rc=$?
  summary=$(grep -E '^(=+ )?[0-9]+ (passed|failed)' "$log" | tail -1)
  crashed=$(grep -E -c "$crash" "$log")
  if [ "$rc" -eq 0 ] && [ "$crashed" -eq 0 ]; then
    passed=$((passed + 1))
    verdict=pass
  else
    verdict=FAIL
  fi
  echo "flake_check: run $i/$runs: $verdict (exit $rc, $crashed crash line(s), $(($(date +%s) - start)) s): ${summary:-no summary} -> $log"
  if [ "$verdict" = FAIL ]; then
    grep -E "^(FAILED|ERROR) |$crash" "$log" | head -20 | sed 's/^/  /'
  fi
done
echo "flake_check: $passed/$runs passed"
[ "$passed" -eq "$runs" ]
