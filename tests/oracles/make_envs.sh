#!/usr/bin/env bash
# Creates the reference-implementation ("oracle") virtual environments that the oracle tests call.
# Devkits pin old numpy (nuscenes-devkit: numpy<2), so each lives in its own venv under .oracle-envs/,
# never in the project's environment. Idempotent: an env whose marker file lists the same requirements is kept;
# changing an env's requirements here rebuilds it.
#
# The environments are built at the same time: a build is mostly download and unpacking (pip's own work is one
# core), so four in parallel take about as long as the largest (Waymo's TensorFlow) instead of their sum
# (CI: 286 s one after another). Each build logs to its own file; a failed build prints its log and the script
# fails after every build has ended.
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
envs="$root/.oracle-envs"
mkdir -p "$envs"

started=$SECONDS
names=()
pids=()

make_env() {
    local name="$1"; shift
    local dir="$envs/$name"
    if [ -f "$dir/.complete" ] && [ "$(cat "$dir/.complete")" = "$*" ]; then
        echo "oracle env $name: kept"
        return
    fi
    echo "oracle env $name: building ($*)"
    (
        begin=$SECONDS
        rm -rf "$dir"
        python3 -m venv "$dir"
        # No wheel cache: CI machines can have little disk, and every env is built once.
        "$dir/bin/python" -m pip install --quiet --disable-pip-version-check --no-cache-dir "$@"
        echo "$*" > "$dir/.complete"
        echo "oracle env $name: ready in $((SECONDS - begin)) s"
    ) > "$envs/$name.log" 2>&1 &
    names+=("$name")
    pids+=("$!")
}

# The devkit's tracking evaluation (AMOTA) also needs motmetrics 1.4.0 and pandas, which it does not declare.
make_env nuscenes "nuscenes-devkit==1.2.0" "motmetrics==1.4.0" "pandas<2.2"
# trackeval 1.3.0 requires numpy>=2.3.2 on Python 3.11 (its metadata), so numpy<2 cannot be pinned here.
make_env trackeval "trackeval==1.3.0" "motmetrics==1.4.0" "scipy" "pandas"
# Argoverse 2's own API (issue 11): AV2SensorDataLoader, SE3, CuboidList, detection evaluation.
# av2 requires torch; unpinned, pip takes a CUDA build (torch plus nvidia-* wheels, several GB), which filled a
# CI machine's disk. 2.13.0 is the local CPU wheel, as in the project's own venv.
make_env av2 "av2==0.3.6" "torch==2.13.0"
# Waymo's own v2 conversion (compat_v1), range-image to points and detection metrics; TensorFlow 2.13, ~2.8 GB.
make_env waymo "waymo-open-dataset-tf-2-12-0==1.6.7"

failed=()
for i in "${!pids[@]}"; do
    if wait "${pids[$i]}"; then
        tail -n 1 "$envs/${names[$i]}.log"
    else
        failed+=("${names[$i]}")
        echo "oracle env ${names[$i]}: FAILED; its log ($envs/${names[$i]}.log):" >&2
        cat "$envs/${names[$i]}.log" >&2
    fi
done
if [ "${#failed[@]}" -ne 0 ]; then
    echo "oracle envs: ${failed[*]} failed ($((SECONDS - started)) s)" >&2
    exit 1
fi
echo "oracle envs: ${#names[@]} built, the others kept, in $((SECONDS - started)) s"
