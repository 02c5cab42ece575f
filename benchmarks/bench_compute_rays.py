"""Shadow rays on the GPU module's compute shaders against Blender's BVH tree, same process.

Run: ``.venv/bin/python benchmarks/bench_compute_rays.py [--rays 262144] [--triangles 1024]``.
Casts the same rays, towards a narrow cone as a sun's disk asks, at random triangles with
``mathutils.bvhtree`` (the add-on's :class:`~cubegi_addon.bvh_rays.BvhRays`) and with a
compute shader that tests every ray against every triangle (no tree: the throughput of the
machine's compute, llvmpipe's on a CPU). Prints each one's rays a second, the shader's
ray-triangle tests a second and how many answers differ. Where the GPU module has no storage
buffers (bpy 4.5 LTS) it says so and measures the tree alone.
"""

import argparse
import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

SHADER = """
void main() {
  int i = int(gl_GlobalInvocationID.x);
  if (i >= ray_count) { return; }
  vec3 o = rays_in[2 * i].xyz;
  vec3 d = rays_in[2 * i + 1].xyz;
  int hit = 0;
  for (int k = 0; k < tri_count && hit == 0; k++) {
    vec3 a = tris[3 * k].xyz;
    vec3 e1 = tris[3 * k + 1].xyz - a, e2 = tris[3 * k + 2].xyz - a;
    vec3 p = cross(d, e2);
    float det = dot(e1, p);
    if (abs(det) < 1e-12) { continue; }
    vec3 s = o - a;
    float u = dot(s, p) / det;
    vec3 q = cross(s, e1);
    float v = dot(d, q) / det;
    if (u >= 0.0 && v >= 0.0 && u + v <= 1.0 && dot(e2, q) / det > 0.0) { hit = 1; }
  }
  hit_out[i] = hit;
}
"""


def compute_blocked(origins, dirs, corners):
    """``(n,)`` bool by the brute-force compute shader; None where the GPU module has no
    storage buffers."""
    import gpu
    import numpy as np

    if not hasattr(gpu.types, "GPUStorageBuf") or not hasattr(gpu.types.GPUShaderCreateInfo, "storage_buf"):
        return None
    info = gpu.types.GPUShaderCreateInfo()
    info.local_group_size(64, 1, 1)
    info.storage_buf(0, "vec4", "rays_in[]", qualifiers={"READ"})
    info.storage_buf(1, "vec4", "tris[]", qualifiers={"READ"})
    info.storage_buf(2, "int", "hit_out[]", qualifiers={"WRITE"})
    info.push_constant("INT", "ray_count")
    info.push_constant("INT", "tri_count")
    info.compute_source(SHADER)
    shader = gpu.shader.create_from_info(info)
    n = len(origins)
    rays = np.zeros((n, 2, 4), np.float32)
    rays[:, 0, :3], rays[:, 1, :3] = origins, dirs
    tris = np.zeros((corners.size // 3, 4), np.float32)
    tris[:, :3] = corners.reshape(-1, 3)
    buffers = {"rays_in": gpu.types.GPUStorageBuf(gpu.types.Buffer("FLOAT", rays.size, rays.ravel())),
               "tris": gpu.types.GPUStorageBuf(gpu.types.Buffer("FLOAT", tris.size, tris.ravel())),
               "hit_out": gpu.types.GPUStorageBuf(gpu.types.Buffer("INT", n, np.zeros(n, np.int32)))}
    shader.bind()
    shader.uniform_int("ray_count", n)
    shader.uniform_int("tri_count", len(corners))
    for name, buf in buffers.items():
        shader.storage_block(name, buf)
    gpu.compute.dispatch(shader, (n + 63) // 64, 1, 1)
    raw = np.asarray(buffers["hit_out"].read(), dtype=np.uint8)  # (the read gives bytes)
    return raw.view(np.int32)[:n] != 0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rays", type=int, default=1 << 18)
    ap.add_argument("--triangles", type=int, default=1024)
    args = ap.parse_args()

    import bpy
    import numpy as np

    from tools import load_extension

    cubegi = load_extension()
    cubegi.cubegi_addon.gpu_capture.ensure_gpu()
    import gpu

    rng = np.random.default_rng(0)
    corners = (rng.random((args.triangles, 3, 3)) * [4.0, 4.0, 2.0] + [0.0, 0.0, 0.5]).astype(np.float32)
    origins = np.column_stack([rng.random(args.rays) * 4.0, rng.random(args.rays) * 4.0, np.zeros(args.rays)])
    dirs = np.tile([0.3, 0.2, 1.0], (args.rays, 1)) + rng.normal(scale=0.01, size=(args.rays, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    print(f"bpy {bpy.app.version_string}, {gpu.platform.renderer_get()}: {args.rays:,} rays, {args.triangles:,} triangles")
    tree = cubegi.cubegi_addon.bvh_rays.BvhRays(corners.reshape(-1, 3).astype(np.float64), np.arange(corners.size // 3).reshape(-1, 3))
    t = time.perf_counter()
    by_tree = tree.blocked(origins, dirs)
    tree_s = time.perf_counter() - t
    print(f"BVH tree: {tree_s:.3f} s, {args.rays / tree_s / 1e6:.2f}M rays a second, {by_tree.mean():.1%} blocked")
    compute_blocked(origins[:64], dirs[:64], corners)  # (the shader's compile and first dispatch)
    t = time.perf_counter()
    by_shader = compute_blocked(origins.astype(np.float32), dirs.astype(np.float32), corners)
    shader_s = time.perf_counter() - t
    if by_shader is None:
        print("compute shader: this GPU module has no storage buffers")
        return
    print(f"compute shader, every triangle: {shader_s:.3f} s, {args.rays / shader_s / 1e6:.2f}M rays a second "
          f"(at most {args.rays * args.triangles / shader_s / 1e6:,.0f}M ray-triangle tests a second), "
          f"{int((by_shader != by_tree).sum())} answers differ from the tree's")


if __name__ == "__main__":
    main()
