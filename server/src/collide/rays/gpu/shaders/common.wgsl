// Shared by the all-pairs and the BVH kernels: the conservative f32 line-triangle
// filter and the per-side candidate lists. See `collide/gpu/mod.rs` for the math.

const EPS: f32 = 1.1920929e-7;
// Key of an empty slot, and key lower bound of a hit whose t is unknown.
const KEY_EMPTY: f32 = 3.0e38;
const KEY_UNKNOWN: f32 = -3.0e38;
const NO_TRI: u32 = 0xffffffffu;
const K: u32 = 8u;
// u32 words written per ray: per side K triangle ids, K key bounds, threshold.
const OUT_WORDS: u32 = 2u * (2u * K + 1u);

struct Params {
    // Number of rays, triangles, and for the BVH the number of nodes.
    n_rays: u32,
    n_tris: u32,
    n_nodes: u32,
    // First node and node count of the level a refit pass works on.
    level_first: u32,
    level_count: u32,
    // Bound on the f32 error of transformed coordinates (m), see mod.rs.
    m_err: f32,
    // Padding of BVH boxes (m).
    box_pad: f32,
    _pad: u32,
}

struct Ray {
    origin: vec4<f32>,
    dir: vec4<f32>,
}

// The K smallest key lower bounds seen on one side, ascending, and whether a
// candidate was dropped (or a subtree skipped) so the list is not complete.
struct TopK {
    key: array<f32, K>,
    tri: array<u32, K>,
    dropped: bool,
    // Smallest key upper bound of a candidate that is surely an exact hit: the
    // nearest exact hit on this side has a key <= ub.
    ub: f32,
}

fn topk_empty() -> TopK {
    var r: TopK;
    for (var i = 0u; i < K; i++) {
        r.key[i] = KEY_EMPTY;
        r.tri[i] = NO_TRI;
    }
    r.dropped = false;
    r.ub = KEY_EMPTY;
    return r;
}

fn topk_insert(list: ptr<function, TopK>, key: f32, tri: u32) {
    if key >= (*list).key[K - 1u] {
        (*list).dropped = true;
        return;
    }
    if (*list).tri[K - 1u] != NO_TRI {
        (*list).dropped = true;
    }
    var i = K - 1u;
    loop {
        if i == 0u { break; }
        let k = (*list).key[i - 1u];
        if k <= key { break; }
        (*list).key[i] = k;
        (*list).tri[i] = (*list).tri[i - 1u];
        i = i - 1u;
    }
    (*list).key[i] = key;
    (*list).tri[i] = tri;
}

// Threshold the host compares against: every exact hit on this side that is not
// in the list has a key >= threshold. Complete lists give KEY_EMPTY.
fn topk_threshold(list: TopK) -> f32 {
    if list.dropped {
        return list.key[K - 1u];
    }
    return KEY_EMPTY;
}

fn write_side(base: u32, list: TopK) {
    for (var i = 0u; i < K; i++) {
        out_words[base + i] = list.tri[i];
        out_words[base + K + i] = bitcast<u32>(list.key[i]);
    }
    out_words[base + 2u * K] = bitcast<u32>(topk_threshold(list));
}

// The ray in the frame of the watertight test (Woop, Benthin, Wald 2013).
struct RayFrame {
    o: vec3<f32>,
    kx: u32,
    ky: u32,
    kz: u32,
    s: vec3<f32>,
}

fn ray_frame(origin: vec3<f32>, d: vec3<f32>) -> RayFrame {
    var f: RayFrame;
    let a = abs(d);
    var kz = 0u;
    if a.y > a.x { kz = 1u; }
    if a.z > max(a.x, a.y) { kz = 2u; }
    var kx = (kz + 1u) % 3u;
    var ky = (kx + 1u) % 3u;
    if d[kz] < 0.0 {
        let tmp = kx;
        kx = ky;
        ky = tmp;
    }
    f.o = origin;
    f.kx = kx;
    f.ky = ky;
    f.kz = kz;
    f.s = vec3<f32>(d[kx] / d[kz], d[ky] / d[kz], 1.0 / d[kz]);
    return f;
}

