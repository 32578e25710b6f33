//! Spatulas and their source nodes (DESIGN.md section 2, "Instrument").
//!
//! # Instrument frame
//! Origin at the handle point: the centre of the plate's base edge, at
//! mid-thickness. `+z` runs along the plate's length to the tip, `+x` is the
//! outward normal of face A (at `x = +h/2` for a flat plate), `y` runs across
//! the width. Face B is at `x = -h/2` with outward normal `-x`. A pose
//! (`Isometry3<f64>`) maps this frame to the scene frame; metres throughout.
//!
//! # Plate shapes ([`Plate`])
//! The mid-surface is parametrised by arc length `s in [0, L]` and the
//! across-width coordinate `y`. The local width is
//! `w(s) = w_base + (w_tip - w_base) s / L` (a trapezoid when they differ).
//! A flat plate has mid-surface `m(s, y) = (0, y, s)` and face-A normal
//! `n = (1, 0, 0)`. A curved plate is bent along its length in the `x-z` plane
//! with signed radius `R` (centre of curvature at `(-R, 0, 0)`; `R > 0` makes
//! face A convex):
//! `m(s, y) = (-R (1 - cos(s/R)), y, R sin(s/R))`, tangent
//! `T(s) = (-sin(s/R), 0, cos(s/R))`, face-A normal `n(s) = (cos(s/R), 0, sin(s/R))`.
//! Face A is `m + (h/2) n`, face B is `m - (h/2) n` with normal `-n`.
//!
//! # Source nodes and the pairing rule
//! Face nodes lie on a grid of the `(s, y)` parameters at cell centres, the same
//! grid on both faces: node `i` of face A at `m(s, y) + (h/2) n(s)` and its
//! partner on face B at `m(s, y) - (h/2) n(s)` lie on one line along the face
//! normal `n(s)`, which is what history culling needs (the line of a node's hits
//! in front is its partner's line of hits behind).
//!
//! Optional rim nodes ([`RimNodes`]) sit at mid-thickness:
//! * on the two side edges, `y = +-w(s)/2`, with normals `+-y`, paired across the
//!   width (the two nodes at one `s` lie on one line along `y`). For a trapezoid
//!   `+-y` is within the taper angle `atan(|w_tip - w_base| / (2L))` of the edge's
//!   true outward normal; `+-y` is used so that the pairing rule stays exact.
//! * across the tip edge, `s = L`, with the tangent `T(L)` as normal; these are
//!   unpaired (their line behind runs back along the plate).
//!
//! Every node has a *reach*: the largest depth `|t|` behind it at which its
//! nearest triangle behind may still form a pair. Face nodes have infinite reach
//! (the paper's rule); side rim nodes reach half the local width (the line
//! behind a side node crosses the plate to its centre line there); tip nodes
//! reach [`RimNodes::tip_reach`]. A finite reach keeps a rim node from pairing
//! with tissue far along the plate's own length or width.

use nalgebra::{Isometry3, Point3, Vector3};

/// Errors in an instrument description; each names the offending value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum InstrumentError {
    /// A length that must be positive and finite is not.
    #[error("{what} must be positive and finite, got {value} m")]
    NonPositive { what: &'static str, value: f64 },
    /// The plate bends more than half a turn, or its radius is inside the plate.
    #[error(
        "bend radius {radius} m is invalid for length {length} m and thickness {thickness} m (need |R| > h/2 and L/|R| <= pi)"
    )]
    BadRadius {
        radius: f64,
        length: f64,
        thickness: f64,
    },
    /// A node count that must be positive is zero.
    #[error("{what} must be at least 1")]
    ZeroCount { what: &'static str },
    /// The tip fraction is outside (0, 1].
    #[error("tip fraction must be in (0, 1], got {0}")]
    BadFraction(f64),
}

/// The plate of a spatula (metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plate {
    /// Thickness h.
    pub thickness: f64,
    /// Width at the base (handle end), `s = 0`.
    pub base_width: f64,
    /// Width at the tip, `s = L`.
    pub tip_width: f64,
    /// Length L (arc length for a curved plate).
    pub length: f64,
    /// Signed bend radius R; `None` for a flat plate.
    pub bend_radius: Option<f64>,
}

