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
//! The same functions serve the free-running force loops (each on its own
//! thread, exchanging rows with the others through a [`RowExchange`]) and
//! the stepped runner ([`super::stepped`]), which queries every instrument
//! of one time before solving any.

use super::engine::{ContactQuery, History, Model, RowRule, penalty};
use super::flags;
use super::local_model::{ForceSolver, SampleAnswer};
use super::rows::{self, FreePositions, Row, SKULL_OWNER, TIE_OWNER};
use super::snapshot::Snapshot;
use crate::scene::{HistoryMode, Scene};
use faer::Par;
use nalgebra::{Isometry3, Vector3};
use std::sync::{Arc, Mutex};

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
    /// Scratch of the query's vertex count.
    vertices: Vec<u32>,
    last_good: (Vector3<f64>, Vector3<f64>),
    /// A blade's pose at the last query, the surface its edge swept since,
    /// and the ties' workspace ([`crate::sim::core::engine::TiesAtStep::adjust`]).
    last_pose: Option<Isometry3<f64>>,
    swept: Vec<[nalgebra::Point3<f64>; 3]>,
    removed: Vec<f64>,
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
            paper_mode: scene.collision.history == HistoryMode::PaperFaithful,
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
            vertices: Vec::new(),
            last_good: (Vector3::zeros(), Vector3::zeros()),
            last_pose: None,
            swept: Vec::new(),
            removed: Vec::new(),
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
        self.last_pose = None;
    }

    /// The collision query for `pose` against `snap`, and the instrument's
    /// rows. Returns the number of surface vertices the rows name (the
    /// candidates; [`Self::solve`] counts those in contact).
    pub fn query(&mut self, model: &Model, snap: &Snapshot, pose: &Isometry3<f64>) -> u32 {
        if self.paper_mode {
            self.history.copy_from(&snap.paper_history[self.index]);
        }
        self.cut(model, snap, pose);
        let out = self
            .query
            .query(model, snap, self.index, pose, &mut self.history);
        let fm = &snap.force_model;
        // Written on the rest positions, as the step's rows are; a tangent
        // patch rewrites them all at the solve ([`rows::to_tangent`]).
        let free = FreePositions::Rest(&model.mesh.nodes);
        self.poses.clear();
        self.poses.resize(self.index + 1, *pose);
        self.rows.clear();
        self.rule.rows(
            model,
            out,
            &free,
            &snap.displacements,
            &fm.anchors,
            &self.poses,
            &mut self.rows,
        );
        self.contact_count = out.contact_vertices(&mut self.vertices) as u32;
        self.contact_count
    }

    /// A blade's cuts: every intact tie (at the snapshot's shape) that the
    /// edge crossed moving from the last query's pose to `pose`
    /// ([`crate::collide::tool::sweep`]); they take effect at once.
    fn cut(&mut self, model: &Model, snap: &Snapshot, pose: &Isometry3<f64>) {
        let (Some(edge), Some(ties)) = (
            model.blades.get(self.index).copied().flatten(),
            snap.force_model.ties.as_ref(),
        ) else {
            return;
        };
        let Some(last) = self.last_pose.replace(*pose) else {
            return;
        };
        self.swept.clear();
        crate::collide::tool::sweep::swept_triangles(&edge, &last, pose, &mut self.swept);
        // The sweep's box: ties wholly outside it are not tested.
        let (mut lo, mut hi) = (
            nalgebra::Point3::from([f64::INFINITY; 3]),
            nalgebra::Point3::from([f64::NEG_INFINITY; 3]),
        );
        for t in &self.swept {
            for p in t {
                lo = lo.inf(p);
                hi = hi.sup(p);
            }
        }
        let u = &snap.displacements;
        for (i, tie) in model.ties.iter().enumerate() {
            if ties.states[i] != crate::fem::ties::TieState::Intact || ties.cuts.is_cut(i) {
                continue;
            }
            let xa = model.mesh.nodes[tie.a as usize] + u[tie.a as usize];
            let xb = model.mesh.nodes[tie.b as usize] + u[tie.b as usize];
            if (0..3).any(|c| xa[c].max(xb[c]) < lo[c] || xa[c].min(xb[c]) > hi[c]) {
                continue;
            }
            if self
                .swept
                .iter()
                .any(|t| crate::collide::tool::sweep::segment_crosses_triangle(&xa, &xb, t))
            {
                let mid = nalgebra::center(&xa, &xb);
                let strain = tie.strain((xb - xa).norm() - tie.rest_length_m);
                ties.cuts.cut(i, self.index as u16, mid, strain);
            }
        }
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
        // The skull's rows the step found pushing: its contact set holds
        // from one step to the next (its rows are far from the spatulas and
        // a sample solves with the few that carry the brain, not with the
        // hundreds to thousands within the band of the skull).
        self.all.extend(
            fm.step_rows
                .iter()
                .zip(&fm.step_lambda)
                .filter(|(r, l)| r.owner == SKULL_OWNER && **l > 0.0)
                .map(|(r, _)| *r),
        );
        // The ties as the step left them (torn ones have no row), less
        // those a blade cut since.
        let tie_start = self.all.len();
        rows::append_owner(&mut self.all, &fm.step_rows, TIE_OWNER);
        if let Some(ties) = &fm.ties {
            ties.adjust(model, &mut self.all, tie_start, &mut self.removed);
        }
        if !fm.patch.linear {
            rows::to_tangent(
                &mut self.all,
                &FreePositions::Tangent {
                    rest: &model.mesh.nodes,
                    index: &fm.patch_index,
                    positions: &fm.patch.free_positions,
                },
            );
        }
        let mut out_flags = 0;
        if fm
            .ties
            .as_ref()
            .is_some_and(|t| t.tore_vessel.get(self.index) == Some(&true))
        {
            out_flags |= flags::VESSEL_TORN;
        }
        if let Err(e) = self.solver.solve(fm, &self.all, &mut self.answer) {
            tracing::debug!(instrument = self.index, error = %e, "force-loop contact solve failed");
            return SampleForce {
                force_n: self.last_good.0,
                torque_nm: self.last_good.1,
                contact_count: self.contact_count,
                flags: flags::CONTACT_UNSOLVED | out_flags,
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

/// The free-running force loops' exchange of contact rows: each loop
/// publishes its instrument's rows after its query and reads the other
/// instruments' latest before its solve, so that every sample's contact
/// problem couples the instruments (DESIGN.md section 4) without a loop
/// waiting for another. A slot's rows are replaced in place when no reader
/// holds them, so a sample allocates nothing once the slots have grown.
#[derive(Debug)]
pub struct RowExchange {
    slots: Vec<Mutex<RowSlot>>,
}

/// One instrument's latest rows.
#[derive(Debug, Default)]
struct RowSlot {
    /// Whether its instrument is claimed (a released one's rows are stale).
    live: bool,
    rows: Arc<Vec<Row>>,
}

/// The other instruments' rows as one sample read them (reused from one
/// sample to the next).
#[derive(Debug, Default)]
pub struct HeldRows {
    held: Vec<Option<Arc<Vec<Row>>>>,
}

impl HeldRows {
    /// Instrument `j`'s rows, if it was live when they were read.
    pub fn of(&self, j: usize) -> Option<&[Row]> {
        self.held
            .get(j)
            .and_then(|h| h.as_deref().map(|v| v.as_slice()))
    }

    /// Lets the rows go (their slots may be reused in place again).
    pub fn clear(&mut self) {
        self.held.clear();
    }
}

impl RowExchange {
    /// Slots for `instruments` instruments, none live.
    pub fn new(instruments: usize) -> Self {
        Self {
            slots: (0..instruments)
                .map(|_| Mutex::new(RowSlot::default()))
                .collect(),
        }
    }

    /// Instrument `index`'s rows of its latest sample; it is live from now on.
    pub fn publish(&self, index: usize, rows: &[Row]) {
        let mut mine = self.slots[index].lock().expect("rows lock");
        mine.live = true;
        match Arc::get_mut(&mut mine.rows) {
            Some(v) => {
                v.clear();
                v.extend_from_slice(rows);
            }
            None => mine.rows = Arc::new(rows.to_vec()),
        }
    }

    /// Instrument `index` was released: the others stop reading its rows.
    pub fn release(&self, index: usize) {
        self.slots[index].lock().expect("rows lock").live = false;
    }

    /// Every other live instrument's latest rows into `held` (instrument
    /// `index`'s own slot reads as none).
    pub fn gather(&self, index: usize, held: &mut HeldRows) {
        held.held.clear();
        for (j, slot) in self.slots.iter().enumerate() {
            if j == index {
                held.held.push(None);
                continue;
            }
            let s = slot.lock().expect("rows lock");
            held.held.push(s.live.then(|| s.rows.clone()));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fem::{ContactRow, RowKind};
    use nalgebra::Point3;

    fn row(owner: u16, node: u32) -> Row {
        Row {
            key: rows::key(node, owner, 0, 0),
            owner,
            row: ContactRow::at_node(node, Vector3::z(), 1e-3, RowKind::Unilateral),
            point: Point3::origin(),
            triangle: rows::NO_TRIANGLE,
        }
    }

    /// Each loop reads the others' latest rows, never its own, and none of
    /// a released instrument; a slot no reader holds is rewritten in place
    /// (the same allocation), one a reader holds is replaced and the reader
    /// keeps what it read.
    #[test]
    fn the_exchange_gives_each_loop_the_other_live_instruments_latest_rows() {
        let exchange = RowExchange::new(3);
        let mut held = HeldRows::default();
        exchange.gather(0, &mut held);
        assert!((0..3).all(|j| held.of(j).is_none()), "nothing is live yet");

        exchange.publish(0, &[row(0, 1)]);
        exchange.publish(1, &[row(1, 2), row(1, 3)]);
        exchange.gather(0, &mut held);
        assert!(held.of(0).is_none(), "a loop does not read its own slot");
        assert_eq!(held.of(1).map(<[Row]>::len), Some(2));
        assert!(held.of(2).is_none(), "instrument 2 never published");

        // Held by a reader: the publisher replaces the slot, the reader
        // keeps the rows it read.
        exchange.publish(1, &[row(1, 4)]);
        assert_eq!(held.of(1).map(|r| r[0].row.node), Some(2));
        held.clear();
        let before = Arc::as_ptr(&exchange.slots[1].lock().unwrap().rows);
        exchange.publish(1, &[row(1, 5)]);
        let after = Arc::as_ptr(&exchange.slots[1].lock().unwrap().rows);
        assert_eq!(before, after, "a slot no one holds is rewritten in place");
        exchange.gather(2, &mut held);
        assert_eq!(held.of(1).map(|r| r[0].row.node), Some(5));
        assert_eq!(held.of(0).map(|r| r[0].row.node), Some(1));

        exchange.release(1);
        exchange.gather(0, &mut held);
        assert!(
            held.of(1).is_none(),
            "a released instrument's rows are not read"
        );
    }
}
