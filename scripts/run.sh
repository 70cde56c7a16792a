#!/usr/bin/env bash
# The main job: install, then run a full simulated inspection mission on the paper's scenario.
# Secure by default (a development key set in .keys/dev, mutual TLS, certificate ACL, signed commands);
# pass --insecure to turn that off (README, "Trust").
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh test
exec .venv/bin/skynet mission "$@"
