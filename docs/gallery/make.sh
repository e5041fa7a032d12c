#!/usr/bin/env bash
# Regenerates the gallery: for each terrain × difficulty, a short flight with `jointloc sim`,
# then its first UAV frame and the map tile nearest the flight (the map is centred on it).
# Usage: docs/gallery/make.sh [path/to/jointloc]   (default: target/release/jointloc)
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
bin="${1:-target/release/jointloc}"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
for terrain in crater gravel mountain; do
  for difficulty in easy medium hard; do
    out="$work/$terrain-$difficulty"
    "$bin" sim --terrain "$terrain" --difficulty "$difficulty" --seed 1 --length-m 2 \
      --out "$out" --quiet > /dev/null
    cp "$out/uav/images/000000.png" "$here/$terrain-$difficulty-uav.png"
    # The tile whose centre is nearest the map centre.
    read -r w h tw th < <(awk -F' = ' '
      /^\[tiles\]/ { t = 1 } /^\[scene\]/ { t = 0 }
      $1 == "width_px"  { if (t) tw = $2; else w = $2 }
      $1 == "height_px" { if (t) th = $2; else h = $2 }
      END { print w, h, tw, th }' "$out/map.toml")
    best=$(ls "$out/satellite" | awk -F'[_.]' -v w="$w" -v h="$h" -v tw="$tw" -v th="$th" '
      { dx = $2 + tw / 2 - w / 2; dy = $3 + th / 2 - h / 2; d = dx * dx + dy * dy
        if (NR == 1 || d < best) { best = d; name = $0 } }
      END { print name }')
    cp "$out/satellite/$best" "$here/$terrain-$difficulty-map.png"
    echo "$terrain $difficulty: frame 000000, tile $best"
  done
done
