//! The force loop of one instrument (DESIGN.md section 4): for a fresh
//! pose, the collision query against the last published surface (its own
//! history renewed at every sample), the instrument's contact rows, and the
//! contact problem coupled with the other instruments' latest rows and the
//! skull's, solved on the last step's compliance
//! ([`super::local_model`]). The force on the instrument is minus the sum
//! of its rows' forces; a row whose vertex has no compliance yet is
//! answered by a penalty and flagged ([`super::flags::COLUMNS_PENDING`]).
//! A sample whose contact problem fails repeats the last good force,
//! flagged ([`super::flags::CONTACT_UNSOLVED`]). Strategies without a
//! compliance patch hold the last step's force while the instrument is in
//! contact.
//!
//!
//! **The sample's contact geometry.** Which rows a pose has (covered
//! vertices, polygon points) depends on the tissue's shape, which the
//! sample's own solve changes. With a linear patch the loop keeps its own
//! copy of the surface: at a new frame the published one, then after each
//! solve the patch's vertices moved to where the solve puts them
//! (`x_i = x_rest_i + sum_j C_ij f_j`, the contact loads `f` on the patch's
//! nodes), and it queries again at the same pose: up to
//! [`GEOMETRY_ROUNDS`] rounds, until the rows come back the same (point
//! weights within 1e-6). The next sample starts from that shape. A sample
//! is then the full solve at its poses (the rays still cast on the
//! published tree; only the stages after the cast see the moved vertices).
//!
//! The same functions serve the free-running force loops (each on its own
//! thread, reading the others' rows from shared slots) and the stepped
//! runner ([`super::stepped`]), which queries every instrument of one time
//! before solving any.

use super::engine::{ContactQuery, History, Model, RowRule, penalty};
use super::flags;
use super::local_model::{ForceSolver, SampleAnswer};
use super::rows::{self, FreePositions, Row, SKULL_OWNER};
use super::snapshot::Snapshot;
use crate::scene::{HistoryMode, Scene};
use faer::Par;
use nalgebra::{Isometry3, Point3, Vector3};

/// Most rounds of a sample's contact geometry (solves per sample).
pub const GEOMETRY_ROUNDS: usize = 3;

/// Point weights (barycentric, 1) within this of the last round's: the
/// sample's contact geometry has converged.
const GEOMETRY_TOLERANCE: f64 = 1e-6;

/// A sample's force on one instrument.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SampleForce {
    /// Force of the tissue on the instrument, N.
    pub force_n: Vector3<f64>,
    /// Torque about the handle point, N m.
    pub torque_nm: Vector3<f64>,
    /// Surface vertices the instrument's rows name.
    pub contact_count: u32,
    /// [`super::flags`] bits of the sample's contact solve.
    pub flags: u32,
}

/// The force-loop state of one instrument.
pub struct ForceLoop {
    index: usize,
    history: History,
    paper_mode: bool,
    query: ContactQuery,
    rule: RowRule,
    rows: Vec<Row>,
    all: Vec<Row>,
    poses: Vec<Isometry3<f64>>,
    solver: ForceSolver,
    answer: SampleAnswer,
    contact_count: u32,
    touching: Vec<u32>,
    last_good: (Vector3<f64>, Vector3<f64>),
    /// The loop's copy of the surface (module documentation) and the frame
    /// it was copied from.
    surface: Vec<Point3<f64>>,
    surface_frame: Option<u64>,
    /// The pose of the last query.
    pose: Isometry3<f64>,
    /// Contact loads on the patch's nodes, N.
    loads: Vec<Vector3<f64>>,
    /// The rows of the last round.
    last_rows: Vec<Row>,
}

impl std::fmt::Debug for ForceLoop {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ForceLoop")
            .field("instrument", &self.index)
            .field("rows", &self.rows.len())
            .finish_non_exhaustive()
    }
}

impl ForceLoop {
    /// The force loop of instrument `index` of `scene`, casting on the
    /// snapshots' published trees (or `backend`, when given).
    pub fn new(
        scene: &Scene,
        model: &Model,
        index: usize,
        backend: Option<Box<dyn crate::collide::RayBackend>>,
    ) -> Self {
        Self {
            index,
            history: model.new_history(index),
            paper_mode: scene.collision.history == HistoryMode::Paper,
            query: match backend {
                Some(b) => ContactQuery::with_backend(scene, b),
                None => ContactQuery::new(scene, Par::Seq),
            },
            rule: RowRule::of(scene),
            rows: Vec::new(),
            all: Vec::new(),
            poses: Vec::new(),
            solver: ForceSolver::new(),
            answer: SampleAnswer::default(),
            contact_count: 0,
            touching: Vec::new(),
            last_good: (Vector3::zeros(), Vector3::zeros()),
            surface: Vec::new(),
            surface_frame: None,
            pose: Isometry3::identity(),
            loads: Vec::new(),
            last_rows: Vec::new(),
        }
    }

