//! Ray files and `fissure bench rays`: the collision stage's rays, written
//! once and cast again by fissure's BVH and by any other ray tracer, so that
//! both time exactly the same work.
//!
//! `fissure bench collision --dump-rays DIR` writes, per placement and node
//! count, the rays one deformation-stage query casts (every source node of
//! both spatulas, bounded as the server casts them) with the surface they
//! hit and fissure's answers. `fissure bench rays FILE` times fissure's CPU
//! BVH on them, one thread by default: the bounded and the whole-line cast,
//! each walked per ray and bundled, the build and the refit. The Embree
//! comparison (`client-cli/benches/embree/`) reads the same files.
//!
//! # File format (little-endian)
//! ```text
//! "FSRAYS01"                          8 bytes
//! V, T, R                             u64 each: vertices, triangles, rays
//! rest positions                      3V f64, m
//! deformed positions                  3V f64, m (the benchmark's local bump)
//! moved positions                     3V f64, m (every vertex moved: a global refit)
//! triangles                           3T u32 (outward, indices < V)
//! rays                                R x 8 f64: origin (m), unit direction, behind, front (m)
//! answers on the rest surface         R x (i64, f64, i64, f64): behind triangle, t; front triangle, t
//! ```
//! A ray is the line `origin + t direction`; its answer is the nearest hit
//! behind (`t <= 0`) within `|t| <= behind` and the nearest in front
//! (`t > 0`) within `t <= front`; a negative bound looks nowhere on its side
//! ([`RayRange`]). A missing hit is triangle -1 with `t` NaN.
//!
//! Hand-written rather than a serialisation crate: the file is read by a C++
//! program too, and a fixed little-endian layout is the format both can read
//! without a library.

use crate::lab::bench::collision::time_refit;
use anyhow::Context;
use fissure_engine::collide::rays::bvh::Traversal;
use fissure_engine::collide::{Bvh, Hit, NodeHits, RayBackend, RayRange};
use nalgebra::{Point3, Vector3};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The file's first 8 bytes.
pub const MAGIC: &[u8; 8] = b"FSRAYS01";

/// The rays of one query with their surface and fissure's answers.
#[derive(Debug, Clone, PartialEq)]
pub struct RayFile {
    /// Rest positions, m.
    pub rest: Vec<Point3<f64>>,
    /// Locally deformed positions, m.
    pub deformed: Vec<Point3<f64>>,
    /// Every vertex moved, m.
    pub moved: Vec<Point3<f64>>,
    /// Outward triangles.
    pub triangles: Vec<[u32; 3]>,
    /// Line origins, m.
    pub origins: Vec<Point3<f64>>,
    /// Unit directions.
    pub dirs: Vec<Vector3<f64>>,
    /// How far each line looks, m.
    pub ranges: Vec<RayRange>,
    /// The answers on the rest surface within the ranges.
    pub answers: Vec<NodeHits>,
}

/// What is wrong with a ray file.
#[derive(Debug, thiserror::Error)]
pub enum RayFileError {
    /// The file cannot be read or written.
    #[error("ray file {path}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// Not a ray file.
    #[error("{path}: not a fissure ray file (the first 8 bytes are not \"FSRAYS01\")")]
    Magic {
        /// The file.
        path: PathBuf,
    },
    /// The size does not match the counts of the header.
    #[error(
        "{path}: {vertices} vertices, {triangles} triangles and {rays} rays need {expected} bytes, the file has {actual}"
    )]
    Size {
        /// The file.
        path: PathBuf,
        /// Header counts.
        vertices: u64,
        /// Header counts.
        triangles: u64,
        /// Header counts.
        rays: u64,
        /// Bytes the counts need (None: more than a u64 holds).
        expected: String,
        /// Bytes the file has.
        actual: u64,
    },
    /// A value that cannot be right.
    #[error("{path}: {what}")]
    Value {
        /// The file.
        path: PathBuf,
        /// What is wrong and where.
        what: String,
    },
}

const HEADER: u64 = 8 + 3 * 8;
const RAY_BYTES: u64 = 8 * 8;
const ANSWER_BYTES: u64 = 4 * 8;

fn expected_size(v: u64, t: u64, r: u64) -> Option<u64> {
    let pos = v.checked_mul(3 * 3 * 8)?;
    let tri = t.checked_mul(3 * 4)?;
    let ray = r.checked_mul(RAY_BYTES + ANSWER_BYTES)?;
    HEADER.checked_add(pos)?.checked_add(tri)?.checked_add(ray)
}