impl Plate {
    /// A flat rectangular plate: thickness `h`, width `w`, length `l`.
    pub fn flat(h: f64, w: f64, l: f64) -> Self {
        Self {
            thickness: h,
            base_width: w,
            tip_width: w,
            length: l,
            bend_radius: None,
        }
    }

    /// A flat trapezoid plate whose width goes from `w_base` to `w_tip`.
    pub fn trapezoid(h: f64, w_base: f64, w_tip: f64, l: f64) -> Self {
        Self {
            thickness: h,
            base_width: w_base,
            tip_width: w_tip,
            length: l,
            bend_radius: None,
        }
    }

    /// A rectangular plate bent along its length with signed radius `r`
    /// (`r > 0`: face A convex).
    pub fn curved(h: f64, w: f64, l: f64, r: f64) -> Self {
        Self {
            thickness: h,
            base_width: w,
            tip_width: w,
            length: l,
            bend_radius: Some(r),
        }
    }

    fn validate(&self) -> Result<(), InstrumentError> {
        for (what, value) in [
            ("thickness", self.thickness),
            ("base width", self.base_width),
            ("tip width", self.tip_width),
            ("length", self.length),
        ] {
            if !(value > 0.0 && value.is_finite()) {
                return Err(InstrumentError::NonPositive { what, value });
            }
        }
        if let Some(r) = self.bend_radius {
            if !r.is_finite()
                || r.abs() <= 0.5 * self.thickness
                || self.length / r.abs() > std::f64::consts::PI
            {
                return Err(InstrumentError::BadRadius {
                    radius: r,
                    length: self.length,
                    thickness: self.thickness,
                });
            }
        }
        Ok(())
    }

    /// Local width `w(s)`, m.
    pub fn width_at(&self, s: f64) -> f64 {
        self.base_width + (self.tip_width - self.base_width) * s / self.length
    }

    /// Mid-surface point `m(s, y)`, face-A normal `n(s)` and tangent `T(s)` in
    /// the instrument frame.
    pub fn frame_at(&self, s: f64, y: f64) -> (Point3<f64>, Vector3<f64>, Vector3<f64>) {
        match self.bend_radius {
            None => (Point3::new(0.0, y, s), Vector3::x(), Vector3::z()),
            Some(r) => {
                let (sin, cos) = (s / r).sin_cos();
                (
                    Point3::new(-r * (1.0 - cos), y, r * sin),
                    Vector3::new(cos, 0.0, sin),
                    Vector3::new(-sin, 0.0, cos),
                )
            }
        }
    }

    /// The plate's closed outward surface in the instrument frame (m), for
    /// clients that draw the real tool: the two faces, the two side edges,
    /// the base and the tip, over `n` rings along the length (one for a
    /// flat plate, whose faces are planar; a chord angle of at most
    /// [`Self::OUTLINE_CHORD_RAD`] for a curved one, so that the drawn faces
    /// lie within `R (1 - cos(a/2)) <= 0.3 %` of `R` of the true ones).
    /// Ring `i` at `s_i = i L / n` has its corners in the order face A at
    /// `-w/2`, face A at `+w/2`, face B at `+w/2`, face B at `-w/2`
    /// (counter-clockwise about the tangent), so that `4 (n + 1)` vertices
    /// and `8 n + 4` triangles close the plate with outward normals (right-
    /// hand rule).
    pub fn outline(&self) -> (Vec<Point3<f64>>, Vec<[u32; 3]>) {
        let n = match self.bend_radius {
            None => 1,
            Some(r) => ((self.length / r.abs()) / Self::OUTLINE_CHORD_RAD)
                .ceil()
                .clamp(1.0, 256.0) as usize,
        };
        let h2 = 0.5 * self.thickness;
        let mut positions = Vec::with_capacity(4 * (n + 1));
        for i in 0..=n {
            let s = self.length * i as f64 / n as f64;
            let w2 = 0.5 * self.width_at(s);
            for (y, side) in [(-w2, h2), (w2, h2), (w2, -h2), (-w2, -h2)] {
                let (m, normal, _) = self.frame_at(s, y);
                positions.push(m + side * normal);
            }
        }
        let mut triangles = Vec::with_capacity(8 * n + 4);
        let corner = |ring: usize, j: usize| (4 * ring + j % 4) as u32;
        for i in 0..n {
            for j in 0..4 {
                let (p, q) = (corner(i, j), corner(i, j + 1));
                let (r, t) = (corner(i + 1, j + 1), corner(i + 1, j));
                triangles.push([p, q, r]);
                triangles.push([p, r, t]);
            }
        }
        // The base faces -T(0), the tip +T(L).
        triangles.push([corner(0, 0), corner(0, 2), corner(0, 1)]);
        triangles.push([corner(0, 0), corner(0, 3), corner(0, 2)]);
        triangles.push([corner(n, 0), corner(n, 1), corner(n, 2)]);
        triangles.push([corner(n, 0), corner(n, 2), corner(n, 3)]);
        (positions, triangles)
    }

