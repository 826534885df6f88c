#!/usr/bin/env bash
# Print the path of a udevadm that has `verify` (systemd >= 254), for tests/test_udev.py.
#
#     bash scripts/udevadm_tool.sh DIR
#
# The machine's own udevadm where it has `verify`.  Otherwise (Debian 12 ships systemd 252)
# udev and libsystemd-shared from Debian's bookworm-backports are unpacked into DIR, not
# installed: nothing on the machine changes, and udevadm runs from DIR with its library.
# The packages are checked as apt checks them: the suite's InRelease against Debian's
# archive keyring (gpgv), Packages.xz against the InRelease's SHA256, each .deb against
# Packages' SHA256.  A failed check is a failure, not a skip (CI requires the verify).
set -euo pipefail

dir=${1:?usage: udevadm_tool.sh DIR}
if command -v udevadm >/dev/null 2>&1 && udevadm --help 2>/dev/null | grep -qw verify; then
  command -v udevadm
  exit 0
fi
if [ -x "$dir/udevadm" ] && "$dir/udevadm" --help 2>/dev/null | grep -qw verify; then
  echo "$dir/udevadm"
  exit 0
fi

mirror=${DEBIAN_MIRROR:-http://deb.debian.org/debian}
suite=bookworm-backports
arch=$(dpkg --print-architecture)
keyring=/usr/share/keyrings/debian-archive-keyring.gpg
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
mkdir -p "$dir"

curl -fsSL -o "$work/InRelease" "$mirror/dists/$suite/InRelease"
gpgv --keyring "$keyring" --output "$work/Release" "$work/InRelease" 2>/dev/null || {
  echo "udevadm_tool: $suite's InRelease does not verify against $keyring" >&2
  exit 1
}
index="main/binary-$arch/Packages.xz"
want=$(awk -v f="$index" 'length($1) == 64 && $3 == f {print $1}' "$work/Release" | tail -1)
curl -fsSL -o "$work/Packages.xz" "$mirror/dists/$suite/$index"
echo "$want  $work/Packages.xz" | sha256sum -c --quiet - || {
  echo "udevadm_tool: $index does not match its InRelease" >&2
  exit 1
}
xz -dc "$work/Packages.xz" >"$work/Packages"

for pkg in udev libsystemd-shared; do
  read -r file sum < <(awk -v p="$pkg" '
    $1 == "Package:" {ok = ($2 == p)}
    ok && $1 == "Filename:" {f = $2}
    ok && $1 == "SHA256:" {print f, $2; exit}' "$work/Packages")
  [ -n "${file:-}" ] || { echo "udevadm_tool: no $pkg in $suite" >&2; exit 1; }
  curl -fsSL -o "$work/$pkg.deb" "$mirror/$file"
  echo "$sum  $work/$pkg.deb" | sha256sum -c --quiet - || {
    echo "udevadm_tool: $file does not match Packages" >&2
    exit 1
  }
  dpkg-deb -x "$work/$pkg.deb" "$dir/root"
done

bin=$(find "$dir/root" -path '*bin/udevadm' -type f | head -1)
lib=$(dirname "$(find "$dir/root" -name 'libsystemd-shared-*.so' | head -1)")
cat >"$dir/udevadm" <<EOF
#!/bin/sh
LD_LIBRARY_PATH="$lib" exec "$bin" "\$@"
EOF
chmod +x "$dir/udevadm"
"$dir/udevadm" --help | grep -qw verify || {
  echo "udevadm_tool: the unpacked udevadm has no verify" >&2
  exit 1
}
echo "$dir/udevadm"
