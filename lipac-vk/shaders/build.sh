#!/usr/bin/env bash
# Regenerates lipac-vk/shaders/spv/*.spv from the GLSL sources: compute
# shaders (NAME.comp -> spv/NAME.spv) and ray-tracing-pipeline stages
# (NAME.rgen/.rchit/.rahit/.rmiss -> spv/NAME.STAGE.spv).
# The .spv files are committed; tests/shaders.rs checks they match this script's output.
set -euo pipefail
cd "$(dirname "$0")"
mkdir -p spv
for src in *.comp *.rgen *.rchit *.rahit *.rmiss; do
  case "$src" in
    *.comp) out="spv/${src%.comp}.spv" ;;
    *) out="spv/$src.spv" ;;
  esac
  glslangValidator --target-env vulkan1.2 -I. -o "$out" "$src" | { grep -v "^$src$" || true; }
  spirv-val --target-env vulkan1.2 "$out"
done
