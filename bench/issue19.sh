#!/bin/sh
# Issue 19's acceptance on one sitting: the synthetic 1080p clips SYN_1 (followed most frames) and
# SYN_3 (searched most frames) paced at 30 FPS, V_DRONE_086 (640x512) paced and unpaced against the
# tiled baseline, SYN_1 unpaced, and val's ablation rows GLAD against tiled. Run on an idle machine
# (the load is printed at the start and the end); a few minutes.
#   sh bench/issue19.sh [SYN_DIR]     (SYN_DIR: where SYN_1/SYN_3 are, rendered there when missing)
GP=${GLAD_PAYLOAD:-.venv/bin/glad-payload}
SYN=${1:-/tmp/glad-issue19-syn}
CLIP=${CLIP:-../shared/data/halmstad/visible/V_DRONE_086.mp4}
MODULES='^(grey|GAD|GMD|scan|points|LAD|LMD|region|classifier|switcher|verifier) '
for seed in 1 3; do
    [ -f "$SYN/SYN_$seed.mp4" ] || $GP synth "$SYN" --seed $seed --frames 150 >/dev/null 2>&1
done
echo "== start $(date +%T) load $(cut -d' ' -f1-3 /proc/loadavg)"
for clip in SYN_1 SYN_1 SYN_1 SYN_1 SYN_3 SYN_3; do
    echo "== $clip 1920x1080 --paced 30"
    $GP bench "$SYN/$clip.mp4" --paced 30 --no-stream 2>/dev/null | grep -E "$MODULES|^paced|^latency"
done
echo "== $CLIP --paced 30"
$GP bench "$CLIP" --paced 30 --no-stream 2>/dev/null | grep -E "$MODULES|^paced|^latency"
for runner in glad glad tiled; do
    echo "== $CLIP unpaced --runner $runner"
    $GP bench "$CLIP" --runner $runner --no-stream 2>/dev/null | grep -E '^fps end-to-end \(|^latency|load_avg'
done
echo "== SYN_1 unpaced --runner glad"
$GP bench "$SYN/SYN_1.mp4" --runner glad --no-stream 2>/dev/null | grep -E '^fps end-to-end \(|^latency'
echo "== val: bench --ablation, GLAD against tiled"
$GP bench --ablation --split val --rows "GLAD (adaptive region)" "tiled full-res (SAHI-style)" --no-progress 2>/dev/null | tail -3
echo "== end $(date +%T) load $(cut -d' ' -f1-3 /proc/loadavg)"
