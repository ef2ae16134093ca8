#!/usr/bin/env bash
# Run the whole test suite. pytest's exit 5 (no test collected) is a failure here.
set -uo pipefail
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
# A domain of its own (1-100) unless one is set: two suites on one machine (a flake check, a
# developer's shell) then never see each other's nodes and topics.
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$((RANDOM % 100 + 1))}"
export PYTHONDONTWRITEBYTECODE=1
export MPLBACKEND=Agg
python -m pytest "$@"
rc=$?
if [ "$rc" -eq 5 ]; then
  echo 'run_pytest: no test was collected: that is a failure' >&2
  exit 1
fi
exit "$rc"
