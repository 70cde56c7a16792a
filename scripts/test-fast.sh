#!/usr/bin/env bash
# The edit-test loop: the unit layer and the doctests (pure logic, no processes, no Zenoh session, no mission,
# nothing that needs root, Docker, a browser or a data set) on two workers. The whole suite: scripts/test.sh.
# Extra arguments go to pytest (e.g. a path, -k EXPR, -x).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh test
exec .venv/bin/python -m pytest -q -n "${SKYNET_TEST_WORKERS:-2}" --durations=10 \
  -m "not mission and not network and not root and not docker and not browser and not data and not slow" "$@"
