//! The ties' stage of a step ([`crate::fem::ties`]): their rows in the
//! contact problem, their rupture after each solve, and what the frame
//! reports of them.
//!
//! Each step the rows of the intact ties' node pairs join the problem,
//! written at rest (the linear strategies' small-displacement theory,
//! [`crate::fem::ties`]). After a solve, every
//! intact tie whose row's stretch (its multiplier over the pair's
//! stiffness) reaches its rupture criterion tears; the torn ties' pairs
//! lose their stiffness (a pair with no tie left loses its row) and the
//! step solves again, up to [`TEAR_ROUNDS`] times, so that the load a torn
//! tie carried passes to its neighbours within the step (a cascade).

use super::Model;
use crate::fem::ties::{TieRows, TieState};
use crate::sim::core::rows::{self, NO_TRIANGLE, Row, TIE_OWNER};
use crate::sim::core::snapshot::{TieCause, TieEvent, TieFrame};
use nalgebra::{Point3, Vector3};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

/// Cuts made by the force loops' blades, shared with the step engine that
/// published the snapshot: a cut takes effect in the cutting sample and in
/// every later sample of every force loop ([`TiesAtStep::adjust`]), and the
/// next deformation step makes it part of the ties' state.
///
/// Cuts are never undone (a reset starts a new set): a force loop still on
/// an older snapshot sees them too.
#[derive(Debug, Default)]
pub struct TieCuts {
    cut: Vec<AtomicBool>,
    any: AtomicBool,
    /// Every cut tie, in the order cut (never drained).
    list: Mutex<Vec<u32>>,
    /// Cuts not yet taken by a step.
    fresh: Mutex<Vec<FreshCut>>,
}

/// A cut not yet taken by a step: tie, instrument, midpoint (m), strain.
type FreshCut = (u32, u16, Point3<f64>, f64);

impl TieCuts {
    /// No tie of `n` cut.
    pub fn new(n: usize) -> Self {
        Self {
            cut: (0..n).map(|_| AtomicBool::new(false)).collect(),
            ..Default::default()
        }
    }

    /// Whether tie `i` is cut.
    #[inline]
    pub fn is_cut(&self, i: usize) -> bool {
        self.cut.get(i).is_some_and(|c| c.load(Ordering::Acquire))
    }

    /// Whether any tie is cut.
    #[inline]
    pub fn any(&self) -> bool {
        self.any.load(Ordering::Acquire)
    }

    /// Cuts tie `i` by `instrument` at its midpoint `at` (m) and `strain`;
    /// false if it was cut already.
    pub fn cut(&self, i: usize, instrument: u16, at: Point3<f64>, strain: f64) -> bool {
        let Some(flag) = self.cut.get(i) else {
            return false;
        };
        if flag.swap(true, Ordering::AcqRel) {
            return false;
        }
        // A poisoned lock only means a panicking writer: the data are plain.
        self.list
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(i as u32);
        self.fresh
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push((i as u32, instrument, at, strain));
        self.any.store(true, Ordering::Release);
        true
    }

    /// Calls `f` with every cut tie.
    pub fn for_each(&self, mut f: impl FnMut(u32)) {
        for &i in self.list.lock().unwrap_or_else(|e| e.into_inner()).iter() {
            f(i);
        }
    }

    fn take_fresh(&self) -> Vec<FreshCut> {
        std::mem::take(&mut *self.fresh.lock().unwrap_or_else(|e| e.into_inner()))
    }
}

/// What the force loops need of the ties at a step: its grouping into rows,
/// each tie's state, and the cuts since.
#[derive(Debug)]
pub struct TiesAtStep {
    /// The step's rows of the ties (pairs, and each tie's pair).
    pub rows: TieRows,
    /// Each tie's state at the step.
    pub states: Vec<TieState>,
    /// Cuts made since (shared with the engine).
    pub cuts: Arc<TieCuts>,
    /// Per instrument: whether it has torn a vessel since the last reset.
    pub tore_vessel: Vec<bool>,
}

impl TiesAtStep {
    /// Tie `i`'s state as the force loops have it now: the step's, or cut
    /// if a blade cut it since.
    pub fn state_now(&self, i: usize) -> TieState {
        match self.states.get(i).copied().unwrap_or_default() {
            TieState::Intact if self.cuts.is_cut(i) => TieState::Cut,
            st => st,
        }
    }

