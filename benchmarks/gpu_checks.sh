#!/usr/bin/env bash
# The CUDA checks of the GPU issue, one stage per argument, as they are run on a GPU machine
# (docs/gpu.md has the figures). Needs the package installed with its `cuda` extra and a CUDA device;
# every stage also runs on CPU with DEVICE=cpu (small sizes: SMALL=1), which is how it is tested.
#
#   bash benchmarks/gpu_checks.sh parity          # pytest -m gpu: gsplat vs the torch reference
#   bash benchmarks/gpu_checks.sh suite           # the default suite with --device cuda
#   bash benchmarks/gpu_checks.sh bench           # rasterizers.py + iteration_cost.py (+ profile)
#   bash benchmarks/gpu_checks.sh beer-haze DATA  # vanilla-gs depth, then td-synth haze on DATA
#   bash benchmarks/gpu_checks.sh beer-train      # tri-dehaze, 15000 steps, timed end to end
#
# Results go to $RESULTS (default benchmarks/results/gpu); runs to $RUNS (default /tmp/td-gpu-runs).
set -euo pipefail
cd "$(dirname "$0")/.."
DEVICE=${DEVICE:-cuda}
RESULTS=${RESULTS:-benchmarks/results/gpu}
RUNS=${RUNS:-/tmp/td-gpu-runs}
JOBS=${JOBS:-8}
SMALL=${SMALL:-0}
mkdir -p "$RESULTS" "$RUNS"
export PYTHONUNBUFFERED=1

case "${1:-}" in
parity)
    python -m pytest -m gpu -p no:cacheprovider -rA -v
    ;;
suite)
    # every test that takes a device gets $DEVICE; the pipeline runs of the rest use `auto` (CUDA)
    python -m pytest --device "$DEVICE" -p no:cacheprovider -q -n "$JOBS" -ra
    ;;
bench)
    # 1) the CPU table's cases with every backend (gsplat's speed-up is against torch on CPU);
    # 2) gsplat alone at the sizes of the iteration benchmark
    if [ "$SMALL" = 1 ]; then
        sizes="80x60:2000:4"
        rast_default=(--n 2000 --size 80x60 --repeats 2)
        rast_large=(--n 4000 --size 96x72 --repeats 2 --backends torch)
    else
        sizes="320x240:50000:8 320x240:500000:12 1280x960:50000:6 1280x960:500000:6"
        rast_default=()
        rast_large=(--n 50000 500000 --size 320x240 1280x960 --repeats 5 --backends gsplat)
    fi
    python benchmarks/rasterizers.py "${rast_default[@]}"
    for ext in json csv png; do cp "benchmarks/results/rasterizers.$ext" "$RESULTS/rasterizers.$ext"; done
    python benchmarks/rasterizers.py "${rast_large[@]}"
    for ext in json csv; do cp "benchmarks/results/rasterizers.$ext" "$RESULTS/rasterizers_large.$ext"; done
    for case in $sizes; do
        IFS=: read -r size points views <<<"$case"
        w=${size%x*}
        h=${size#*x}
        python benchmarks/iteration_cost.py --device "$DEVICE" --width "$w" --height "$h" \
            --points "$points" --views "$views" --profile 5 \
            --variants vanilla-gs "tri-dehaze (default: ~1200 rays)" "tri-dehaze (stride 1, every pixel)" \
            --out "$RESULTS/iteration_cost_${size}_${points}"
    done
    ;;
beer-haze)
    data=${2:?beer-haze needs the clean dataset folder}
    steps=3000
    [ "$SMALL" = 1 ] && steps=30
    td-train vanilla-gs --data "$data" --device "$DEVICE" --max-steps "$steps" --output-dir "$RUNS" \
        --timestamp depth ${DOWNSCALE:+--downscale "$DOWNSCALE"}
    td-synth haze --data "$data" --output-dir "$RUNS/beer-hazy" --overwrite --median-transmittance 0.5 \
        --heterogeneous 0.5 --depth-from-run "$RUNS"/*/vanilla-gs/depth/config.yml \
        ${DOWNSCALE:+--downscale "$DOWNSCALE"}
    ;;
beer-train)
    steps=15000
    [ "$SMALL" = 1 ] && steps=40
    start=$(date +%s.%N)
    td-train tri-dehaze --data "$RUNS/beer-hazy" --device "$DEVICE" --max-steps "$steps" \
        --output-dir "$RUNS" --timestamp full --eval-at-end
    end=$(date +%s.%N)
    metrics=$(ls "$RUNS"/*/tri-dehaze/full/eval/metrics.json)
    python - "$metrics" "$start" "$end" "$RESULTS/beer_full_resolution.json" <<'EOF'
import json, sys
metrics, start, end, out = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), sys.argv[4]
m = json.load(open(metrics))
import torch
m["end_to_end_seconds"] = end - start
m["device"] = torch.cuda.get_device_name() if torch.cuda.is_available() else "cpu"
open(out, "w").write(json.dumps(m, indent=2))
print(json.dumps({k: m[k] for k in m if not isinstance(m[k], (dict, list))}, indent=2))
EOF
    ;;
*)
    echo "usage: $0 parity|suite|bench|beer-haze DATA|beer-train" >&2
    exit 2
    ;;
esac
