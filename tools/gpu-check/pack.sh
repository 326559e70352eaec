#!/usr/bin/env bash
# Builds the GPU check's release binaries and packs them, stripped, with
# run.sh into a folder git ignores, for a machine that has a GPU but no
# Rust toolchain (docs/BENCHMARKS.md, "GPU benchmark").
#
#   tools/gpu-check/pack.sh [DIR] [--with-loader] [--with-validation] [--max-mib N]
#
# DIR (default: .gpu-check at the repository root, added to the repository's
# .git/info/exclude) is created fresh; it must not exist or must be a pack
# made by this script. It gets run.sh, bin/ (gpu_bench, device_profile,
# device_oom, vk_city), tests/ (every test binary of lipac-vk, its device
# tests among them, and the root crate's vk_city test: whatever `cargo test
# --no-run` produces) and
# MANIFEST.txt. --with-loader adds this
# machine's Vulkan loader and the glvnd libraries a vendor's driver loads
# through (libvulkan.so.1, libGLdispatch.so.0, libGLX.so.0, libGL.so.1,
# libEGL.so.1, libOpenGL.so.0; run.sh uses those the target lacks);
# --with-validation adds the Khronos validation layer (the tests and
# examples then run under it where the target has none).
# When the binaries exceed --max-mib (default 48) they are packed as
# payload.tar.xz instead; the script fails if even that does not fit.
set -euo pipefail
root=$(git rev-parse --show-toplevel)
cd "$root"
dest="$root/.gpu-check"
with_loader=0 with_validation=0 max_mib=48
while [ $# -gt 0 ]; do
  case "$1" in
    --with-loader) with_loader=1 ;;
    --with-validation) with_validation=1 ;;
    --max-mib) max_mib=$2; shift ;;
    -*) echo "pack.sh: unknown option $1" >&2; exit 2 ;;
    *) dest=$(realpath -m "$1") ;;
  esac
  shift
done
case "$dest" in
  "$root"|"$root/"|/) echo "pack.sh: refusing to use $dest" >&2; exit 2 ;;
esac
if [ -e "$dest" ] && [ ! -f "$dest/MANIFEST.txt" ]; then
  echo "pack.sh: $dest exists and is not a pack made by pack.sh; not touching it" >&2
  exit 2
fi
# Ignored by git (the folder holds build outputs only).
if [ "${dest#"$root"/}" != "$dest" ]; then
  exclude=$(git rev-parse --git-path info/exclude)
  rel="/${dest#"$root"/}/"
  mkdir -p "$(dirname "$exclude")"
  grep -qxF "$rel" "$exclude" 2>/dev/null || echo "$rel" >>"$exclude"
fi

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
echo "== cargo build --release (lipac-vk tests and examples, vk_city)"
cargo test --release --locked -p lipac-vk --no-run --message-format=json-render-diagnostics >"$tmp/vk.json"
cargo build --release --locked -p lipac-vk --example gpu_bench --example device_profile \
  --example device_oom --message-format=json-render-diagnostics >"$tmp/ex.json"
cargo test --release --locked --features vk,sim --test vk_city --no-run \
  --message-format=json-render-diagnostics >"$tmp/city-test.json"
cargo build --release --locked --features vk,sim --example vk_city \
  --message-format=json-render-diagnostics >"$tmp/city.json"

# "executable" of every test artifact (tests), of the named examples (bin).
list() { # FILE KIND(test|example)
  python3 - "$1" "$2" <<'PY'
import json, sys
path, kind = sys.argv[1], sys.argv[2]
for line in open(path):
    try:
        m = json.loads(line)
    except ValueError:
        continue
    if m.get("reason") != "compiler-artifact" or not m.get("executable"):
        continue
    t = m["target"]
    if kind == "test" and m["profile"]["test"]:
        print(t["name"], m["executable"])
    elif kind == "example" and "example" in t["kind"] and not m["profile"]["test"]:
        print(t["name"], m["executable"])
PY
}
rm -rf "$dest"
mkdir -p "$dest/bin" "$dest/tests"
{ list "$tmp/vk.json" test; list "$tmp/city-test.json" test; } | sort -u | while read -r name exe; do
  cp "$exe" "$dest/tests/$name"
