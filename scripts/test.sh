#!/usr/bin/env bash
# The whole test suite: sets up ./.venv if needed, checks the code with ruff (pyflakes and import
# order, configured in pyproject.toml), then runs pytest.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/scripts/ensure_venv.sh"
cd "$root"
"$root/.venv/bin/ruff" check --quiet .
exec "$root/.venv/bin/python" -m pytest "$@"
