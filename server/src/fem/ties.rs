//! Ties: elastic, tension-only links between two tissue nodes (the
//! arachnoid trabeculae and the bridging vessels that hold a fissure's
//! walls together), their rows in the contact problem, and their rupture.
//!
//! # The law
//! A tie joins volume nodes `a` and `b` with rest length `L0` (m, the wall
//! gap where it was seeded) and stiffness `k` (N/m). At current positions
//! `x_a`, `x_b` its length is `L = |x_b - x_a|`, its stretch `s = L - L0`
//! and its strain `e = s / L0`; it pulls both nodes towards each other along
//! `n = (x_b - x_a) / L` with the tension `T = k max(0, s)` (N) and carries
//! nothing while slack.
//!
//! # In the contact problem (why rows, not a stiffness change)
//! A tie is one row of the contact problem ([`super::contact`]) on both of
//! its nodes (weights `+1` at `a`, `-1` at `b`, direction `n`), unilateral,
//! with its own compliance `c = 1 / k` ([`ContactRow::compliance_m_per_n`]):
//! the row's gap is `g = -s + c T`, and `T >= 0`, `g >= 0`, `T g = 0` is
//! exactly `T = k max(0, s)`. [`TieRows::row`] writes the stretch at rest,
//! `s(u) = |X_b - X_a| - L0 + n . (u_b - u_a)` with `n` the rest direction:
//! the small-displacement theory of the linear strategies, so that a tie's
//! row is the same in every step and every force sample, and a sample
//! equals a full solve.
//!
//! # In the nonlinear strategies: springs of the energy
//! `corotational` and `neo-hookean` solve large rotations, where a row
//! written at rest would pull along a direction the walls have turned away
//! from; and their contact solve has no path for a row between two nodes
//! with its own compliance (they take no nodal loads). They hold the intact
//! ties as springs of their own energy instead ([`TieSprings`]: the true
//! length and direction at every iterate, energy `k max(0, s)^2 / 2`, the
//! material and geometric tangent), coupled in their sparsity pattern at
//! construction (each pair a pseudo-element, so the tangent goes through
//! their element assembly and elimination unchanged). Their local model for
//! the force loop is their tangent compliance, springs included, so a
//! sample is the linearization of the full problem about the last step, as
//! for their tissue; a blade's cut reaches them at the next step (there is
//! no tie row in their force loop to drop).
//!
//! The alternative, the ties' stiffness `sum k n n^T` added to `K` and the
//! cached compliance updated by the Woodbury identity as ties are cut,
//! would keep every tie in the operator whether slack or not: a slack tie
//! would push, and each change of the slack set would be a low-rank update
//! of every cached column. As rows, the compliance strategy stays
//! factor-once (its factor never sees a tie), the slack set is the contact
//! problem's own active set, the force loop solves the same problem at every
//! sample (a tie's row is on its two nodes, both in the patch), and cutting
//! a tie is dropping its row. Ties at the same node pair (a wall vertex and
//! its facing vertex) are one row with the sum of their stiffnesses
//! ([`TieRows`]); the tension of each follows from the row's stretch.
//!
//! # Rupture
//! A tie breaks when its strain or its tension (its kind's criterion)
//! reaches the criterion's value: [`Tie::breaks`], judged on its true
//! length at the solved shape (`sim::core::engine::ties`). Units: m, N, N/m.

// Negated comparisons are deliberate: NaN must fail the checks.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::contact::ContactRow;
use super::lcp::RowKind;
use nalgebra::{Point3, Vector3};

/// What a tie is made of.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TieKind {
    /// An arachnoid trabecula: many, weak; cutting them is the step.
    Trabecula,
    /// A bridging vessel: few, stronger; tearing one is an injury.
    Vessel,
}

impl TieKind {
    /// Every kind.
    pub const ALL: [TieKind; 2] = [TieKind::Trabecula, TieKind::Vessel];

    /// The kind's name as in scene files.
    pub fn name(self) -> &'static str {
        match self {
            TieKind::Trabecula => "trabecula",
            TieKind::Vessel => "vessel",
        }
    }
}

/// When a tie breaks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Rupture {
    /// At this strain `(L - L0) / L0` (> 0).
    Strain(f64),
    /// At this tension, N (> 0).
    Force(f64),
}

