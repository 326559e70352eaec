#version 460
// assemble_merged.comp -- Algorithm 1 pass 2 with adaptive hitboxes, one
// thread per hitbox (lipac_core::hitbox_tree::HitboxTree::emit_boxes, in the
// per-leaf form of its tests' reference): after assemble_hitboxes.comp turned
// every height range back into f32, an inactive hitbox finds the highest
// quadtree node above it (levels pc.adaptiveLevels..1) whose hitboxes are all
// inactive. None: its own counting box, as without the option. Else the first
// hitbox of that node (row-major) holding inactive instances emits the node's
// box: its own box if it is the only one, else one box over the union of
// their boxes as the hardware evaluates them ([t, t + s] per axis of each
// box's unit-cube map), custom index = node id, SBT offset pc.mergedSbt.
#extension GL_GOOGLE_include_directive : require
#include "lipac_assembly.glsl"

// The box a hitbox would get (its unit-cube map's [t, t + s] per axis);
// false when it gets none (active, empty, or no finite map).
bool leafBox(uint k, out vec3 lo, out vec3 hi) {
    lo = vec3(0.0);
    hi = vec3(0.0);
    LipacHitboxRecord h = hitboxes[k];
    float minY = uintBitsToFloat(h.minY);
    float maxY = uintBitsToFloat(h.maxY);
    if ((h.packed & LIPAC_HITBOX_ACTIVE) != 0u || minY > maxY) {
        return false;
    }
    vec4 b = hitboxBounds[k];
    float tx, sx, ty, sy, tz, sz;
    if (!lipacAxisMap(b.x, b.z, pc.minExtent, tx, sx) ||
        !lipacAxisMap(minY, maxY, pc.minExtent, ty, sy) ||
        !lipacAxisMap(b.y, b.w, pc.minExtent, tz, sz)) {
        return false;
    }
    precise vec3 t = vec3(tx, ty, tz);
    precise vec3 s = vec3(sx, sy, sz);
    lo = t;
    hi = t + s;
    return true;
}

// Cells of level l along one axis of n leaves: ceil(n / 2^l).
uint levelDim(uint n, uint l) {
    return (n + (1u << l) - 1u) >> l;
}

void main() {
    uint nx = pc.gridNx;
    uint nz = pc.gridNz;
    LIPAC_FOR_EACH(k, pc.hitboxCount) {
        if ((hitboxes[k].packed & LIPAC_HITBOX_ACTIVE) != 0u) {
            continue;
        }
        uint cx = k % nx;
        uint cz = k / nx;
        // The highest level whose node around k holds no active hitbox.
        uint level = 0u;
        for (uint l = pc.adaptiveLevels; l >= 1u; --l) {
            uint x0 = (cx >> l) << l, z0 = (cz >> l) << l;
            uint x1 = min(x0 + (1u << l), nx), z1 = min(z0 + (1u << l), nz);
            bool cold = true;
            for (uint z = z0; z < z1 && cold; ++z) {
                for (uint x = x0; x < x1; ++x) {
                    if ((hitboxes[x + z * nx].packed & LIPAC_HITBOX_ACTIVE) != 0u) {
                        cold = false;
                        break;
                    }
                }
            }
            if (cold) {
                level = l;
                break;
            }
        }
        vec3 lo, hi;
        if (level == 0u) {
            if (leafBox(k, lo, hi)) {
                LipacHitboxRecord h = hitboxes[k];
                vec4 b = hitboxBounds[k];
                lipacAppendCountingBox(vec3(b.x, uintBitsToFloat(h.minY), b.y),
                                       vec3(b.z, uintBitsToFloat(h.maxY), b.w), k, pc.hitboxSbt);
            }
            continue;
        }
        uint x0 = (cx >> level) << level, z0 = (cz >> level) << level;
        uint x1 = min(x0 + (1u << level), nx), z1 = min(z0 + (1u << level), nz);
        uint count = 0u;
        uint first = 0xFFFFFFFFu;
        vec3 ulo = vec3(uintBitsToFloat(0x7F800000u));   // +inf
        vec3 uhi = vec3(uintBitsToFloat(0xFF800000u));   // -inf
        for (uint z = z0; z < z1; ++z) {
            for (uint x = x0; x < x1; ++x) {
                uint leaf = x + z * nx;
                if (leafBox(leaf, lo, hi)) {
                    count += 1u;
                    if (first == 0xFFFFFFFFu) {
                        first = leaf;
                    }
                    ulo = min(ulo, lo);
                    uhi = max(uhi, hi);
                }
            }
        }
        if (first != k) {
            continue;
        }
        if (count == 1u) {
            LipacHitboxRecord h = hitboxes[k];
            vec4 b = hitboxBounds[k];
            lipacAppendCountingBox(vec3(b.x, uintBitsToFloat(h.minY), b.y),
                                   vec3(b.z, uintBitsToFloat(h.maxY), b.w), k, pc.hitboxSbt);
            continue;
        }
        // Node id: the levels below first, then i + j * width at this level.
        uint id = 0u;
        for (uint l = 1u; l < level; ++l) {
            id += levelDim(nx, l) * levelDim(nz, l);
        }
        id += (cx >> level) + (cz >> level) * levelDim(nx, level);
        lipacAppendCountingBox(ulo, uhi, id, pc.mergedSbt);
    }
}
