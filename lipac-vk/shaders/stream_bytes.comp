#version 460
// stream_bytes.comp -- the bandwidth reference of the GPU benchmark
// (lipac-vk/examples/gpu_bench.rs): streams `readVec4s` 16-byte words from
// `src` and writes `writeVec4s` 16-byte words to `dst`, each word once,
// coalesced (grid-stride loop over max(readVec4s, writeVec4s)). What a pass
// that must read R bytes and write W bytes cannot beat; `vkCmdCopyBuffer`
// is no such reference (it runs far below memory bandwidth on some GPUs).
//
// The XOR of everything read decides one store that never happens in
// practice (`magic` is chosen so), so the reads cannot be optimised away.
#extension GL_EXT_buffer_reference : require

layout(local_size_x = 256) in;

layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer StreamSrc {
    uvec4 words[];
};
layout(buffer_reference, std430, buffer_reference_align = 16) writeonly buffer StreamDst {
    uvec4 words[];
};

layout(push_constant) uniform StreamPush {
    StreamSrc src;
    StreamDst dst;
    uint readVec4s;
    uint writeVec4s;
    uint magic;
} pc;

void main() {
    uint n = max(pc.readVec4s, pc.writeVec4s);
    uint stride = gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    uvec4 acc = uvec4(0u);
    for (uint i = gl_GlobalInvocationID.x; i < n; i += stride) {
        uvec4 v = uvec4(i);
        if (i < pc.readVec4s) {
            v = pc.src.words[i];
            acc ^= v;
        }
        if (i < pc.writeVec4s) {
            pc.dst.words[i] = v;
        }
    }
    if (acc.x == pc.magic && acc.y == ~pc.magic && acc.z == pc.magic && acc.w == ~pc.magic) {
        pc.dst.words[0] = acc;
    }
}
