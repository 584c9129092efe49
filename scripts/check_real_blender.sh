#!/usr/bin/env bash
# End-to-end check of the extension in the real Blender program (Debian trixie's Blender 4.3.2,
# Python 3.13, no numpy), as a user drives it. Needs root (a cached chroot, see
# scripts/real_blender_chroot.sh, built here when missing) and network access to the package index.
#
#   scripts/check_real_blender.sh [--images DIR] [--keep]
#
# Steps: the pins resolve to wheels for Python 3.11 and 3.13; `blender --command extension build`;
# `extension install-file` into a clean user folder; in a window under Xvfb (tests/real_blender/
# ui_check.py): Install Dependencies (cancel, then the whole install, the LPIPS weights included),
# import a capture and a head into the startup file (the head framed, the default cube hidden),
# train through the modal operator with the panel's default preset (cancel, resume; the avatar
# linked and scored with LPIPS; the progress text fits the sidebar), load the avatar (its longest
# interface block timed), render a frame and a keyed animation, export a PLY, the avatar in the
# viewport and in F12; the pixels of each place read back against the core render, one line each
# ("pixels PLACE: X dB against the core render"; below 35 dB under Standard fails), with
# screenshots under AgX and Standard; disable the extension (F12 without the avatar, the head a
# mesh again, no threads left) and enable it again; Drive from Footage on the trained avatar with
# another subject's clip (the keys equal the tracker's parameters, two rendered frames each the core
# render of its keys) and Track Footage of a phone clip (the movie behind the camera, the head's
# landmarks read back from Blender against the tracker's fit, its F12 silhouette against the
# person's mask, the interface timed while each child runs); headless: scripts/mogaface_blend.py with
# --factory-startup, with a .blend, and training with the demo preset (scored with LPIPS); then
# disable and remove the extension (its user folder must be gone).
#
# Environment: MOGAFACE_CHECK_TORCH_INDEX: the torch index the add-on installs from ("" = PyPI's
# torch, the CUDA build: ≈ 8 GB of disk). By default, the CPU build's index when it can be reached;
# else Blender's Python gets Debian's python3-torch, the add-on uses it and installs the rest
# (said in the log).
# MOGAFACE_CHECK_WORK (default: a fresh folder under /var/cache/mogaface), MOGAFACE_PIP_CACHE
# (default /var/cache/mogaface/pip-cache: pip's cache folder, kept between runs).
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
images="$root/docs/images"
keep=0
while [ $# -gt 0 ]; do
    case "$1" in
        --images) images="$(realpath -m "$2")"; shift 2 ;;
        --keep) keep=1; shift ;;
        *) echo "usage: $0 [--images DIR] [--keep]" >&2; exit 2 ;;
    esac
done
cpu_index=https://download.pytorch.org/whl/cpu
pip_cache="${MOGAFACE_PIP_CACHE:-/var/cache/mogaface/pip-cache}"
work="${MOGAFACE_CHECK_WORK:-$(mkdir -p /var/cache/mogaface && mktemp -d /var/cache/mogaface/check.XXXXXX)}"
chroot_sh="$root/scripts/real_blender_chroot.sh"
python="$root/.venv/bin/python"
started=$(date +%s)

say() { echo "[check] $(( $(date +%s) - started )) s: $*"; }
cleanup() { [ "$keep" = 1 ] || rm -rf "$work"; }
trap cleanup EXIT

say "work folder $work (load $(cut -d' ' -f1-3 /proc/loadavg))"
system_torch=no
if [ -n "${MOGAFACE_CHECK_TORCH_INDEX+set}" ]; then
    torch_index="$MOGAFACE_CHECK_TORCH_INDEX"
elif "$python" -c "import urllib.request; urllib.request.urlopen('$cpu_index/', timeout=15)" 2>/dev/null; then
    torch_index="$cpu_index"
else  # the product never falls back silently; the check says so and tests with the system's torch
    torch_index="$cpu_index" system_torch=yes
    say "$cpu_index cannot be reached from here: Blender's Python gets Debian's python3-torch (and numpy)"
fi
bash "$chroot_sh" ensure
bash "$chroot_sh" system-torch "$system_torch"
mkdir -p "$work/dist" "$work/images" "$pip_cache"

