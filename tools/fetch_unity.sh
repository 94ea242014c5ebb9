#!/usr/bin/env bash
# Fetches the Unity test framework (ThrowTheSwitch, MIT licence) into DEST without touching any
# system file: Debian's cjson source package bundles Unity under tests/unity, so we download that
# source package with a private apt sources list, lists and cache dir, unpack it with tar and copy
# the Unity parts we use.
#
#   tools/fetch_unity.sh [DEST]        (default DEST: <repo>/.deps/unity)
#
# Does nothing when DEST/src/unity.c already exists. Needs only apt-get, tar and gzip (all in a
# minbase Debian); the signature of the source index is checked against debian-archive-keyring.
# Overrides: VL_DEBIAN_MIRROR (default http://deb.debian.org/debian), VL_DEBIAN_SUITE (bookworm).
set -euo pipefail

repo_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
dest="${1:-$repo_root/.deps/unity}"
mirror="${VL_DEBIAN_MIRROR:-http://deb.debian.org/debian}"
suite="${VL_DEBIAN_SUITE:-bookworm}"
keyring=/usr/share/keyrings/debian-archive-keyring.gpg

if [ -f "$dest/src/unity.c" ]; then
  echo "Unity already present at $dest"
  exit 0
fi
command -v apt-get >/dev/null 2>&1 || { echo "ERROR: apt-get not found; get Unity yourself and pass UNITY_ROOT=/path/to/Unity" >&2; exit 1; }

tmp="$(mktemp -d "${TMPDIR:-/tmp}/vl-unity.XXXXXX")"
trap 'rm -rf "$tmp"' EXIT
mkdir -p "$tmp/lists/partial" "$tmp/cache/archives/partial" "$tmp/src"

signed_by=""
[ -f "$keyring" ] && signed_by="[signed-by=$keyring] "
echo "deb-src ${signed_by}$mirror $suite main" >"$tmp/sources.list"

# As root apt downloads as the unprivileged _apt user; let it write where it downloads so it does
# not warn and fall back to downloading as root.
chmod 755 "$tmp"
if [ "$(id -u)" -eq 0 ] && id _apt >/dev/null 2>&1; then
  chown _apt "$tmp/lists/partial" "$tmp/cache/archives/partial" "$tmp/src"
fi

apt_private=(
  -o "Dir::Etc::SourceList=$tmp/sources.list"
  -o "Dir::Etc::SourceParts=/dev/null"
  -o "Dir::State::Lists=$tmp/lists"
  -o "Dir::Cache=$tmp/cache"
  -o "Dir::Cache::pkgcache="
  -o "Dir::Cache::srcpkgcache="
  -o "Acquire::Languages=none"
  -q
)

echo "fetching Debian's cjson source package ($suite) for its bundled Unity"
apt-get "${apt_private[@]}" update
(cd "$tmp/src" && apt-get "${apt_private[@]}" source --download-only cjson)

orig="$(find "$tmp/src" -maxdepth 1 -name 'cjson_*.orig.tar.gz' | head -n1)"
[ -n "$orig" ] || { echo "ERROR: no cjson_*.orig.tar.gz was downloaded" >&2; exit 1; }
tar -xzf "$orig" -C "$tmp/src" --wildcards '*/tests/unity/*'
unity="$(find "$tmp/src" -mindepth 3 -maxdepth 3 -type d -path '*/tests/unity' | head -n1)"
if [ -z "$unity" ] || [ ! -f "$unity/src/unity.c" ]; then
  echo "ERROR: tests/unity/src/unity.c not found in $orig" >&2
  exit 1
fi

# Assemble next to DEST, then move into place, so an interrupted run never leaves a half tree.
mkdir -p "$(dirname "$dest")"
stage="$(mktemp -d "$(dirname "$dest")/.unity-stage.XXXXXX")"
trap 'rm -rf "$tmp" "$stage"' EXIT
mkdir -p "$stage/examples" "$stage/extras/fixture" "$stage/release"
cp -R "$unity/src" "$stage/src"
cp "$unity/examples/unity_config.h" "$stage/examples/"
[ -d "$unity/extras/fixture/src" ] && cp -R "$unity/extras/fixture/src" "$stage/extras/fixture/src"
[ -f "$unity/docs/license.txt" ] && cp "$unity/docs/license.txt" "$stage/LICENSE.txt"
[ -f "$unity/release/version.info" ] && cp "$unity/release/version.info" "$stage/release/"
echo "$(basename "$orig") (Debian $suite), tests/unity" >"$stage/SOURCE"
chmod 755 "$stage"
rm -rf "$dest"
mv "$stage" "$dest"
echo "Unity $(cat "$dest/release/version.info" 2>/dev/null || echo '?') installed at $dest"
