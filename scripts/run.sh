#!/usr/bin/env bash
# The main job: install the package (no optional extras), then run a full simulated inspection mission on
# the paper's scenario. Secure by default (a development key set in .keys/dev, mutual TLS, certificate ACL,
# signed commands); pass --insecure to turn that off (docs/security.md). Options pass through to
# `skynet mission` (--speed, --uavs, --scenario FILE, --camera DIR, --impair, --quiet, ...).
# It ends by naming the report folder (report.md, the figures, mission.mcap, inspection/).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh main
exec .venv/bin/skynet mission "$@"
