#!/usr/bin/env bash
# A user-mode Linux kernel that boots on this host, for `wheelchair-hil sandbox --socketcan`.
#
#   tools/bus/uml-kernel.sh [ROOT]     (ROOT: $WHEELCHAIR_HIL_UML_ROOT or ~/.cache/wheelchair-hil/uml)
#
# Debian bookworm's user-mode-linux (6.1) cannot start its init on a host whose CPU has AMX
# (Sapphire Rapids and later): the host kernel's xstate is larger than the buffer UML 6.1
# hands to ptrace ("userspace - ptrace set fp regs failed, errno = 14", then a panic).  UML
# 7.2 sizes it from the host.  This script boots the installed kernel once; if that fails, it
# downloads the pinned user-mode-linux package from Debian unstable and a libc6 new enough
# for it from Debian trixie into ROOT (nothing of the host's is replaced: a private apt list,
# `apt-get download`, `dpkg-deb -x`), points the kernel at that libc with patchelf, and boots
# it once.  tools/bus/umlguest.py uses ROOT's kernel and modules when ROOT/usr/bin/linux.uml
# exists.  Exit 0 when a kernel that boots is there, 1 otherwise (with the reason).
set -euo pipefail

UML_VERSION=7.2um1             # Debian unstable
LIBC_VERSION=2.41-12+deb13u5   # Debian trixie (the kernel needs glibc >= 2.38)
ROOT=${1:-${WHEELCHAIR_HIL_UML_ROOT:-$HOME/.cache/wheelchair-hil/uml}}

say() { echo "uml-kernel: $*" >&2; }

# boot KERNEL with an init that only reports; 0 if it ran
boots() {
    local kernel=$1 tmp
    tmp=$(mktemp -d)
    printf '#!/bin/sh\necho uml-kernel-probe-ok\npoweroff -f\n' > "$tmp/init"
    chmod 755 "$tmp/init"
    local ok=1
    if TMPDIR=$tmp timeout 60 "$kernel" mem=256M rootfstype=hostfs rootflags=/ rw quiet \
        "init=$tmp/init" con=null con0=null,fd:1 > "$tmp/console" 2>&1 </dev/null \
        && grep -q uml-kernel-probe-ok "$tmp/console"; then
        ok=0
    elif grep -q "uml-kernel-probe-ok" "$tmp/console"; then
        ok=0  # powered off with a non-zero kernel exit
    else
        grep -m1 -E "fp regs failed|panic|error" "$tmp/console" >&2 || tail -3 "$tmp/console" >&2
    fi
    rm -rf "$tmp"
    return $ok
}

if [ -x "$ROOT/usr/bin/linux.uml" ] && boots "$ROOT/usr/bin/linux.uml"; then
    say "$ROOT/usr/bin/linux.uml boots"
    exit 0
fi
if command -v linux.uml >/dev/null && boots "$(command -v linux.uml)"; then
    say "the installed linux.uml boots on this host; nothing to do"
    exit 0
fi
say "the installed linux.uml does not boot here; installing user-mode-linux $UML_VERSION into $ROOT"

sudo=()
[ "$(id -u)" -eq 0 ] || sudo=(sudo)
if ! command -v patchelf >/dev/null; then
    DEBIAN_FRONTEND=noninteractive "${sudo[@]}" apt-get install -y -qq --no-install-recommends patchelf
fi

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
mkdir -p "$work/lists/partial" "$work/debs"
cat > "$work/sources.list" <<EOF
deb http://deb.debian.org/debian sid main
deb http://deb.debian.org/debian trixie main
EOF
apt_opts=(-o "Dir::Etc::sourcelist=$work/sources.list" -o Dir::Etc::sourceparts=/dev/null
          -o "Dir::State::Lists=$work/lists" -o Debug::NoLocking=1)
apt-get "${apt_opts[@]}" update -qq
(cd "$work/debs" && apt-get "${apt_opts[@]}" download -qq \
    "user-mode-linux=$UML_VERSION" "libc6=$LIBC_VERSION") 2>&1 | grep -v "unsandboxed" >&2 || true
for pkg in user-mode-linux libc6; do
    if ! ls "$work/debs/${pkg}_"*.deb >/dev/null 2>&1; then
        say "could not download $pkg (pinned: user-mode-linux=$UML_VERSION, libc6=$LIBC_VERSION)"
        exit 1
    fi
done

rm -rf "$ROOT.new"
mkdir -p "$ROOT.new"
for deb in "$work/debs/"*.deb; do dpkg-deb -x "$deb" "$ROOT.new"; done
libdir="$ROOT/usr/lib/x86_64-linux-gnu"
patchelf --set-interpreter "$libdir/ld-linux-x86-64.so.2" --set-rpath "$libdir" \
    "$ROOT.new/usr/bin/linux.uml"
rm -rf "$ROOT"
mv "$ROOT.new" "$ROOT"
if boots "$ROOT/usr/bin/linux.uml"; then
    say "$ROOT/usr/bin/linux.uml ($UML_VERSION) boots"
    exit 0
fi
say "$ROOT/usr/bin/linux.uml ($UML_VERSION) does not boot either"
exit 1
