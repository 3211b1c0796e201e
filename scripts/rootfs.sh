#!/usr/bin/env bash
# Debian root filesystems with newer tshark releases, for the version matrix.
#
#   scripts/rootfs.sh build SUITE...    make (once) and print the root folder of each suite
#   scripts/rootfs.sh path SUITE        print the root folder (exit 3 when not built yet)
#   scripts/rootfs.sh version SUITE     print the tshark version inside
#   scripts/rootfs.sh mirror            print the Debian mirror taken from apt's configuration
#   scripts/rootfs.sh clean SUITE...    remove the root folder of each suite
#
# The roots live in a cache folder outside the repository, made once and reused:
# $SHAREDLINK_ROOTFS_CACHE (default /var/cache/sharedlink-rootfs). The Debian mirror comes
# from this machine's apt configuration (/etc/apt/sources.list, /etc/apt/sources.list.d/*.list
# and *.sources) or $SHAREDLINK_DEBIAN_MIRROR; no host name is written into the repository.
# Each root is made with `debootstrap --variant=minbase`, then tshark is installed inside with
# the setuid question pre-answered "no" and without recommended packages, and an unprivileged
# user `sharedlink` is created (Wireshark 4.6 skips Lua plugins when run as root).
# scripts/tshark-in-rootfs runs tshark in such a root.
set -euo pipefail

CACHE=${SHAREDLINK_ROOTFS_CACHE:-/var/cache/sharedlink-rootfs}
APT_ETC=${SHAREDLINK_APT_ETC:-/etc/apt}  # where apt's configuration is read (tests point it elsewhere)
USER_INSIDE=sharedlink
READY=.sharedlink-ready
SUDO=""
[ "$(id -u)" = 0 ] || SUDO=sudo

die() { echo "rootfs: $*" >&2; exit 2; }
say() { echo "rootfs: $*" >&2; }