/// Little-endian reader over a byte slice whose size was checked first.
struct Cursor<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Cursor<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let b: [u8; N] = self.bytes[self.at..self.at + N]
            .try_into()
            .expect("size checked");
        self.at += N;
        b
    }
    fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.take())
    }
    fn i64(&mut self) -> i64 {
        i64::from_le_bytes(self.take())
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }
    fn f64(&mut self) -> f64 {
        f64::from_le_bytes(self.take())
    }
    fn point(&mut self) -> Point3<f64> {
        Point3::new(self.f64(), self.f64(), self.f64())
    }
}

impl RayFile {
    /// Writes the file.
    pub fn write(&self, path: &Path) -> Result<(), RayFileError> {
        let mut b = Vec::with_capacity(
            expected_size(
                self.rest.len() as u64,
                self.triangles.len() as u64,
                self.origins.len() as u64,
            )
            .unwrap_or(0) as usize,
        );
        b.extend_from_slice(MAGIC);
        for n in [self.rest.len(), self.triangles.len(), self.origins.len()] {
            b.extend_from_slice(&(n as u64).to_le_bytes());
        }
        for set in [&self.rest, &self.deformed, &self.moved] {
            for p in set.iter() {
                for x in p.iter() {
                    b.extend_from_slice(&x.to_le_bytes());
                }
            }
        }
        for t in &self.triangles {
            for i in t {
                b.extend_from_slice(&i.to_le_bytes());
            }
        }
        for ((o, d), r) in self.origins.iter().zip(&self.dirs).zip(&self.ranges) {
            for x in o.iter().chain(d.iter()).chain([&r.behind, &r.front]) {
                b.extend_from_slice(&x.to_le_bytes());
            }
        }
        for a in &self.answers {
            for h in [a.behind, a.front] {
                let (tri, t) = h.map_or((-1i64, f64::NAN), |h| (i64::from(h.triangle), h.t));
                b.extend_from_slice(&tri.to_le_bytes());
                b.extend_from_slice(&t.to_le_bytes());
            }
        }
        std::fs::write(path, b).map_err(|source| RayFileError::Io {
            path: path.to_owned(),
            source,
        })
    }

    /// Reads and checks a file written by [`RayFile::write`].
    pub fn read(path: &Path) -> Result<Self, RayFileError> {
        let bytes = std::fs::read(path).map_err(|source| RayFileError::Io {
            path: path.to_owned(),
            source,
        })?;
        Self::parse(&bytes, path)
    }

    /// Parses the bytes of a ray file; `path` names it in errors.
    pub fn parse(bytes: &[u8], path: &Path) -> Result<Self, RayFileError> {
        let path = || path.to_owned();
        if bytes.len() < 8 || &bytes[..8] != MAGIC {
            return Err(RayFileError::Magic { path: path() });
        }
        if (bytes.len() as u64) < HEADER {
            return Err(RayFileError::Size {
                path: path(),
                vertices: 0,
                triangles: 0,
                rays: 0,
                expected: format!("at least {HEADER}"),
                actual: bytes.len() as u64,
            });
        }
        let mut c = Cursor { bytes, at: 8 };
        let (v, t, r) = (c.u64(), c.u64(), c.u64());
        let expected = expected_size(v, t, r);
        if expected != Some(bytes.len() as u64) {
            return Err(RayFileError::Size {
                path: path(),
                vertices: v,
                triangles: t,
                rays: r,
                expected: expected.map_or("more than 2^64".into(), |e| e.to_string()),
                actual: bytes.len() as u64,
            });
        }
        let bad = |what: String| RayFileError::Value { path: path(), what };
        let mut sets = [Vec::new(), Vec::new(), Vec::new()];
        for (k, set) in sets.iter_mut().enumerate() {
            for i in 0..v {
                let p = c.point();
                if !p.iter().all(|x| x.is_finite()) {
                    let name = ["rest", "deformed", "moved"][k];
                    return Err(bad(format!("{name} position of vertex {i} is not finite")));
                }
                set.push(p);
            }
        }
        let [rest, deformed, moved] = sets;
        let mut triangles = Vec::with_capacity(t as usize);
        for i in 0..t {
            let tri = [c.u32(), c.u32(), c.u32()];
            if let Some(&x) = tri.iter().find(|&&x| u64::from(x) >= v) {
                return Err(bad(format!(
                    "triangle {i} names vertex {x}, the file has {v} vertices"
                )));
            }
            triangles.push(tri);
        }
        let (mut origins, mut dirs, mut ranges) = (Vec::new(), Vec::new(), Vec::new());
        for i in 0..r {
            let o = c.point();
            let d = Vector3::new(c.f64(), c.f64(), c.f64());
            let range = RayRange {
                behind: c.f64(),
                front: c.f64(),
            };
            if !o.iter().chain(d.iter()).all(|x| x.is_finite()) {
                return Err(bad(format!("ray {i}: origin or direction is not finite")));
            }
            if (d.norm() - 1.0).abs() > 1e-9 {
                return Err(bad(format!(
                    "ray {i}: direction is not unit length (|d| = {})",
                    d.norm()
                )));
            }
            if range.behind.is_nan() || range.front.is_nan() {
                return Err(bad(format!("ray {i}: a bound is NaN")));
            }
            origins.push(o);
            dirs.push(d);
            ranges.push(range);
        }
        let mut answers = Vec::with_capacity(r as usize);
        for i in 0..r {
            let mut side = |name: &str| -> Result<Option<Hit>, RayFileError> {
                let (tri, t) = (c.i64(), c.f64());
                match tri {
                    -1 => Ok(None),
                    k if k >= 0 && (k as u64) < triangles.len() as u64 && t.is_finite() => {
                        Ok(Some(Hit {
                            triangle: k as u32,
                            t,
                            u: f64::NAN,
                            v: f64::NAN,
                        }))
                    }
                    k => Err(bad(format!(
                        "answer of ray {i}: {name} hit on triangle {k} at t = {t} (the file has {} triangles)",
                        triangles.len()
                    ))),
                }
            };
            let behind = side("behind")?;
            let front = side("front")?;
            answers.push(NodeHits { behind, front });
        }
        Ok(Self {
            rest,
            deformed,
            moved,
            triangles,
            origins,
            dirs,
            ranges,
            answers,
        })
    }
}