    /// The instrument's index.
    pub fn index(&self) -> usize {
        self.index
    }

    /// The instrument's rows of the last query.
    pub fn rows(&self) -> &[Row] {
        &self.rows
    }

    /// The history after the last query.
    pub fn history(&self) -> &History {
        &self.history
    }

    /// Back to no contact (a reset): all flags off, no rows, no cache.
    pub fn clear(&mut self, model: &Model) {
        self.history = model.new_history(self.index);
        self.rows.clear();
        self.solver = ForceSolver::new();
        self.last_good = (Vector3::zeros(), Vector3::zeros());
        self.surface_frame = None;
    }

    /// The collision query for `pose` against `snap`, and the instrument's
    /// rows. Returns the number of surface vertices the rows name (the
    /// candidates; [`Self::solve`] counts those in contact).
    pub fn query(&mut self, model: &Model, snap: &Snapshot, pose: &Isometry3<f64>) -> u32 {
        if self.paper_mode {
            self.history.copy_from(&snap.paper_history[self.index]);
        }
        if self.surface_frame != Some(snap.frame) {
            self.surface.clear();
            self.surface.extend_from_slice(&snap.surface);
            self.surface_frame = Some(snap.frame);
        }
        self.pose = *pose;
        self.rows_at(model, snap, pose)
    }

    /// The query on the loop's surface and the rows of its answer.
    fn rows_at(&mut self, model: &Model, snap: &Snapshot, pose: &Isometry3<f64>) -> u32 {
        let out = self.query.query_at(
            model,
            snap,
            &self.surface,
            self.index,
            pose,
            &mut self.history,
        );
        let fm = &snap.force_model;
        let free = if fm.patch.linear || !fm.has_patch {
            FreePositions::Rest(&model.mesh.nodes)
        } else {
            FreePositions::Tangent {
                rest: &model.mesh.nodes,
                index: &fm.patch_index,
                positions: &fm.patch.free_positions,
            }
        };
        self.poses.clear();
        self.poses.resize(self.index + 1, *pose);
        self.rows.clear();
        self.rule
            .rows(model, out, &free, &fm.anchors, &self.poses, &mut self.rows);
        self.contact_count = out.contact_vertices() as u32;
        self.contact_count
    }

