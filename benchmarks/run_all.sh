#!/bin/bash
# The benchmarks one after another, as docs/performance.md was measured, then each speed target with its verdict:
#   bash benchmarks/run_all.sh [LOG]   (from the project root; about 17 minutes on 2 idle cores)
out=${1:-benchmarks-$(date -u +%Y%m%dT%H%M%S).log}
: > "$out"
for name in format_io format_io format_io eval_tracking eval_tracking loaders loaders generate_lidar generate_lidar \
            convert_kitti convert_nuscenes v2x_loader cli_startup object_store; do
  echo "=== $name $(date -u +%H:%M:%S) load $(cut -d' ' -f1-3 /proc/loadavg)" >> "$out"
  timeout 1200 python "benchmarks/$name.py" >> "$out" 2>&1
done
echo "=== done $(date -u +%H:%M:%S)" >> "$out"
echo "wrote $out"
python benchmarks/targets.py "$out"
