#!/usr/bin/env bash
# Shared set-up for tools/test.sh and tools/demo.sh: Debian packages, Unity, Python venv.
#
# Source it to get the vl_* functions (the caller should run with `set -euo pipefail`), or run it
# directly to do the whole set-up:  bash tools/setup.sh
#
# Environment overrides (all optional):
#   VL_SKIP_APT=1   do not check or install Debian packages (e.g. on a non-Debian host)
#   UNITY_ROOT      use this Unity tree (must hold src/unity.c) instead of fetching one
#   UNITY_DEST      where the fetched Unity goes (default <repo>/.deps/unity)
#   VENV_DIR        Python venv location (default <repo>/.venv)
#   VL_PYTHON       interpreter the venv is made from (default /usr/bin/python3, Debian's, so a
#                   pyenv shim or similar on PATH cannot make this machine differ from a clean one)
#   REQUIREMENTS    pip requirements file (default <repo>/tools/requirements.txt)

VL_REPO_ROOT="${VL_REPO_ROOT:-$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)}"

# Every Debian package the project needs, in one place.
#   build: cmake g++ make pkg-config libeigen3-dev liblcm-dev liblcm-bin (lcm-gen) libglib2.0-dev libinih-dev
#   python tools: python3 python3-venv ca-certificates (pip over https)
#   LCM integration tests: iproute2 (`ip` inside `unshare --net`; util-linux gives unshare)
#   benchmarks: valgrind
#   fuzzing (tools/fuzz.sh, libFuzzer): clang libclang-rt-dev (the sanitizer and fuzzer runtimes)
#   style: clang-format (the format_check test against .clang-format)
#   misc: dpkg-dev (apt-get source), git, xz-utils
VL_DEB_PACKAGES=(
  cmake g++ make pkg-config
  libeigen3-dev liblcm-dev liblcm-bin libglib2.0-dev libinih-dev
  python3 python3-venv ca-certificates
  iproute2 util-linux
  valgrind
  clang libclang-rt-dev
  clang-format
  dpkg-dev git xz-utils
)

vl_log() { printf '%s\n' "$*"; }
vl_err() { printf 'ERROR: %s\n' "$*" >&2; }

# Prefix for commands that need root: empty as root, sudo when available, else fail clearly.
vl_root_cmd() {
  if [ "$(id -u)" -eq 0 ]; then
    "$@"
  elif command -v sudo >/dev/null 2>&1; then
    sudo DEBIAN_FRONTEND=noninteractive "$@"
  else
    vl_err "need root to run: $*   (run this script as root, or install sudo)"
    return 1
  fi
}

# Prints the packages of VL_DEB_PACKAGES that are not installed, space-separated.
vl_missing_debs() {
  local installed pkg missing=()
  # One dpkg-query call; unknown packages go to stderr and simply count as missing.
  installed="$(dpkg-query -W -f='${Package} ${db:Status-Abbrev}\n' "${VL_DEB_PACKAGES[@]}" 2>/dev/null || true)"
  for pkg in "${VL_DEB_PACKAGES[@]}"; do
    if ! printf '%s\n' "$installed" | awk -v p="$pkg" '$1 == p && $2 == "ii" { f = 1 } END { exit !f }'; then
      missing+=("$pkg")
    fi
  done
  printf '%s' "${missing[*]:-}"
}

# Installs whatever of VL_DEB_PACKAGES is missing; touches apt only when something is.
vl_install_debs() {
  if [ "${VL_SKIP_APT:-0}" = 1 ]; then
    vl_log "VL_SKIP_APT=1: not checking Debian packages"
    return 0
  fi
  if ! command -v dpkg-query >/dev/null 2>&1 || ! command -v apt-get >/dev/null 2>&1; then
    vl_log "WARNING: no dpkg/apt here; make sure these are installed: ${VL_DEB_PACKAGES[*]}"
    return 0
  fi
  local missing
  missing="$(vl_missing_debs)"
  if [ -z "$missing" ]; then
    vl_log "all ${#VL_DEB_PACKAGES[@]} Debian packages already installed"
    return 0
  fi
  vl_log "installing missing Debian packages: $missing"
  export DEBIAN_FRONTEND=noninteractive
  local apt_opts=(-y -q -o DPkg::Lock::Timeout=300 -o Dpkg::Use-Pty=0)
  vl_root_cmd apt-get "${apt_opts[@]}" update || return 1
  # shellcheck disable=SC2086  # word splitting of the package list is wanted
  vl_root_cmd apt-get "${apt_opts[@]}" install --no-install-recommends $missing || return 1
  missing="$(vl_missing_debs)"
  if [ -n "$missing" ]; then
    vl_err "still missing after apt-get install: $missing"
    return 1
  fi
}

