//! A scene's ties (`[[ties]]`): the connective tissue across a fissure,
//! declared per kind and placed on the model ([`crate::fem::ties`] has the
//! law).
//!
//! # Placement on a region
//! The walls of the region are its outer-surface triangles (centroid in a
//! box, sphere or landmark; or all three nodes in a vertex list) whose
//! vertices each *face* another vertex of the region across the gap: the
//! facing vertex `w` of `v` is the nearest region vertex with `|X_w - X_v|
//! <= max_gap_m`, within 45 degrees of `v`'s outward normal (`(X_w - X_v) .
//! n_v >= |X_w - X_v| cos 45`) and with its own normal turned back
//! (`n_w . n_v <= -0.5`); fixed nodes take no part. With `A` the walls'
//! area (both walls, mm^2) a declaration of density `rho` (ties per mm^2 of
//! wall) places `N = round(rho A / 2)` ties, so each wall carries `rho`
//! tie ends per mm^2 (half the ties are seeded on each wall, the other
//! ends land on it). Each tie is seeded at a point drawn uniformly by area
//! over the walls (ChaCha8 from the declaration's `seed`: the same scene
//! and mesh give the same ties on every machine), attached at the vertex of
//! its triangle nearest that point, and joined to that vertex's facing
//! vertex; its rest length is their distance at rest.
//!
//! # Placement from a file
//! `pairs_file`: one tie a line, `ax ay az bx by bz` (m, scene frame; `#`
//! comments), each end attached at the nearest free surface vertex (within
//! `max_gap_m`, or the line is refused), for a user's mesh with its own
//! segmentation of the connective tissue.

// Negated comparisons are deliberate: NaN must fail the checks.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::Region;
use super::region::{OnModel, RegionError, Resolved};
use crate::fem::ties::{Rupture, Tie, TieKind};
use nalgebra::{Point3, Vector3};
use rand_chacha::ChaCha8Rng;
use rand_chacha::rand_core::{RngCore, SeedableRng};
use serde::Deserialize;
use std::path::PathBuf;

/// The most ties a scene may declare in all (each pair of nodes is a row of
/// every contact solve; far beyond any published trabecular density over a
/// fissure's walls).
pub const MAX_TIES: usize = 20_000;

/// The default reach of a tie across the fissure, m.
pub const DEFAULT_MAX_GAP_M: f64 = 0.006;

/// One `[[ties]]` declaration.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TieSpec {
    /// `"trabecula"` or `"vessel"`.
    pub kind: TieKindName,
    /// The fissure region whose walls the ties join (with `density_per_mm2`).
    #[serde(default)]
    pub region: Option<Region>,
    /// Ties per mm^2 of wall (with `region`), > 0.
    #[serde(default)]
    pub density_per_mm2: Option<f64>,
    /// A file of point pairs instead of a region (module documentation),
    /// relative to the scene file.
    #[serde(default)]
    pub pairs_file: Option<PathBuf>,
    /// Seed of the random placement.
    #[serde(default)]
    pub seed: u64,
    /// Stiffness of one tie, N/m (> 0).
    pub stiffness_n_per_m: f64,
    /// The tie breaks at this strain `(L - L0) / L0` (> 0); or give
    /// `rupture_force_n`.
    #[serde(default)]
    pub rupture_strain: Option<f64>,
    /// The tie breaks at this tension, N (> 0); or give `rupture_strain`.
    #[serde(default)]
    pub rupture_force_n: Option<f64>,
    /// How far across the fissure a tie may reach, m (default 6 mm).
    #[serde(default = "default_max_gap")]
    pub max_gap_m: f64,
}

fn default_max_gap() -> f64 {
    DEFAULT_MAX_GAP_M
}

/// A tie kind's name in scene files.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum TieKindName {
    /// [`TieKind::Trabecula`].
    Trabecula,
    /// [`TieKind::Vessel`].
    Vessel,
}

impl From<TieKindName> for TieKind {
    fn from(k: TieKindName) -> Self {
        match k {
            TieKindName::Trabecula => TieKind::Trabecula,
            TieKindName::Vessel => TieKind::Vessel,
        }
    }
}

