// BVH over the surface triangles: level-by-level refit and per-ray traversal
// of the whole line (both directions), keeping the candidate lists per side.

struct Node {
    lo: vec3<f32>,
    // Internal: index of the left child (the right child follows it).
    // Leaf: first triangle in BVH order.
    a: u32,
    hi: vec3<f32>,
    // Leaf: triangle count (>= 1). Internal: 0.
    b: u32,
}

const STACK: u32 = 64u;

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> positions: array<vec4<f32>>;
// Vertex indices and original triangle id, in BVH leaf order.
@group(0) @binding(2) var<storage, read> tris: array<vec4<u32>>;
@group(0) @binding(3) var<storage, read_write> nodes: array<Node>;
@group(0) @binding(4) var<storage, read> rays: array<Ray>;
@group(0) @binding(5) var<storage, read_write> out_words: array<u32>;

// One invocation per node of one level, deepest level first.
@compute @workgroup_size(64)
fn refit_level(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= params.level_count {
        return;
    }
    let i = params.level_first + gid.x;
    let n = nodes[i];
    var lo = vec3<f32>(KEY_EMPTY);
    var hi = vec3<f32>(-KEY_EMPTY);
    if n.b == 0u {
        let l = nodes[n.a];
        let r = nodes[n.a + 1u];
        lo = min(l.lo, r.lo);
        hi = max(l.hi, r.hi);
    } else {
        for (var k = n.a; k < n.a + n.b; k++) {
            let t = tris[k];
            let p0 = positions[t.x].xyz;
            let p1 = positions[t.y].xyz;
            let p2 = positions[t.z].xyz;
            lo = min(lo, min(p0, min(p1, p2)));
            hi = max(hi, max(p0, max(p1, p2)));
        }
    }
    nodes[i].lo = lo;
    nodes[i].hi = hi;
}

// Parameter interval of the line o + t d inside the box padded by `pad`;
// x > y when the line misses it.
fn line_box(o: vec3<f32>, inv_d: vec3<f32>, flat_axis: vec3<bool>, lo: vec3<f32>, hi: vec3<f32>, pad: f32) -> vec2<f32> {
    var t0 = -KEY_EMPTY;
    var t1 = KEY_EMPTY;
    for (var k = 0u; k < 3u; k++) {
        let l = lo[k] - pad;
        let h = hi[k] + pad;
        if flat_axis[k] {
            if o[k] < l || o[k] > h {
                return vec2<f32>(1.0, -1.0);
            }
        } else {
            let ta = (l - o[k]) * inv_d[k];
            let tb = (h - o[k]) * inv_d[k];
            t0 = max(t0, min(ta, tb));
            t1 = min(t1, max(ta, tb));
        }
    }
    let slack = 8.0 * EPS * (abs(t0) + abs(t1));
    return vec2<f32>(t0 - slack, t1 + slack);
}

@compute @workgroup_size(64)
fn cast_bvh(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let ray_index = gid.x + gid.y * nwg.x * 64u;
    if ray_index >= params.n_rays {
        return;
    }
    let ray = rays[ray_index];
    let o = ray.origin.xyz;
    let d = ray.dir.xyz;
    let f = ray_frame(o, d);
    let m = params.m_err;
    let flat_axis = abs(d) < vec3<f32>(1.0e-30);
    let inv_d = 1.0 / select(d, vec3<f32>(1.0), flat_axis);
    var behind = topk_empty();
    var front = topk_empty();
    var stack: array<u32, 64>;
    var sp = 0u;
    if params.n_nodes > 0u {
        stack[0] = 0u;
        sp = 1u;
    }
    while sp > 0u {
        sp -= 1u;
        let n = nodes[stack[sp]];
        let span = line_box(o, inv_d, flat_axis, n.lo, n.hi, params.box_pad);
        if span.x > span.y {
            continue;
        }
        // Every exact hit inside the box has t in span. A side needs the box
        // only if the box can hold a hit no worse than a sure hit found already
        // (hits strictly worse than a sure hit are never the answer).
        let skip_front = span.y <= 0.0 || span.x > front.ub;
        let skip_behind = span.x > 0.0 || -span.y > behind.ub;
        if skip_front && skip_behind {
            continue;
        }
        if n.b == 0u {
            if sp + 2u > STACK {
                // Cannot happen for the balanced trees the host builds; stay
                // conservative anyway: the host falls back for this ray.
                front.dropped = true;
                behind.dropped = true;
                front.key[K - 1u] = KEY_UNKNOWN;
                behind.key[K - 1u] = KEY_UNKNOWN;
                front.tri[K - 1u] = NO_TRI;
                behind.tri[K - 1u] = NO_TRI;
                break;
            }
            stack[sp] = n.a;
            stack[sp + 1u] = n.a + 1u;
            sp += 2u;
        } else {
            for (var k = n.a; k < n.a + n.b; k++) {
                let t = tris[k];
                let r = tri_filter(f, positions[t.x].xyz, positions[t.y].xyz, positions[t.z].xyz, m);
                add_candidate(&behind, &front, r, t.w);
            }
        }
    }
    write_side(ray_index * OUT_WORDS, behind);
    write_side(ray_index * OUT_WORDS + 2u * K + 1u, front);
}
