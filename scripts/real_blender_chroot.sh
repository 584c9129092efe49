#!/usr/bin/env bash
# The real Blender program (Debian trixie's Blender 4.3.2, Python 3.13) in a cached chroot.
#
#   scripts/real_blender_chroot.sh ensure              build the chroot if missing (idempotent)
#   scripts/real_blender_chroot.sh system-torch yes|no Debian's python3-torch (with its numpy) in the
#                                                      chroot's Python, or not (idempotent)
#   [MOGAFACE_EXTRA_BIND=HOST:INSIDE] scripts/real_blender_chroot.sh run CHECKOUT WORK -- CMD...
#                                                      run CMD inside it with CHECKOUT bind-mounted
#                                                      read-only at /src and WORK read-write at /work;
#                                                      everything mounted is unmounted on exit
#
# The host release only packages Blender 3.4 (no `--command extension`), so the chroot is the
# reproducible way to get Blender >= 4.2 here. It lives outside any repository:
# MOGAFACE_BLENDER_CHROOT (default /var/cache/mogaface/blender-trixie). Needs root and debootstrap.
set -euo pipefail

CHROOT="${MOGAFACE_BLENDER_CHROOT:-/var/cache/mogaface/blender-trixie}"
MIRROR="${MOGAFACE_DEBIAN_MIRROR:-http://deb.debian.org/debian}"
PACKAGES=(blender xvfb xauth mesa-utils libgl1-mesa-dri ca-certificates python3-pip imagemagick)
CHROOT_PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin

die() { echo "real_blender_chroot: $*" >&2; exit 1; }

ensure() {
    [ "$(id -u)" = 0 ] || die "needs root (debootstrap, chroot, mount)"
    if [ -x "$CHROOT/usr/bin/blender" ] && [ "$(cat "$CHROOT/.mogaface-ready" 2>/dev/null)" = "${PACKAGES[*]}" ]; then
        return 0
    fi
    command -v debootstrap >/dev/null || {
        export DEBIAN_FRONTEND=noninteractive
        apt-get update -qq && apt-get install -y -qq debootstrap >/dev/null
    }
    mkdir -p "$(dirname "$CHROOT")"
    if [ ! -x "$CHROOT/usr/bin/apt-get" ]; then
        rm -rf "$CHROOT.partial"
        debootstrap --variant=minbase trixie "$CHROOT.partial" "$MIRROR"
        mv "$CHROOT.partial" "$CHROOT"
    fi
    cp -L /etc/resolv.conf "$CHROOT/etc/resolv.conf"
    mkdir -p "$CHROOT/usr/local/share/ca-certificates/host"
    if [ -f /etc/ssl/certs/ca-certificates.crt ]; then
        cp -L /etc/ssl/certs/ca-certificates.crt "$CHROOT/usr/local/share/ca-certificates/host/host.crt"
    fi
    in_chroot_plain bash -c "export DEBIAN_FRONTEND=noninteractive
        apt-get update -qq && apt-get install -y -qq --no-install-recommends ${PACKAGES[*]} >/dev/null
        update-ca-certificates >/dev/null 2>&1 || true
        apt-get clean"
    in_chroot_plain blender --version | head -1
    echo "${PACKAGES[*]}" > "$CHROOT/.mogaface-ready"
}

system_torch() {  # the system Python's torch, as a Debian user with python3-torch has it
    ensure
    case "${1:-}" in
        yes) in_chroot_plain bash -c "dpkg -s python3-torch >/dev/null 2>&1 || {
                 export DEBIAN_FRONTEND=noninteractive
                 apt-get update -qq && apt-get install -y -qq --no-install-recommends python3-torch >/dev/null &&
                 apt-get clean; }" ;;
        no) in_chroot_plain bash -c "! dpkg -s python3-torch >/dev/null 2>&1 ||
                 DEBIAN_FRONTEND=noninteractive apt-get purge -y -qq --autoremove python3-torch >/dev/null" ;;
        *) die "usage: system-torch yes|no" ;;
    esac
}

MOUNTED=()
unmount_all() {
    local i
    for ((i=${#MOUNTED[@]}-1; i>=0; i--)); do
        umount -l "${MOUNTED[$i]}" 2>/dev/null || true
    done
    MOUNTED=()
}
trap unmount_all EXIT INT TERM

mount_into() {  # mount_into TARGET MOUNT-ARGS...
    local target="$1"; shift
    mkdir -p "$target"
    mount "$@" "$target"
    MOUNTED+=("$target")
}

mount_system() {
    mountpoint -q "$CHROOT/proc" || mount_into "$CHROOT/proc" -t proc proc
    mountpoint -q "$CHROOT/dev" || mount_into "$CHROOT/dev" --bind /dev
    mountpoint -q "$CHROOT/dev/shm" || mount_into "$CHROOT/dev/shm" -t tmpfs tmpfs
    mountpoint -q "$CHROOT/dev/pts" || mount_into "$CHROOT/dev/pts" --bind /dev/pts  # apt's log
}

in_chroot_plain() {
    mount_system
    chroot "$CHROOT" env -i HOME=/root PATH="$CHROOT_PATH" LANG=C.UTF-8 \
        SSL_CERT_FILE=/etc/ssl/certs/ca-certificates.crt PIP_CERT=/etc/ssl/certs/ca-certificates.crt "$@"
}

run() {
    [ $# -ge 3 ] && [ "$3" = "--" ] || die "usage: run CHECKOUT WORK -- CMD..."
    if [ -z "${MOGAFACE_PRIVATE_MOUNTS:-}" ] && command -v unshare >/dev/null; then
        # A private mount namespace: our mounts are invisible to (and cannot be unmounted by)
        # another run using the same chroot, and vanish with the process whatever happens.
        MOGAFACE_PRIVATE_MOUNTS=1 exec unshare --mount --propagation private "$0" run "$@"
    fi
    local checkout work
    checkout="$(realpath "$1")"; work="$(realpath "$2")"; shift 3
    ensure
    mount_into "$CHROOT/src" --bind "$checkout"
    mount -o remount,bind,ro "$CHROOT/src"
    mount_into "$CHROOT/work" --bind "$work"
    if [ -n "${MOGAFACE_EXTRA_BIND:-}" ]; then  # HOST:INSIDE, read-write (e.g. a pip cache)
        mkdir -p "${MOGAFACE_EXTRA_BIND%%:*}"
        mount_into "$CHROOT${MOGAFACE_EXTRA_BIND#*:}" --bind "${MOGAFACE_EXTRA_BIND%%:*}"
    fi
    cp -L /etc/hosts "$CHROOT/etc/hosts"
    cp -L /etc/resolv.conf "$CHROOT/etc/resolv.conf"
    in_chroot_plain "$@"
}

case "${1:-}" in
    ensure) ensure ;;
    system-torch) system_torch "${2:-}" ;;
    run) shift; run "$@" ;;
    *) die "usage: $0 ensure | system-torch yes|no | run CHECKOUT WORK -- CMD..." ;;
esac
