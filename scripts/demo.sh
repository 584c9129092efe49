#!/usr/bin/env bash
# The main job on the embedded default: sets up ./.venv if needed, then runs the demo into out/demo
# (replacing the outputs of an earlier demo there).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/scripts/ensure_venv.sh"
exec "$root/.venv/bin/python" -m mogaface demo --out "$root/out/demo" --overwrite "$@"
