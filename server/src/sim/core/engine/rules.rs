//! How a scene's contact law makes rows ([`RowRule`]) and the skull's rows
//! ([`SkullRows`]).

use super::model::Model;
use crate::collide::contact::ContactOutput;
use crate::fem::{self, ContactRow, RowKind};
use crate::scene::{ContactLaw, Scene};
use crate::sim::core::rows::{self, Anchors, FreePositions, Row, SKULL_OWNER};
use nalgebra::{Isometry3, Point3, Vector3};

/// How a scene's contact law makes rows.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RowRule {
    /// The law.
    pub law: ContactLaw,
    /// The Coulomb coefficient (Coulomb only).
    pub friction: Option<f64>,
}

impl RowRule {
    /// The rule of `scene`.
    pub fn of(scene: &Scene) -> Self {
        Self {
            law: scene.contact.law,
            friction: match scene.contact.law {
                ContactLaw::Coulomb => scene.contact.friction_coefficient,
                _ => None,
            },
        }
    }

    /// The rows of a query's output for `owner`'s pose `pose_of(owner)`,
    /// with the free positions `free`, the last solve's displacements `now`
    /// (m; where a new frictional contact anchors) and the frictional
    /// anchors.
    #[allow(clippy::too_many_arguments)]
    pub fn rows(
        &self,
        model: &Model,
        out: &ContactOutput,
        free: &FreePositions<'_>,
        now: &[Vector3<f64>],
        anchors: &Anchors,
        poses: &[Isometry3<f64>],
        dst: &mut Vec<Row>,
    ) {
        match self.law {
            ContactLaw::Paper => {
                rows::from_enforced(&out.enforced, &model.mesh.nodes, &model.fixed_mask, dst)
            }
            _ => {
                let inputs = rows::RowInputs {
                    free: *free,
                    now,
                    friction: self.friction,
                    anchors,
                    poses,
                    fixed: &model.fixed_mask,
                };
                rows::from_candidates(&out.candidates, &inputs, dst);
                rows::from_edges(&out.edges, &inputs, dst);
            }
        }
    }
}

/// The skull as contact rows (DESIGN.md section 3b's machinery).
///
/// * Spheres: each surface node within `band_m` of leaving the containing
///   sphere (or of entering the excluding one) at its current position `x`
///   gets a unilateral row along the radial direction
///   `r = (x - c) / |x - c|`, linearised there: the containing sphere
///   pushes inward (`dir = -r`, gap `R - r . (X + u - c)`), the excluding
///   one outward (`dir = r`, gap `r . (X + u - c) - R`).
/// * The skull surface ([`fem::skull::SkullSurface`], on the model): each
///   supported node whose gap `g - n . u` is within `surface_band_m` (the
///   skull's own band, [`crate::scene::SkullSurfaceSpec::band_m`]) gets a
///   unilateral row along `-n` with free gap `g`.
#[derive(Debug, Clone)]
pub struct SkullRows {
    skull: fem::skull::Skull,
    pub(super) band_m: f64,
    surface_band_m: f64,
}

impl SkullRows {
    /// The skull of `scene`, if it has one.
    pub fn of(scene: &Scene) -> Option<Self> {
        let skull = scene.skull.as_ref()?;
        let sphere = |s: &crate::scene::SphereSpec| fem::skull::Sphere {
            centre: Point3::from(s.centre_m),
            radius: s.radius_m,
        };
        Some(Self {
            skull: fem::skull::Skull {
                containing: skull.containing.as_ref().map(sphere),
                excluding: skull.excluding.as_ref().map(sphere),
            },
            band_m: scene.contact.band_m,
            surface_band_m: skull
                .surface
                .as_ref()
                .map_or(scene.contact.band_m, |s| s.band_m(scene.contact.band_m)),
        })
    }

