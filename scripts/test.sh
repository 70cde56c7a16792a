#!/usr/bin/env bash
# The whole test suite, in the project's own virtual environment (created from pyproject.toml).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh test
exec .venv/bin/python -m pytest -q "$@"
