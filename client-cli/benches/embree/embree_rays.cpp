// embree_rays: Embree 3 on a fissure ray file, one thread.
//
// What it measures. A ray file ("FSRAYS01", written by `fissure bench
// collision --dump-rays DIR`, timed on fissure's side by `fissure bench rays
// FILE`; format in client-cli/src/bench_rays.rs) holds a surface (rest,
// locally deformed and globally moved vertex positions, triangles), the lines
// one deformation-stage query casts with their bounds, and fissure's answers
// on the rest surface. This program casts exactly those lines with Embree 3
// on one thread and reports, as one JSON object on stdout:
//   - the scene build time;
//   - the bounded cast and the whole-line cast, one rtcIntersect1 per
//     half-ray and, where the CPU has native 8-wide packets, rtcIntersect8 on
//     groups of 8 consecutive lines (coherent context), in ns per line;
//   - an update of the surface after every vertex moved (global) and after
//     the local bump, in ms, each including the f64 -> f32 conversion of all
//     positions into Embree's vertex buffer, and that conversion alone;
//   - how Embree's answers on the bounded cast compare with fissure's.
//
// Why. It is a comparison baseline for fissure's CPU BVH: the same rays, the
// same surface and the same questions, asked of a widely used ray tracer. It
// is not part of the product, of its tests or of the cargo build.
//
// One line, two half-rays. A line origin + t dir asks for the nearest hit
// behind (t <= 0, smallest |t|, within |t| <= behind) and the nearest in
// front (t > 0, smallest t, within t <= front); a negative bound looks nowhere
// on its side, +inf is allowed. Here that is two Embree rays from the origin:
// the front one along dir with [tnear, tfar] = [0, front], the behind one
// along -dir with [0, behind] (its hit t is the negated tfar). A side whose
// bound is negative casts nothing. The whole-line cast has both bounds +inf.
// Times are per line, both halves included.
//
// Precision. Embree works in single precision: positions, origins,
// directions and bounds are rounded from f64 to f32 (fissure casts in f64 with
// a watertight test). Answers that may differ for that reason alone:
//   - a line through a shared edge or vertex, where both sides pick one of
//     the triangles there with a different tie rule (counted as differ_same_t:
//     other triangle, same t);
//   - a hit at t = 0 exactly (an origin on the surface): Embree's default
//     triangle test accepts tnear < t <= tfar, so such a hit falls between
//     the two half-rays; fissure counts it behind. With --robust (Embree's
//     Pluecker test, tnear <= t <= tfar) the front half-ray starts at
//     tnear = FLT_MIN instead, so that t = 0 is found behind only;
//   - a hit within an f32 rounding of a bound.
//
// Refit. Embree 3 refits only a two-level ("dynamic") scene: the geometry's
// build quality RTC_BUILD_QUALITY_REFIT is honoured by the two-level builder,
// which the scene uses when its own build quality is RTC_BUILD_QUALITY_LOW,
// and the scene keeps its hierarchy between commits only with
// RTC_SCENE_FLAG_DYNAMIC. That is the default here (--scene refit): the first
// commit is a full SAH build of the mesh, later commits after
// rtcUpdateGeometryBuffer refit it (with one mesh the two-level top is the
// mesh's own tree). Embree has no local refit: the local bump refits the
// whole tree like the global move. --scene static uses Embree's default scene
// settings instead (one-level SAH BVH, rebuilt from scratch on every commit),
// so its update times are rebuild times.
//
// Threads. The device is created with "threads=1" and nothing else starts
// threads; process_threads reports the process's thread count (Linux) after
// the measurements as a check. FTZ/DAZ are set, as Embree recommends.
//
// Timing. Each cast row is cast once untimed, then repeated until at least
// --min-time-ms (default 500) and 3 casts have passed; each update row is
// done once untimed, then repeated, alternating the two position sets, until
// at least min(--min-time-ms, 200) ms and 20 updates have passed. This is the
// scheme `fissure bench rays` uses.
//
// Build: see the Makefile next to this file, or
//   g++ -O3 -march=native -std=c++17 embree_rays.cpp -lembree3 -o embree_rays
// Run:
//   ./embree_rays [--min-time-ms N] [--scene refit|static] [--robust] FILE
//
// JSON keys (numbers; null where not measured): embree_version (string),
// vertices, triangles, rays, half_rays_bounded, half_rays_line, build_ms,
// bounded_ns_per_line, line_ns_per_line, bounded8_ns_per_line,
// line8_ns_per_line, refit_global_ms, refit_local_ms, copy_global_ms,
// repeats_bounded, repeats_line, same_triangles, differ_same_t, differ_other;
// then scene (string), robust (bool), max_abs_t_diff (largest |t| difference,
// m, over sides where both hit the same triangle), packet_mismatch (bounded
// lines whose rtcIntersect8 answer is not the rtcIntersect1 one: Embree's
// packet and single-ray triangle tests round differently, so a tie on an
// edge or vertex, or a hit within rounding of a bound, may go either way;
// the first 5 are listed on stderr), after_refit_mismatch (bounded lines
// whose answer changed after the update rows and a return to the rest
// positions), process_threads. With no rays the cast times are null.
//
// Exit status: 0 success, 2 usage error or bad file, 1 Embree error.

