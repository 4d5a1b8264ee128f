#!/usr/bin/env bash
# Install weight: for each source tree given (default: the current directory) and for
# `pip install -e .` and `pip install -e ".[test]"`, a fresh venv: packages installed, the
# venv's size in MB, and the seconds pip took (optimistic with a warm pip wheel cache).
# Usage: benchmarks/measure_install.sh [TREE ...]
set -u
trees=("${@:-.}")
for tree in "${trees[@]}"; do
  tree=$(cd "$tree" && pwd)
  for spec in "." ".[test]"; do
    v=${TMPDIR:-/tmp}/jaxcart-install-$(basename "$tree")-$(echo "$spec" | tr -dc 'a-z')
    rm -rf "$v"; python3 -m venv "$v"; "$v/bin/pip" install -q --upgrade pip 2>/dev/null
    base=$("$v/bin/pip" list --format=freeze 2>/dev/null | wc -l)
    start=$(date +%s.%N)
    (cd "$tree" && "$v/bin/pip" install -q -e "$spec" >/dev/null 2>&1)
    end=$(date +%s.%N)
    n=$("$v/bin/pip" list --format=freeze 2>/dev/null | wc -l)
    mb=$(du -sm "$v" | cut -f1)
    printf "%s %s: packages=%d (jaxcart included) MB=%s seconds=%.1f load=%s\n" "$(basename "$tree")" "$spec" \
      $((n - base)) "$mb" "$(echo "$end - $start" | bc)" "$(cut -d' ' -f1 /proc/loadavg)"
  done
done
