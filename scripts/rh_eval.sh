#!/usr/bin/env bash
# Quick evaluation of one Radiance Hints configuration (development aid):
#   [SCENE=cellar] scripts/rh_eval.sh NAME [headless flags...]
# Renders the indirect light at 256² and prints block RMSE / energy against the committed ground truths of
# the scene (cornell: all-bounce, one-bounce and two-bounce), plus the GPU milliseconds of the RH passes.
set -euo pipefail
cd "$(dirname "$0")/.."
name=$1; shift
export WGPU_BACKEND=${WGPU_BACKEND:-vulkan}
scene=${SCENE:-cornell}
out=out/eval/$name.exr
cargo run -q --release --example headless -- --scene "$scene" --method rh --indirect-only --out "$out" "$@" 2>&1 \
    | grep -E "ERROR|panicked|headless:" || true
row="$name"
truths=$scene
[ "$scene" = cornell ] && truths="cornell cornell_b1 cornell_b2"
for gt in $truths; do
    m=$(cargo run -q --release --example compare -- "$out" assets/ground_truth/$gt.exr --diff out/eval/$name.$gt.diff.png)
    b=$(echo "$m" | awk '/block/ {print $4}'); e=$(echo "$m" | awk '/energy/ {print $3}')
    row="$row | $gt $b / $e"
done
ms=$(python3 -c "
import json; d=json.load(open('$out'.replace('.exr','.json')))['gpu_ms']
print(' '.join(f\"{k.split('/')[1]}={v:.1f}\" for k,v in sorted(d.items()) if k.startswith('diffuse_gi')))")
echo "$row | $ms"