/// One tie (module documentation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tie {
    /// What it is.
    pub kind: TieKind,
    /// Its two volume nodes (distinct, neither fixed).
    pub a: u32,
    /// The second node.
    pub b: u32,
    /// Rest length `L0`, m (> 0).
    pub rest_length_m: f64,
    /// Stiffness `k`, N/m (> 0).
    pub stiffness_n_per_m: f64,
    /// Its rupture criterion.
    pub rupture: Rupture,
}

impl Tie {
    /// The tension at stretch `stretch_m` (m): `k max(0, s)`, N.
    #[inline]
    pub fn tension_n(&self, stretch_m: f64) -> f64 {
        self.stiffness_n_per_m * stretch_m.max(0.0)
    }

    /// The strain at stretch `stretch_m`: `s / L0`.
    #[inline]
    pub fn strain(&self, stretch_m: f64) -> f64 {
        stretch_m / self.rest_length_m
    }

    /// Whether the tie breaks at stretch `stretch_m` (m): its strain or its
    /// tension reaches the criterion. A non-finite stretch breaks it.
    pub fn breaks(&self, stretch_m: f64) -> bool {
        if !stretch_m.is_finite() {
            return true;
        }
        match self.rupture {
            Rupture::Strain(e) => self.strain(stretch_m) >= e,
            Rupture::Force(f) => self.tension_n(stretch_m) >= f,
        }
    }

    /// Its length at node positions `x`, m.
    pub fn length_m(&self, x: impl Fn(u32) -> Point3<f64>) -> f64 {
        (x(self.b) - x(self.a)).norm()
    }
}

/// What has become of a tie.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TieState {
    /// It holds.
    #[default]
    Intact,
    /// An instrument cut it.
    Cut,
    /// It broke under tension.
    Torn,
}

/// The rows of a set of ties: one per node pair with an intact tie.
#[derive(Debug, Clone, Default)]
pub struct TieRows {
    /// Per row: its node pair `(a, b)`, the sum of its intact ties'
    /// stiffnesses (N/m) and the rest length (m).
    pub pairs: Vec<TiePair>,
    /// Per tie: its row (`u32::MAX`: broken, no row).
    pub row_of: Vec<u32>,
}

/// One node pair's row.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TiePair {
    /// The first of its ties (the lowest index).
    pub first_tie: u32,
    /// Its nodes.
    pub a: u32,
    /// The second node.
    pub b: u32,
    /// Rest length, m.
    pub rest_length_m: f64,
    /// Sum of the intact ties' stiffnesses, N/m.
    pub stiffness_n_per_m: f64,
}

impl TieRows {
    /// Groups the intact ties by node pair (in order of first appearance,
    /// so the rows are a function of the ties alone).
    pub fn group(ties: &[Tie], states: &[TieState]) -> Self {
        let mut index = std::collections::HashMap::new();
        let mut pairs: Vec<TiePair> = Vec::new();
        let mut row_of = vec![u32::MAX; ties.len()];
        for (i, t) in ties.iter().enumerate() {
            if states.get(i).copied().unwrap_or_default() != TieState::Intact {
                continue;
            }
            let key = (t.a.min(t.b), t.a.max(t.b));
            let r = *index.entry(key).or_insert_with(|| {
                pairs.push(TiePair {
                    first_tie: i as u32,
                    a: t.a,
                    b: t.b,
                    rest_length_m: t.rest_length_m,
                    stiffness_n_per_m: 0.0,
                });
                pairs.len() as u32 - 1
            });
            pairs[r as usize].stiffness_n_per_m += t.stiffness_n_per_m;
            row_of[i] = r;
        }
        Self { pairs, row_of }
    }

    /// The rows of every tie intact: the pairs a strategy declares at
    /// construction ([`super::SolverOptions::tie_pairs`]), whose order
    /// indexes [`TieSprings`]'s pairs.
    pub fn all(ties: &[Tie]) -> Self {
        Self::group(ties, &vec![TieState::Intact; ties.len()])
    }