/// Arguments of `fissure bench rays`.
#[derive(Debug, Clone, clap::Args)]
pub struct RaysArgs {
    /// Ray files written by `fissure bench collision --dump-rays DIR`.
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
    /// Rayon threads (1: the single-thread comparison).
    #[arg(long, default_value_t = 1)]
    pub threads: usize,
    /// Least time spent per cast row, ms.
    #[arg(long, default_value_t = 500)]
    pub min_time_ms: u64,
    /// Print JSON (one object per file, in an array) instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// Fissure's times on one ray file.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RaysReport {
    /// The file.
    pub file: String,
    /// Surface vertices.
    pub vertices: usize,
    /// Surface triangles.
    pub triangles: usize,
    /// Lines.
    pub rays: usize,
    /// Rayon threads.
    pub threads: usize,
    /// Tree build, ms.
    pub build_ms: f64,
    /// Bounded cast, bundled walk (the server's default), ns per line.
    pub bounded_ns_per_line: f64,
    /// Bounded cast walked once per ray, ns per line.
    pub bounded_per_ray_ns_per_line: f64,
    /// Whole-line cast, bundled walk, ns per line.
    pub line_ns_per_line: f64,
    /// Whole-line cast walked once per ray, ns per line.
    pub line_per_ray_ns_per_line: f64,
    /// Refit after every vertex moved, ms.
    pub refit_global_ms: f64,
    /// Refit after the local bump, ms.
    pub refit_local_ms: f64,
    /// Timed casts per bounded row.
    pub repeats_bounded: usize,
    /// Timed casts per whole-line row.
    pub repeats_line: usize,
    /// Rays whose answer equals the file's (triangle and `t`), all four rows.
    pub same_answers: usize,
}

/// Mean time of `cast` over `min` (at least 3 casts), ns per line, and casts.
fn time_cast(rays: usize, min: Duration, mut cast: impl FnMut()) -> (f64, usize) {
    cast();
    let start = Instant::now();
    let mut n = 0;
    while n < 3 || start.elapsed() < min {
        cast();
        n += 1;
    }
    let ns = start.elapsed().as_secs_f64() * 1e9 / (n * rays.max(1)) as f64;
    (ns, n)
}

fn same(a: &NodeHits, b: &NodeHits) -> bool {
    let side = |x: Option<Hit>, y: Option<Hit>| match (x, y) {
        (None, None) => true,
        (Some(x), Some(y)) => x.triangle == y.triangle && x.t == y.t,
        _ => false,
    };
    side(a.behind, b.behind) && side(a.front, b.front)
}

