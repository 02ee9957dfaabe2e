#!/bin/bash
# The issue-14 benchmarks one after another, as the README's performance table was measured:
#   bash benchmarks/run_all.sh [LOG]   (from the project root; about 17 minutes on 2 idle cores)
out=${1:-benchmarks-$(date -u +%Y%m%dT%H%M%S).log}
: > "$out"
for name in format_io format_io format_io eval_tracking eval_tracking loaders generate_lidar generate_lidar \
            convert_kitti convert_nuscenes cli_startup; do
  echo "=== $name $(date -u +%H:%M:%S) load $(cut -d' ' -f1-3 /proc/loadavg)" >> "$out"
  timeout 1200 python "benchmarks/$name.py" >> "$out" 2>&1
done
echo "=== done $(date -u +%H:%M:%S)" >> "$out"
echo "wrote $out"
