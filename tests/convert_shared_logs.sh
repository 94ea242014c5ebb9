#!/usr/bin/env bash
# CTest fixture: converts the seed datasets in ../shared/data into LCM logs in the build
# directory (never into the project), for the tests and benchmarks that run on real data.
# Exits 77 (reported as skipped) when ../shared/data is absent.
set -euo pipefail
shopt -s nullglob # a data folder without datasets converts nothing
data_dir="$1"
out_dir="$2"
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
if [ ! -d "$data_dir" ]; then
  echo "convert_shared_logs: $data_dir not found: real-data tests are skipped" >&2
  exit 77
fi
mkdir -p "$out_dir"
for npz in "$data_dir"/*.npz; do
  name="$(basename "$npz" .npz)"
  log="$out_dir/$name.lcmlog"
  if [ ! -s "$log" ] || [ "$npz" -nt "$log" ]; then
    "$repo/tools/npz2lcm" "$npz" "$log.tmp"
    mv "$log.tmp" "$log"
  fi
done
ls -l "$out_dir"
