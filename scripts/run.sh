#!/usr/bin/env bash
# The main job: install, then run a full simulated inspection mission on the paper's scenario.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh test
exec .venv/bin/skynet mission "$@"
