#!/usr/bin/env bash
# Builds the programs of tests/consumer/ on vislam as a user would, from outside vislam's tree.
#
#   test_install_consumer.sh install BUILD_DIR SOURCE_DIR
#     `cmake --install BUILD_DIR` into a temporary prefix; against it, the consumer built with
#     find_package(vislam) (C, C++, the LCM message types) and with pkg-config (cc and c++, the
#     public header warning-free under -Wall -Wextra -Werror), run, the pose checked by the program;
#     a program compiled with another VL_MAX_LANDMARKS, or with a copy of the headers whose two
#     configuration keys are swapped (every size the same), gets VL_ERR_ABI_MISMATCH from vl_init
#     (exit 3, no crash); the generated Python message types import from share/vislam/python.
#   test_install_consumer.sh subproject BUILD_DIR SOURCE_DIR
#     the consumer with vislam's source tree as a subproject (add_subdirectory): it builds and runs,
#     a consumer file with a #warning compiles, and the compile lines of the consumer's files carry
#     none of vislam's flags (-Werror, -Wall, -Wextra, -march=native) while vislam's own keep them.
#   test_install_consumer.sh core_only BUILD_DIR SOURCE_DIR
#     vislam itself configured with -DVL_CORE_ONLY=ON where pkg-config cannot be found (so neither
#     LCM nor libinih): it builds the core alone and installs the core, its headers, CMake package
#     and pkg-config file, nothing of the messages'; the consumer finds it (find_package without
#     components, pkg-config off there too) and runs.
#
# CC and CXX (the main build's compilers, set by CTest) compile the consumers.
set -uo pipefail
MODE=$1
BUILD=$(cd "$2" && pwd)
SRC=$(cd "$3" && pwd)
CONSUMER=$SRC/tests/consumer
CC=${CC:-cc}
CXX=${CXX:-c++}
export CC CXX
# shellcheck source=tests/support/vl_record.sh
source "$SRC/tests/support/vl_record.sh" # check, eq
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT
FAILS=0
START=$SECONDS

# The capacity the library was built with, and another one for the mismatch case.
N=$(sed -n 's/^VL_MAX_LANDMARKS:STRING=//p' "$BUILD/CMakeCache.txt")
OTHER=64
[ "$N" != 64 ] || OTHER=32

# run NAME PROGRAM: runs PROGRAM, its output in $TMP/NAME.out (shown), its exit status in $RUN_RC.
run() {
  "$2" >"$TMP/$1.out" 2>&1
  RUN_RC=$?
  sed 's/^/      /' "$TMP/$1.out"
}