    /// The contact row of pair `p`, written at rest (module
    /// documentation).
    pub fn row(&self, p: usize, rest: &[Point3<f64>]) -> ContactRow {
        let pair = &self.pairs[p];
        let d = rest[pair.b as usize] - rest[pair.a as usize];
        let len = d.norm();
        // Coincident nodes cannot be placed (L0 > 0); pull along z then.
        let n = if len > 0.0 { d / len } else { Vector3::z() };
        ContactRow::between(
            pair.a,
            pair.b,
            n,
            pair.rest_length_m - len,
            RowKind::Unilateral,
            1.0 / pair.stiffness_n_per_m,
        )
    }
}

/// The intact ties as springs of a nonlinear strategy's own energy
/// (`corotational`, `neo-hookean`): the law of the module documentation at
/// the current shape, not its small-displacement row.
///
/// With `d = (X_b - X_a) + (u_b - u_a)`, `L = |d|`, `n = d / L` and the
/// stretch `s = L - L0`, a stretched pair (`s > 0`) stores the energy
/// `k s^2 / 2` (J), adds the internal force `dE/du_b = T n = -dE/du_a`
/// (N, `T = k s`) and the tangent block
/// `K_bb = K_aa = -K_ab = k n n^T + (T / L) (I - n n^T)` (N/m: the
/// material part along the tie and the geometric part across it, both
/// positive semi-definite); a slack pair carries nothing. Pairs are the
/// [`TieRows`] grouping (one per node pair, stiffnesses summed), each with
/// its index among the pairs the strategy coupled in its sparsity pattern
/// at construction ([`super::SolverOptions::tie_pairs`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TieSprings {
    /// The intact pairs and their index among the declared ones.
    pub pairs: Vec<(usize, TiePair)>,
}

/// What one spring does at a displacement: its direction, length (m),
/// tension (N) and tangent block `K_aa` (N/m); `None` while slack.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpringState {
    /// Unit direction from `a` to `b`.
    pub n: Vector3<f64>,
    /// Tension `k max(0, s)`, N.
    pub tension_n: f64,
    /// `K_aa = k n n^T + (T / L) (I - n n^T)`, N/m.
    pub block: nalgebra::Matrix3<f64>,
}

impl TieSprings {
    /// The state of pair `p` at displacement `u` (DOF vector, m) over rest
    /// positions `rest` (m).
    pub fn state(p: &TiePair, rest: &[Point3<f64>], u: &[f64]) -> Option<SpringState> {
        let (a, b) = (p.a as usize, p.b as usize);
        let du = Vector3::new(
            u[3 * b] - u[3 * a],
            u[3 * b + 1] - u[3 * a + 1],
            u[3 * b + 2] - u[3 * a + 2],
        );
        let d = (rest[b] - rest[a]) + du;
        let len = d.norm();
        let s = len - p.rest_length_m;
        if !(s > 0.0 && len > 0.0) {
            return None;
        }
        let n = d / len;
        let k = p.stiffness_n_per_m;
        let tension_n = k * s;
        let nn = n * n.transpose();
        let block = k * nn + (tension_n / len) * (nalgebra::Matrix3::identity() - nn);
        Some(SpringState {
            n,
            tension_n,
            block,
        })
    }

    /// Their energy at `u`, J.
    pub fn energy(&self, rest: &[Point3<f64>], u: &[f64]) -> f64 {
        self.pairs
            .iter()
            .filter_map(|(_, p)| {
                Self::state(p, rest, u).map(|s| 0.5 * s.tension_n.powi(2) / p.stiffness_n_per_m)
            })
            .sum()
    }

    /// Adds their internal force at `u` (N, DOF vector) to `f`.
    pub fn add_forces(&self, rest: &[Point3<f64>], u: &[f64], f: &mut [f64]) {
        for (_, p) in &self.pairs {
            if let Some(st) = Self::state(p, rest, u) {
                let t = st.tension_n * st.n;
                for i in 0..3 {
                    f[3 * p.a as usize + i] -= t[i];
                    f[3 * p.b as usize + i] += t[i];
                }
            }
        }
    }

    /// Adds their tangent at `u` times `x` to `y` (DOF vectors).
    pub fn add_product(&self, rest: &[Point3<f64>], u: &[f64], x: &[f64], y: &mut [f64]) {
        for (_, p) in &self.pairs {
            if let Some(st) = Self::state(p, rest, u) {
                let (a, b) = (3 * p.a as usize, 3 * p.b as usize);
                let dx = Vector3::new(x[b] - x[a], x[b + 1] - x[a + 1], x[b + 2] - x[a + 2]);
                let q = st.block * dx;
                for i in 0..3 {
                    y[a + i] -= q[i];
                    y[b + i] += q[i];
                }
            }
        }
    }