    /// Rewrites the tie rows of `rows[start..]` (the step's tie rows, in
    /// pair order) for the cuts made since the step: a pair's stiffness
    /// loses its cut ties', and a pair left with none is switched off.
    /// `removed` is a workspace (one entry per pair).
    pub fn adjust(&self, model: &Model, rows: &mut [Row], start: usize, removed: &mut Vec<f64>) {
        if !self.cuts.any() {
            return;
        }
        removed.clear();
        removed.resize(self.rows.pairs.len(), 0.0);
        let mut touched = false;
        self.cuts.for_each(|i| {
            let i = i as usize;
            if self.states.get(i) == Some(&TieState::Intact) {
                let p = self.rows.row_of[i];
                if let Some(r) = removed.get_mut(p as usize) {
                    *r += model.ties[i].stiffness_n_per_m;
                    touched = true;
                }
            }
        });
        if !touched {
            return;
        }
        let start = start.min(rows.len());
        let tail = &mut rows[start..];
        for (p, pair) in self.rows.pairs.iter().enumerate() {
            if removed[p] == 0.0 {
                continue;
            }
            let key = rows::key(pair.first_tie, TIE_OWNER, 8, 0);
            let Some(row) = tail.get_mut(p).filter(|r| r.key == key) else {
                continue;
            };
            let k = pair.stiffness_n_per_m - removed[p];
            // Relative to the pair's stiffness: what is left of sums of
            // equal stiffnesses is exact or zero.
            if k > 1e-9 * pair.stiffness_n_per_m {
                row.row.compliance_m_per_n = 1.0 / k;
            } else {
                row.row.kind = crate::fem::RowKind::Off;
            }
        }
    }
}

/// Most re-solves of one step after ties tore (each tears at least one).
pub const TEAR_ROUNDS: u32 = 16;

/// The ties' state across steps.
#[derive(Debug, Clone, Default)]
pub struct TieStage {
    states: Vec<TieState>,
    rows: TieRows,
    events: Vec<TieEvent>,
    cuts: Arc<TieCuts>,
    tore_vessel: Vec<bool>,
    /// Whether ties tear here; `false` for a mirror of another engine's
    /// ties ([`Self::mirror`]).
    mirror: bool,
    /// Each node pair's index among the pairs of every tie intact (the
    /// strategy's [`crate::fem::SolverOptions::tie_pairs`]).
    declared: std::collections::HashMap<(u32, u32), usize>,
}

impl TieStage {
    /// Every tie of `model` intact.
    pub fn new(model: &Model) -> Self {
        let states = vec![TieState::Intact; model.ties.len()];
        let rows = TieRows::all(&model.ties);
        let declared = rows
            .pairs
            .iter()
            .enumerate()
            .map(|(i, p)| ((p.a.min(p.b), p.a.max(p.b)), i))
            .collect();
        Self {
            declared,
            cuts: Arc::new(TieCuts::new(states.len())),
            tore_vessel: vec![false; model.instruments.len()],
            states,
            rows,
            events: Vec::new(),
            mirror: false,
        }
    }

    /// What the force loops need of the ties now (`None`: no ties).
    pub fn at_step(&self) -> Option<Arc<TiesAtStep>> {
        (!self.states.is_empty()).then(|| {
            Arc::new(TiesAtStep {
                rows: self.rows.clone(),
                states: self.states.clone(),
                cuts: self.cuts.clone(),
                tore_vessel: self.tore_vessel.clone(),
            })
        })
    }

    /// Takes the force loops' cuts since the last step into the ties'
    /// state (events at `sim_time_s`); returns whether any was new.
    pub fn take_cuts(&mut self, model: &Model, sim_time_s: f64) -> bool {
        let fresh = self.cuts.take_fresh();
        let mut any = false;
        for (i, instrument, at, strain) in fresh {
            let iu = i as usize;
            if self.states.get(iu) != Some(&TieState::Intact) {
                continue;
            }
            self.states[iu] = TieState::Cut;
            any = true;
            self.events.push(TieEvent {
                sim_time_s,
                tie: i,
                kind: model.ties[iu].kind,
                cause: TieCause::Cut { instrument },
                position_m: at,
                strain,
            });
        }
        if any {
            self.rows = TieRows::group(&model.ties, &self.states);
        }
        any
    }

    /// Whether the model has ties.
    pub fn is_empty(&self) -> bool {
        self.states.is_empty()
    }

    /// Whether ties tear at this stage's steps (not in a mirror).
    pub fn tears(&self) -> bool {
        !self.mirror && !self.states.is_empty()
    }