#include <embree3/rtcore.h>
#include <pmmintrin.h>
#include <xmmintrin.h>

#include <algorithm>
#include <cerrno>
#include <cfloat>
#include <chrono>
#include <cinttypes>
#include <cmath>
#include <cstdarg>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

namespace {

const char* const kProgram = "embree_rays";
const char kMagic[8] = {'F', 'S', 'R', 'A', 'Y', 'S', '0', '1'};
const uint64_t kHeader = 8 + 3 * 8;
const uint64_t kRayBytes = 8 * 8;
const uint64_t kAnswerBytes = 4 * 8;
// Embree counts items in 32 bits.
const uint64_t kEmbreeMaxItems = 0xFFFFFFFFull;

[[noreturn]] void usage_error(const char* fmt, ...) {
  std::fprintf(stderr, "%s: ", kProgram);
  va_list ap;
  va_start(ap, fmt);
  std::vfprintf(stderr, fmt, ap);
  va_end(ap);
  std::fprintf(stderr, "\n(try %s --help)\n", kProgram);
  std::exit(2);
}

[[noreturn]] void file_error(const std::string& path, const char* fmt, ...) {
  std::fprintf(stderr, "%s: %s: ", kProgram, path.c_str());
  va_list ap;
  va_start(ap, fmt);
  std::vfprintf(stderr, fmt, ap);
  va_end(ap);
  std::fprintf(stderr, "\n");
  std::exit(2);
}

void print_help() {
  std::printf(
      "usage: %s [--min-time-ms N] [--scene refit|static] [--robust] FILE\n"
      "\n"
      "Times Embree 3 on one thread on the rays and surface of a fissure ray\n"
      "file (\"FSRAYS01\", written by `fissure bench collision --dump-rays DIR`)\n"
      "and prints one JSON object: build, bounded and whole-line casts\n"
      "(rtcIntersect1 and rtcIntersect8), updates after a global and a local\n"
      "change, and the agreement with fissure's answers on the bounded cast.\n"
      "Lines whose answer differs from fissure's other than by a tie are listed\n"
      "on stderr (the first 5).\n"
      "\n"
      "options:\n"
      "  --min-time-ms N   least time per cast row, ms (default 500); update rows\n"
      "                    use min(N, 200) ms and at least 20 updates\n"
      "  --scene refit     two-level dynamic scene, geometry build quality REFIT:\n"
      "                    updates refit the tree (default)\n"
      "  --scene static    Embree's default scene settings: updates rebuild\n"
      "  --robust          RTC_SCENE_FLAG_ROBUST (Pluecker triangle test)\n"
      "  --verbose N       Embree's own diagnostics (device config verbose=N, 0-3);\n"
      "                    Embree prints them to stdout, ahead of the JSON\n"
      "  --help            this text\n"
      "\n"
      "exit status: 0 done, 1 Embree error, 2 usage error or bad file\n",
      kProgram);
}

// ---------------------------------------------------------------- the file

struct Answer {
  int64_t tri;  // -1: none
  double t;
};

struct RayFile {
  uint64_t v = 0, t = 0, r = 0;
  std::vector<double> rest, deformed, moved;  // 3V each
  std::vector<uint32_t> triangles;            // 3T
  std::vector<double> rays;                   // 8R: origin, dir, behind, front
  std::vector<Answer> behind, front;          // R each
};

bool checked_size(uint64_t v, uint64_t t, uint64_t r, uint64_t* out) {
  uint64_t pos, tri, ray, sum;
  if (__builtin_mul_overflow(v, uint64_t(3 * 3 * 8), &pos)) return false;
  if (__builtin_mul_overflow(t, uint64_t(3 * 4), &tri)) return false;
  if (__builtin_mul_overflow(r, kRayBytes + kAnswerBytes, &ray)) return false;
  if (__builtin_add_overflow(kHeader, pos, &sum)) return false;
  if (__builtin_add_overflow(sum, tri, &sum)) return false;
  if (__builtin_add_overflow(sum, ray, &sum)) return false;
  *out = sum;
  return true;
}

template <typename T>
T load_le(const unsigned char* p) {
  // The file is little-endian; so are the machines this runs on (checked in
  // main).
  T x;
  std::memcpy(&x, p, sizeof x);
  return x;
}

std::vector<unsigned char> read_all(const std::string& path) {
  FILE* f = std::fopen(path.c_str(), "rb");
  if (!f) file_error(path, "cannot open: %s", std::strerror(errno));
  std::vector<unsigned char> bytes;
  unsigned char buf[1 << 16];
  size_t n;
  while ((n = std::fread(buf, 1, sizeof buf, f)) > 0) bytes.insert(bytes.end(), buf, buf + n);
  if (std::ferror(f)) file_error(path, "cannot read: %s", std::strerror(errno));
  std::fclose(f);
  return bytes;
}

RayFile parse(const std::vector<unsigned char>& b, const std::string& path) {
  if (b.size() < 8 || std::memcmp(b.data(), kMagic, 8) != 0)
    file_error(path, "not a fissure ray file (the first 8 bytes are not \"FSRAYS01\")");
  if (b.size() < kHeader)
    file_error(path, "truncated: the header needs %" PRIu64 " bytes, the file has %zu", kHeader,
               b.size());
  RayFile f;
  f.v = load_le<uint64_t>(&b[8]);
  f.t = load_le<uint64_t>(&b[16]);
  f.r = load_le<uint64_t>(&b[24]);
  uint64_t expected;
  if (!checked_size(f.v, f.t, f.r, &expected))
    file_error(path,
               "%" PRIu64 " vertices, %" PRIu64 " triangles and %" PRIu64
               " rays need more than 2^64 bytes, the file has %zu",
               f.v, f.t, f.r, b.size());
  if (expected != b.size())
    file_error(path,
               "%s: %" PRIu64 " vertices, %" PRIu64 " triangles and %" PRIu64
               " rays need %" PRIu64 " bytes, the file has %zu",
               expected > b.size() ? "truncated" : "trailing bytes", f.v, f.t, f.r, expected,
               b.size());
  if (f.t == 0) file_error(path, "the surface has no triangles");
  if (f.v > kEmbreeMaxItems || f.t > kEmbreeMaxItems)
    file_error(path, "%" PRIu64 " vertices and %" PRIu64 " triangles: Embree takes at most %" PRIu64
               " of each", f.v, f.t, kEmbreeMaxItems);

  const unsigned char* p = b.data() + kHeader;
  const char* names[3] = {"rest", "deformed", "moved"};
  std::vector<double>* sets[3] = {&f.rest, &f.deformed, &f.moved};
  for (int k = 0; k < 3; ++k) {
    sets[k]->resize(3 * f.v);
    for (uint64_t i = 0; i < 3 * f.v; ++i, p += 8) {
      double x = load_le<double>(p);
      if (!std::isfinite(x))
        file_error(path, "%s position of vertex %" PRIu64 " is not finite", names[k], i / 3);
      (*sets[k])[i] = x;
    }
  }
  f.triangles.resize(3 * f.t);
  for (uint64_t i = 0; i < 3 * f.t; ++i, p += 4) {
    uint32_t x = load_le<uint32_t>(p);
    if (x >= f.v)
      file_error(path, "triangle %" PRIu64 " names vertex %" PRIu32 ", the file has %" PRIu64
                 " vertices", i / 3, x, f.v);
    f.triangles[i] = x;
  }
  f.rays.resize(8 * f.r);
  for (uint64_t i = 0; i < f.r; ++i) {
    double* q = &f.rays[8 * i];
    for (int k = 0; k < 8; ++k, p += 8) q[k] = load_le<double>(p);
    for (int k = 0; k < 6; ++k)
      if (!std::isfinite(q[k]))
        file_error(path, "ray %" PRIu64 ": origin or direction is not finite", i);
    double norm = std::sqrt(q[3] * q[3] + q[4] * q[4] + q[5] * q[5]);
    if (std::fabs(norm - 1.0) > 1e-9)
      file_error(path, "ray %" PRIu64 ": direction is not unit length (|d| = %.17g)", i, norm);
    if (std::isnan(q[6]) || std::isnan(q[7])) file_error(path, "ray %" PRIu64 ": a bound is NaN", i);
  }
  f.behind.resize(f.r);
  f.front.resize(f.r);
  for (uint64_t i = 0; i < f.r; ++i) {
    Answer* sides[2] = {&f.behind[i], &f.front[i]};
    const char* side_names[2] = {"behind", "front"};
    for (int k = 0; k < 2; ++k, p += 16) {
      int64_t tri = load_le<int64_t>(p);
      double t = load_le<double>(p + 8);
      if (tri == -1) {
        *sides[k] = {-1, NAN};
      } else if (tri >= 0 && uint64_t(tri) < f.t && std::isfinite(t)) {
        *sides[k] = {tri, t};
      } else {
        file_error(path, "answer of ray %" PRIu64 ": %s hit on triangle %" PRId64
                   " at t = %.17g (the file has %" PRIu64 " triangles)",
                   i, side_names[k], tri, t, f.t);
      }
    }
  }
  return f;
}

// ---------------------------------------------------------------- Embree

void embree_error(void*, RTCError code, const char* str) {
  std::fprintf(stderr, "%s: Embree error %d: %s\n", kProgram, int(code), str ? str : "");
  std::exit(1);
}

// One line as Embree sees it: f32 origin and direction, and per side whether
// to cast and how far.
struct Line {
  float o[3], d[3];
  float behind, front;  // f32 bounds; meaningful where look_* is set
  bool look_behind, look_front;
};

// One side's answer: triangle (-1 none) and t along the line.
struct Side {
  int64_t tri;
  double t;
};

struct Result {
  Side behind, front;
};

inline bool same_result(const Result& a, const Result& b) {
  auto side = [](const Side& x, const Side& y) {
    return x.tri == y.tri && (x.tri < 0 || x.t == y.t);
  };
  return side(a.behind, b.behind) && side(a.front, b.front);
}

struct Caster {
  RTCScene scene;
  float front_tnear;  // 0, or FLT_MIN in robust mode (see the file comment)