    /// Their tangent blocks at `u` as pseudo-elements on the nodes
    /// `[a, b, a, b]` (the `[a, b]` blocks of a 12 x 12 element matrix,
    /// zero elsewhere), each with its declared index, for assembly through
    /// the element path ([`super::assembly::Pattern::with_pairs`]).
    pub fn elements<'a>(
        &'a self,
        rest: &'a [Point3<f64>],
        u: &'a [f64],
    ) -> impl Iterator<Item = (usize, [u32; 4], super::element::ElementMatrix)> + 'a {
        self.pairs.iter().filter_map(move |(i, p)| {
            let st = Self::state(p, rest, u)?;
            let mut k = super::element::ElementMatrix::zeros();
            for (r, c, sign) in [(0, 0, 1.0), (3, 3, 1.0), (0, 3, -1.0), (3, 0, -1.0)] {
                k.fixed_view_mut::<3, 3>(r, c).copy_from(&(sign * st.block));
            }
            Some((*i, [p.a, p.b, p.a, p.b], k))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tie(a: u32, b: u32, k: f64, rupture: Rupture) -> Tie {
        Tie {
            kind: TieKind::Trabecula,
            a,
            b,
            rest_length_m: 0.002,
            stiffness_n_per_m: k,
            rupture,
        }
    }

    #[test]
    fn tension_is_k_times_stretch_and_zero_when_slack() {
        let t = tie(0, 1, 5.0, Rupture::Strain(1.0));
        assert_eq!(t.tension_n(0.001), 5.0 * 0.001);
        assert_eq!(t.tension_n(-0.001), 0.0);
        assert_eq!(t.strain(0.001), 0.5);
    }

    #[test]
    fn a_tie_breaks_at_its_criterion_not_before() {
        let by_strain = tie(0, 1, 5.0, Rupture::Strain(0.5));
        assert!(!by_strain.breaks(0.000_999_999));
        assert!(by_strain.breaks(0.001));
        let by_force = tie(0, 1, 5.0, Rupture::Force(0.01));
        assert!(!by_force.breaks(0.001_999_99));
        assert!(by_force.breaks(0.002));
        assert!(by_force.breaks(f64::NAN));
    }

    #[test]
    fn ties_on_one_pair_share_a_row_with_summed_stiffness() {
        let ties = [
            tie(3, 7, 2.0, Rupture::Strain(1.0)),
            tie(7, 3, 3.0, Rupture::Strain(1.0)),
            tie(3, 8, 1.0, Rupture::Strain(1.0)),
        ];
        let rows = TieRows::group(&ties, &[TieState::Intact; 3]);
        assert_eq!(rows.pairs.len(), 2);
        assert_eq!(rows.pairs[0].stiffness_n_per_m, 5.0);
        assert_eq!(rows.row_of, vec![0, 0, 1]);
        let cut = TieRows::group(&ties, &[TieState::Intact, TieState::Cut, TieState::Intact]);
        assert_eq!(cut.pairs[0].stiffness_n_per_m, 2.0);
        assert_eq!(cut.row_of[1], u32::MAX);
    }

    #[test]
    fn a_row_at_rest_has_zero_free_gap_and_points_from_a_to_b() {
        let rest = [Point3::new(0.0, 0.0, 0.0), Point3::new(0.0, 0.0, 0.002)];
        let rows = TieRows::group(&[tie(0, 1, 4.0, Rupture::Strain(1.0))], &[TieState::Intact]);
        let r = rows.row(0, &rest);
        assert!(r.gap_free_m.abs() < 1e-18);
        assert_eq!(r.dir, Vector3::z());
        assert_eq!(r.compliance_m_per_n, 0.25);
        // Pulled apart by 1 mm along the tie: the gap is minus the stretch.
        let u = [
            Vector3::new(0.0, 0.0, -0.0005),
            Vector3::new(0.0, 0.0, 0.0005),
        ];
        let g = r.gap_free_m + r.normal_motion(&u);
        assert!((g + 0.001).abs() < 1e-15, "gap {g}");
    }
}