done
{ list "$tmp/ex.json" example; list "$tmp/city.json" example; } | sort -u | while read -r name exe; do
  cp "$exe" "$dest/bin/$name"
done
strip --strip-all "$dest"/bin/* "$dest"/tests/*
for need in bin/gpu_bench bin/device_profile bin/device_oom tests/device; do
  [ -x "$dest/$need" ] || { echo "pack.sh: $need was not built" >&2; exit 1; }
done
cp tools/gpu-check/run.sh "$dest/run.sh"
chmod +x "$dest/run.sh"

if [ "$with_loader" = 1 ]; then
  mkdir -p "$dest/loader"
  for so in libvulkan.so.1 libGLdispatch.so.0 libGLX.so.0 libGL.so.1 libEGL.so.1 libOpenGL.so.0; do
    lib=$(ldconfig -p | awk -v n="$so" '$1 == n && /x86-64/ {print $NF; exit}')
    [ -n "$lib" ] || { echo "pack.sh: no $so here for --with-loader" >&2; exit 1; }
    cp -L "$lib" "$dest/loader/$so"
  done
fi
if [ "$with_validation" = 1 ]; then
  json=""
  for d in /usr/share/vulkan/explicit_layer.d /etc/vulkan/explicit_layer.d /usr/local/share/vulkan/explicit_layer.d; do
    [ -f "$d/VkLayer_khronos_validation.json" ] && json="$d/VkLayer_khronos_validation.json" && break
  done
  [ -n "$json" ] || { echo "pack.sh: no validation layer here for --with-validation" >&2; exit 1; }
  so=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["layer"]["library_path"])' "$json")
  case "$so" in /*) ;; *) so=$(ldconfig -p | awk -v n="$(basename "$so")" '$1 == n {print $NF; exit}') ;; esac
  mkdir -p "$dest/layers"
  cp -L "$so" "$dest/layers/libVkLayer_khronos_validation.so"
  strip --strip-all "$dest/layers/libVkLayer_khronos_validation.so"
  python3 - "$json" "$dest/layers/VkLayer_khronos_validation.json" <<'PY'
import json, sys
d = json.load(open(sys.argv[1]))
d["layer"]["library_path"] = "./libVkLayer_khronos_validation.so"
json.dump(d, open(sys.argv[2], "w"), indent=1)
PY
fi

mib() { du -sb "$1" | awk '{printf "%.1f", $1 / 1048576}'; }
raw=$(mib "$dest")
if awk -v r="$raw" -v m="$max_mib" 'BEGIN { exit !(r > m) }'; then
  echo "== $raw MiB is over $max_mib MiB: packing bin/, tests/ and layers/ as payload.tar.xz"
  parts=(bin tests)
  [ -d "$dest/layers" ] && parts+=(layers)
  tar -C "$dest" -cf - "${parts[@]}" | xz -6 -T2 >"$dest/payload.tar.xz"
  rm -rf "${parts[@]/#/$dest/}"
fi
total=$(mib "$dest")
{
  echo "lipac GPU check pack (tools/gpu-check/pack.sh)"
  echo "commit: $(git rev-parse HEAD)$(git diff --quiet HEAD -- . ':!.gpu-check' 2>/dev/null || echo ' (with uncommitted changes)')"
  echo "rustc: $(rustc --version)"
  echo "size: $total MiB"
  (cd "$dest" && find . -type f ! -name MANIFEST.txt -printf '%s %p\n' | sort -k2)
} >"$dest/MANIFEST.txt"
echo "== packed into $dest: $total MiB"
if awk -v r="$total" -v m="$max_mib" 'BEGIN { exit !(r > m) }'; then
  echo "pack.sh: $total MiB is still over $max_mib MiB" >&2
  exit 1
fi