    /// The largest bend angle between two rings of [`Self::outline`], rad.
    pub const OUTLINE_CHORD_RAD: f64 = 0.15;
}

/// The outline of a plate as a scene names it: its kind and the parameter
/// only that kind has (`shape` and `base_width_m` or `bend_radius_m` in a
/// scene file). The widths and lengths every plate has stay beside it.
///
/// This enum is the one description of the shapes a scene file reads: its
/// serde form is the `shape` tag with the variant's fields beside it
/// (`crate::scene` gathers them from the instrument's table), so a new
/// shape is a new variant here and its geometry below.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Deserialize)]
#[serde(tag = "shape", rename_all = "kebab-case", deny_unknown_fields)]
pub enum PlateShape {
    /// A flat rectangular plate.
    #[default]
    Flat,
    /// A flat plate whose width goes from `base_width_m` at the handle end to
    /// the plate's width at the tip.
    Trapezoid {
        /// Width at the handle end, m.
        base_width_m: f64,
    },
    /// A rectangular plate bent along its length.
    Curved {
        /// Signed bend radius, m (`> 0`: face A convex).
        bend_radius_m: f64,
    },
    /// A thin flat blade (micro-scissors, an arachnoid knife): it pushes
    /// the tissue as a flat plate does, and its tip edge cuts the ties it
    /// sweeps across ([`PlateShape::cutting_edge`], [`super::sweep`]).
    Blade,
}

impl PlateShape {
    /// The shape's name in scene files and in `InstrumentDescription.shape`.
    pub fn name(&self) -> &'static str {
        match self {
            Self::Flat => "flat",
            Self::Trapezoid { .. } => "trapezoid",
            Self::Curved { .. } => "curved",
            Self::Blade => "blade",
        }
    }

    /// The cutting edge of a plate of width `w` and length `l` (m), in the
    /// instrument frame: a blade's tip edge at mid-thickness, `(0, -w/2, l)`
    /// to `(0, w/2, l)`; `None` for shapes that do not cut.
    pub fn cutting_edge(&self, w: f64, l: f64) -> Option<[Point3<f64>; 2]> {
        match self {
            Self::Blade => Some([Point3::new(0.0, -0.5 * w, l), Point3::new(0.0, 0.5 * w, l)]),
            _ => None,
        }
    }

    /// The plate of this outline with thickness `h`, width `w` (at the tip
    /// for a trapezoid) and length `l`, m.
    pub fn plate(&self, h: f64, w: f64, l: f64) -> Plate {
        match *self {
            Self::Flat | Self::Blade => Plate::flat(h, w, l),
            Self::Trapezoid { base_width_m } => Plate::trapezoid(h, base_width_m, w, l),
            Self::Curved { bend_radius_m } => Plate::curved(h, w, l, bend_radius_m),
        }
    }
}

/// Where the face nodes sit, as a scene names it (`layout`); with a node
/// count it gives the [`NodeLayout`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LayoutKind {
    /// A grid over the whole face.
    #[default]
    WholeFace,
    /// A grid over the last [`TIP_FRACTION`] of the length.
    Tip,
}

/// The share of the plate's length, from the tip, that a `tip` layout
/// covers (the paper's tip-concentrated nodes).
pub const TIP_FRACTION: f64 = 0.3;