if [ "$MODE" = install ]; then
  P=$TMP/prefix
  cmake --install "$BUILD" --prefix "$P" >"$TMP/install.log" 2>&1
  check "cmake --install into a temporary prefix" eq $? 0
  LIBDIR=$(dirname "$(find "$P" -name libvislam_core.a)")
  missing=""
  for f in include/vislam/vislam.h include/vislam/vl_config_schema.h include/vislam/lcm/vislam_pose_t.h \
    share/vislam/lcm/vislam_pose_t.lcm share/vislam/python/vislam/pose_t.py; do
    [ -f "$P/$f" ] || missing="$missing $f"
  done
  for f in libvislam_lcm_types.a cmake/vislam/vislamConfig.cmake pkgconfig/vislam.pc pkgconfig/vislam-lcm.pc; do
    [ -f "$LIBDIR/$f" ] || missing="$missing $f"
  done
  check "installed: headers, core and message libraries, CMake package, pkg-config files, .lcm, Python" eq "$missing" ""

  # find_package: one configure and build of C, C++ and LCM consumers.
  cmake -S "$CONSUMER" -B "$TMP/find" -DCMAKE_BUILD_TYPE=Release -DCMAKE_PREFIX_PATH="$P" >"$TMP/find.log" 2>&1 &&
    cmake --build "$TMP/find" -j 2 >>"$TMP/find.log" 2>&1
  rc=$?
  check "find_package(vislam): the consumers configure and build" eq $rc 0
  [ "$rc" -eq 0 ] || cat "$TMP/find.log"
  check "find_package found the temporary prefix's package, VL_MAX_LANDMARKS $N" \
    grep -q "vislam 0.1.0, VL_MAX_LANDMARKS $N, from $LIBDIR/cmake/vislam" "$TMP/find.log"
  for prog in consumer_c consumer_cxx lcm_consumer; do
    run "$prog" "$TMP/find/$prog"
    check "find_package: $prog runs and checks its result" eq "$RUN_RC" 0
  done

  # pkg-config: plain compiler commands, nothing added by hand.
  export PKG_CONFIG_PATH=$LIBDIR/pkgconfig
  read -r -a VL <<<"$(pkg-config --cflags --libs vislam)"
  read -r -a VL_LCM <<<"$(pkg-config --cflags --libs vislam-lcm)"
  check "pkg-config: Cflags carry -DVL_MAX_LANDMARKS=$N" grep -q -- "-DVL_MAX_LANDMARKS=$N" <<<"${VL[*]}"
  WARN=(-Wall -Wextra -Werror)
  "$CC" -std=c99 "${WARN[@]}" "$CONSUMER/consumer.c" "${VL[@]}" -o "$TMP/pc_c"
  check "pkg-config: C consumer compiles (-std=c99 ${WARN[*]}) and links with $CC" eq $? 0
  "$CXX" -std=c++17 "${WARN[@]}" -I"$CONSUMER" "$CONSUMER/consumer.cpp" "${VL[@]}" -o "$TMP/pc_cxx"
  check "pkg-config: C++ consumer compiles (-std=c++17 ${WARN[*]}) and links with $CXX" eq $? 0
  "$CC" -std=c99 "$CONSUMER/lcm_consumer.c" "${VL_LCM[@]}" -o "$TMP/pc_lcm"
  check "pkg-config: LCM consumer (vislam-lcm) compiles and links" eq $? 0
  for prog in pc_c pc_cxx pc_lcm; do
    run "$prog" "$TMP/$prog"
    check "pkg-config: $prog runs and checks its result" eq "$RUN_RC" 0
  done

  # The mismatch: a program compiled with another capacity than the library's.
  "$CC" -std=c99 "$CONSUMER/consumer.c" "${VL[@]}" -UVL_MAX_LANDMARKS -DVL_MAX_LANDMARKS="$OTHER" -o "$TMP/pc_other"
  check "a consumer compiled with -DVL_MAX_LANDMARKS=$OTHER builds" eq $? 0
  run other "$TMP/pc_other"
  check "... and vl_init refuses it with VL_ERR_ABI_MISMATCH (exit 3, no crash)" eq "$RUN_RC" 3
  check "... saying so" grep -q "VL_MAX_LANDMARKS $OTHER: vl_init: caller compiled with other capacities" "$TMP/other.out"

  # Another vislam.h of the same sizes: two configuration keys of one type swapped in a copy of
  # the installed headers. Every sizeof agrees; only the layout hash can tell.
  mkdir -p "$TMP/swapped" && cp -r "$P/include" "$TMP/swapped/"
  SCHEMA=$TMP/swapped/include/vislam/vl_config_schema.h
  sed -i -e 's/ linear_offset_prior, DOUBLE/ VL_SWAP_, DOUBLE/' \
    -e 's/ angular_offset_prior, DOUBLE/ linear_offset_prior, DOUBLE/' \
    -e 's/ VL_SWAP_, DOUBLE/ angular_offset_prior, DOUBLE/' "$SCHEMA"
  check "the copy's vislam.h declares angular_offset_prior before linear_offset_prior" \
    test "$(grep -o -m 1 -E ' (linear|angular)_offset_prior, DOUBLE' "$SCHEMA")" = " angular_offset_prior, DOUBLE"
  read -r -a VL_SWAPPED <<<"$(pkg-config --cflags --libs vislam | sed "s|-I[^ ]*|-I$TMP/swapped/include|")"
  "$CC" -std=c99 "$CONSUMER/consumer.c" "${VL_SWAPPED[@]}" -o "$TMP/pc_swapped"
  check "a consumer compiled with that vislam.h builds" eq $? 0
  run swapped "$TMP/pc_swapped"
  check "... and vl_init refuses it with VL_ERR_ABI_MISMATCH (exit 3, no crash)" eq "$RUN_RC" 3

  PYTHONPATH=$P/share/vislam/python "${VISLAM_PYTHON:-python3}" -c '
import bot_core, vislam
m = vislam.pose_t()
m.utime = 7
assert vislam.pose_t.decode(m.encode()).utime == 7
assert bot_core.pose_t.decode(bot_core.pose_t().encode()).utime == 0'
  check "Python: the message types import from share/vislam/python and round-trip" eq $? 0