say "the pins resolve to binary wheels for Python 3.11 and 3.13"
for version in 3.11 3.13; do
    mapfile -t pins < <("$python" -c "
from mogaface.core.for_blender import dependencies as d
print(*d.requirements(tuple(map(int, '$version'.split('.'))), has_numpy=False), sep='\n')")
    "$python" -m pip install --quiet --dry-run --no-deps --ignore-installed --target "$work/resolve" \
        --python-version "$version" --only-binary=:all: --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 \
        --platform manylinux2014_x86_64 "${pins[@]}"
done

say "fixtures: a small capture and a head"
"$python" -m mogaface make-capture "$work/capture" --views 3 --timesteps 16 --size 48 --quiet
"$python" -m mogaface make-head "$work/head.npz"
say "fixtures: a phone clip to track and another subject's performance to drive an avatar with"
"$python" -m mogaface make-footage "$work/footage" --size 144x256 --seconds 0.5 --supersample 1 --novel-views 0 \
    --seed 3 --quiet
"$python" -m mogaface make-footage "$work/performance-clip" --kind fixed --subject 1 --size 144x256 --seconds 0.6 \
    --supersample 1 --novel-views 0 --seed 5 --quiet

# Everything below runs inside the chroot: /src is this checkout (read-only), /work the work folder.
cat > "$work/steps.sh" <<EOF
set -euo pipefail
export BLENDER_USER_RESOURCES=/work/user PIP_CACHE_DIR=/pip-cache
say() { echo "[check] \$*"; }
say "build and install the extension"
blender -b --factory-startup --command extension build --source-dir /src --output-dir /work/dist
blender -b --command extension install-file -r user_default -e /work/dist/mogaface-*.zip
test -f /work/user/extensions/user_default/mogaface/__init__.py
say "the extension in a window: dependencies, import, train, render, export"
xvfb-run -a -s "-screen 0 1600x1000x24" blender --enable-event-simulate --python /src/tests/real_blender/ui_check.py -- \
    '{"work": "/work", "images": "/work/images", "capture": "/work/capture", "head": "/work/head.npz",
      "torch_index": "$torch_index", "system_torch": $([ "$system_torch" = yes ] && echo true || echo false),
      "steps": 300, "footage": "/work/footage/footage/clip.mp4",
      "performance": "/work/performance-clip/footage/clip.mp4"}'
python3 -c "import json, sys; r = json.load(open('/work/results.json')); print(json.dumps(r, indent=1)); sys.exit(0 if r.get('ok') else 1)"
say "headless: --factory-startup, then a .blend"
blender -b --factory-startup --python /src/scripts/mogaface_blend.py -- /work/capture --run /work/run \
    --blend /work/scene.blend --frames 1 2
test -f /work/scene.blend
blender -b /work/scene.blend --python /src/scripts/mogaface_blend.py -- /work/capture --run /work/run \
    --blend /work/scene2.blend --frames 1 1
test -f /work/scene2.blend
say "headless training with the demo preset: a linked, scored avatar"
blender -b --factory-startup --python /src/scripts/mogaface_blend.py -- /work/capture --run /work/run-demo \
    --blend /work/scene-demo.blend --train --preset demo --steps 60 --frames 1 2
test -f /work/scene-demo.blend
python3 -c "import json, sys; m = json.load(open('/work/run-demo/metrics_train_end.json')); print('headless demo run:', m)
sys.exit(0 if 'lpips' in m and 'not_scored' not in m else 1)"
say "disable and remove the extension"
blender -b --command extension remove user_default.mogaface
test ! -e /work/user/extensions/user_default/mogaface
test ! -e /work/user/extensions/.user/user_default/mogaface
EOF

say "in the real Blender"
MOGAFACE_EXTRA_BIND="$pip_cache:/pip-cache" bash "$chroot_sh" run "$root" "$work" -- bash /work/steps.sh
mkdir -p "$images"
cp "$work"/images/blender-*.png "$images"/ 2>/dev/null || true
say "passed: $(python3 -c "import json; r = json.load(open('$work/results.json')); print(json.dumps(r.get('install')))")"
