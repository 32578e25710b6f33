//! One instrument's part of a query ([`Tool`]: its source nodes, pose and
//! history) and the buffers a query reuses from one call to the next
//! ([`Workspace`]), so that the steady state allocates nothing.

use super::history::History;
use super::types::Pair;
use crate::collide::rays::{NodeHits, RayRange};
use crate::collide::tool::instrument::Instrument;
use crate::mesh::adjacency::Csr;
use nalgebra::{Isometry3, Point3, Vector3};

/// One instrument in a query: its source nodes, scene pose and history.
#[derive(Debug)]
pub struct Tool<'a> {
    /// The spatula.
    pub instrument: &'a Instrument,
    /// Instrument frame -> scene frame.
    pub pose: Isometry3<f64>,
    /// Its history flags (renewed according to `history.mode` and the stage).
    pub history: &'a mut History,
}

/// Reused buffers of [`detect`](super::detect) / [`detect_many`](super::detect_many).
#[derive(Debug, Clone, Default)]
pub struct Workspace {
    /// Scene-frame ray origins of all nodes of all instruments (last query).
    pub origins: Vec<Point3<f64>>,
    /// Scene-frame ray directions (last query).
    pub dirs: Vec<Vector3<f64>>,
    /// Backend answers per ray (last query). With bounded rays, a flagged
    /// node's front hit is its nearest one when that lies within the node's
    /// reach or could be a pair's triangle (see [`DetectOptions::bounded_rays`](super::types::DetectOptions::bounded_rays));
    /// farther ones are not looked for and read `None`.
    pub hits: Vec<NodeHits>,
    pub(crate) offsets: Vec<usize>,
    pub(crate) ranges: Vec<RayRange>,
    /// Second pass of flagged rays: ray index, then its origin, direction
    /// and answer.
    pub(crate) recast: Vec<usize>,
    pub(crate) recast_origins: Vec<Point3<f64>>,
    pub(crate) recast_dirs: Vec<Vector3<f64>>,
    pub(crate) recast_ranges: Vec<RayRange>,
    pub(crate) recast_hits: Vec<NodeHits>,
    pub(crate) candidates: Vec<Pair>,
    pub(crate) mark: Vec<u32>,
    pub(crate) stamp: u32,
    pub(crate) slot: Vec<u32>,
    /// Surface topology for the gap stage (built on first use for a
    /// triangle list, identified by its address and length).
    pub(crate) topology: Option<Topology>,
    pub(crate) visit: Vec<u32>,
    pub(crate) visit_stamp: u32,
    pub(crate) queue: Vec<u32>,
    pub(crate) order: Vec<usize>,
    pub(crate) keep: Vec<bool>,
    pub(crate) covered: Vec<u32>,
    pub(crate) covered_stamp: u32,
    /// Per surface vertex covered at `covered_stamp`: the large face (A or
    /// B, as [`FaceId::index`]) whose candidate it is, or `u8::MAX`.
    ///
    /// [`FaceId::index`]: crate::collide::tool::faces::FaceId::index
    pub(crate) claimed: Vec<u8>,
    /// Per surface triangle, the `covered_stamp` at which faces A and B
    /// clipped it.
    pub(crate) clipped: Vec<[u32; 2]>,
}

/// Vertex neighbours and vertex triangles of a surface.
#[derive(Debug, Clone, Default)]
pub(crate) struct Topology {
    pub key: (usize, usize),
    pub neighbours: Csr,
    pub triangles: Csr,
}

impl Workspace {
    /// An empty workspace; buffers grow on first use.
    pub fn new() -> Self {
        Self::default()
    }

    pub(crate) fn next_stamp(&mut self, triangles: usize) {
        if self.mark.len() != triangles {
            self.mark.clear();
            self.mark.resize(triangles, 0);
            self.stamp = 0;
        }
        if self.stamp == u32::MAX {
            self.mark.fill(0);
            self.stamp = 0;
        }
        self.stamp += 1;
    }
}
