#!/usr/bin/env bash
# The test suite: sets up ./.venv if needed, checks the code with ruff (pyflakes and import order,
# configured in pyproject.toml), then runs pytest on every core (at most 4 workers, each test file
# on one worker so that its module fixtures are built once; the longest files first,
# tests/conftest.py). The engine's kernels are compiled first, in parallel, into the tests' cache
# (tests/conftest.py's default folder): on an empty cache each worker and the first child
# processes would otherwise compile them again. The tests marked ``benchmark`` (a benchmark
# command end to end) are left out: ``bash scripts/test.sh -m benchmark`` runs them (CI does).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/scripts/ensure_venv.sh"
cd "$root"
"$root/.venv/bin/ruff" check --quiet .
cores="$(nproc 2>/dev/null || echo 2)"
export MOGAFACE_CACHE_DIR="${MOGAFACE_CACHE_DIR:-${TMPDIR:-/tmp}/mogaface-test-cache}"
"$root/.venv/bin/python" -m mogaface compile-kernels --jobs "$(( cores < 3 ? cores : 3 ))" >/dev/null \
    || echo "compile-kernels failed: the tests compile the kernels as they go" >&2
exec "$root/.venv/bin/python" -m pytest -n "$(( cores < 4 ? cores : 4 ))" --dist loadfile --no-loadscope-reorder \
    -m "not benchmark" "$@"
