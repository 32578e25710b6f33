//! What the deformation loop publishes: an immutable snapshot swapped atomically
//! (latest wins), read by the force loops without waiting, and a frame summary
//! for watchers.

use nalgebra::{Point3, Vector3};
use std::sync::Arc;
use std::time::Instant;

use super::local_model::ForceModel;
use crate::collide::Bvh;

/// Reaction of the tissue on one instrument in a deformation step.
#[derive(Debug, Clone, PartialEq)]
pub struct InstrumentReaction {
    /// Instrument name.
    pub name: String,
    /// Force of the tissue on the instrument, N.
    pub force_n: Vector3<f64>,
    /// Torque about the handle point, N m.
    pub torque_nm: Vector3<f64>,
    /// Collision pairs found.
    pub pairs: u32,
    /// Pairs cancelled by the history culling.
    pub culled: u32,
    /// Surface vertices the instrument pushes (a non-zero multiplier).
    pub contact_vertices: u32,
    /// Of those, vertices answered by a penalty because their compliance
    /// is not computed yet.
    pub pending_vertices: u32,
    /// Handle position used, m.
    pub position_m: Vector3<f64>,
    /// Orientation used (w, x, y, z).
    pub orientation: [f64; 4],
    /// The retraction pressure under it, and its session sums
    /// ([`super::injury`]).
    pub pressure: super::injury::Pressure,
}

/// Stage timings of one step, microseconds.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StepTimings {
    /// Collision of all instruments.
    pub collision_us: f64,
    /// FEM solve and reactions.
    pub solve_us: f64,
    /// Whole step.
    pub total_us: f64,
    /// The injury measures ([`super::injury`]), part of the whole step.
    pub assess_us: f64,
}

/// One deformation frame, as watchers and recordings see it.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Frame number (0 is the rest state).
    pub frame: u64,
    /// Simulation time, s.
    pub sim_time_s: f64,
    /// Surface vertex positions, m, single precision.
    pub positions: Arc<Vec<[f32; 3]>>,
    /// Per-instrument reactions.
    pub instruments: Vec<InstrumentReaction>,
    /// Stage timings.
    pub timings: StepTimings,
    /// Set when the step failed (positions are the last good state's).
    pub solver_error: Option<String>,
    /// Largest surface displacement from rest, m.
    pub max_displacement_m: f64,
    /// The rigid part of the surface motion and the largest non-rigid
    /// displacement near the instruments' tips and beyond
    /// ([`super::motion`]).
    pub rigid: super::motion::RigidPart,
    /// The ties across the fissure: how many hold, and what happened to
    /// them in this step.
    pub ties: TieFrame,
    /// The tissue's largest principal strain ([`super::injury`]).
    pub strain: super::injury::StrainMeasure,
    /// The strain as a picture, in the frames where the session's largest
    /// strain grew by a quarter since the last picture (the worst frame's is
    /// the last one sent).
    pub strain_picture: Option<Arc<super::injury::StrainPicture>>,
}

/// The ties of one frame.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TieFrame {
    /// Intact trabeculae.
    pub trabeculae_intact: u32,
    /// Intact vessels.
    pub vessels_intact: u32,
    /// Ties cut or torn in this step, in the order they broke.
    pub events: Vec<TieEvent>,
    /// Every tie released so far, ascending.
    pub released: Vec<u32>,
}

/// A tie released: cut by an instrument or torn by tension.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TieEvent {
    /// Simulation time of the step that released it, s.
    pub sim_time_s: f64,
    /// The tie's index in the model ([`super::engine::Model::ties`]).
    pub tie: u32,
    /// What it was.
    pub kind: crate::fem::ties::TieKind,
    /// How it went.
    pub cause: TieCause,
    /// Its midpoint when it went, scene frame, m.
    pub position_m: Point3<f64>,
    /// Its strain when it went.
    pub strain: f64,
}

/// How a tie was released.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TieCause {
    /// Tension reached its rupture criterion; `instrument` is the
    /// instrument pushing the tissue nearest the tie, which tore it.
    Torn { instrument: u16 },
    /// An instrument's blade cut it.
    Cut { instrument: u16 },
}