elif [ "$MODE" = subproject ]; then
  cmake -S "$CONSUMER" -B "$TMP/sub" -DCMAKE_BUILD_TYPE=Release -DVISLAM_SOURCE_DIR="$SRC" \
    -DCMAKE_EXPORT_COMPILE_COMMANDS=ON >"$TMP/sub.log" 2>&1 &&
    cmake --build "$TMP/sub" -j 2 --target consumer_c consumer_cxx consumer_warns >>"$TMP/sub.log" 2>&1
  rc=$?
  check "add_subdirectory(vislam): the consumers configure and build" eq $rc 0
  [ "$rc" -eq 0 ] || cat "$TMP/sub.log"
  check "the consumer's file with a #warning compiled (warned, not failed)" \
    grep -q "warning: #warning \"tests/consumer/warns.c" "$TMP/sub.log"
  check "vislam built no tests inside the consumer" test ! -e "$TMP/sub/vislam/tests"
  for prog in consumer_c consumer_cxx; do
    run "$prog" "$TMP/sub/$prog"
    check "subproject: $prog runs and checks its result" eq "$RUN_RC" 0
  done
  # flags FILE: the compile line of the source file FILE (path from the source root).
  flags() {
    "${VISLAM_PYTHON:-python3}" -c '
import json, sys
for e in json.load(open(sys.argv[1])):
    if e["file"].endswith(sys.argv[2]):
        print(e["command"])' "$TMP/sub/compile_commands.json" "$1"
  }
  for f in tests/consumer/warns.c tests/consumer/consumer.c tests/consumer/consumer.cpp; do
    line=$(flags "$f")
    check "$f: compiled, without -Werror, -Wall, -Wextra or -march=native" \
      test -n "$line" -a -z "$(grep -oE -- '-Werror|-Wall|-Wextra|-march=native' <<<"$line")"
  done
  line=$(flags core/src/vl_estimator.c)
  check "core/src/vl_estimator.c keeps vislam's -Wall -Wextra -march=native" \
    test -n "$(grep -- '-Wall' <<<"$line" | grep -- '-Wextra' | grep -- '-march=native')"
  check "core/src/vl_estimator.c: no -Werror by default as a subproject" test -z "$(grep -o -- '-Werror' <<<"$line")"
elif [ "$MODE" = core_only ]; then
  P=$TMP/prefix
  NO_PC=-DCMAKE_DISABLE_FIND_PACKAGE_PkgConfig=ON
  cmake -S "$SRC" -B "$TMP/core" -DCMAKE_BUILD_TYPE=Release -DVL_CORE_ONLY=ON "$NO_PC" \
    -DVL_MAX_LANDMARKS="$N" >"$TMP/core.log" 2>&1 &&
    cmake --build "$TMP/core" -j 2 >>"$TMP/core.log" 2>&1 &&
    cmake --install "$TMP/core" --prefix "$P" >>"$TMP/core.log" 2>&1
  rc=$?
  check "VL_CORE_ONLY without pkg-config (no LCM, no libinih): configures, builds, installs" eq $rc 0
  [ "$rc" -eq 0 ] || cat "$TMP/core.log"
  built=$(find "$TMP/core" -name '*.a' -printf '%f\n' | sort | tr '\n' ' ')
  check "built the core alone (no checked copy, no message types, no programs)" \
    eq "$built$(find "$TMP/core" -path '*/bin/*' -type f | head -1)" "libvislam_core.a "
  LIBDIR=$(dirname "$(find "$P" -name libvislam_core.a)")
  missing=""
  for f in include/vislam/vislam.h include/vislam/vl_config_schema.h; do
    [ -f "$P/$f" ] || missing="$missing $f"
  done
  for f in cmake/vislam/vislamConfig.cmake pkgconfig/vislam.pc; do
    [ -f "$LIBDIR/$f" ] || missing="$missing $f"
  done
  check "installed: the headers, the core, its CMake package and pkg-config file" eq "$missing" ""
  extra=$(cd "$P" && find . -name '*lcm*' -o -name share -o -path '*/bin*' | tr '\n' ' ')
  check "installed nothing of the messages' and no programs" eq "$extra" ""
  cmake -S "$CONSUMER" -B "$TMP/find" -DCMAKE_BUILD_TYPE=Release -DCMAKE_PREFIX_PATH="$P" \
    -DVISLAM_CONSUMER_LCM=OFF "$NO_PC" >"$TMP/find.log" 2>&1 &&
    cmake --build "$TMP/find" -j 2 >>"$TMP/find.log" 2>&1
  rc=$?
  check "find_package(vislam) of the core-only install: the consumers configure and build" eq $rc 0
  [ "$rc" -eq 0 ] || cat "$TMP/find.log"
  for prog in consumer_c consumer_cxx; do
    run "$prog" "$TMP/find/$prog"
    check "core only: $prog runs and checks its result" eq "$RUN_RC" 0
  done
else
  echo "usage: $0 install|subproject|core_only BUILD_DIR SOURCE_DIR" >&2
  exit 2
fi

echo "== $((SECONDS - START)) s, $FAILS failure(s)"
[ "$FAILS" -eq 0 ]