impl LayoutKind {
    /// The layout of `per_face` nodes a face.
    pub fn layout(self, per_face: usize) -> NodeLayout {
        match self {
            Self::WholeFace => NodeLayout::WholeFace { per_face },
            Self::Tip => NodeLayout::Tip {
                per_face,
                fraction: TIP_FRACTION,
            },
        }
    }
}

/// Where the face nodes go.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum NodeLayout {
    /// `per_face` nodes on a grid over the whole face (the paper: 150).
    WholeFace { per_face: usize },
    /// `per_face` nodes on a grid over the last `fraction` of the length, at the
    /// tip (the paper: 30).
    Tip { per_face: usize, fraction: f64 },
}

/// Rim nodes at mid-thickness (module documentation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RimNodes {
    /// Nodes on each side edge, evenly spread over the length.
    pub per_side: usize,
    /// Nodes across the tip edge (0 for none).
    pub tip: usize,
    /// Reach of the tip nodes, m.
    pub tip_reach: f64,
}

/// What a source node belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NodeKind {
    /// Face A (normal `+n`).
    FaceA,
    /// Face B (normal `-n`).
    FaceB,
    /// Side edge, `+y`.
    RimPlusY,
    /// Side edge, `-y`.
    RimMinusY,
    /// Tip edge.
    RimTip,
}

/// A source node in the instrument frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SourceNode {
    /// Position, m.
    pub position: Point3<f64>,
    /// Unit outward normal N_R of the face (or rim) it sits on.
    pub normal: Vector3<f64>,
    /// Which face or rim.
    pub kind: NodeKind,
    /// Index of the node on the same line across the plate, if any.
    pub partner: Option<u32>,
    /// Largest depth behind the node at which a pair may form, m.
    pub reach: f64,
}

/// A spatula: its plate and its source nodes (instrument frame).
#[derive(Debug, Clone, PartialEq)]
pub struct Instrument {
    /// The plate's shape.
    pub plate: Plate,
    /// Source nodes: face A nodes, then face B nodes (same order, partner of
    /// node `i < n` is `i + n`), then rim nodes.
    pub nodes: Vec<SourceNode>,
    /// Nodes per face.
    pub per_face: usize,
}

/// The factor pair `(along, across)` of `n` whose ratio best matches
/// `length / width`.
fn grid_for(n: usize, length: f64, width: f64) -> (usize, usize) {
    let target = (length / width).ln();
    (1..=n)
        .filter(|a| n % a == 0)
        .map(|a| (a, n / a))
        .min_by(|x, y| {
            let ex = ((x.0 as f64 / x.1 as f64).ln() - target).abs();
            let ey = ((y.0 as f64 / y.1 as f64).ln() - target).abs();
            ex.total_cmp(&ey)
        })
        .unwrap_or((n, 1))
}