// Sheared, projected vertex: (x, y) in the plane across the ray, z = t along it.
fn shear(f: RayFrame, p: vec3<f32>) -> vec3<f32> {
    let a = p - f.o;
    return vec3<f32>(a[f.kx] - f.s.x * a[f.kz], a[f.ky] - f.s.y * a[f.kz], f.s.z * a[f.kz]);
}

// Edge function of the directed edge P -> Q and a bound of its f32 error.
fn edge_tol(p: vec3<f32>, q: vec3<f32>, m: f32) -> f32 {
    let s = abs(p.x) + abs(p.y) + abs(q.x) + abs(q.y) + 2.0 * m;
    return 2.0 * (m * s + 2.0 * EPS * (abs(q.x * p.y) + abs(q.y * p.x)));
}

// Conservative test: returns (maybe_hit, t_lo, t_hi, sure). Every triangle the
// exact line meets (closed triangle, non-zero determinant) gives maybe_hit = 1
// with the exact t inside [t_lo, t_hi]; t_lo = -inf, t_hi = +inf when t is
// ill-conditioned. sure = 1 when the exact line passes strictly inside (every
// edge function beyond its error), so the f64 test reports the hit.
fn tri_filter(f: RayFrame, pa: vec3<f32>, pb: vec3<f32>, pc: vec3<f32>, m: f32) -> vec4<f32> {
    let a = shear(f, pa);
    let b = shear(f, pb);
    let c = shear(f, pc);
    // The line meets the closed triangle only if (0, 0) is in the box of the
    // projected vertices; this also rejects degenerate triangles away from it.
    let lo = min(a.xy, min(b.xy, c.xy));
    let hi = max(a.xy, max(b.xy, c.xy));
    if any(lo > vec2<f32>(m)) || any(hi < vec2<f32>(-m)) {
        return vec4<f32>(0.0);
    }
    let u = c.x * b.y - c.y * b.x;
    let v = a.x * c.y - a.y * c.x;
    let w = b.x * a.y - b.y * a.x;
    let tu = edge_tol(b, c, m);
    let tv = edge_tol(c, a, m);
    let tw = edge_tol(a, b, m);
    let pos = u >= -tu && v >= -tv && w >= -tw;
    let neg = u <= tu && v <= tv && w <= tw;
    if !(pos || neg) {
        return vec4<f32>(0.0);
    }
    let det = u + v + w;
    let det_err = tu + tv + tw + 2.0 * EPS * (abs(u) + abs(v) + abs(w));
    if abs(det) <= 2.0 * det_err {
        return vec4<f32>(1.0, -KEY_EMPTY, KEY_EMPTY, 0.0);
    }
    let tt = u * a.z + v * b.z + w * c.z;
    let t_err_num = tu * (abs(a.z) + m) + tv * (abs(b.z) + m) + tw * (abs(c.z) + m)
        + (abs(u) + abs(v) + abs(w)) * m
        + 2.0 * EPS * (abs(u * a.z) + abs(v * b.z) + abs(w * c.z));
    let t = tt / det;
    let t_err = 2.0 * (t_err_num + abs(t) * det_err) / (abs(det) - det_err) + 4.0 * EPS * abs(t);
    let sure = (u > tu && v > tv && w > tw) || (u < -tu && v < -tv && w < -tw);
    return vec4<f32>(1.0, t - t_err, t + t_err, select(0.0, 1.0, sure));
}

// Adds a filtered candidate to the lists of the sides it may lie on. Keys are
// lower bounds of |t| on each side: behind (t <= 0) and in front (t > 0).
fn add_candidate(behind: ptr<function, TopK>, front: ptr<function, TopK>, r: vec4<f32>, tri: u32) {
    if r.x == 0.0 {
        return;
    }
    let sure = r.w != 0.0;
    if r.y <= 0.0 {
        var kb = -r.z;
        if r.y <= -KEY_EMPTY { kb = KEY_UNKNOWN; }
        topk_insert(behind, kb, tri);
        // Surely behind only when the whole interval is.
        if sure && r.z <= 0.0 { (*behind).ub = min((*behind).ub, -r.y); }
    }
    if r.z > 0.0 {
        var kf = r.y;
        if r.y <= -KEY_EMPTY { kf = KEY_UNKNOWN; }
        topk_insert(front, kf, tri);
        if sure && r.y > 0.0 { (*front).ub = min((*front).ub, r.z); }
    }
}