impl TieSpec {
    /// The rupture criterion (validated: exactly one is given).
    pub fn rupture(&self) -> Rupture {
        match (self.rupture_strain, self.rupture_force_n) {
            (Some(e), _) => Rupture::Strain(e),
            (None, Some(f)) => Rupture::Force(f),
            (None, None) => Rupture::Strain(f64::INFINITY),
        }
    }

    /// Checks the declaration's values; `field` names it (`ties[i]`).
    /// Errors are `(field, reason)`.
    pub fn check(&self, field: &str) -> Result<(), (String, String)> {
        let positive = |name: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err((
                    format!("{field}.{name}"),
                    format!("must be a finite positive number, got {v}"),
                ))
            }
        };
        positive("stiffness_n_per_m", self.stiffness_n_per_m)?;
        positive("max_gap_m", self.max_gap_m)?;
        match (self.rupture_strain, self.rupture_force_n) {
            (Some(e), None) => positive("rupture_strain", e)?,
            (None, Some(f)) => positive("rupture_force_n", f)?,
            _ => {
                return Err((
                    field.to_owned(),
                    "give exactly one rupture criterion: rupture_strain or rupture_force_n".into(),
                ));
            }
        }
        match (&self.region, &self.pairs_file, self.density_per_mm2) {
            (Some(_), None, Some(d)) => positive("density_per_mm2", d)?,
            (Some(_), None, None) => {
                return Err((
                    format!("{field}.density_per_mm2"),
                    "a region's ties need their density (ties per mm^2 of wall)".into(),
                ));
            }
            (None, Some(_), None) => {}
            (None, Some(_), Some(_)) => {
                return Err((
                    format!("{field}.density_per_mm2"),
                    "ties from a pairs_file are placed by the file, not by a density".into(),
                ));
            }
            _ => {
                return Err((
                    field.to_owned(),
                    "give the ties' place: a region (with density_per_mm2) or a pairs_file".into(),
                ));
            }
        }
        Ok(())
    }
}

/// Why a scene's ties cannot be placed.
#[derive(Debug, thiserror::Error)]
pub enum TieError {
    /// The region could not be resolved.
    #[error(transparent)]
    Region(#[from] RegionError),
    /// The region has no facing walls.
    #[error(
        "`{field}`: the region names no facing walls (no surface vertex of it faces another within max_gap_m = {max_gap_m} m)"
    )]
    NoWalls { field: String, max_gap_m: f64 },
    /// The density gives no tie on the walls.
    #[error(
        "`{field}.density_per_mm2`: {density} ties per mm^2 over {area_mm2:.1} mm^2 of wall places no tie"
    )]
    NoTies {
        field: String,
        density: f64,
        area_mm2: f64,
    },
    /// Too many ties.
    #[error(
        "`{field}`: {count} ties ({detail}) would bring the scene to {total}, over the most a scene may have ({MAX_TIES})"
    )]
    TooMany {
        field: String,
        count: usize,
        total: usize,
        detail: String,
    },
    /// A pairs file cannot be read.
    #[error("`{field}.pairs_file`: cannot read {path}: {source}")]
    Io {
        field: String,
        path: String,
        source: std::io::Error,
    },
    /// A bad line of a pairs file.
    #[error("`{field}.pairs_file`: {path}, line {line}: {reason}")]
    BadPair {
        field: String,
        path: String,
        line: usize,
        reason: String,
    },
}

/// Places every declaration's ties on the model `on`, in declaration order.
pub fn place(specs: &[TieSpec], on: &OnModel<'_>) -> Result<Vec<Tie>, TieError> {
    let mut ties = Vec::new();
    let walls = Walls::normals(on);
    for (i, spec) in specs.iter().enumerate() {
        let field = format!("ties[{i}]");
        let before = ties.len();
        match (&spec.region, &spec.pairs_file) {
            (Some(region), _) => {
                place_on_region(spec, region, &field, on, &walls, &mut ties)?;
            }
            (None, Some(path)) => place_from_file(spec, path, &field, on, &mut ties)?,
            (None, None) => {}
        }
        if ties.len() > MAX_TIES {
            return Err(TieError::TooMany {
                field,
                count: ties.len() - before,
                total: ties.len(),
                detail: match spec.density_per_mm2 {
                    Some(d) => format!("density_per_mm2 = {d}"),
                    None => "pairs_file".into(),
                },
            });
        }
    }
    Ok(ties)
}

