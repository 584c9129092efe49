#!/usr/bin/env bash
# The screenshots of docs/blender.md (run by hand, not in CI): a demo-preset avatar in the real
# Blender program (Debian trixie's Blender 4.3.2 in the chroot of scripts/real_blender_chroot.sh,
# under Xvfb), as a user sees it: the 3D viewport, F12 beside a cube and a backdrop, Render Frame,
# under Standard; the same view drawn by the GPU (Draw: GPU) beside Draw: CPU Exact; the viewport
# (Material Preview) and F12 under AgX too
# (tests/real_blender/docs_screenshots.py). About 4 minutes on 2 cores once the packages are in.
#
#   scripts/docs_screenshots.sh [--demo DIR] [--images DIR] [--frame N]
#
# --demo: a finished `scripts/demo.sh` (default out/demo: its capture/ and run/ are used);
# --images: where the PNGs go (default docs/images). Needs root. Blender's Python gets Debian's
# python3-torch, and Install Dependencies installs the rest once into the work folder
# (MOGAFACE_SCREENSHOTS_WORK, default /var/cache/mogaface/docs-screenshots, kept between runs).
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
demo="$root/out/demo"
images="$root/docs/images"
frame=1
while [ $# -gt 0 ]; do
    case "$1" in
        --demo) demo="$(realpath "$2")"; shift 2 ;;
        --images) images="$(realpath -m "$2")"; shift 2 ;;
        --frame) frame="$2"; shift 2 ;;
        *) echo "usage: $0 [--demo DIR] [--images DIR] [--frame N]" >&2; exit 2 ;;
    esac
done
[ -f "$demo/run/avatar.pt" ] && [ -d "$demo/capture" ] || {
    echo "error: $demo holds no finished demo (run scripts/demo.sh first)" >&2; exit 1; }
work="${MOGAFACE_SCREENSHOTS_WORK:-/var/cache/mogaface/docs-screenshots}"
chroot_sh="$root/scripts/real_blender_chroot.sh"
camera="$("$root/.venv/bin/python" -c "
from mogaface.core.data.capture import Capture
capture = Capture.open('$demo/capture')
print(capture.splits['val'][0].camera_id if capture.splits.get('val') else next(iter(capture.cameras)))")"

bash "$chroot_sh" ensure
bash "$chroot_sh" system-torch yes
rm -rf "$work/images" "$work/dist"
mkdir -p "$work/images" "$work/dist"
cat > "$work/steps.sh" <<EOF
set -euo pipefail
export BLENDER_USER_RESOURCES=/work/user
blender -b --factory-startup --command extension build --source-dir /src --output-dir /work/dist
blender -b --command extension install-file -r user_default -e /work/dist/mogaface-*.zip
xvfb-run -a -s "-screen 0 1600x1000x24" blender --enable-event-simulate \
    --python /src/tests/real_blender/docs_screenshots.py -- \
    '{"work": "/work", "images": "/work/images", "capture": "/demo/capture", "run": "/demo/run",
      "camera": "$camera", "frame": $frame, "torch_index": "https://download.pytorch.org/whl/cpu"}'
python3 -c "import json, sys; r = json.load(open('/work/results.json')); print(json.dumps(r, indent=1)); sys.exit(0 if r.get('ok') else 1)"
EOF
MOGAFACE_EXTRA_BIND="$demo:/demo" bash "$chroot_sh" run "$root" "$work" -- bash /work/steps.sh
mkdir -p "$images"
cp "$work"/images/blender_*.png "$images"/
ls -l "$work"/images/blender_*.png