/// Times fissure's BVH on `rays` (in the calling thread's rayon pool).
pub fn bench_file(file: &RayFile, name: &str, min: Duration) -> anyhow::Result<RaysReport> {
    let start = Instant::now();
    let mut bvh = Bvh::new(&file.triangles, &file.rest).context("the file's surface")?;
    let build_ms = start.elapsed().as_secs_f64() * 1e3;
    let n = file.origins.len();
    let line: Vec<RayRange> = vec![RayRange::LINE; n];
    let mut out = Vec::new();
    let mut row = |bvh: &mut Bvh, traversal: Traversal, ranges: &[RayRange]| {
        bvh.set_traversal(traversal);
        let (ns, reps) = time_cast(n, min, || {
            bvh.cast_ranged(&file.origins, &file.dirs, ranges, &mut out)
        });
        // Whole-line answers clipped to the file's ranges are its answers.
        let agree = out
            .iter()
            .zip(&file.ranges)
            .zip(&file.answers)
            .filter(|((h, r), a)| same(&r.clip(**h), a))
            .count();
        (ns, reps, agree)
    };
    let (bounded, repeats_bounded, a1) = row(&mut bvh, Traversal::Bundled, &file.ranges);
    let (bounded_pr, _, a2) = row(&mut bvh, Traversal::PerRay, &file.ranges);
    let (whole, repeats_line, a3) = row(&mut bvh, Traversal::Bundled, &line);
    let (whole_pr, _, a4) = row(&mut bvh, Traversal::PerRay, &line);
    bvh.set_traversal(Traversal::Bundled);
    let rmin = min.min(Duration::from_millis(200));
    let refit_global_ms = time_refit(&mut bvh, &file.rest, &file.moved, rmin);
    let refit_local_ms = time_refit(&mut bvh, &file.rest, &file.deformed, rmin);
    Ok(RaysReport {
        file: name.into(),
        vertices: file.rest.len(),
        triangles: file.triangles.len(),
        rays: n,
        threads: rayon::current_num_threads(),
        build_ms,
        bounded_ns_per_line: bounded,
        bounded_per_ray_ns_per_line: bounded_pr,
        line_ns_per_line: whole,
        line_per_ray_ns_per_line: whole_pr,
        refit_global_ms,
        refit_local_ms,
        repeats_bounded,
        repeats_line,
        same_answers: a1.min(a2).min(a3).min(a4),
    })
}