impl Instrument {
    /// Builds the source nodes of `plate` with the face layout `layout` and
    /// optional rim nodes.
    pub fn new(
        plate: Plate,
        layout: NodeLayout,
        rim: Option<RimNodes>,
    ) -> Result<Self, InstrumentError> {
        plate.validate()?;
        let (per_face, s0) = match layout {
            NodeLayout::WholeFace { per_face } => (per_face, 0.0),
            NodeLayout::Tip { per_face, fraction } => {
                if !(fraction > 0.0 && fraction <= 1.0) {
                    return Err(InstrumentError::BadFraction(fraction));
                }
                (per_face, plate.length * (1.0 - fraction))
            }
        };
        if per_face == 0 {
            return Err(InstrumentError::ZeroCount {
                what: "nodes per face",
            });
        }
        let span = plate.length - s0;
        let mean_width = plate.width_at(0.5 * (s0 + plate.length));
        let (along, across) = grid_for(per_face, span, mean_width);
        let h2 = 0.5 * plate.thickness;
        let mut face = Vec::with_capacity(per_face);
        for k in 0..along {
            let s = s0 + span * (k as f64 + 0.5) / along as f64;
            let w = plate.width_at(s);
            for j in 0..across {
                let y = w * ((j as f64 + 0.5) / across as f64 - 0.5);
                face.push(plate.frame_at(s, y));
            }
        }
        let n = per_face as u32;
        let mut nodes = Vec::with_capacity(2 * per_face);
        for (i, (m, nrm, _)) in face.iter().enumerate() {
            nodes.push(SourceNode {
                position: m + nrm * h2,
                normal: *nrm,
                kind: NodeKind::FaceA,
                partner: Some(i as u32 + n),
                reach: f64::INFINITY,
            });
        }
        for (i, (m, nrm, _)) in face.iter().enumerate() {
            nodes.push(SourceNode {
                position: m - nrm * h2,
                normal: -nrm,
                kind: NodeKind::FaceB,
                partner: Some(i as u32),
                reach: f64::INFINITY,
            });
        }
        if let Some(rim) = rim {
            if rim.tip_reach.is_nan() || rim.tip_reach <= 0.0 {
                return Err(InstrumentError::NonPositive {
                    what: "tip reach",
                    value: rim.tip_reach,
                });
            }
            let first = nodes.len() as u32;
            let ps = rim.per_side as u32;
            for (sign, kind) in [(1.0, NodeKind::RimPlusY), (-1.0, NodeKind::RimMinusY)] {
                for k in 0..rim.per_side {
                    let s = plate.length * (k as f64 + 0.5) / rim.per_side as f64;
                    let w = plate.width_at(s);
                    let (m, _, _) = plate.frame_at(s, sign * 0.5 * w);
                    let partner = if sign > 0.0 {
                        first + ps + k as u32
                    } else {
                        first + k as u32
                    };
                    nodes.push(SourceNode {
                        position: m,
                        normal: Vector3::y() * sign,
                        kind,
                        partner: Some(partner),
                        reach: 0.5 * w,
                    });
                }
            }
            let w = plate.tip_width;
            for j in 0..rim.tip {
                let y = w * ((j as f64 + 0.5) / rim.tip as f64 - 0.5);
                let (m, _, t) = plate.frame_at(plate.length, y);
                nodes.push(SourceNode {
                    position: m,
                    normal: t,
                    kind: NodeKind::RimTip,
                    partner: None,
                    reach: rim.tip_reach,
                });
            }
        }
        Ok(Self {
            plate,
            nodes,
            per_face,
        })
    }

    /// Caps every node's reach at `max_m` (the scenes'
    /// `collision.max_depth_m`): no pair forms with a triangle farther
    /// behind a face than that.
    pub fn cap_reach(&mut self, max_m: f64) {
        for node in &mut self.nodes {
            node.reach = node.reach.min(max_m);
        }
    }

    /// Number of source nodes.
    pub fn len(&self) -> usize {
        self.nodes.len()
    }

