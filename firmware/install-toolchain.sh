#!/bin/sh
# Install the AVR toolchain and simavr that the firmware tests need, when missing.
# Idempotent and quiet: does nothing when every package is already installed.
# Used by .ci/run; on a developer machine run it once (as root or via sudo).
set -eu

# make, gcc and libc6-dev build and run the host-side unit tests and the simavr harness;
# a slim CI image may lack them.
PACKAGES="make gcc libc6-dev binutils-avr gcc-avr avr-libc simavr libsimavr-dev"

missing=""
for p in $PACKAGES; do
    if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
        missing="$missing $p"
    fi
done
[ -z "$missing" ] && exit 0

SUDO=""
if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1; then
        SUDO="sudo"
    else
        echo "install-toolchain.sh: need root to install:$missing" >&2
        exit 1
    fi
fi

export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq >/dev/null
# shellcheck disable=SC2086
$SUDO apt-get install -y -qq --no-install-recommends $missing >/dev/null
echo "install-toolchain.sh: installed$missing"
