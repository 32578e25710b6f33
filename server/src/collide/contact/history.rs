//! History flags of the source nodes (DESIGN.md section 2, B1-B3), and when
//! they are renewed.
//!
//! A node's flag is on when the node gave an enforced displacement (a pair that
//! survived culling) at the last renewal. Culling uses the flags; a call of
//! [`detect`](super::detect) renews them from its surviving pairs when
//! the [`HistoryMode`] says so for the call's [`Stage`].
//!
//! # How the simulation calls it
//! * [`HistoryMode::ForceRate`] (default): the force loop calls `detect` with
//!   [`Stage::Force`] for every pose sample (1 kHz) against the last published
//!   surface, and every call renews the flags. The contact state thus follows the
//!   spatula in steps of (speed / 1 kHz), far below the plate's thickness, however
//!   slow the deformation loop is. The deformation loop, at its own rate, calls
//!   `detect` with [`Stage::Deformation`] using a *copy* of the force loop's
//!   latest history ([`History::copy_from`], no allocation); it may renew its
//!   copy but never writes back. When both loops run in one thread (the stepped
//!   mode) they can simply share one `History`.
//! * [`HistoryMode::PaperFaithful`]: as in the paper, only the deformation loop
//!   renews the flags (once per deformation step); force-loop calls use the
//!   flags of the last deformation step read-only (they work on a copy, or pass
//!   the shared history: a `Stage::Force` call does not modify it). Travel per
//!   deformation step larger than the thickness then defeats the culling, which
//!   this mode exists to show.

use crate::collide::tool::instrument::Instrument;

/// When the history flags are renewed (a scene's `collision.history`:
/// `"force-rate"` or `"paper"`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum HistoryMode {
    /// Renewed at every call (force-loop rate, robust to fast travel).
    #[default]
    ForceRate,
    /// Renewed only by deformation-loop calls (once per step, as in the
    /// seed paper).
    #[serde(rename = "paper")]
    PaperFaithful,
}

impl HistoryMode {
    /// The name a scene file gives it.
    pub fn name(self) -> &'static str {
        match self {
            Self::ForceRate => "force-rate",
            Self::PaperFaithful => "paper",
        }
    }
}

/// Which loop makes a `detect` call.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// The haptic force loop (one instrument, about 1 kHz).
    Force,
    /// The deformation loop (all instruments, one call per deformation step).
    Deformation,
}

/// Per-node history flags of one instrument.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct History {
    /// The renewal mode.
    pub mode: HistoryMode,
    flags: Vec<bool>,
    /// (face index, surface vertex) of the tissue the last contact solve
    /// found pushed, sorted: the gap stage looks there first, so a contact
    /// the solve closed is found again on the shape it made (the plate's
    /// node rays need not see tissue that lies on an edge of the plate).
    seeds: Vec<(u8, u32)>,
}

impl History {
    /// All flags off, one per source node of `instrument`.
    pub fn new(instrument: &Instrument, mode: HistoryMode) -> Self {
        Self {
            mode,
            flags: vec![false; instrument.len()],
            seeds: Vec::new(),
        }
    }

    /// Whether a call at `stage` renews the flags.
    pub fn renews(&self, stage: Stage) -> bool {
        match self.mode {
            HistoryMode::ForceRate => true,
            HistoryMode::PaperFaithful => stage == Stage::Deformation,
        }
    }

    /// The flags, one per source node.
    pub fn flags(&self) -> &[bool] {
        &self.flags
    }

    /// Number of flags that are on.
    pub fn active(&self) -> usize {
        self.flags.iter().filter(|&&f| f).count()
    }

    /// Turns every flag off (e.g. when the spatula is withdrawn or the scene resets).
    pub fn clear(&mut self) {
        self.flags.fill(false);
        self.seeds.clear();
    }

    /// Copies `other` into `self` without allocating once sizes match.
    pub fn copy_from(&mut self, other: &History) {
        self.mode = other.mode;
        self.flags.clear();
        self.flags.extend_from_slice(&other.flags);
        self.seeds.clear();
        self.seeds.extend_from_slice(&other.seeds);
    }

    /// Sets the seeds ((face index, surface vertex)).
    pub fn set_seeds(&mut self, seeds: impl Iterator<Item = (u8, u32)>) {
        self.seeds.clear();
        self.seeds.extend(seeds);
        self.seeds.sort_unstable();
        self.seeds.dedup();
    }

    /// Whether surface vertex `v` is seeded for face index `face`.
    pub fn is_seed(&self, face: u8, v: u32) -> bool {
        self.seeds.binary_search(&(face, v)).is_ok()
    }

    /// The surface vertices seeded for face index `face`.
    pub fn seeds_of(&self, face: u8) -> impl Iterator<Item = u32> + '_ {
        let from = self.seeds.partition_point(|s| s.0 < face);
        self.seeds[from..]
            .iter()
            .take_while(move |s| s.0 == face)
            .map(|s| s.1)
    }

    /// Renews the flags from the surviving pairs of this instrument when the
    /// mode renews at `stage`: a node's flag is on exactly when it holds a
    /// pair.
    pub fn renew<'a>(&mut self, stage: Stage, pairs: impl Iterator<Item = &'a super::types::Pair>) {
        if self.renews(stage) {
            self.flags.fill(false);
            for p in pairs {
                if let Some(f) = self.flags.get_mut(p.node as usize) {
                    *f = true;
                }
            }
        }
    }

    /// Resizes to `n` nodes (new flags off).
    pub(crate) fn ensure_len(&mut self, n: usize) {
        if self.flags.len() != n {
            self.flags.resize(n, false);
        }
    }
}