  // Casts one half-ray; returns the hit as a Side with t along the half-ray.
  inline Side half(const float o[3], const float d[3], float sign, float tnear, float tfar,
                   RTCIntersectContext* ctx) const {
    RTCRayHit rh;
    rh.ray.org_x = o[0];
    rh.ray.org_y = o[1];
    rh.ray.org_z = o[2];
    rh.ray.tnear = tnear;
    rh.ray.dir_x = sign * d[0];
    rh.ray.dir_y = sign * d[1];
    rh.ray.dir_z = sign * d[2];
    rh.ray.time = 0.0f;
    rh.ray.tfar = tfar;
    rh.ray.mask = 0xFFFFFFFFu;
    rh.ray.id = 0;
    rh.ray.flags = 0;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.primID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(scene, ctx, &rh);
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return {-1, NAN};
    return {int64_t(rh.hit.primID), double(rh.ray.tfar)};
  }

  // All lines, one rtcIntersect1 per half-ray. `line`: whole lines (both
  // bounds +inf). Returns the half-rays cast.
  uint64_t cast1(const std::vector<Line>& lines, bool line, std::vector<Result>& out) const {
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    const float inf = INFINITY;
    uint64_t n = 0;
    for (size_t i = 0; i < lines.size(); ++i) {
      const Line& l = lines[i];
      Result& r = out[i];
      if (line || l.look_front) {
        r.front = half(l.o, l.d, 1.0f, front_tnear, line ? inf : l.front, &ctx);
        ++n;
      } else {
        r.front = {-1, NAN};
      }
      if (line || l.look_behind) {
        r.behind = half(l.o, l.d, -1.0f, 0.0f, line ? inf : l.behind, &ctx);
        if (r.behind.tri >= 0) r.behind.t = -r.behind.t;
        ++n;
      } else {
        r.behind = {-1, NAN};
      }
    }
    return n;
  }