# Makes sure a Unity tree exists and sets VL_UNITY_ROOT to it.
vl_setup_unity() {
  if [ -n "${UNITY_ROOT:-}" ]; then
    if [ ! -f "$UNITY_ROOT/src/unity.c" ]; then
      vl_err "UNITY_ROOT=$UNITY_ROOT does not contain src/unity.c"
      return 1
    fi
    VL_UNITY_ROOT="$(cd "$UNITY_ROOT" && pwd)"
    vl_log "using Unity from UNITY_ROOT=$VL_UNITY_ROOT (nothing fetched)"
    return 0
  fi
  VL_UNITY_ROOT="${UNITY_DEST:-$VL_REPO_ROOT/.deps/unity}"
  bash "$VL_REPO_ROOT/tools/fetch_unity.sh" "$VL_UNITY_ROOT" || return 1
}

# Creates/updates the venv; pip runs only when the venv is new or requirements.txt changed.
vl_setup_venv() {
  local venv="${VENV_DIR:-$VL_REPO_ROOT/.venv}"
  local req="${REQUIREMENTS:-$VL_REPO_ROOT/tools/requirements.txt}"
  local py="${VL_PYTHON:-/usr/bin/python3}"
  local stamp="$venv/.vl-requirements.sha256"

  if [ ! -f "$req" ]; then
    vl_err "Python requirements file not found: $req"
    return 1
  fi
  if [ ! -x "$py" ]; then
    vl_err "Python interpreter not found: $py (install python3, or set VL_PYTHON)"
    return 1
  fi

  # Recreate a venv that is broken or was made from another interpreter (e.g. a pyenv one).
  local want_home have_home=""
  want_home="$(dirname "$py")"
  if [ -f "$venv/pyvenv.cfg" ]; then
    have_home="$(sed -n 's/^home *= *//p' "$venv/pyvenv.cfg" | head -n1)"
  fi
  if [ -d "$venv" ] && { [ "$have_home" != "$want_home" ] || ! "$venv/bin/python" -c 'import sys' >/dev/null 2>&1; }; then
    vl_log "venv at $venv is broken or not made from $py (home=$have_home); recreating it"
    rm -rf "$venv"
  fi
  if [ ! -x "$venv/bin/python" ]; then
    vl_log "creating venv at $venv with $py"
    "$py" -m venv "$venv" || { vl_err "python venv creation failed (is python3-venv installed?)"; return 1; }
  fi

  local want_hash have_hash=""
  want_hash="$( { cat "$req"; "$venv/bin/python" -c 'import sys; print(sys.version)'; } | sha256sum | cut -d' ' -f1)"
  [ -f "$stamp" ] && have_hash="$(cat "$stamp")"
  if [ "$want_hash" = "$have_hash" ]; then
    vl_log "venv up to date with $(basename "$req") ($venv)"
    return 0
  fi
  vl_log "installing Python requirements from $req"
  rm -f "$stamp"
  "$venv/bin/python" -m pip install --disable-pip-version-check --no-input --progress-bar off \
    -r "$req" || { vl_err "pip install -r $req failed"; return 1; }
  printf '%s\n' "$want_hash" >"$stamp"
}

vl_setup_all() {
  vl_install_debs && vl_setup_unity && vl_setup_venv
}

# Run directly: do the whole set-up.
if [ "${BASH_SOURCE[0]}" = "$0" ]; then
  set -euo pipefail
  vl_setup_all
fi