/// Unit outward area-weighted rest normals of the surface vertices.
struct Walls {
    normals: Vec<Vector3<f64>>,
}

impl Walls {
    fn normals(on: &OnModel<'_>) -> Self {
        let (mesh, surface) = (on.mesh, on.surface);
        let mut normals = vec![Vector3::zeros(); surface.to_volume.len()];
        for t in &surface.triangles {
            let [a, b, c] = t.map(|v| mesh.nodes[surface.to_volume[v as usize] as usize]);
            let n = (b - a).cross(&(c - a));
            for &v in t {
                normals[v as usize] += n;
            }
        }
        for n in &mut normals {
            let len = n.norm();
            if len > 0.0 {
                *n /= len;
            }
        }
        Self { normals }
    }
}

fn place_on_region(
    spec: &TieSpec,
    region: &Region,
    field: &str,
    on: &OnModel<'_>,
    walls: &Walls,
    ties: &mut Vec<Tie>,
) -> Result<(), TieError> {
    let (mesh, surface) = (on.mesh, on.surface);
    let resolved = on
        .resolve_all(std::slice::from_ref(region), &format!("{field}.region"))?
        .remove(0);
    let x = |s: u32| mesh.nodes[surface.to_volume[s as usize] as usize];
    let free = |s: u32| !on.fixed[surface.to_volume[s as usize] as usize];
    // The region's surface triangles (free nodes only) and their vertices.
    let in_region: Vec<usize> = surface
        .triangles
        .iter()
        .enumerate()
        .filter(|(_, t)| {
            t.iter().all(|&s| free(s))
                && match &resolved {
                    Resolved::Shape(shape) => {
                        let c = Point3::from(
                            t.iter().map(|&s| x(s).coords).sum::<Vector3<f64>>() / 3.0,
                        );
                        shape.contains(&c)
                    }
                    Resolved::Nodes(m) => {
                        t.iter().all(|&s| m[surface.to_volume[s as usize] as usize])
                    }
                }
        })
        .map(|(i, _)| i)
        .collect();
    let mut verts: Vec<u32> = in_region
        .iter()
        .flat_map(|&i| surface.triangles[i])
        .collect();
    verts.sort_unstable();
    verts.dedup();
    // Each vertex's facing vertex (module documentation).
    let cos45 = std::f64::consts::FRAC_1_SQRT_2;
    let mut facing = std::collections::HashMap::new();
    for &v in &verts {
        let (xv, nv) = (x(v), walls.normals[v as usize]);
        let mut best: Option<(f64, u32)> = None;
        for &w in &verts {
            if w == v {
                continue;
            }
            let d = x(w) - xv;
            let dist = d.norm();
            if dist > spec.max_gap_m
                || !(d.dot(&nv) >= cos45 * dist)
                || !(walls.normals[w as usize].dot(&nv) <= -0.5)
            {
                continue;
            }
            if best.is_none_or(|(bd, _)| dist < bd) {
                best = Some((dist, w));
            }
        }
        if let Some((_, w)) = best {
            facing.insert(v, w);
        }
    }
    // The walls: triangles whose vertices all face another.
    let mut tris = Vec::new();
    let mut cumulative = Vec::new();
    let mut area_m2 = 0.0;
    for &i in &in_region {
        let t = surface.triangles[i];
        if t.iter().all(|s| facing.contains_key(s)) {
            let [a, b, c] = t.map(x);
            area_m2 += 0.5 * (b - a).cross(&(c - a)).norm();
            tris.push(t);
            cumulative.push(area_m2);
        }
    }
    if tris.is_empty() {
        return Err(TieError::NoWalls {
            field: field.to_owned(),
            max_gap_m: spec.max_gap_m,
        });
    }
    let density = spec.density_per_mm2.unwrap_or(0.0);
    let area_mm2 = area_m2 * 1e6;
    let count_f = (density * area_mm2 / 2.0).round();
    if count_f < 1.0 {
        return Err(TieError::NoTies {
            field: field.to_owned(),
            density,
            area_mm2,
        });
    }
    if count_f > MAX_TIES as f64 {
        return Err(TieError::TooMany {
            field: field.to_owned(),
            count: count_f as usize,
            total: ties.len() + count_f as usize,
            detail: format!("density_per_mm2 = {density} over {area_mm2:.1} mm^2 of wall"),
        });
    }
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    let mut uniform = || (rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
    for _ in 0..count_f as usize {
        let pick = uniform() * area_m2;
        let k = cumulative
            .partition_point(|&c| c < pick)
            .min(tris.len() - 1);
        let t = tris[k];
        // Uniform on the triangle: weights (1 - sqrt r1, sqrt r1 (1 - r2),
        // sqrt r1 r2); the tie attaches at the vertex of the largest.
        let (r1, r2) = (uniform().sqrt(), uniform());
        let w = [1.0 - r1, r1 * (1.0 - r2), r1 * r2];
        let corner = (0..3)
            .max_by(|&i, &j| w[i].total_cmp(&w[j]).then(j.cmp(&i)))
            .unwrap_or(0);
        let a = t[corner];
        let b = facing[&a];
        ties.push(Tie {
            kind: spec.kind.into(),
            a: surface.to_volume[a as usize],
            b: surface.to_volume[b as usize],
            rest_length_m: (x(b) - x(a)).norm(),
            stiffness_n_per_m: spec.stiffness_n_per_m,
            rupture: spec.rupture(),
        });
    }
    Ok(())
}

fn place_from_file(
    spec: &TieSpec,
    path: &std::path::Path,
    field: &str,
    on: &OnModel<'_>,
    ties: &mut Vec<Tie>,
) -> Result<(), TieError> {
    let shown = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|source| TieError::Io {
        field: field.to_owned(),
        path: shown.clone(),
        source,
    })?;
    let (mesh, surface) = (on.mesh, on.surface);
    let nearest = |p: Point3<f64>| {
        surface
            .to_volume
            .iter()
            .filter(|&&v| !on.fixed[v as usize])
            .map(|&v| ((mesh.nodes[v as usize] - p).norm(), v))
            .min_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)))
    };
    for (line_no, line) in super::region::data_lines(&text) {
        let bad = |reason: String| TieError::BadPair {
            field: field.to_owned(),
            path: shown.clone(),
            line: line_no,
            reason,
        };
        let v: Vec<f64> = line
            .split_whitespace()
            .map(|s| s.parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|_| bad(format!("{line:?} is not six numbers")))?;
        if v.len() != 6 || !v.iter().all(|c| c.is_finite()) {
            return Err(bad(format!(
                "{line:?} is not six finite numbers (ax ay az bx by bz, m)"
            )));
        }
        let mut ends = [0u32; 2];
        for (e, p) in [Point3::new(v[0], v[1], v[2]), Point3::new(v[3], v[4], v[5])]
            .into_iter()
            .enumerate()
        {
            match nearest(p) {
                Some((d, node)) if d <= spec.max_gap_m => ends[e] = node,
                Some((d, _)) => {
                    return Err(bad(format!(
                        "end {} at {:?} m is {d} m from the nearest free surface vertex (more than max_gap_m = {} m)",
                        e + 1,
                        p.coords.as_slice(),
                        spec.max_gap_m
                    )));
                }
                None => return Err(bad("the model has no free surface vertex".into())),
            }
        }
        if ends[0] == ends[1] {
            return Err(bad(format!(
                "both ends attach at surface vertex of node {}: a tie needs two",
                ends[0]
            )));
        }
        ties.push(Tie {
            kind: spec.kind.into(),
            a: ends[0],
            b: ends[1],
            rest_length_m: (mesh.nodes[ends[1] as usize] - mesh.nodes[ends[0] as usize]).norm(),
            stiffness_n_per_m: spec.stiffness_n_per_m,
            rupture: spec.rupture(),
        });
    }
    Ok(())
}