    /// Rows of the surface nodes within the band of a sphere at
    /// displacements `u` (and of every node in `also`), appended to `dst`.
    pub fn rows(&self, model: &Model, u: &[Vector3<f64>], also: &[u32], dst: &mut Vec<Row>) {
        // A skull surface alone has no sphere rows to look for.
        let spheres = self.skull.containing.is_some() || self.skull.excluding.is_some();
        let (nodes, extra): (&[u32], &[u32]) = if spheres {
            (&model.surface.to_volume, also)
        } else {
            (&[], &[])
        };
        let mut done = std::collections::HashSet::new();
        for &v in nodes.iter().chain(extra) {
            if model.fixed_mask[v as usize] || !done.insert(v) {
                continue;
            }
            let rest = model.mesh.nodes[v as usize];
            let x = rest + u[v as usize];
            for (code, sphere, containing) in [
                (0u8, self.skull.containing, true),
                (1u8, self.skull.excluding, false),
            ] {
                let Some(s) = sphere else { continue };
                let d = x - s.centre;
                let dist = d.norm();
                let r = if dist > 0.0 { d / dist } else { Vector3::z() };
                let near = if containing {
                    dist > s.radius - self.band_m
                } else {
                    dist < s.radius + self.band_m
                };
                if !near && !also.contains(&v) {
                    continue;
                }
                let (dir, gap) = if containing {
                    (-r, s.radius - r.dot(&(rest - s.centre)))
                } else {
                    (r, r.dot(&(rest - s.centre)) - s.radius)
                };
                dst.push(Row {
                    key: rows::key(v, SKULL_OWNER, 7, code as u32),
                    owner: SKULL_OWNER,
                    row: ContactRow::at_node(v, dir, gap, RowKind::Unilateral),
                    point: s.centre + r * s.radius,
                    triangle: rows::NO_TRIANGLE,
                });
            }
        }
        if let Some(s) = &model.skull_surface {
            // A node gets one surface row: a later call (nodes found beyond
            // the skull) adds only the nodes that have none.
            let had: std::collections::HashSet<u64> = dst
                .iter()
                .filter(|r| r.owner == SKULL_OWNER)
                .map(|r| r.key)
                .collect();
            for (k, &(v, n)) in s.nodes.iter().enumerate() {
                let key = rows::key(v, SKULL_OWNER, 7, 2);
                if (s.gap_m(k, &u[v as usize]) > self.surface_band_m && !also.contains(&v))
                    || had.contains(&key)
                {
                    continue;
                }
                dst.push(Row {
                    key,
                    owner: SKULL_OWNER,
                    row: ContactRow::at_node(v, -n, s.csf_gap_m, RowKind::Unilateral),
                    point: model.mesh.nodes[v as usize] + n * s.csf_gap_m,
                    triangle: rows::NO_TRIANGLE,
                });
            }
        }
    }

    /// Surface nodes that violate a sphere at displacements `u` by more
    /// than `tol_m` and have no skull row in `have`.
    pub fn violations(
        &self,
        model: &Model,
        u: &[Vector3<f64>],
        have: &[Row],
        tol_m: f64,
        out: &mut Vec<u32>,
    ) {
        out.clear();
        let held: std::collections::HashSet<u32> = have
            .iter()
            .filter(|r| r.owner == SKULL_OWNER)
            .map(|r| r.row.node)
            .collect();
        for &v in &model.surface.to_volume {
            if model.fixed_mask[v as usize] || held.contains(&v) {
                continue;
            }
            let x = model.mesh.nodes[v as usize] + u[v as usize];
            let out_of = self
                .skull
                .containing
                .is_some_and(|s| (x - s.centre).norm() > s.radius + tol_m);
            let into = self
                .skull
                .excluding
                .is_some_and(|s| (x - s.centre).norm() < s.radius - tol_m);
            if out_of || into {
                out.push(v);
            }
        }
        if let Some(s) = &model.skull_surface {
            for (k, &(v, _)) in s.nodes.iter().enumerate() {
                if s.gap_m(k, &u[v as usize]) < -tol_m && !held.contains(&v) && !out.contains(&v) {
                    out.push(v);
                }
            }
        }
    }
}