    /// `true` when the instrument has no source nodes (never, once built).
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    /// Appends the scene-frame source-node rays under `pose`: origins (m) and
    /// unit directions (the face normals N_R).
    pub fn place(
        &self,
        pose: &Isometry3<f64>,
        origins: &mut Vec<Point3<f64>>,
        dirs: &mut Vec<Vector3<f64>>,
    ) {
        origins.extend(self.nodes.iter().map(|n| pose * n.position));
        dirs.extend(self.nodes.iter().map(|n| pose * n.normal));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    /// Volume of a closed outward-oriented triangle mesh (divergence
    /// theorem: the sum of the signed tetrahedra to the origin), m^3.
    fn enclosed_volume(p: &[Point3<f64>], t: &[[u32; 3]]) -> f64 {
        t.iter()
            .map(|f| {
                let [a, b, c] = f.map(|i| p[i as usize].coords);
                a.dot(&b.cross(&c)) / 6.0
            })
            .sum()
    }

    /// A plate's drawn outline is a closed, consistently oriented surface
    /// (every edge used once in each direction) enclosing the plate's
    /// volume: exactly `h w l` (flat), `h (w_base + w_tip) / 2 l`
    /// (trapezoid), and for a bent plate `h w l` less the chords' sag,
    /// `1 - sin(a) / a <= a^2 / 6` of it for ring angle `a`.
    #[test]
    fn the_outline_of_every_plate_is_closed_and_encloses_its_volume() {
        let (h, w, l) = (0.002, 0.01, 0.05);
        let cases = [
            (Plate::flat(h, w, l), h * w * l, 1e-12),
            (
                Plate::trapezoid(h, 0.004, w, l),
                h * 0.5 * (0.004 + w) * l,
                1e-12,
            ),
            (
                Plate::curved(h, w, l, 0.04),
                h * w * l,
                0.15f64.powi(2) / 6.0,
            ),
            (
                Plate::curved(h, w, l, -0.04),
                h * w * l,
                0.15f64.powi(2) / 6.0,
            ),
        ];
        for (plate, volume, rel) in cases {
            let (p, t) = plate.outline();
            let mut edges = std::collections::HashMap::new();
            for f in &t {
                for k in 0..3 {
                    *edges.entry((f[k], f[(k + 1) % 3])).or_insert(0) += 1;
                }
            }
            for (&(a, b), &count) in &edges {
                assert_eq!(count, 1, "{plate:?}: edge {a}-{b} used {count} times");
                assert_eq!(
                    edges.get(&(b, a)),
                    Some(&1),
                    "{plate:?}: edge {a}-{b} is open"
                );
            }
            let v = enclosed_volume(&p, &t);
            assert!(
                v > 0.0 && ((v - volume) / volume).abs() <= rel,
                "{plate:?}: volume {v:e} m^3, expected {volume:e}"
            );
        }
    }

    /// The outline's tip ring holds the blade's cutting edge: the edge's
    /// ends are the midpoints of the tip's two side edges.
    #[test]
    fn a_blades_cutting_edge_lies_on_its_outlines_tip() {
        let (h, w, l) = (0.0005, 0.003, 0.04);
        let (p, _) = PlateShape::Blade.plate(h, w, l).outline();
        let edge = PlateShape::Blade.cutting_edge(w, l).unwrap();
        let tip = &p[p.len() - 4..];
        let left = nalgebra::center(&tip[0], &tip[3]);
        let right = nalgebra::center(&tip[1], &tip[2]);
        assert!((left - edge[0]).norm() < 1e-15 && (right - edge[1]).norm() < 1e-15);
    }

    fn check_pairing(inst: &Instrument) {
        for (i, n) in inst.nodes.iter().enumerate() {
            assert!((n.normal.norm() - 1.0).abs() < 1e-14);
            let Some(p) = n.partner else { continue };
            let m = &inst.nodes[p as usize];
            assert_eq!(m.partner, Some(i as u32), "partner of partner");
            // Opposite normals, and the segment between them is along the normal.
            assert!((n.normal + m.normal).norm() < 1e-14, "node {i}");
            let d = m.position - n.position;
            assert!(
                d.cross(&n.normal).norm() < 1e-14 * (1.0 + d.norm()),
                "node {i} off line"
            );
            assert!(d.dot(&n.normal) < 0.0, "partner lies behind node {i}");
        }
    }

    #[test]
    fn flat_whole_face_grid_and_pairing() {
        let inst = Instrument::new(
            Plate::flat(1e-3, 0.01, 0.03),
            NodeLayout::WholeFace { per_face: 150 },
            None,
        )
        .unwrap();
        assert_eq!(inst.len(), 300);
        check_pairing(&inst);
        for n in &inst.nodes[..150] {
            assert!((n.position.x - 5e-4).abs() < 1e-15);
            assert!(n.position.y.abs() < 0.005 && n.position.z > 0.0 && n.position.z < 0.03);
        }
        for n in &inst.nodes[150..] {
            assert!((n.position.x + 5e-4).abs() < 1e-15);
            assert_eq!(n.normal, -Vector3::x());
        }
    }

    #[test]
    fn tip_layout_is_at_the_tip() {
        let inst = Instrument::new(
            Plate::flat(1e-3, 0.01, 0.03),
            NodeLayout::Tip {
                per_face: 30,
                fraction: 0.2,
            },
            None,
        )
        .unwrap();
        assert_eq!(inst.len(), 60);
        check_pairing(&inst);
        assert!(
            inst.nodes
                .iter()
                .all(|n| n.position.z > 0.024 && n.position.z < 0.03)
        );
    }

    #[test]
    fn trapezoid_and_curved_keep_the_pairing_rule() {
        let rim = Some(RimNodes {
            per_side: 10,
            tip: 5,
            tip_reach: 2e-3,
        });
        let trap = Instrument::new(
            Plate::trapezoid(1e-3, 0.012, 0.006, 0.04),
            NodeLayout::WholeFace { per_face: 150 },
            rim,
        )
        .unwrap();
        check_pairing(&trap);
        // Nodes stay inside the tapering outline.
        for n in &trap.nodes {
            let w = trap.plate.width_at(n.position.z);
            assert!(n.position.y.abs() <= 0.5 * w + 1e-15);
        }
        for r in [0.05, -0.05] {
            let curved = Instrument::new(
                Plate::curved(1e-3, 0.01, 0.04, r),
                NodeLayout::WholeFace { per_face: 150 },
                rim,
            )
            .unwrap();
            check_pairing(&curved);
            // Face nodes lie at distance |R -+ h/2| from the centre of curvature.
            let centre = Point3::new(-r, 0.0, 0.0);
            for n in &curved.nodes[..300] {
                let d = Vector3::new(n.position.x - centre.x, 0.0, n.position.z - centre.z).norm();
                let expect = if n.kind == NodeKind::FaceA {
                    r.abs() + 0.5e-3 * r.signum()
                } else {
                    r.abs() - 0.5e-3 * r.signum()
                };
                assert!((d - expect).abs() < 1e-12, "{d} {expect}");
            }
        }
    }

    #[test]
    fn rim_nodes_point_outward() {
        let inst = Instrument::new(
            Plate::flat(1e-3, 0.01, 0.03),
            NodeLayout::WholeFace { per_face: 30 },
            Some(RimNodes {
                per_side: 6,
                tip: 3,
                tip_reach: 1e-3,
            }),
        )
        .unwrap();
        assert_eq!(inst.len(), 60 + 12 + 3);
        for n in &inst.nodes[60..] {
            match n.kind {
                NodeKind::RimPlusY => {
                    assert!(n.normal.y == 1.0 && (n.position.y - 0.005).abs() < 1e-15)
                }
                NodeKind::RimMinusY => {
                    assert!(n.normal.y == -1.0 && (n.position.y + 0.005).abs() < 1e-15)
                }
                NodeKind::RimTip => assert!(n.normal.z == 1.0 && n.position.z == 0.03),
                k => panic!("unexpected {k:?}"),
            }
        }
    }

    #[test]
    fn bad_input_is_reported() {
        let l = NodeLayout::WholeFace { per_face: 10 };
        assert!(matches!(
            Instrument::new(Plate::flat(0.0, 0.01, 0.03), l, None),
            Err(InstrumentError::NonPositive {
                what: "thickness",
                ..
            })
        ));
        assert!(matches!(
            Instrument::new(Plate::curved(1e-3, 0.01, 0.03, 0.005), l, None),
            Err(InstrumentError::BadRadius { .. })
        ));
        assert!(matches!(
            Instrument::new(
                Plate::flat(1e-3, 0.01, 0.03),
                NodeLayout::WholeFace { per_face: 0 },
                None
            ),
            Err(InstrumentError::ZeroCount { .. })
        ));
        assert!(matches!(
            Instrument::new(
                Plate::flat(1e-3, 0.01, 0.03),
                NodeLayout::Tip {
                    per_face: 4,
                    fraction: 0.0
                },
                None
            ),
            Err(InstrumentError::BadFraction(_))
        ));
    }

    #[test]
    fn place_applies_the_pose() {
        let inst = Instrument::new(
            Plate::flat(1e-3, 0.01, 0.03),
            NodeLayout::WholeFace { per_face: 6 },
            None,
        )
        .unwrap();
        let pose = Isometry3::from_parts(
            Translation3::new(0.1, 0.2, 0.3),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), std::f64::consts::FRAC_PI_2),
        );
        let (mut o, mut d) = (Vec::new(), Vec::new());
        inst.place(&pose, &mut o, &mut d);
        assert_eq!(o.len(), 12);
        // Face A normal +x rotates to -z about y by +90 degrees.
        assert!((d[0] - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-15);
        assert!((o[0] - (pose * inst.nodes[0].position)).norm() < 1e-15);
    }
}
