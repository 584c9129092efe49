#!/usr/bin/env bash
# Build the ready-to-install extension zip, dist/mogaface-VERSION.zip, with Blender's own tool,
# then validate the zip with Blender's validator. "Install from Disk" in Blender takes this file.
#
#   scripts/build_extension.sh [--output-dir DIR]
#
# The tool is `blender --command extension` when BLENDER names a Blender program, else the copy
# of the same tool inside the bpy wheel of .venv (bpy/5.0/scripts/addons_core/bl_pkg/cli/
# blender_ext.py; MOGAFACE_PYTHON picks another interpreter with the bpy wheel). In a git checkout
# the zip holds the tracked files only (as they are in the working tree), so nothing left lying
# in the folder is shipped; the manifest's [build] paths_exclude_pattern then leaves out tests,
# docs, benchmarks and caches.
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
out="$root/dist"
while [ $# -gt 0 ]; do
    case "$1" in
        --output-dir) out="$(realpath -m "$2")"; shift 2 ;;
        *) echo "usage: $0 [--output-dir DIR]" >&2; exit 2 ;;
    esac
done

if [ -n "${BLENDER:-}" ]; then
    tool=("$BLENDER" -b --factory-startup --command extension)
else
    python="${MOGAFACE_PYTHON:-$root/.venv/bin/python}"
    ext="$("$python" - <<'PY'
import importlib.util, pathlib, sys
spec = importlib.util.find_spec("bpy")
found = sorted(pathlib.Path(spec.origin).parent.glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py")) if spec else []
if not found:
    sys.exit("build_extension: no bpy wheel with Blender's extension tool in this Python; "
             "set BLENDER to a Blender program, or MOGAFACE_PYTHON to a Python with bpy")
print(found[-1])
PY
)"
    tool=("$python" "$ext")
fi

stage="$(mktemp -d)"
trap 'rm -rf "$stage"' EXIT
source_dir="$root"
if git -C "$root" rev-parse --is-inside-work-tree >/dev/null 2>&1; then
    source_dir="$stage/src"
    mkdir -p "$source_dir"
    # tracked files present in the working tree (a deleted one is simply not shipped)
    while IFS= read -r -d '' path; do
        [ -f "$root/$path" ] && (cd "$root" && cp --parents -p "$path" "$source_dir/")
    done < <(git -C "$root" ls-files -z --cached)
fi
mkdir -p "$out"
version="$(sed -n 's/^version *= *"\(.*\)"/\1/p' "$root/blender_manifest.toml" | head -1)"
zip="$out/mogaface-$version.zip"
rm -f "$zip"
"${tool[@]}" build --source-dir "$source_dir" --output-filepath "$zip"
"${tool[@]}" validate "$zip"
echo "built $zip"
