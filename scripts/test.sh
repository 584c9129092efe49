#!/usr/bin/env bash
# The whole test suite: sets up ./.venv if needed, checks the code with ruff (pyflakes and import
# order, configured in pyproject.toml), then runs pytest on every core (at most 4 workers, each
# test file on one worker so that its module fixtures are built once).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/scripts/ensure_venv.sh"
cd "$root"
"$root/.venv/bin/ruff" check --quiet .
cores="$(nproc 2>/dev/null || echo 2)"
exec "$root/.venv/bin/python" -m pytest -n "$(( cores < 4 ? cores : 4 ))" --dist loadfile "$@"
