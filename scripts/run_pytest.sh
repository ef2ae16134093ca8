#!/usr/bin/env bash
# Run the whole test suite. pytest's exit 5 (no test collected) is a failure here.
set -uo pipefail
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
# A domain of its own (1-100) unless one is set: two suites on one machine (a flake check, a
# developer's shell) then never see each other's nodes and topics; one with no Fast DDS
# shared-memory port left by a killed process (tt_ros.testing.unique_domain).
if [ -z "${ROS_DOMAIN_ID:-}" ]; then
  ROS_DOMAIN_ID="$(python -c 'from tt_ros.testing import unique_domain
print(unique_domain(1, 100))' || echo $((RANDOM % 100 + 1)))"
fi
export ROS_DOMAIN_ID
export PYTHONDONTWRITEBYTECODE=1
export MPLBACKEND=Agg
python -m pytest "$@"
rc=$?
# The graph tests kill nodes on purpose: remove the shared memory they left (tt_ros.shm).
python -c 'from tt_ros.shm import remove_dead_segments; remove_dead_segments()'
if [ "$rc" -eq 5 ]; then
  echo 'run_pytest: no test was collected: that is a failure' >&2
  exit 1
fi
exit "$rc"