  // All lines in groups of 8 consecutive ones: the front halves in one
  // rtcIntersect8, the behind halves in another; lanes past the end or with a
  // negative bound are off in the valid vector (and get an empty segment).
  uint64_t cast8(const std::vector<Line>& lines, bool line, std::vector<Result>& out) const {
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
    const float inf = INFINITY;
    uint64_t n = 0;
    alignas(32) RTCRayHit8 rh;
    alignas(32) int valid[8];
    for (size_t g = 0; g < lines.size(); g += 8) {
      const size_t m = std::min<size_t>(8, lines.size() - g);
      for (int side = 0; side < 2; ++side) {  // 0 front, 1 behind
        const float sign = side == 0 ? 1.0f : -1.0f;
        int active = 0;
        for (size_t k = 0; k < 8; ++k) {
          bool on = false;
          float tfar = -inf;
          const Line* l = k < m ? &lines[g + k] : nullptr;
          if (l) {
            on = line || (side == 0 ? l->look_front : l->look_behind);
            if (on) tfar = line ? inf : (side == 0 ? l->front : l->behind);
          }
          valid[k] = on ? -1 : 0;
          active += on;
          rh.ray.org_x[k] = l ? l->o[0] : 0.0f;
          rh.ray.org_y[k] = l ? l->o[1] : 0.0f;
          rh.ray.org_z[k] = l ? l->o[2] : 0.0f;
          rh.ray.tnear[k] = side == 0 ? front_tnear : 0.0f;
          rh.ray.dir_x[k] = l ? sign * l->d[0] : 0.0f;
          rh.ray.dir_y[k] = l ? sign * l->d[1] : 0.0f;
          rh.ray.dir_z[k] = l ? sign * l->d[2] : 1.0f;
          rh.ray.time[k] = 0.0f;
          rh.ray.tfar[k] = tfar;
          rh.ray.mask[k] = 0xFFFFFFFFu;
          rh.ray.id[k] = unsigned(k);
          rh.ray.flags[k] = 0;
          rh.hit.geomID[k] = RTC_INVALID_GEOMETRY_ID;
          rh.hit.primID[k] = RTC_INVALID_GEOMETRY_ID;
          rh.hit.instID[0][k] = RTC_INVALID_GEOMETRY_ID;
        }
        if (active) rtcIntersect8(valid, scene, &ctx, &rh);
        n += uint64_t(active);
        for (size_t k = 0; k < m; ++k) {
          Side s{-1, NAN};
          if (valid[k] && rh.hit.geomID[k] != RTC_INVALID_GEOMETRY_ID)
            s = {int64_t(rh.hit.primID[k]), double(sign * rh.ray.tfar[k])};
          (side == 0 ? out[g + k].front : out[g + k].behind) = s;
        }
      }
    }
    return n;
  }
};

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

// Mean time of `cast` over at least `min_s` and 3 casts (after one untimed),
// ns per line, and the number of timed casts.
template <typename F>
std::pair<double, uint64_t> time_cast(uint64_t lines, double min_s, F cast) {
  cast();
  auto t0 = Clock::now();
  uint64_t n = 0;
  while (n < 3 || seconds_since(t0) < min_s) {
    cast();
    ++n;
  }
  double s = seconds_since(t0);
  return {s * 1e9 / double(n * std::max<uint64_t>(lines, 1)), n};
}

// Mean time of `update(p)` alternating `a` and `b` over at least `min_s` and
// 20 updates (after one untimed, to `a`), ms.
template <typename F>
double time_update(const std::vector<double>& a, const std::vector<double>& b, double min_s,
                   F update) {
  update(a);
  auto t0 = Clock::now();
  uint64_t n = 0;
  while (n < 20 || seconds_since(t0) < min_s) {
    update(n % 2 == 0 ? b : a);
    ++n;
  }
  return seconds_since(t0) * 1e3 / double(n);
}

int process_threads() {
  FILE* f = std::fopen("/proc/self/status", "r");
  if (!f) return -1;
  char line[256];
  int n = -1;
  while (std::fgets(line, sizeof line, f))
    if (std::sscanf(line, "Threads: %d", &n) == 1) break;
  std::fclose(f);
  return n;
}

// ---------------------------------------------------------------- output

struct Json {
  std::string s = "{";
  bool first = true;
  void key(const char* k) {
    s += first ? "\n  \"" : ",\n  \"";
    s += k;
    s += "\": ";
    first = false;
  }
  void str(const char* k, const char* v) {
    key(k);
    s += "\"";
    s += v;  // version strings and fixed names only: nothing to escape
    s += "\"";
  }
  void u(const char* k, uint64_t v) {
    key(k);
    s += std::to_string(v);
  }
  void b(const char* k, bool v) {
    key(k);
    s += v ? "true" : "false";
  }
  void null(const char* k) {
    key(k);
    s += "null";
  }
  void f(const char* k, double v, bool present = true) {
    if (!present || !std::isfinite(v)) return null(k);
    key(k);
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.6g", v);
    s += buf;
  }
  std::string done() { return s + "\n}\n"; }
};

void print_side(const char* who, const Side& behind, const Side& front) {
  std::fprintf(stderr, "    %-8s behind ", who);
  if (behind.tri < 0)
    std::fprintf(stderr, "none");
  else
    std::fprintf(stderr, "tri %" PRId64 " t %.17g", behind.tri, behind.t);
  std::fprintf(stderr, ", front ");
  if (front.tri < 0)
    std::fprintf(stderr, "none");
  else
    std::fprintf(stderr, "tri %" PRId64 " t %.17g", front.tri, front.t);
  std::fprintf(stderr, "\n");
}

}  // namespace