/// `fissure bench rays`: reads each file, times, prints.
pub fn run(args: &RaysArgs) -> anyhow::Result<()> {
    if args.threads == 0 {
        anyhow::bail!("--threads must be at least 1");
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.threads)
        .build()
        .context("building the thread pool")?;
    let min = Duration::from_millis(args.min_time_ms);
    let mut reports = Vec::new();
    for path in &args.files {
        let file = RayFile::read(path)?;
        let name = path.display().to_string();
        let r = pool.install(|| bench_file(&file, &name, min))?;
        if r.same_answers != r.rays {
            anyhow::bail!(
                "{name}: fissure's BVH gives {} of {} answers the file holds; the file was written by another build or for another surface",
                r.same_answers,
                r.rays
            );
        }
        reports.push(r);
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&reports)?);
        return Ok(());
    }
    println!(
        "{:<40} {:>7} {:>6} {:>9} {:>9} {:>9} {:>9} {:>8} {:>8} {:>8}",
        "file",
        "tris",
        "rays",
        "bnd ns",
        "bnd/ray",
        "line ns",
        "line/ray",
        "build ms",
        "glob ms",
        "local ms"
    );
    for r in &reports {
        println!(
            "{:<40} {:>7} {:>6} {:>9.1} {:>9.1} {:>9.1} {:>9.1} {:>8.2} {:>8.4} {:>8.4}",
            r.file,
            r.triangles,
            r.rays,
            r.bounded_ns_per_line,
            r.bounded_per_ray_ns_per_line,
            r.line_ns_per_line,
            r.line_per_ray_ns_per_line,
            r.build_ms,
            r.refit_global_ms,
            r.refit_local_ms
        );
    }
    println!(
        "ns per line (one line: the nearest hit behind and in front); bnd: bounded, /ray: walked once per ray"
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 2 x 2 square of 8 triangles at z = 0 and rays through it.
    fn small() -> RayFile {
        let mut rest = Vec::new();
        for j in 0..3 {
            for i in 0..3 {
                rest.push(Point3::new(i as f64, j as f64, 0.0));
            }
        }
        let mut triangles = Vec::new();
        for j in 0..2u32 {
            for i in 0..2u32 {
                let a = j * 3 + i;
                triangles.push([a, a + 1, a + 4]);
                triangles.push([a, a + 4, a + 3]);
            }
        }
        let origins = vec![
            Point3::new(0.3, 0.6, 1.0),
            Point3::new(1.3, 0.2, -1.0),
            Point3::new(5.0, 5.0, 1.0),
        ];
        let dirs = vec![Vector3::z(), Vector3::z(), Vector3::z()];
        let ranges = vec![
            RayRange {
                behind: 2.0,
                front: -1.0,
            },
            RayRange::LINE,
            RayRange::LINE,
        ];
        let deformed = rest.iter().map(|p| p + Vector3::z() * 0.01).collect();
        let moved = rest.iter().map(|p| p + Vector3::x() * 1e-6).collect();
        let mut f = RayFile {
            rest,
            deformed,
            moved,
            triangles,
            origins,
            dirs,
            ranges,
            answers: Vec::new(),
        };
        let mut bvh = Bvh::new(&f.triangles, &f.rest).unwrap();
        bvh.cast_ranged(&f.origins, &f.dirs, &f.ranges, &mut f.answers);
        f
    }

    fn bytes(f: &RayFile) -> Vec<u8> {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.rays");
        f.write(&p).unwrap();
        std::fs::read(p).unwrap()
    }

    /// What is written is read back (answers by triangle and `t`), and
    /// fissure's BVH gives the file's answers on every ray.
    #[test]
    fn a_written_file_reads_back_and_its_answers_are_the_bvh_answers() {
        let f = small();
        assert_eq!(f.answers[0].behind.unwrap().t, -1.0);
        assert!(
            f.answers[0].front.is_none(),
            "a negative bound looks nowhere"
        );
        assert_eq!(f.answers[1].front.unwrap().t, 1.0);
        assert_eq!(f.answers[2], NodeHits::default(), "misses the square");
        let b = bytes(&f);
        let g = RayFile::parse(&b, Path::new("a.rays")).unwrap();
        assert_eq!(
            (g.rest.clone(), g.triangles.clone()),
            (f.rest.clone(), f.triangles.clone())
        );
        assert_eq!(
            (g.origins.clone(), g.ranges.clone()),
            (f.origins.clone(), f.ranges.clone())
        );
        for (x, y) in g.answers.iter().zip(&f.answers) {
            assert!(same(x, y));
        }
        let r = bench_file(&g, "a.rays", Duration::from_millis(1)).unwrap();
        assert_eq!(r.same_answers, 3);
        assert!(r.bounded_ns_per_line > 0.0 && r.refit_global_ms > 0.0);
    }

    /// A bad file is refused with an error naming the file and what is wrong.
    #[test]
    fn bad_files_are_refused_naming_what_is_wrong() {
        let f = small();
        let good = bytes(&f);
        let err = |b: &[u8]| {
            RayFile::parse(b, Path::new("x.rays"))
                .unwrap_err()
                .to_string()
        };
        assert!(err(b"FSRAYS02").contains("not a fissure ray file"));
        assert!(err(&good[..good.len() - 1]).contains("the file has"));
        assert!(err(&good[..20]).contains("x.rays"));
        // A header whose counts overflow.
        let mut huge = good.clone();
        huge[8..16].copy_from_slice(&u64::MAX.to_le_bytes());
        assert!(err(&huge).contains("more than 2^64"));
        // A triangle index past the vertices.
        let v = f.rest.len();
        let tri_at = (HEADER as usize) + 3 * 3 * 8 * v;
        let mut b = good.clone();
        b[tri_at..tri_at + 4].copy_from_slice(&99u32.to_le_bytes());
        assert!(
            err(&b).contains("triangle 0 names vertex 99"),
            "{}",
            err(&b)
        );
        // A non-unit direction.
        let ray_at = tri_at + 12 * f.triangles.len();
        let mut b = good.clone();
        b[ray_at + 40..ray_at + 48].copy_from_slice(&2.0f64.to_le_bytes());
        assert!(
            err(&b).contains("ray 0: direction is not unit length"),
            "{}",
            err(&b)
        );
        // A non-finite position.
        let mut b = good.clone();
        b[HEADER as usize..HEADER as usize + 8].copy_from_slice(&f64::NAN.to_le_bytes());
        assert!(err(&b).contains("rest position of vertex 0"));
        // An answer on a triangle that does not exist.
        let ans_at = ray_at + 64 * f.origins.len();
        let mut b = good;
        b[ans_at..ans_at + 8].copy_from_slice(&1000i64.to_le_bytes());
        assert!(err(&b).contains("answer of ray 0: behind hit on triangle 1000"));
    }
}