/// The state force loops read: the surface and the local force model of the
/// last deformation step.
#[derive(Debug)]
pub struct Snapshot {
    /// Frame number.
    pub frame: u64,
    /// Simulation time, s.
    pub sim_time_s: f64,
    /// When it was published.
    pub published: Instant,
    /// Current surface vertex positions, m.
    pub surface: Arc<Vec<Point3<f64>>>,
    /// Displacement of every volume node from rest, m.
    pub displacements: Arc<Vec<Vector3<f64>>>,
    /// A BVH fitted to `surface` (scenes with the CPU BVH), refitted once per
    /// step by the deformation loop and shared read-only by every force loop,
    /// so that no force sample pays for a refit.
    pub surface_bvh: Option<Arc<Bvh>>,
    /// The compliance and contact state the force loops solve on.
    pub force_model: Arc<ForceModel>,
    /// Paper-mode history flags per instrument (renewed once a step).
    pub paper_history: Vec<super::engine::History>,
    /// Set while the last step failed.
    pub solver_error: Option<String>,
    /// The frame summary sent to watchers.
    pub frame_summary: Arc<Frame>,
}

impl InstrumentReaction {
    /// No contact, the instrument at its scene's home pose.
    pub fn at_rest(spec: &crate::scene::InstrumentSpec) -> Self {
        Self {
            name: spec.name.clone(),
            force_n: Vector3::zeros(),
            torque_nm: Vector3::zeros(),
            pairs: 0,
            culled: 0,
            contact_vertices: 0,
            pending_vertices: 0,
            position_m: Vector3::from(spec.home_position_m),
            orientation: spec.home_orientation,
            pressure: Default::default(),
        }
    }
}

impl Frame {
    /// The summary of a solved step (or of the rest state): `surface` (m)
    /// sent in single precision, no error.
    pub fn solved(
        frame: u64,
        sim_time_s: f64,
        surface: &[Point3<f64>],
        instruments: Vec<InstrumentReaction>,
        timings: StepTimings,
        max_displacement_m: f64,
        rigid: super::motion::RigidPart,
    ) -> Self {
        Self {
            frame,
            sim_time_s,
            positions: Self::positions_of(surface),
            instruments,
            timings,
            solver_error: None,
            max_displacement_m,
            rigid,
            ties: TieFrame::default(),
            strain: Default::default(),
            strain_picture: None,
        }
    }

    /// This frame with the tissue's `strain` and, where one is due, its
    /// `picture`.
    pub fn with_strain(
        mut self,
        strain: super::injury::StrainMeasure,
        picture: Option<super::injury::StrainPicture>,
    ) -> Self {
        self.strain = strain;
        self.strain_picture = picture.map(Arc::new);
        self
    }

    /// This frame with `ties`.
    pub fn with_ties(mut self, ties: TieFrame) -> Self {
        self.ties = ties;
        self
    }

    /// Surface positions in single precision, as watchers get them, m.
    pub fn positions_of(surface: &[Point3<f64>]) -> Arc<Vec<[f32; 3]>> {
        Arc::new(
            surface
                .iter()
                .map(|p| [p.x as f32, p.y as f32, p.z as f32])
                .collect(),
        )
    }
}

impl Snapshot {
    /// What a solved step (or the rest state) publishes now: its surface
    /// (m), node displacements (m), fitted tree, force model and paper
    /// history, with `summary`'s frame number and time.
    pub fn solved(
        surface: Arc<Vec<Point3<f64>>>,
        displacements: Arc<Vec<Vector3<f64>>>,
        surface_bvh: Option<Arc<Bvh>>,
        force_model: ForceModel,
        paper_history: Vec<super::engine::History>,
        summary: Frame,
    ) -> Self {
        Self {
            frame: summary.frame,
            sim_time_s: summary.sim_time_s,
            published: Instant::now(),
            surface,
            displacements,
            surface_bvh,
            force_model: Arc::new(force_model),
            paper_history,
            solver_error: None,
            frame_summary: Arc::new(summary),
        }
    }

    /// What a failed step `frame` at `sim_time_s` publishes: this last good
    /// state, renumbered, with `error` in it and in its summary, so that the
    /// force loops keep answering on the last good model and watchers see
    /// why the shape did not move.
    pub fn failed(&self, frame: u64, sim_time_s: f64, timings: StepTimings, error: String) -> Self {
        let mut summary = (*self.frame_summary).clone();
        summary.frame = frame;
        summary.sim_time_s = sim_time_s;
        summary.timings = timings;
        summary.solver_error = Some(error.clone());
        // Releases belong to the frame that made them.
        summary.ties.events.clear();
        summary.strain_picture = None;
        let mut force_model = (*self.force_model).clone();
        force_model.frame = frame;
        Self {
            frame,
            sim_time_s,
            published: Instant::now(),
            surface: self.surface.clone(),
            displacements: self.displacements.clone(),
            surface_bvh: self.surface_bvh.clone(),
            force_model: Arc::new(force_model),
            paper_history: self.paper_history.clone(),
            solver_error: Some(error),
            frame_summary: Arc::new(summary),
        }
    }
}