# The first Debian archive URI in apt's configuration: an enabled `deb` entry one of whose
# suites is a Debian release (not -security, -updates or -backports, nor a foreign archive).
mirror() {
    if [ -n "${SHAREDLINK_DEBIAN_MIRROR:-}" ]; then echo "$SHAREDLINK_DEBIAN_MIRROR"; return; fi
    local codename uri
    # shellcheck disable=SC1091
    codename=$(. /etc/os-release 2>/dev/null && echo "${VERSION_CODENAME:-}")
    uri=$(
        {
            # one-line format: deb [options] URI SUITE COMPONENT...
            for f in "$APT_ETC/sources.list" "$APT_ETC"/sources.list.d/*.list; do
                [ -f "$f" ] || continue
                sed -e 's/#.*//' -e 's/\[[^]]*\]//' "$f" | awk '$1 == "deb" && NF >= 4 { print $2, $3 }'
            done
            # deb822 format: stanzas of Types, URIs, Suites (and Enabled)
            for f in "$APT_ETC"/sources.list.d/*.sources; do
                [ -f "$f" ] || continue
                awk '
                    function flush() {
                        if (types ~ /(^| )deb( |$)/ && enabled != "no")
                            for (i = 1; i <= nu; i++) for (j = 1; j <= ns; j++) print u[i], s[j]
                        types = ""; enabled = ""; nu = 0; ns = 0
                    }
                    /^[[:space:]]*#/ { next }
                    /^[[:space:]]*$/ { flush(); next }
                    {
                        key = tolower($1); sub(/:$/, "", key)
                        if (key == "types") { types = ""; for (i = 2; i <= NF; i++) types = types " " $i; sub(/^ /, "", types) }
                        else if (key == "uris") { for (i = 2; i <= NF; i++) u[++nu] = $i }
                        else if (key == "suites") { for (i = 2; i <= NF; i++) s[++ns] = $i }
                        else if (key == "enabled") { enabled = tolower($2) }
                    }
                    END { flush() }
                ' "$f"
            done
        } | awk -v host="$codename" '
            {
                suite = $2
                if (suite ~ /-(security|updates|backports|proposed-updates)$/ || suite ~ /\//) next
                if (suite == host || suite ~ /^(stable|testing|unstable|oldstable|sid|experimental|buster|bullseye|bookworm|trixie|forky|duke)$/) {
                    print $1; exit
                }
            }'
    )
    [ -n "$uri" ] || die "no Debian archive found in apt's configuration; set SHAREDLINK_DEBIAN_MIRROR"
    echo "${uri%/}"
}

root_of() { echo "$CACHE/$1"; }

check_suite() {
    [[ "$1" =~ ^[a-z][a-z0-9-]*$ ]] || die "bad suite name: $1"
}

# Run a command inside ROOT as root with /proc mounted, in a private mount namespace
# (nothing stays mounted afterwards).
in_root() {
    local root=$1; shift
    # shellcheck disable=SC2016 # expanded by the inner sh
    $SUDO unshare --mount --propagation private -- sh -c '
        root=$1; shift
        mount -t proc proc "$root/proc"
        exec chroot "$root" "$@"' sh "$root" env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin \
        DEBIAN_FRONTEND=noninteractive LC_ALL=C.UTF-8 HOME=/root "$@"
}

build_one() {
    local suite=$1 root tmp mirror_uri
    root=$(root_of "$suite")
    if [ -f "$root/$READY" ]; then echo "$root"; return; fi
    command -v debootstrap >/dev/null || {
        say "installing debootstrap from Debian's packages"
        $SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq debootstrap >/dev/null
    }
    $SUDO mkdir -p "$CACHE"
    mirror_uri=$(mirror)
    tmp="$root.partial"
    $SUDO rm -rf "$tmp"
    say "debootstrap $suite from $mirror_uri into $tmp (minbase; a few minutes)"
    local start=$SECONDS
    if ! $SUDO debootstrap --variant=minbase --components=main "$suite" "$tmp" "$mirror_uri" \
            >"$CACHE/$suite.debootstrap.log" 2>&1; then
        tail -20 "$CACHE/$suite.debootstrap.log" >&2
        die "debootstrap of $suite failed (log: $CACHE/$suite.debootstrap.log)"
    fi
    say "installing tshark into $suite"
    # no daemons started inside; setuid dumpcap declined; only what tshark needs
    printf '#!/bin/sh\nexit 101\n' | $SUDO tee "$tmp/usr/sbin/policy-rc.d" >/dev/null
    $SUDO chmod 755 "$tmp/usr/sbin/policy-rc.d"
    # a snapshot mirror serves Release files past their Valid-Until date (sid's lasts a week)
    echo 'Acquire::Check-Valid-Until "false";' | $SUDO tee "$tmp/etc/apt/apt.conf.d/99sharedlink" >/dev/null
    in_root "$tmp" sh -c '
        set -e
        echo "wireshark-common wireshark-common/install-setuid boolean false" | debconf-set-selections
        apt-get update -qq
        apt-get install -y -qq --no-install-recommends tshark >/dev/null
        command -v setpriv >/dev/null || apt-get install -y -qq --no-install-recommends setpriv >/dev/null
        apt-get clean
        rm -rf /var/lib/apt/lists/*
        useradd --create-home --user-group --shell /usr/sbin/nologin '"$USER_INSIDE"'
    ' >"$CACHE/$suite.install.log" 2>&1 || {
        tail -20 "$CACHE/$suite.install.log" >&2
        die "installing tshark into $suite failed (log: $CACHE/$suite.install.log)"
    }
    local version
    version=$(in_root "$tmp" tshark --version 2>/dev/null | head -1)
    echo "$version" | $SUDO tee "$tmp/$READY" >/dev/null
    $SUDO rm -rf "$root"
    $SUDO mv "$tmp" "$root"
    say "$suite ready in $((SECONDS - start)) s: $version"
    echo "$root"
}

# one build per suite at a time (parallel test workers, parallel make)
build() {
    local suite
    for suite in "$@"; do
        check_suite "$suite"
        $SUDO mkdir -p "$CACHE"
        (
            exec 9>"$CACHE/.$suite.lock" || die "cannot write $CACHE"
            flock 9
            build_one "$suite"
        )
    done
}

cmd=${1:-}
[ -n "$cmd" ] && shift
case "$cmd" in
    build) [ $# -gt 0 ] || die "usage: rootfs.sh build SUITE..."; build "$@" ;;
    path)
        [ $# -eq 1 ] || die "usage: rootfs.sh path SUITE"; check_suite "$1"
        root=$(root_of "$1"); [ -f "$root/$READY" ] || { say "$1 is not built (make rootfs)"; exit 3; }
        echo "$root" ;;
    version)
        [ $# -eq 1 ] || die "usage: rootfs.sh version SUITE"; check_suite "$1"
        root=$(root_of "$1"); [ -f "$root/$READY" ] || { say "$1 is not built (make rootfs)"; exit 3; }
        cat "$root/$READY" ;;
    mirror) mirror ;;
    clean)
        for suite in "$@"; do check_suite "$suite"; $SUDO rm -rf "$(root_of "$suite")" "$(root_of "$suite").partial"; done ;;
    *) sed -n '2,8s/^# \{0,1\}//p' "$0" >&2; exit 2 ;;
esac
