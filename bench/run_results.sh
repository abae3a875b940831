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
# Table V and the baselines on a fixed seeded set of ten synthetic 1080p clips with 4-20 px drones
# (seeds 100-109: never used for training, tuning or tests).
$PY -m payload bench --ablation --synthetic 100-109 --target-px 4 20 "${CFG[@]}" --no-progress \
  --json "$OUT/ablation_synthetic_100_109.json" > "$OUT/ablation_synthetic_100_109.txt"
# Precision-recall curves per detector on val: the global detector alone and the tiled local detector
# with their thresholds at 0.05 (whole curve), and GLAD as shipped.
printf 'detector:\n  global:\n    appearance:\n      confidence: 0.05\n' > "$OUT/low_threshold.yaml"
$PY -m payload bench --ablation --split val --rows "global detector alone (down-scaled)" "tiled full-res (SAHI-style)" \
  -c "$OUT/low_threshold.yaml" --no-progress --json "$OUT/pr_val_detectors.json" > "$OUT/pr_val_detectors.txt"
uptime >> "$OUT/load.txt"

$PY bench/plot_results.py --ablation "$OUT/ablation_val.json" \
  --profiles "$OUT/profile_V_DRONE_013.json" "$OUT/profile_syn1080_glad.json" --out docs/img
$PY bench/plot_results.py --pr "$OUT/pr_val_detectors.json" "$OUT/ablation_val.json" --pr-rows \
  "global detector alone (down-scaled)" "tiled full-res (SAHI-style)" "GLAD (adaptive region)" \
  --pr-title "Halmstad val" --out docs/img/pr_val.png
$PY bench/plot_results.py --pr "$OUT/ablation_synthetic_100_109.json" --pr-rows "GAD" "GLAD (adaptive region)" \
  "global detector alone (down-scaled)" "tiled full-res (SAHI-style)" --pr-title "synthetic 1080p, 4-20 px" \
  --out docs/img/pr_synthetic.png
