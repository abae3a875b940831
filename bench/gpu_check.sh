#!/bin/bash
# The payload's GPU path against its CPU path on one machine (docs/results.md "On a GPU").
# Needs an onnxruntime build with the CUDA provider importable (onnxruntime-gpu) and the payload's
# runtime dependencies; run from the repository root:  bash bench/gpu_check.sh [CLIP_640x512]
export PYTHONUNBUFFERED=1 PYTHONPATH="${PYTHONPATH:+$PYTHONPATH:}$PWD"
t0=$(date +%s); say() { echo "### [$(( $(date +%s) - t0 ))s] $*"; }
python3 -c "import onnxruntime as o; print(o.__version__, o.get_available_providers())"
d=$(mktemp -d)
printf 'detector:\n  backend: cuda\n' > "$d/cuda.yaml"
printf 'detector:\n  backend: cpu\n' > "$d/cpu.yaml"
say synth; python3 -m payload synth "$d/syn" --seed 1 --frames 150 2>&1 | tail -1
for b in cuda tensorrt; do say models $b; python3 bench/backend_check.py "$d/syn/SYN_1.mp4" --backend $b --frames 40 2>&1 | grep -v " INFO "; done
rows="^(GAD|GMD|scan|LAD|classifier|switcher|verifier|points) |fps end|latency|paced at|onnxruntime"
for c in cpu cuda; do say bench SYN_1 $c; python3 -m payload bench "$d/syn/SYN_1.mp4" --no-stream --config "$d/$c.yaml" 2>&1 | grep -E "$rows"; done
say bench paced cuda; python3 -m payload bench "$d/syn/SYN_1.mp4" --paced 30 --no-stream --config "$d/cuda.yaml" 2>&1 | grep -E "$rows"
if [ -n "$1" ]; then for c in cpu cuda; do say bench "$1" $c; python3 -m payload bench "$1" --no-stream --config "$d/$c.yaml" 2>&1 | grep -E "$rows"; done; fi
for c in cpu cuda; do say eval $c; python3 -m payload eval --synthetic 100 --frames 150 --no-progress --config "$d/$c.yaml" 2>&1 | grep POOLED; done
say end
