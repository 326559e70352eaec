#!/usr/bin/env bash
# The GPU check: runs a pack made by tools/gpu-check/pack.sh on the machine
# with the GPU (no Rust toolchain needed) and writes few files into OUTDIR:
#
#   summary.json  every step: command, status, exit code, seconds, test counts
#   log.txt       everything the steps printed, the device and driver
#   bench.json    gpu_bench (Algorithms 1 and 2, upload, TLAS, BLAS batches)
#   profile.json  device_profile (lipac-sim's --device-profile format)
#   oom.json      device_oom (real out-of-memory, then the passes again)
#   vk_city.png   the vk_city example's last frame (where it ran)
#
#   run.sh OUTDIR
#
# Steps, each under a time limit and all within LIPAC_GPU_CHECK_BUDGET_S
# (default 420 s): the benchmark at 100k, 1M and 10M slots, the device
# profile, real out-of-memory, every packed test binary (--nocapture), the
# vk_city example. A step that fails does not stop the others; the exit
# status is 1 when any step failed. LIPAC_GPU_CHECK_SMALL=1 runs small
# sizes (CPU Vulkan, lavapipe); LIPAC_GPU_CHECK_PACK=DIR names the pack when
# this script is not inside one; LIPAC_GPU_CHECK_VK_CITY_ARGS adds
# arguments to vk_city; LIPAC_GPU_CHECK_TEST_ARGS replaces the test
# binaries' arguments (default --nocapture).
set -u
if [ $# -ne 1 ]; then
  echo "usage: run.sh OUTDIR" >&2
  exit 2
fi
out=$1
here=$(cd "$(dirname "$0")" && pwd)
if [ -n "${LIPAC_GPU_CHECK_PACK:-}" ]; then
  pack=$(cd "$LIPAC_GPU_CHECK_PACK" && pwd)
elif [ -f "$here/MANIFEST.txt" ]; then
  pack=$here
else
  pack=$(cd "$here/../.." && pwd)/.gpu-check
fi
[ -f "$pack/MANIFEST.txt" ] || { echo "run.sh: no pack at $pack (run tools/gpu-check/pack.sh)" >&2; exit 2; }
mkdir -p "$out" || exit 2
out=$(cd "$out" && pwd)
for f in summary.json log.txt bench.json profile.json oom.json vk_city.png; do
  if [ -e "$out/$f" ]; then
    echo "run.sh: $out/$f exists; give an empty folder (nothing is overwritten)" >&2
    exit 2
  fi
done
log=$out/log.txt
start=$(date +%s)
budget=${LIPAC_GPU_CHECK_BUDGET_S:-420}
deadline=$((start + budget))
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
say() { echo "$*" | tee -a "$log"; }

# The binaries: in the pack, or unpacked from its payload.
bins=$pack
if [ -f "$pack/payload.tar.xz" ]; then
  xz -dc "$pack/payload.tar.xz" | tar -C "$work" -xf - || { say "run.sh: cannot unpack the payload"; exit 1; }
  bins=$work
fi

say "== lipac GPU check: $(uname -srm), $(nproc) CPUs"
sed -n '1,4p' "$pack/MANIFEST.txt" | tee -a "$log"
if command -v nvidia-smi >/dev/null 2>&1; then
  nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.sm,clocks.mem,temperature.gpu,power.draw \
    --format=csv 2>&1 | tee -a "$log"
fi

# The Vulkan loader (and the glvnd libraries drivers load through): the
# system's, and the pack's for those the system lacks.
have_lib() {
  { command -v ldconfig >/dev/null && ldconfig -p 2>/dev/null || /sbin/ldconfig -p 2>/dev/null; } |
    grep -q "^[[:space:]]*$1 " && return 0
  local d
  for d in ${LD_LIBRARY_PATH:+${LD_LIBRARY_PATH//:/ }} /usr/lib/x86_64-linux-gnu /lib/x86_64-linux-gnu /usr/lib64 /usr/lib /usr/local/lib; do
    [ -e "$d/$1" ] && return 0
  done
  return 1
}
loader=system
mkdir -p "$work/loader"
for f in "$pack"/loader/*; do
  [ -f "$f" ] || continue
  so=$(basename "$f")
  if ! have_lib "$so"; then
    ln -s "$f" "$work/loader/$so"
    loader="system + the pack's $(ls "$work/loader" | tr '\n' ' ')"
  fi
done
if [ -n "$(ls "$work/loader")" ]; then
  export LD_LIBRARY_PATH="$work/loader${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
fi
if ! have_lib libvulkan.so.1; then
  loader="none found (no libvulkan.so.1 on the system and none in the pack: pack.sh --with-loader)"
fi
say "Vulkan loader: $loader"
# A driver manifest where the loader looks, else a vendor's install path.
if [ -z "${VK_DRIVER_FILES:-}${VK_ICD_FILENAMES:-}" ]; then
  found=$(ls /etc/vulkan/icd.d/*.json /usr/share/vulkan/icd.d/*.json /usr/local/share/vulkan/icd.d/*.json 2>/dev/null | head -n 1)
  if [ -z "$found" ]; then
    alt=$(ls /usr/local/nvidia/share/vulkan/icd.d/*.json 2>/dev/null | head -n 1)
    if [ -n "$alt" ]; then
      export VK_DRIVER_FILES=$alt
      say "Vulkan driver manifest: $alt (VK_DRIVER_FILES)"
    else
      say "Vulkan driver manifest: none found in the loader's folders"
    fi
  else
    say "Vulkan driver manifests: $(ls /etc/vulkan/icd.d/*.json /usr/share/vulkan/icd.d/*.json /usr/local/share/vulkan/icd.d/*.json 2>/dev/null | tr '\n' ' ')"
  fi
fi
# The validation layer: the system's or the pack's; the tests use it where
# there is one. They require a device (LIPAC_REQUIRE_VULKAN=device: a
# missing device fails them; a test the device cannot run is reported as
# ignored, with its reason, never as passed).
layer=none
for d in /usr/share/vulkan/explicit_layer.d /etc/vulkan/explicit_layer.d /usr/local/share/vulkan/explicit_layer.d; do
  [ -f "$d/VkLayer_khronos_validation.json" ] && layer="system ($d)" && break
done
if [ "$layer" = none ] && [ -f "$bins/layers/VkLayer_khronos_validation.json" ]; then
  export VK_LAYER_PATH="$bins/layers${VK_LAYER_PATH:+:$VK_LAYER_PATH}"
  layer="pack"
fi
export LIPAC_REQUIRE_VULKAN=device
say "validation layer: $layer; LIPAC_REQUIRE_VULKAN=device${LIPAC_VK_DEVICE:+; LIPAC_VK_DEVICE=$LIPAC_VK_DEVICE}${LIPAC_VK_HIDE:+; LIPAC_VK_HIDE=$LIPAC_VK_HIDE}"

small=${LIPAC_GPU_CHECK_SMALL:-0}
if [ "$small" = 1 ]; then
  bench_args=(--slots 10k,50k --reps 5 --blas 16x512,2x8192 --warmup-ms 200 --evict-mib 8 --bandwidth-mib 32)
  profile_args=(--slots 20k --tlas 10k --blas 16x512,2x8192 --reps 3 --warmup-ms 100 --evict-mib 8)
  oom_args=(--check-slots 20k)
  city_args=(--instances 600 --frames 4 --width 64 --height 40)
  say "small sizes (LIPAC_GPU_CHECK_SMALL=1)"
else
  bench_args=(--slots 100k,1M,10M --reps 40)
  profile_args=(--slots 1M --tlas 1M --reps 40)
  oom_args=(--check-slots 1M)
  city_args=()
fi
# shellcheck disable=SC2206
city_args+=(${LIPAC_GPU_CHECK_VK_CITY_ARGS:-})

steps=()
failed=0
json_escape() { printf '%s' "$1" | sed -e 's/\\/\\\\/g' -e 's/"/\\"/g' | tr '\n\t' '  '; }

# step NAME LIMIT_S COMMAND...: runs it within the budget, logs, records.
step() {
  local name=$1 limit=$2
  shift 2
  local now left status rc t0 secs extra="" text
  now=$(date +%s)
  left=$((deadline - now))
  [ "$left" -lt "$limit" ] && limit=$left
  local cmd="$*"
  cmd=${cmd//$bins\//}
  cmd=${cmd//$out\//OUTDIR/}
  say ""
  say "== $name: $cmd (limit ${limit} s)"
  if [ "$limit" -lt 5 ]; then
    status="not run: time budget" rc=-1 secs=0
    say "-- not run: the time budget (LIPAC_GPU_CHECK_BUDGET_S=$budget) is spent"
  elif [ ! -x "$1" ]; then
    status="not run" rc=-1 secs=0
    say "-- not run: $1 is not in the pack"
  else
    t0=$(date +%s)
    timeout --kill-after=10 "$limit" "$@" >"$work/step.txt" 2>&1
    rc=$?
    secs=$(($(date +%s) - t0))
    cat "$work/step.txt" >>"$log"
    cp "$work/step.txt" "$work/out-$name.txt" 2>/dev/null
    if [ "$rc" = 124 ] || [ "$rc" = 137 ]; then
      status="timed out"
    elif [ "$rc" != 0 ]; then
      status="failed"
    elif grep -qiE '(^|: )skipped' "$work/step.txt"; then
      status="not run"
    elif grep -q ': not run (' "$work/step.txt"; then
      status="passed, some cases not run"
    else
      status="passed"
    fi
    # libtest's counts, summed over its result lines, and SKIPPED lines.
    if grep -q '^test result:' "$work/step.txt"; then
      local counts p f ig sk
      counts=$(awk '/^test result:/ { for (i = 2; i <= NF; i++) {
          if ($i ~ /^passed/) p += $(i - 1); if ($i ~ /^failed/) f += $(i - 1);
          if ($i ~ /^ignored/) g += $(i - 1) } }
        /^SKIPPED/ { s++ }
        END { printf "%d %d %d %d", p, f, g, s }' "$work/step.txt")
      read -r p f ig sk <<<"$counts"
      extra=", \"tests\": {\"passed\": $p, \"failed\": $f, \"ignored\": $ig, \"skipped\": $sk}"
      if [ "$rc" = 0 ]; then
        if [ "$p" = 0 ]; then
          status="not run"
        elif [ $((sk + ig)) -gt 0 ]; then
          status="passed, some not run"
        else
          status="passed"
        fi
      fi
      say "   tests: $p passed, $f failed, $ig ignored (not run), $sk SKIPPED"
    fi
    say "-- $name: $status (exit $rc, ${secs} s)"
  fi
  case "$status" in failed | "timed out" | "not run: time budget") failed=1 ;; esac
  steps+=("{\"name\": \"$(json_escape "$name")\", \"command\": \"$(json_escape "$cmd")\", \"status\": \"$status\", \"exit_code\": $rc, \"seconds\": $secs$extra}")
  return 0
}

step "gpu_bench" 240 "$bins/bin/gpu_bench" --out "$out/bench.json" "${bench_args[@]}"
step "device_profile" 150 "$bins/bin/device_profile" --out "$out/profile.json" "${profile_args[@]}"
step "device_oom" 120 "$bins/bin/device_oom" --out "$out/oom.json" "${oom_args[@]}"
for t in "$bins"/tests/*; do
  [ -x "$t" ] || continue
  # shellcheck disable=SC2086
  step "test $(basename "$t")" 150 "$t" ${LIPAC_GPU_CHECK_TEST_ARGS---nocapture}
done
if [ -x "$bins/bin/vk_city" ]; then
  step "vk_city" 120 "$bins/bin/vk_city" --out "$out/vk_city.png" "${city_args[@]}"
fi
if command -v nvidia-smi >/dev/null 2>&1; then
  say ""
  nvidia-smi --query-gpu=clocks.sm,clocks.mem,temperature.gpu,power.draw --format=csv 2>&1 | tee -a "$log"
fi

say ""
say "== the benchmark's and the profile's tables"
for f in "$work/out-gpu_bench.txt" "$work/out-device_profile.txt" "$work/out-device_oom.txt"; do
  [ -f "$f" ] && grep -E '^(\||gpu_bench:|device_profile:|device_oom:|BLAS|TLAS|Algorithms|unit cube)' "$f"
done
total=$(($(date +%s) - start))
{
  echo "{"
  echo "  \"format\": \"lipac-gpu-check\","
  echo "  \"version\": 1,"
  echo "  \"host\": \"$(json_escape "$(uname -srm)")\","
  echo "  \"pack\": \"$(json_escape "$(sed -n 2p "$pack/MANIFEST.txt")")\","
  echo "  \"vulkan_loader\": \"$(json_escape "$loader")\","
  echo "  \"validation_layer\": \"$(json_escape "$layer")\","
  echo "  \"small\": $([ "$small" = 1 ] && echo true || echo false),"
  echo "  \"seconds\": $total,"
  echo "  \"ok\": $([ "$failed" = 0 ] && echo true || echo false),"
  echo "  \"steps\": ["
  n=${#steps[@]}
  for i in "${!steps[@]}"; do
    sep=","
    [ "$i" = $((n - 1)) ] && sep=""
    echo "    ${steps[$i]}$sep"
  done
  echo "  ]"
  echo "}"
} >"$out/summary.json"
say ""
say "== $(grep -c '"status": "passed' "$out/summary.json") steps passed, failed: $failed (1 = some failed), ${total} s; summary in $out/summary.json"
exit "$failed"
