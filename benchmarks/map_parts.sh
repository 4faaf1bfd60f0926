#!/usr/bin/env bash
# Evaluation maps too big for one carry (a 300,000-edge map is 136-190 MB; a call carries 64
# MiB with the working tree) travel in parts, one folder per call, the way warp-parts sends
# warp-lang.
#   here:    bash benchmarks/map_parts.sh split DIR      (DIR/case1.h5, DIR/case2.h5 -> .evp1 ... .evpN)
#   there:   carry [".evpK"], then  bash benchmarks/map_parts.sh take .evpK   (once per part, in order)
#            and last  bash benchmarks/map_parts.sh join /tmp/lmjx_gpu/maps   (md5-checked)
# Each part folder holds one piece (<= 46 MB, <map>.h5.partNN) and its map's checksum (<map>.h5.md5).
set -euo pipefail
PARTS=/tmp/map_parts
case ${1:-} in
  split)
    dir=${2:?folder with the maps}
    rm -rf .evp[0-9]*; n=0
    for map in "$dir"/case*.h5; do
      name=$(basename "$map"); tmp=$(mktemp -d)
      (cd "$tmp" && split -b 46000000 -d -a 2 "$map" "$name.part" && md5sum "$map" | sed "s|  .*|  $name|" > "$name.md5")
      for p in "$tmp"/"$name".part*; do
        n=$((n + 1)); mkdir -p ".evp$n"; mv "$p" ".evp$n/"; cp "$tmp/$name.md5" ".evp$n/"
        grep -qx "/.evp$n/" .git/info/exclude 2>/dev/null || echo "/.evp$n/" >> .git/info/exclude
      done
      rm -rf "$tmp"
    done
    du -sh .evp[0-9]* ;;
  take)
    mkdir -p "$PARTS" && cp "${2:?part folder}"/* "$PARTS/" && ls "$PARTS" | wc -l ;;
  join)
    out=${2:?folder for the maps}; mkdir -p "$out"
    cd "$PARTS"
    for sum in *.md5; do
      name=${sum%.md5}; cat "$name".part* > "$out/$name"
      (cd "$out" && md5sum -c "$PARTS/$sum")
    done
    ls -la "$out" ;;
  *)
    sed -n 2,8p "$0"; exit 2 ;;
esac
