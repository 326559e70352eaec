#!/usr/bin/env bash
# Regenerates lipac-vk/shaders/spv/*.spv from the GLSL sources.
# The .spv files are committed; tests/shaders.rs checks they match this script's output.
set -euo pipefail
cd "$(dirname "$0")"
mkdir -p spv
for src in *.comp; do
  glslangValidator --target-env vulkan1.2 -I. -o "spv/${src%.comp}.spv" "$src" | { grep -v "^$src$" || true; }
  spirv-val --target-env vulkan1.2 "spv/${src%.comp}.spv"
done
