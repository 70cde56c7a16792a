#!/usr/bin/env bash
# Create or refresh the project's virtual environment (.venv) from pyproject.toml.
# usage: bash scripts/bootstrap.sh [main|EXTRA[,EXTRA...]]   (default: test)
#   main  the package alone: what `skynet mission` on simulated vehicles needs (scripts/run.sh)
#   test  the package with every optional client and the test and lint tools (scripts/test.sh, .ci/run)
# Re-installs only when pyproject.toml changed since the last install of that selection.
set -euo pipefail
cd "$(dirname "$0")/.."
extras="${1:-test}"
py="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
  "$py" -m venv .venv
fi
stamp=".venv/.installed-$extras"
if [ "$extras" = main ]; then target="."; else target=".[$extras]"; fi
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  echo "installing SkyNet Inspect and its dependencies into .venv ($target; about a minute, more on a slow network)..." >&2
  .venv/bin/python -m pip install -q --disable-pip-version-check -U pip >/dev/null
  .venv/bin/python -m pip install -q --disable-pip-version-check -e "$target"
  touch "$stamp"
  echo "installed into .venv" >&2
fi
