#!/usr/bin/env bash
# Reproduce the figures of docs/results.md: JSON into OUT (default bench-results/), then the plots.
#   bench/run_results.sh [OUT] [CONFIG]
# Needs ../shared/data/halmstad beside the repository and matplotlib for the plots only.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-bench-results}
CONFIG=${2:-}
PY=${PY:-python}
CFG=()
if [ -n "$CONFIG" ]; then CFG=(-c "$CONFIG"); fi
DATA=../shared/data/halmstad
mkdir -p "$OUT"
uptime > "$OUT/load.txt"

# Synthetic 1080p scene (seed 1, as the bench's default), rendered once and shared by every run.
$PY -m payload synth "$OUT/synth" --seed 1 --frames 150 > /dev/null
SYN="$OUT/synth/SYN_1.mp4"
for runner in glad global tiled; do
  $PY -m payload bench "$SYN" "${CFG[@]}" --runner "$runner" --json "$OUT/profile_syn1080_$runner.json" > "$OUT/profile_syn1080_$runner.txt"
done

# Every Halmstad val clip (640x512), GLAD.
for clip in $($PY -c "import json; print(' '.join(json.load(open('$DATA/splits.json'))['val']))"); do
  $PY -m payload bench "$DATA/visible/$clip.mp4" "${CFG[@]}" --json "$OUT/profile_$clip.json" > "$OUT/profile_$clip.txt"
done

# Table V and the baselines on val, then on the synthetic 1080p clip.
$PY -m payload bench --ablation --split val "${CFG[@]}" --no-progress --json "$OUT/ablation_val.json" > "$OUT/ablation_val.txt"
$PY -m payload bench --ablation --split negatives_val --limit 100 --rows "GAD+GMD+LAD+LMD" "GLAD (adaptive region)" \
  "global detector alone (down-scaled)" "tiled full-res (SAHI-style)" "${CFG[@]}" --no-progress \
  --json "$OUT/ablation_negatives_val.json" > "$OUT/ablation_negatives_val.txt"
$PY -m payload bench --ablation --clips "$SYN" "${CFG[@]}" --no-progress --json "$OUT/ablation_syn1080.json" > "$OUT/ablation_syn1080.txt"
uptime >> "$OUT/load.txt"

$PY bench/plot_results.py --ablation "$OUT/ablation_val.json" \
  --profiles "$OUT/profile_V_DRONE_013.json" "$OUT/profile_syn1080_glad.json" --out docs/img
