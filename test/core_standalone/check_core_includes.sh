#!/usr/bin/env bash
# Usage: check_core_includes.sh CXX INCLUDE_DIR EIGEN_DIR LIBRARIES FILE...
# Reads each FILE with -H and fails if any header it includes, directly or
# transitively, is something other than the headers of LIBRARIES (a comma-separated list of
# folders under INCLUDE_DIR/dynamic_occupancy_grid, e.g. "core" or "core,evaluation", and
# their private headers beside the sources in src/<folder>), Eigen, zlib, or the C/C++
# standard library (libc, libstdc++, Linux UAPI headers). A header must also compile on its
# own (-fsyntax-only); a source (.cpp), which the build compiles anyway, is only preprocessed
# (-E), several times faster.
set -euo pipefail
cxx=$1 include_dir=$(realpath "$2") eigen_dir=$(realpath "$3")
IFS=, read -r -a libraries <<<"$4"
shift 4
private_dirs=()
for library in "${libraries[@]}"; do private_dirs+=("$(realpath -m "$include_dir/../src/$library")"); done
allowed() {  # is $1 a public or private header of one of the libraries?
  local i
  for i in "${!libraries[@]}"; do
    case "$1" in
      "$include_dir"/dynamic_occupancy_grid/"${libraries[$i]}"/*) return 0 ;;
      "${private_dirs[$i]}"/*.h) return 0 ;;
    esac
  done
  return 1
}
status=0
for file in "$@"; do
  mode=-fsyntax-only
  [[ "$file" == *.cpp ]] && mode=-E
  if ! headers=$("$cxx" -std=c++17 "$mode" -H -I"$include_dir" -I"$eigen_dir" -x c++ "$file" 2>&1 >/dev/null); then
    echo "FAIL: $file does not compile on its own:"; echo "$headers"; status=1; continue
  fi
  # Each header once, all resolved by one realpath (a process per header was most of the time).
  while read -r path; do
    allowed "$path" && continue                              # the libraries themselves
    case "$path" in
      "$eigen_dir"/*) ;;                                     # Eigen
      # zlib: the model file's CRC-32 (src/core/layers/model_io.cpp) is zlib's, the checksum the
      # format promises; named here so the rule says it, not only the libc catch-all below.
      /usr/include/zlib.h|/usr/include/zconf.h|/usr/include/*-linux-gnu/zconf.h) ;;
      /usr/include/c++/*|/usr/include/x86_64-linux-gnu/*|/usr/include/aarch64-linux-gnu/*) ;;
      /usr/lib/gcc/*|/usr/include/linux/*|/usr/include/asm-generic/*|/usr/include/asm/*) ;;
      /usr/include/bits/*|/usr/include/sys/*|/usr/include/gnu/*) ;;
      /usr/include/*/*)                                      # any other library's folder
        echo "FAIL: $file includes $path"; status=1 ;;
      /usr/include/*) ;;                                     # libc's top-level headers
      *) echo "FAIL: $file includes $path"; status=1 ;;
    esac
  done < <(printf '%s\n' "$headers" | sed -n 's/^\.\+ //p' | sort -u | xargs -r -d '\n' realpath -m)
done
[ "$status" -eq 0 ] && echo "includes: only ${libraries[*]}, Eigen, zlib and the standard library ($# files)"
exit "$status"