    /// Makes the ties those of `other` (another engine's, as its force
    /// loops see them: its step's states less the cuts since) and stops
    /// this stage's own tearing: a reference solve then has the ties of
    /// the sample it checks. No event is recorded.
    pub fn mirror(&mut self, model: &Model, other: &TiesAtStep) {
        self.mirror = true;
        let mut changed = false;
        for (i, s) in self.states.iter_mut().enumerate() {
            let want = other.state_now(i);
            if *s != want {
                *s = want;
                changed = true;
            }
        }
        if changed {
            self.rows = TieRows::group(&model.ties, &self.states);
        }
    }

    /// The intact ties' pairs as springs of a nonlinear strategy's energy
    /// ([`crate::fem::ties::TieSprings`]), each with its declared index.
    pub fn springs(&self) -> crate::fem::ties::TieSprings {
        crate::fem::ties::TieSprings {
            pairs: self
                .rows
                .pairs
                .iter()
                .filter_map(|p| {
                    let i = *self.declared.get(&(p.a.min(p.b), p.a.max(p.b)))?;
                    Some((i, *p))
                })
                .collect(),
        }
    }

    /// The rows of the intact ties' pairs (at rest), appended to `dst`.
    pub fn push_rows(&self, model: &Model, dst: &mut Vec<Row>) {
        let rest = &model.mesh.nodes;
        for (p, pair) in self.rows.pairs.iter().enumerate() {
            let (a, b) = (pair.a as usize, pair.b as usize);
            dst.push(Row {
                key: rows::key(pair.first_tie, TIE_OWNER, 8, 0),
                owner: TIE_OWNER,
                row: self.rows.row(p, rest),
                point: Point3::from(0.5 * (rest[a].coords + rest[b].coords)),
                triangle: NO_TRIANGLE,
            });
        }
    }

    /// Tears every intact tie whose stretch at the solved displacements `u`
    /// (m) reaches its criterion; records the events at `sim_time_s`, each
    /// torn by the instrument whose tip (`tips`, m) is nearest among those
    /// pushing the tissue (`pushing[k]`: instrument `k` has a loaded row;
    /// among all when none does). Returns whether any tore (then the rows
    /// are regrouped).
    ///
    /// The stretch is the tie's true one, `|x_b - x_a| - L0` at `x = X +
    /// u`: a fibre breaks at its real strain, whatever the rotation the
    /// row's rest-direction stretch leaves out (the two agree for motion
    /// along the tie; a wall lifted 10 mm across a 3 mm gap turns a tie
    /// far enough that they do not).
    pub fn tear(
        &mut self,
        model: &Model,
        u: &[Vector3<f64>],
        tips: &[Point3<f64>],
        pushing: &[bool],
        sim_time_s: f64,
    ) -> bool {
        let any_pushing = pushing.iter().any(|&p| p);
        let x = |v: u32| model.mesh.nodes[v as usize] + u[v as usize];
        let mut torn = false;
        for (i, tie) in model.ties.iter().enumerate() {
            if self.states[i] != TieState::Intact {
                continue;
            }
            let s = tie.length_m(x) - tie.rest_length_m;
            if !tie.breaks(s) {
                continue;
            }
            self.states[i] = TieState::Torn;
            torn = true;
            let mid = Point3::from(0.5 * (x(tie.a).coords + x(tie.b).coords));
            let instrument = tips
                .iter()
                .enumerate()
                .filter(|(k, _)| !any_pushing || pushing.get(*k) == Some(&true))
                .map(|(k, tip)| (k, (tip - mid).norm()))
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .map_or(0, |(k, _)| k as u16);
            if tie.kind == crate::fem::ties::TieKind::Vessel {
                if let Some(f) = self.tore_vessel.get_mut(instrument as usize) {
                    *f = true;
                }
            }
            self.events.push(TieEvent {
                sim_time_s,
                tie: i as u32,
                kind: tie.kind,
                cause: TieCause::Torn { instrument },
                position_m: mid,
                strain: tie.strain(s),
            });
        }
        if torn {
            self.rows = TieRows::group(&model.ties, &self.states);
        }
        torn
    }

    /// The frame's report: the intact counts and the events since the last
    /// call.
    pub fn frame(&mut self, model: &Model) -> TieFrame {
        let mut f = model.tie_counts(&self.states);
        f.events = std::mem::take(&mut self.events);
        f
    }
}