int main(int argc, char** argv) {
  {
    const uint16_t one = 1;
    unsigned char c;
    std::memcpy(&c, &one, 1);
    if (c != 1) {
      std::fprintf(stderr, "%s: needs a little-endian machine\n", kProgram);
      return 2;
    }
  }

  double min_time_ms = 500.0;
  bool robust = false;
  bool static_scene = false;
  int verbose = 0;
  std::string path;
  for (int i = 1; i < argc; ++i) {
    std::string a = argv[i];
    auto value = [&](const char* name) -> std::string {
      if (i + 1 >= argc) usage_error("%s needs a value", name);
      return argv[++i];
    };
    if (a == "--help" || a == "-h") {
      print_help();
      return 0;
    } else if (a == "--min-time-ms") {
      std::string v = value("--min-time-ms");
      char* end = nullptr;
      errno = 0;
      double x = std::strtod(v.c_str(), &end);
      if (v.empty() || *end != '\0' || errno != 0 || !(x >= 0.0) || !std::isfinite(x))
        usage_error("--min-time-ms: '%s' is not a number of milliseconds >= 0", v.c_str());
      min_time_ms = x;
    } else if (a == "--scene") {
      std::string v = value("--scene");
      if (v == "refit")
        static_scene = false;
      else if (v == "static")
        static_scene = true;
      else
        usage_error("--scene: '%s' is neither 'refit' nor 'static'", v.c_str());
    } else if (a == "--robust") {
      robust = true;
    } else if (a == "--verbose") {
      std::string v = value("--verbose");
      char* end = nullptr;
      long x = std::strtol(v.c_str(), &end, 10);
      if (v.empty() || *end != '\0' || x < 0 || x > 3)
        usage_error("--verbose: '%s' is not 0 to 3", v.c_str());
      verbose = int(x);
    } else if (a.size() > 1 && a[0] == '-') {
      usage_error("unknown option '%s'", a.c_str());
    } else if (path.empty()) {
      path = a;
    } else {
      usage_error("one ray file only (got '%s' and '%s')", path.c_str(), a.c_str());
    }
  }
  if (path.empty()) usage_error("no ray file given");

  const RayFile file = parse(read_all(path), path);
  const uint64_t V = file.v, T = file.t, R = file.r;

  _MM_SET_FLUSH_ZERO_MODE(_MM_FLUSH_ZERO_ON);
  _MM_SET_DENORMALS_ZERO_MODE(_MM_DENORMALS_ZERO_ON);

  std::string config = "threads=1";
  if (verbose) config += ",verbose=" + std::to_string(verbose);
  RTCDevice device = rtcNewDevice(config.c_str());
  if (!device) {
    std::fprintf(stderr, "%s: rtcNewDevice failed (error %d)\n", kProgram,
                 int(rtcGetDeviceError(nullptr)));
    return 1;
  }
  rtcSetDeviceErrorFunction(device, embree_error, nullptr);
  const bool ray8 = rtcGetDeviceProperty(device, RTC_DEVICE_PROPERTY_NATIVE_RAY8_SUPPORTED) != 0;

  // The lines in f32.
  std::vector<Line> lines(R);
  uint64_t half_rays_bounded = 0;
  for (uint64_t i = 0; i < R; ++i) {
    const double* q = &file.rays[8 * i];
    Line& l = lines[i];
    for (int k = 0; k < 3; ++k) {
      l.o[k] = float(q[k]);
      l.d[k] = float(q[3 + k]);
    }
    l.look_behind = q[6] >= 0.0;
    l.look_front = q[7] >= 0.0;
    l.behind = l.look_behind ? float(q[6]) : -INFINITY;
    l.front = l.look_front ? float(q[7]) : -INFINITY;
    half_rays_bounded += uint64_t(l.look_behind) + uint64_t(l.look_front);
  }
  const uint64_t half_rays_line = 2 * R;

  // The scene.
  RTCScene scene = rtcNewScene(device);
  int flags = RTC_SCENE_FLAG_NONE;
  if (!static_scene) {
    flags |= RTC_SCENE_FLAG_DYNAMIC;
    rtcSetSceneBuildQuality(scene, RTC_BUILD_QUALITY_LOW);  // selects the two-level builder
  }
  if (robust) flags |= RTC_SCENE_FLAG_ROBUST;
  rtcSetSceneFlags(scene, RTCSceneFlags(flags));
  RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
  if (!static_scene) rtcSetGeometryBuildQuality(geom, RTC_BUILD_QUALITY_REFIT);
  float* vbuf = static_cast<float*>(rtcSetNewGeometryBuffer(
      geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), size_t(V)));
  unsigned* ibuf = static_cast<unsigned*>(rtcSetNewGeometryBuffer(
      geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned), size_t(T)));
  std::memcpy(ibuf, file.triangles.data(), size_t(3 * T) * sizeof(unsigned));
  const size_t nv = size_t(3 * V);
  auto set_positions = [&](const std::vector<double>& p) {
    const double* src = p.data();
    for (size_t i = 0; i < nv; ++i) vbuf[i] = float(src[i]);
  };
  set_positions(file.rest);

  auto t_build = Clock::now();
  rtcCommitGeometry(geom);
  rtcAttachGeometry(scene, geom);  // geometry 0
  rtcCommitScene(scene);
  const double build_ms = seconds_since(t_build) * 1e3;

  Caster caster{scene, robust ? FLT_MIN : 0.0f};
  const double min_s = min_time_ms * 1e-3;
  std::vector<Result> out(R), first(R), out8(R);

  // Agreement on the bounded rest cast.
  caster.cast1(lines, false, first);
  uint64_t same_triangles = 0, differ_same_t = 0, differ_other = 0, listed = 0;
  double max_abs_t_diff = 0.0;
  auto near_t = [](double a, double b) {
    return std::fabs(a - b) <= 1e-6 * std::max(1.0, std::fabs(b)) + 1e-9;
  };
  for (uint64_t i = 0; i < R; ++i) {
    const Result& e = first[i];
    const Side fb{file.behind[i].tri, file.behind[i].t};
    const Side ff{file.front[i].tri, file.front[i].t};
    bool same_b = e.behind.tri == fb.tri, same_f = e.front.tri == ff.tri;
    if (same_b && fb.tri >= 0) max_abs_t_diff = std::max(max_abs_t_diff, std::fabs(e.behind.t - fb.t));
    if (same_f && ff.tri >= 0) max_abs_t_diff = std::max(max_abs_t_diff, std::fabs(e.front.t - ff.t));
    if (same_b && same_f) {
      ++same_triangles;
      continue;
    }
    auto tie = [&](const Side& a, const Side& b, bool same) {
      return same || (a.tri >= 0 && b.tri >= 0 && near_t(a.t, b.t));
    };
    if (tie(e.behind, fb, same_b) && tie(e.front, ff, same_f)) {
      ++differ_same_t;
      continue;
    }
    ++differ_other;
    if (listed < 5) {
      ++listed;
      const double* q = &file.rays[8 * i];
      std::fprintf(stderr,
                   "%s: ray %" PRIu64 " differs from fissure's answer:\n"
                   "    origin (%.17g, %.17g, %.17g) dir (%.17g, %.17g, %.17g)"
                   " behind %.17g front %.17g\n",
                   kProgram, i, q[0], q[1], q[2], q[3], q[4], q[5], q[6], q[7]);
      print_side("fissure", fb, ff);
      print_side("embree", e.behind, e.front);
    }
  }

  // Casts.
  volatile uint64_t sink = 0;
  auto [bounded_ns, repeats_bounded] =
      time_cast(R, min_s, [&] { sink += caster.cast1(lines, false, out); });
  auto [line_ns, repeats_line] =
      time_cast(R, min_s, [&] { sink += caster.cast1(lines, true, out); });
  double bounded8_ns = NAN, line8_ns = NAN;
  uint64_t packet_mismatch = 0;
  if (ray8) {
    caster.cast8(lines, false, out8);
    for (uint64_t i = 0; i < R; ++i) {
      if (same_result(out8[i], first[i])) continue;
      if (++packet_mismatch <= 5) {
        std::fprintf(stderr, "%s: ray %" PRIu64 ": rtcIntersect8 and rtcIntersect1 differ:\n",
                     kProgram, i);
        print_side("packet", out8[i].behind, out8[i].front);
        print_side("single", first[i].behind, first[i].front);
      }
    }
    bounded8_ns = time_cast(R, min_s, [&] { sink += caster.cast8(lines, false, out8); }).first;
    line8_ns = time_cast(R, min_s, [&] { sink += caster.cast8(lines, true, out8); }).first;
  }

  // Updates.
  const double update_min_s = std::min(min_s, 0.2);
  auto update = [&](const std::vector<double>& p) {
    set_positions(p);
    rtcUpdateGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0);
    rtcCommitGeometry(geom);
    rtcCommitScene(scene);
  };
  const double refit_global_ms = time_update(file.rest, file.moved, update_min_s, update);
  const double refit_local_ms = time_update(file.rest, file.deformed, update_min_s, update);
  const double copy_global_ms =
      time_update(file.rest, file.moved, update_min_s, [&](const std::vector<double>& p) {
        set_positions(p);
        sink += uint64_t(vbuf[0] != 0.0f);
      });

  // Back to rest: the updated tree must answer as the first one did.
  update(file.rest);
  caster.cast1(lines, false, out);
  uint64_t after_refit_mismatch = 0;
  for (uint64_t i = 0; i < R; ++i) after_refit_mismatch += !same_result(out[i], first[i]);

  const int threads = process_threads();

  rtcReleaseGeometry(geom);
  rtcReleaseScene(scene);
  rtcReleaseDevice(device);

  Json j;
  j.str("embree_version", RTC_VERSION_STRING);
  j.u("vertices", V);
  j.u("triangles", T);
  j.u("rays", R);
  j.u("half_rays_bounded", half_rays_bounded);
  j.u("half_rays_line", half_rays_line);
  j.f("build_ms", build_ms);
  j.f("bounded_ns_per_line", bounded_ns, R > 0);
  j.f("line_ns_per_line", line_ns, R > 0);
  j.f("bounded8_ns_per_line", bounded8_ns, ray8 && R > 0);
  j.f("line8_ns_per_line", line8_ns, ray8 && R > 0);
  j.f("refit_global_ms", refit_global_ms);
  j.f("refit_local_ms", refit_local_ms);
  j.f("copy_global_ms", copy_global_ms);
  j.u("repeats_bounded", repeats_bounded);
  j.u("repeats_line", repeats_line);
  j.u("same_triangles", same_triangles);
  j.u("differ_same_t", differ_same_t);
  j.u("differ_other", differ_other);
  j.str("scene", static_scene ? "static" : "refit");
  j.b("robust", robust);
  j.f("max_abs_t_diff", max_abs_t_diff);
  if (ray8)
    j.u("packet_mismatch", packet_mismatch);
  else
    j.null("packet_mismatch");
  j.u("after_refit_mismatch", after_refit_mismatch);
  if (threads > 0)
    j.u("process_threads", uint64_t(threads));
  else
    j.null("process_threads");
  std::fputs(j.done().c_str(), stdout);
  return 0;
}
