#!/usr/bin/env bash
# The whole test suite, in the project's own virtual environment (created from pyproject.toml).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh test
# Two pytest workers (pytest-xdist): the whole missions (marker "mission") run one at a time on one worker,
# the rest of the suite is shared, and the late missions (tests/conftest.py) go to whichever worker is free
# after it; SKYNET_TEST_WORKERS=0 runs everything in one process.
exec .venv/bin/python -m pytest -q -n "${SKYNET_TEST_WORKERS:-2}" --dist loadgroup "$@"
