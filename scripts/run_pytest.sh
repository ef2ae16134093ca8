#!/usr/bin/env bash
# Run the whole test suite. pytest's exit 5 (no test collected) is a failure here.
set -uo pipefail
# The ROS environment (LOCALHOST discovery, a domain of the suite's own, the shared memory
# that killed nodes leave removed at the end) is tt_ros.pytest_env's, which pyproject.toml's
# addopts load, as each package's setup.cfg does for colcon test.
export PYTHONDONTWRITEBYTECODE=1
python -m pytest "$@"
rc=$?
if [ "$rc" -eq 5 ]; then
  echo 'run_pytest: no test was collected: that is a failure' >&2
  exit 1
fi
exit "$rc"
