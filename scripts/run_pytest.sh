#!/usr/bin/env bash
# Run the whole test suite. pytest's exit 5 (no test collected) is a failure here.
set -uo pipefail
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export PYTHONDONTWRITEBYTECODE=1
export MPLBACKEND=Agg
python -m pytest "$@"
rc=$?
if [ "$rc" -eq 5 ]; then
  echo 'run_pytest: no test was collected: that is a failure' >&2
  exit 1
fi
exit "$rc"
