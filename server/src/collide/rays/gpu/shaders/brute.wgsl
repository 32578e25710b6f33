// The paper's all-pairs kernel: one workgroup per ray, every thread tests a
// strided share of the triangles, then the workgroup merges the per-thread
// candidate lists in shared memory (the per-node reduction, same pass).

const WG: u32 = 64u;

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> positions: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> tris: array<vec4<u32>>;
@group(0) @binding(3) var<storage, read> rays: array<Ray>;
@group(0) @binding(4) var<storage, read_write> out_words: array<u32>;

var<workgroup> sh_key: array<f32, 2u * WG * K>;
var<workgroup> sh_tri: array<u32, 2u * WG * K>;
var<workgroup> sh_dropped: array<u32, 2u * WG>;

@compute @workgroup_size(64)
fn cast_brute(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let ray_index = wid.x + wid.y * 65535u;
    if ray_index >= params.n_rays {
        return;
    }
    let ray = rays[ray_index];
    let f = ray_frame(ray.origin.xyz, ray.dir.xyz);
    let m = params.m_err;
    var behind = topk_empty();
    var front = topk_empty();
    for (var i = lid; i < params.n_tris; i += WG) {
        let t = tris[i];
        let r = tri_filter(f, positions[t.x].xyz, positions[t.y].xyz, positions[t.z].xyz, m);
        add_candidate(&behind, &front, r, i);
    }
    for (var j = 0u; j < K; j++) {
        sh_key[lid * K + j] = behind.key[j];
        sh_tri[lid * K + j] = behind.tri[j];
        sh_key[(WG + lid) * K + j] = front.key[j];
        sh_tri[(WG + lid) * K + j] = front.tri[j];
    }
    sh_dropped[lid] = select(0u, 1u, behind.dropped);
    sh_dropped[WG + lid] = select(0u, 1u, front.dropped);
    workgroupBarrier();
    // Thread 0 merges the behind lists, thread 1 the front lists.
    if lid < 2u {
        var merged = topk_empty();
        for (var th = 0u; th < WG; th++) {
            let slot = lid * WG + th;
            if sh_dropped[slot] != 0u {
                merged.dropped = true;
            }
            for (var j = 0u; j < K; j++) {
                let tri = sh_tri[slot * K + j];
                if tri != NO_TRI {
                    topk_insert(&merged, sh_key[slot * K + j], tri);
                }
            }
        }
        write_side(ray_index * OUT_WORDS + lid * (2u * K + 1u), merged);
    }
}
