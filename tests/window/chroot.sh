#!/usr/bin/env bash
# A real Blender with its window on a Debian 12 machine: a chroot of a newer Debian suite holding its
# Blender, Xvfb, xdotool and ImageMagick, cached outside the clone (about 1.5 GB, a few minutes to build
# once). Suites: trixie (Debian 13: Blender 4.3), sid (Debian unstable: Blender 5.2).
#
#   tests/window/chroot.sh setup [SUITE]      build the chroot if it is not there yet (root, network)
#   tests/window/chroot.sh run SUITE CMD…     run CMD inside it, with /proc, /sys and /dev mounted in a
#                                             private mount namespace, so nothing stays mounted after
#   tests/window/chroot.sh path [SUITE]       print the chroot's folder
#
# CONTACT_EDIT_WINDOW_CACHE overrides the parent folder (default: ~/.cache/contact-edit).
set -euo pipefail
cache=${CONTACT_EDIT_WINDOW_CACHE:-$HOME/.cache/contact-edit}
packages="blender python3-numpy python3-cattr python3-requests xvfb xdotool x11-utils imagemagick libgl1-mesa-dri fonts-dejavu-core xauth"

folder() { echo "$cache/blender-$1"; }

in_root() {
    # $1: the chroot; $2…: the command. The namespace is private, so the mounts vanish with it.
    unshare --mount --propagation private -- bash -c '
        root=$1; shift
        mount -t proc proc "$root/proc"
        mount -t sysfs sys "$root/sys"
        mount --rbind /dev "$root/dev"
        exec chroot "$root" /usr/bin/env -i HOME=/root PATH=/usr/sbin:/usr/bin:/sbin:/bin LANG=C.UTF-8 "$@"
    ' in_root "$@"
}

command=${1:-}
shift || true
case $command in
setup)
    suite=${1:-trixie}
    root=$(folder "$suite")
    if [ -f "$root/.contact-edit-ready" ]; then
        if [ "$(cat "$root/.contact-edit-packages" 2>/dev/null)" != "$packages" ]; then
            # made when the list was another: add what is new
            in_root "$root" bash -c "apt-get update -q && DEBIAN_FRONTEND=noninteractive \
                apt-get install -y -q --no-install-recommends $packages && apt-get clean"
            echo "$packages" > "$root/.contact-edit-packages"
        fi
        echo "Blender window chroot ready: $root ($(cat "$root/.contact-edit-ready"))"
        exit 0
    fi
    [ "$(id -u)" = 0 ] || { echo "building the chroot needs root (debootstrap, chroot)" >&2; exit 1; }
    if ! command -v debootstrap >/dev/null; then
        apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q debootstrap
    fi
    mirror=$(awk '/^URIs:/{print $2; exit}' /etc/apt/sources.list.d/debian.sources 2>/dev/null || true)
    mirror=${mirror:-http://deb.debian.org/debian}
    partial="$root.partial"
    rm -rf "$partial"
    mkdir -p "$cache"
    debootstrap --variant=minbase "$suite" "$partial" "$mirror"
    cp /etc/resolv.conf "$partial/etc/"
    ln -sf /proc/self/mounts "$partial/etc/mtab"
    # The machine's mirror may be a dated snapshot whose unstable Release file has expired.
    echo 'Acquire::Check-Valid-Until "false";' > "$partial/etc/apt/apt.conf.d/99contact-edit"
    in_root "$partial" bash -c "apt-get update -q && DEBIAN_FRONTEND=noninteractive \
        apt-get install -y -q --no-install-recommends $packages && apt-get clean"
    in_root "$partial" blender --version | head -1 > "$partial/.contact-edit-ready"
    echo "$packages" > "$partial/.contact-edit-packages"
    rm -rf "$root"
    mv "$partial" "$root"
    echo "Blender window chroot ready: $root ($(cat "$root/.contact-edit-ready"))"
    ;;
run)
    suite=${1:?which suite}
    shift
    root=$(folder "$suite")
    [ -d "$root/usr/bin" ] || { echo "no chroot at $root: run '$0 setup $suite'" >&2; exit 1; }
    in_root "$root" "$@"
    ;;
path)
    folder "${1:-trixie}"
    ;;
*)
    sed -n '2,11p' "$0" >&2
    exit 2
    ;;
esac