    /// The coupled contact problem of this instrument's rows (from the
    /// last [`Self::query`]), the other instruments' rows (`others(j)`:
    /// `Some` their latest rows, `None` their rows of the snapshot's step;
    /// never asked for this instrument) and the skull's; the force on this
    /// instrument about `handle` (m).
    pub fn solve<'a>(
        &mut self,
        model: &Model,
        snap: &Snapshot,
        others: &dyn Fn(usize) -> Option<&'a [Row]>,
        handle: &Vector3<f64>,
    ) -> SampleForce {
        let fm = &snap.force_model;
        let me = self.index as u16;
        if !fm.has_patch {
            // Held: in contact where a row is closed at the step's shape.
            self.touching.clear();
            self.touching.extend(
                self.rows
                    .iter()
                    .filter(|r| {
                        r.row.kind != super::rows::RowKind::Off
                            && r.row.gap_free_m + r.row.normal_motion(&snap.displacements) <= 0.0
                    })
                    .map(|r| r.row.node),
            );
            self.touching.sort_unstable();
            self.touching.dedup();
            self.contact_count = self.touching.len() as u32;
            let (force_n, torque_nm) = if self.touching.is_empty() {
                (Vector3::zeros(), Vector3::zeros())
            } else {
                fm.step_force
                    .get(self.index)
                    .copied()
                    .unwrap_or((Vector3::zeros(), Vector3::zeros()))
            };
            return SampleForce {
                force_n,
                torque_nm,
                contact_count: self.contact_count,
                flags: 0,
            };
        }
        let mut out_flags = 0;
        for round in 0..GEOMETRY_ROUNDS {
            self.all.clear();
            rows::append(&mut self.all, &self.rows);
            for j in 0..model.instruments.len() {
                if j == self.index {
                    continue;
                }
                match others(j) {
                    Some(r) => rows::append(&mut self.all, r),
                    None => rows::append_owner(&mut self.all, &fm.step_rows, j as u16),
                }
            }
            rows::append_owner(&mut self.all, &fm.step_rows, SKULL_OWNER);
            out_flags = 0;
            if let Err(e) = self.solver.solve(fm, &self.all, &mut self.answer) {
                tracing::debug!(instrument = self.index, error = %e, "force-loop contact solve failed");
                return SampleForce {
                    force_n: self.last_good.0,
                    torque_nm: self.last_good.1,
                    contact_count: self.contact_count,
                    flags: flags::CONTACT_UNSOLVED,
                };
            }
            for &p in &self.answer.pending {
                let r = &self.all[p as usize];
                let l = penalty(model, r, &snap.displacements);
                self.answer.lambda[p as usize] = l;
                if r.owner == me && l != 0.0 {
                    out_flags |= flags::COLUMNS_PENDING;
                }
            }
            if !fm.patch.linear || self.surface_frame != Some(snap.frame) {
                break;
            }
            self.move_patch_vertices(model, snap);
            if round + 1 == GEOMETRY_ROUNDS {
                break;
            }
            self.last_rows.clear();
            self.last_rows.extend_from_slice(&self.rows);
            let pose = self.pose;
            self.rows_at(model, snap, &pose);
            // Rows the patch cannot answer (tissue the solve moved beyond
            // the patch's band) would only be penalties: keep the round's
            // answer instead.
            let outside = self.rows.iter().any(|r| {
                r.row.nodes().any(|(n, _)| {
                    fm.patch_index
                        .get(n as usize)
                        .is_none_or(|&p| p == u32::MAX)
                })
            });
            if outside {
                std::mem::swap(&mut self.rows, &mut self.last_rows);
                break;
            }
            if same_rows(&self.last_rows, &self.rows) {
                break;
            }
        }
        let (force_n, torque_nm) = rows::owner_force(&self.all, &self.answer.lambda, me, handle);
        self.last_good = (force_n, torque_nm);
        // In contact: the vertices of this instrument's rows with a force.
        self.touching.clear();
        for (r, &l) in self.all.iter().zip(&self.answer.lambda) {
            if r.owner == me && l != 0.0 {
                self.touching.extend(r.row.nodes().map(|(n, _)| n));
            }
        }
        self.touching.sort_unstable();
        self.touching.dedup();
        self.contact_count = self.touching.len() as u32;
        self.history.set_seeds(rows::seeds_of(
            &self.all,
            &self.answer.lambda,
            me,
            &model.surface.triangles,
            &model.from_volume,
        ));
        SampleForce {
            force_n,
            torque_nm,
            contact_count: self.contact_count,
            flags: out_flags,
        }
    }
}

impl ForceLoop {
    /// Moves the patch's surface vertices in the loop's surface copy to
    /// where the last solve puts them: `x_i = x_rest_i + sum_j C_ij f_j`
    /// (linear patch; `f_j` the contact loads on patch node `j`, N).
    fn move_patch_vertices(&mut self, model: &Model, snap: &Snapshot) {
        let fm = &snap.force_model;
        let patch = &fm.patch;
        let m = patch.nodes.len();
        self.loads.clear();
        self.loads.resize(m, Vector3::zeros());
        for (r, &l) in self.all.iter().zip(&self.answer.lambda) {
            if l == 0.0 {
                continue;
            }
            for (n, w) in r.row.nodes() {
                match fm.patch_index.get(n as usize) {
                    Some(&p) if p != u32::MAX => self.loads[p as usize] += r.row.dir * (l * w),
                    _ => {}
                }
            }
        }
        for i in 0..m {
            let s = model.from_volume[patch.nodes[i] as usize];
            if s == u32::MAX {
                continue;
            }
            let mut u = Vector3::zeros();
            for (j, f) in self.loads.iter().enumerate() {
                if *f != Vector3::zeros() {
                    u += patch.block(i, j) * f;
                }
            }
            self.surface[s as usize] = patch.free_positions[i] + u;
        }
    }
}

/// Whether two rounds' rows are the same problem: the same keys in order,
/// point weights within [`GEOMETRY_TOLERANCE`].
fn same_rows(a: &[Row], b: &[Row]) -> bool {
    a.len() == b.len()
        && a.iter().zip(b).all(|(x, y)| {
            x.key == y.key
                && (0..3).all(|k| (x.triangle.1[k] - y.triangle.1[k]).abs() <= GEOMETRY_TOLERANCE)
        })
}
