//! Dense solvers of the contact problem on the Delassus operator
//! (DESIGN.md section 3b): given `n` rows with the compliance operator
//! `W = H C H^T` (`n x n`, m/N, symmetric positive semi-definite), the free
//! gaps `q` (m) and a kind per row, find the multipliers `lambda` (N, the
//! force a row applies to the tissue along its direction) with the gaps
//! `g = q + W lambda` (m) such that
//!
//! * **unilateral** rows (Signorini): `lambda >= 0`, `g >= 0`, `lambda g = 0`;
//! * **bilateral** rows: `g = 0`, `lambda` of either sign;
//! * **tangent** rows (two per frictional contact, of one unilateral normal
//!   row `n`, Coulomb coefficient `mu`): `|lambda_t| <= mu lambda_n`; inside
//!   the cone the contact sticks (`g_t = 0`), on its boundary it slips.
//!
//! # Without friction: an active-set method
//! The conditions are the KKT conditions of the convex quadratic program
//! `min 1/2 lambda^T W lambda + q^T lambda` subject to `lambda_U >= 0`, solved
//! by the primal active-set method for bounds (Nocedal & Wright,
//! *Numerical Optimization*, algorithm 16.3): a working set `F` of rows whose
//! multiplier is free (every bilateral row and the unilateral rows in
//! contact) and the rest held at zero. Each iteration solves
//! `W_FF lambda_F = -q_F`; a multiplier that would turn negative stops the
//! step and leaves `F` (ratio test); at a stationary point the most negative
//! gap of a row held at zero enters `F`; when no gap is negative the answer
//! is exact. Ties go to the smallest row index (Bland's rule), so the method
//! cannot cycle and the answer is a function of the inputs alone.
//!
//! The Cholesky factor `L L^T = W_FF` is kept across calls and updated one
//! row at a time: a row enters with one forward solve (`O(|F|^2)`), a row
//! leaves with a rank-one update of the trailing block (Golub & Van Loan,
//! *Matrix Computations*, section 6.5.4). A caller that changes rows of `W`
//! between calls says which ([`ContactSolver::changed`]); their rows leave
//! the factor and re-enter with their new entries. Warm-started from the
//! last answer with the same contact set, a call is one pair of triangular
//! solves and one product with the rows held at zero. A row whose
//! direction is (nearly) a combination of the rows already in `F` (a
//! vertex held twice) enters with its pivot raised to `1e-10 W_jj`:
//! it behaves as a contact `1e-10` times softer than the tissue under it.
//!
//! # With friction: projected block Gauss-Seidel
//! Rows are swept contact by contact (the normal row with its two tangent
//! rows; bilateral and frictionless rows alone), each solved with the
//! others held: `lambda_n = max(0, -(b_n + W_nt lambda_t) / W_nn)`, the stick
//! trial `lambda_t = -W_tt^-1 (b_t + W_tn lambda_n)` projected radially onto
//! the disc `|lambda_t| <= mu lambda_n` (Jourdan, Alart & Jean 1998; Duriez
//! et al. 2006 use it at haptic rates). Sweeps stop when no multiplier moves
//! by more than `1e-10` of the largest, when the iterate meets the
//! conditions (tested every 25 sweeps once no multiplier moves by more than
//! `1e-6` of the largest), or at the sweep limit; either way the answer is
//! checked. On rows that depend on each other (a vertex and
//! points of its triangles, neighbours under one plate) the sweeps often
//! find which contacts are closed, stick and slip long before their
//! multipliers settle: after 25, 100, 400, ... sweeps the iterate is
//! polished, an active-set pass over those states with each state's
//! conditions solved exactly as one linear system (closed rows `g = 0`,
//! sticking contacts `g_t = 0`, slipping ones `lambda_t = mu lambda_n d`),
//! in the spirit of Alart & Curnier's 1991 generalized Newton method, and
//! taken when the states hold. Where the split of the force among
//! dependent rows is itself ill-conditioned the states do not settle, the
//! split drifts at about `1e-10` of the force while the gaps hold, and the
//! test of the conditions ends the sweeps.
//!
//! # Why hand-written
//! faer factors dense matrices but has no row up- and down-dates of a
//! Cholesky factor; the problems have tens to a few hundred rows; and the
//! force loop needs a warm start that keeps the factor from one sample to
//! the next without allocating. Every answer is checked
//! ([`ContactSolver::solve`] fails rather than return one that violates the
//! conditions beyond the tolerances), and nothing non-finite is returned.

// Negated comparisons are deliberate: NaN must fail the checks.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

/// What a row constrains.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum RowKind {
    /// An unused slot (its multiplier is zero and it takes no part).
    #[default]
    Off,
    /// A unilateral (Signorini) row: `lambda >= 0`, `g >= 0`, `lambda g = 0`.
    Unilateral,
    /// A bilateral row: `g = 0`.
    Bilateral,
    /// A tangent row of a frictional contact: `normal` is the index of its
    /// unilateral normal row, `mu` the Coulomb coefficient (>= 0). A contact
    /// has exactly two tangent rows, orthogonal to each other and to the
    /// normal.
    Tangent { normal: u32, mu: f64 },
}

/// Tolerances of one solve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tolerances {
    /// Largest violation of a gap condition accepted (`g >= -tol` for
    /// unilateral rows, `|g| <= tol` for bilateral and sticking tangent
    /// rows), m.
    pub gap_m: f64,
    /// Largest relative change of the multipliers over a Gauss-Seidel sweep
    /// at convergence (friction only).
    pub sweep_rel: f64,
    /// Most iterations (active-set changes, or sweeps with friction).
    pub max_iterations: u32,
}

impl Tolerances {
    /// Tolerances for free gaps `q` (m): `gap_m = 1e-12 m + 1e-6 max|q|`
    /// (5 nm for a row 5 mm deep: far below any modelled length, and above
    /// the rounding of `W lambda` on the regularized operator, whose
    /// condition number reaches `1 / REGULARIZATION` = 1e9 when rows depend
    /// on each other: gap errors of 1e-7 max|q| were measured on the
    /// sylvian phantom's contact sets, and a tighter tolerance made the
    /// active set chase rounding), sweeps to `1e-10`, at most `4 n + 100`
    /// active-set changes or 5000 sweeps.
    pub fn for_gaps(q: &[f64], kinds: &[RowKind]) -> Self {
        let scale = q
            .iter()
            .zip(kinds)
            .filter(|(_, k)| **k != RowKind::Off)
            .map(|(v, _)| v.abs())
            .fold(0.0, f64::max);
        let friction = kinds.iter().any(|k| matches!(k, RowKind::Tangent { .. }));
        Self {
            gap_m: 1e-12 + 1e-6 * scale,
            sweep_rel: 1e-10,
            max_iterations: if friction {
                5000
            } else {
                4 * q.len() as u32 + 100
            },
        }
    }
}

/// How a solve went.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Report {
    /// Active-set changes (frictionless) or sweeps (friction).
    pub iterations: u32,
    /// Rows with a non-zero multiplier.
    pub active: usize,
    /// Largest violation of a gap condition, m (0 when none is violated).
    pub max_gap_violation_m: f64,
    /// Largest `|lambda g|` of a unilateral row, N m.
    pub max_complementarity: f64,
    /// Largest excess of a tangential force over its cone, N.
    pub max_cone_excess_n: f64,
    /// Friction: the answer is the polish of the sweeps' iterate (an exact
    /// solve of the contact states they found), not the sweeps' own.
    pub polished: bool,
}

/// Why a solve failed; the caller keeps its last good state.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LcpError {
    /// Inconsistent sizes.
    #[error("contact problem: {0}")]
    Shape(String),
    /// A non-finite entry in `W`, `q` or the warm start.
    #[error("contact problem: non-finite {0}")]
    NonFinite(&'static str),
    /// A row with a non-positive diagonal of `W`.
    #[error("contact row {row} has compliance {value:e} m/N (must be positive)")]
    BadDiagonal { row: usize, value: f64 },
    /// No answer within the iteration limit.
    #[error(
        "contact problem did not converge in {iterations} iterations (largest gap violation {violation_m:e} m)"
    )]
    NotConverged { iterations: u32, violation_m: f64 },
    /// A bilateral row set that `W` cannot satisfy (dependent rows).
    #[error("contact rows are dependent (row {row}): the constraints contradict each other")]
    Dependent { row: usize },
}

const NONE: u32 = u32::MAX;

/// Pivot floor of a row entering the factor, relative to its diagonal.
const PIVOT_FLOOR: f64 = 1e-10;

/// Every row's compliance is raised by this share of itself: `W + REG
/// diag(W)`. A contact 1e-9 softer than the tissue under it changes no
/// answer beyond the tolerances, and makes the problem strictly convex
/// even when rows depend on each other (a triangle held at several points
/// and at its vertices): the answer is then one, whatever the warm start,
/// instead of a split among dependent rows that follows the path of the
/// iterations.
pub const REGULARIZATION: f64 = 1e-9;

/// A dense contact solver with its workspace: the Cholesky factor of the
/// last working set, kept across calls (no allocation once grown).
#[derive(Debug, Clone, Default)]
pub struct ContactSolver {
    /// `L`, row-major with stride `cap`: `l[i * cap + j]`, `j <= i`.
    l: Vec<f64>,
    cap: usize,
    /// Rows in the factor, in factor order.
    fac: Vec<usize>,
    /// Row -> position in `fac`, or NONE.
    pos: Vec<u32>,
    x: Vec<f64>,
    y: Vec<f64>,
    p: Vec<f64>,
    g: Vec<f64>,
    want: Vec<bool>,
    /// Friction: the blocks of the sweep.
    groups: Vec<Group>,
    /// Friction polish: the reduced system (row-major `m x m`), its
    /// right-hand side, pivots, the row of each unknown and, for a
    /// slipping contact's normal unknown, its tangent rows and `mu d`.
    lu: Vec<f64>,
    rhs: Vec<f64>,
    piv: Vec<usize>,
    unknown_rows: Vec<usize>,
    slip: Vec<Slip>,
    state: Vec<State>,
    flipped: Vec<u8>,
    /// Friction polish: the candidate answer and its gaps.
    cand: Vec<f64>,
    cand_g: Vec<f64>,
    /// Row stride of `W` in the current solve.
    stride: usize,
}

/// A slipping contact's tangential force in the polish: `lambda_t = (a1,
/// a2) lambda_n` on its tangent rows `t1`, `t2` (`a = mu d`, `d` the unit
/// slip direction); `t1 == usize::MAX` for an unknown of any other kind.
#[derive(Debug, Clone, Copy)]
struct Slip {
    t1: usize,
    t2: usize,
    a1: f64,
    a2: f64,
}

impl Slip {
    const NONE: Slip = Slip {
        t1: usize::MAX,
        t2: usize::MAX,
        a1: 0.0,
        a2: 0.0,
    };
}

/// Sweeps between two tests of the friction iterate against the conditions
/// (each costs about one sweep).
const CONDITIONS_EVERY: u32 = 25;

/// Largest multiplier change over a sweep, relative to the largest
/// multiplier, at which the friction iterate is tested against the
/// conditions.
const CONDITIONS_REL: f64 = 1e-6;

/// Sweeps after which the friction iterate is polished: 25, 100, 400, ...
/// (growing fourfold, so an iterate that will not polish costs a few LU factors in
/// all, not one per sweep).
const FIRST_POLISH_SWEEP: u32 = 25;

/// A block of the Gauss-Seidel sweep: one row, or a normal row with its
/// two tangent rows.
#[derive(Debug, Clone, Copy)]
struct Group {
    n: usize,
    t: Option<(usize, usize, f64)>,
}

impl ContactSolver {
    /// An empty solver.
    pub fn new() -> Self {
        Self::default()
    }

    /// Forgets the kept factor (every row of `W` changed).
    pub fn forget(&mut self) {
        for &r in &self.fac {
            if let Some(p) = self.pos.get_mut(r) {
                *p = NONE;
            }
        }
        self.fac.clear();
    }

    /// Row `row` of `W` (and its column) changed since the last call, or the
    /// row was replaced: it leaves the kept factor.
    pub fn changed(&mut self, row: usize) {
        if let Some(&p) = self.pos.get(row) {
            if p != NONE {
                self.remove(p as usize);
            }
        }
    }

    fn ensure(&mut self, n: usize) {
        if self.pos.len() < n {
            self.pos.resize(n, NONE);
        }
        if n > self.cap {
            let cap = n.max(2 * self.cap).max(8);
            let mut l = vec![0.0; cap * cap];
            let k = self.fac.len();
            for i in 0..k {
                l[i * cap..i * cap + i + 1]
                    .copy_from_slice(&self.l[i * self.cap..i * self.cap + i + 1]);
            }
            self.l = l;
            self.cap = cap;
        }
        for v in [&mut self.x, &mut self.y, &mut self.p, &mut self.g] {
            if v.len() < n {
                v.resize(n, 0.0);
            }
        }
        if self.want.len() < n {
            self.want.resize(n, false);
        }
    }

    /// Appends row `j` to the factor (`w` row-major `n x n`).
    fn append(&mut self, w: &[f64], j: usize) {
        let k = self.fac.len();
        let cap = self.cap;
        // Solve L y = W[F, j].
        for a in 0..k {
            let mut s = w[self.fac[a] * self.stride + j];
            let row = &self.l[a * cap..a * cap + a];
            for (b, lv) in row.iter().enumerate() {
                s -= lv * self.y[b];
            }
            self.y[a] = s / self.l[a * cap + a];
        }
        let wjj = w[j * self.stride + j] * (1.0 + REGULARIZATION);
        let mut d2 = wjj;
        for a in 0..k {
            d2 -= self.y[a] * self.y[a];
        }
        if !(d2 > PIVOT_FLOOR * wjj) {
            d2 = PIVOT_FLOOR * wjj;
        }
        let row = &mut self.l[k * cap..k * cap + k + 1];
        row[..k].copy_from_slice(&self.y[..k]);
        row[k] = d2.sqrt();
        self.fac.push(j);
        self.pos[j] = k as u32;
    }

    /// Removes the row at factor position `p`: the rows below lose their
    /// column `p` and the trailing block takes a rank-one update with it.
    fn remove(&mut self, p: usize) {
        let k = self.fac.len();
        let cap = self.cap;
        let r = self.fac[p];
        self.pos[r] = NONE;
        // x = column p below the diagonal.
        let m = k - p - 1;
        for i in 0..m {
            self.x[i] = self.l[(p + 1 + i) * cap + p];
        }
        // Shift rows p+1.. up by one and their columns p+1.. left by one.
        for i in p + 1..k {
            let (dst, src) = ((i - 1) * cap, i * cap);
            for j in 0..p {
                self.l[dst + j] = self.l[src + j];
            }
            for j in p + 1..=i {
                self.l[dst + j - 1] = self.l[src + j];
            }
        }
        // Rank-one update of the trailing m x m block (rows/cols p..k-1).
        for i in 0..m {
            let d = (p + i) * cap + p + i;
            let lii = self.l[d];
            let xi = self.x[i];
            let rr = lii.hypot(xi);
            let c = rr / lii;
            let s = xi / lii;
            self.l[d] = rr;
            for j in i + 1..m {
                let e = (p + j) * cap + p + i;
                let v = (self.l[e] + s * self.x[j]) / c;
                self.x[j] = c * self.x[j] - s * v;
                self.l[e] = v;
            }
        }
        self.fac.remove(p);
        for (a, &row) in self.fac.iter().enumerate().skip(p) {
            self.pos[row] = a as u32;
        }
    }

    /// Solves `W_FF x = b_F` in place on `self.x[..|F|]` (factor order).
    fn factor_solve(&mut self) {
        let k = self.fac.len();
        let cap = self.cap;
        for a in 0..k {
            let mut s = self.x[a];
            let row = &self.l[a * cap..a * cap + a];
            for (b, lv) in row.iter().enumerate() {
                s -= lv * self.x[b];
            }
            self.x[a] = s / self.l[a * cap + a];
        }
        for a in (0..k).rev() {
            let mut s = self.x[a];
            for b in a + 1..k {
                s -= self.l[b * cap + a] * self.x[b];
            }
            self.x[a] = s / self.l[a * cap + a];
        }
    }

    /// Solves the problem `(W, q, kinds)`: `w` holds `W` row-major with row
    /// stride `stride >= n` (`W[i][j] = w[i * stride + j]`; only rows and
    /// columns of rows that are not [`RowKind::Off`] are read),
    /// `lambda` the warm start on entry and the answer on return (N). Rows
    /// of `W` that changed since the last call must have been reported
    /// ([`Self::changed`]) or the factor forgotten ([`Self::forget`]).
    pub fn solve(
        &mut self,
        w: &[f64],
        stride: usize,
        n: usize,
        q: &[f64],
        kinds: &[RowKind],
        lambda: &mut [f64],
        tol: &Tolerances,
    ) -> Result<Report, LcpError> {
        if stride < n
            || w.len() < (n.max(1) - 1) * stride + n
            || q.len() != n
            || kinds.len() != n
            || lambda.len() != n
        {
            return Err(LcpError::Shape(format!(
                "{n} rows with W of {} entries (stride {stride}), {} gaps, {} kinds, {} multipliers",
                w.len(),
                q.len(),
                kinds.len(),
                lambda.len()
            )));
        }
        self.ensure(n);
        self.stride = stride;
        for i in 0..n {
            if kinds[i] == RowKind::Off {
                lambda[i] = 0.0;
                continue;
            }
            if !q[i].is_finite() {
                return Err(LcpError::NonFinite("free gap"));
            }
            if !lambda[i].is_finite() {
                lambda[i] = 0.0;
            }
            let d = w[i * self.stride + i];
            if !(d > 0.0 && d.is_finite()) {
                return Err(LcpError::BadDiagonal { row: i, value: d });
            }
            if let RowKind::Tangent { normal, mu } = kinds[i] {
                let ok = (normal as usize) < n
                    && kinds[normal as usize] == RowKind::Unilateral
                    && mu >= 0.0
                    && mu.is_finite();
                if !ok {
                    return Err(LcpError::Shape(format!(
                        "tangent row {i} names normal row {normal} (coefficient {mu})"
                    )));
                }
            }
        }
        for i in 0..n {
            for j in 0..n {
                if kinds[i] != RowKind::Off
                    && kinds[j] != RowKind::Off
                    && !w[i * self.stride + j].is_finite()
                {
                    return Err(LcpError::NonFinite("compliance"));
                }
            }
        }
        // A factor row whose kind went Off leaves.
        let mut a = 0;
        while a < self.fac.len() {
            let r = self.fac[a];
            if r >= n || kinds[r] == RowKind::Off {
                self.remove(a);
            } else {
                a += 1;
            }
        }
        let friction = kinds.iter().any(|k| matches!(k, RowKind::Tangent { .. }));
        if !friction {
            self.groups.clear();
        }
        let mut report = if friction {
            self.forget();
            self.gauss_seidel(w, n, q, kinds, lambda, tol)?
        } else {
            self.active_set(w, n, q, kinds, lambda, tol)?
        };
        self.check(w, n, q, kinds, lambda, tol, &mut report)?;
        Ok(report)
    }

    fn active_set(
        &mut self,
        w: &[f64],
        n: usize,
        q: &[f64],
        kinds: &[RowKind],
        lambda: &mut [f64],
        tol: &Tolerances,
    ) -> Result<Report, LcpError> {
        // Feasible start: the warm start with negative unilateral
        // multipliers clamped; the working set its non-zero rows.
        for i in 0..n {
            self.want[i] = match kinds[i] {
                RowKind::Bilateral => true,
                RowKind::Unilateral => {
                    if !(lambda[i] > 0.0) {
                        lambda[i] = 0.0;
                    }
                    lambda[i] > 0.0
                }
                _ => false,
            };
        }
        let mut a = 0;
        while a < self.fac.len() {
            if self.want[self.fac[a]] {
                a += 1;
            } else {
                self.remove(a);
            }
        }
        for j in 0..n {
            if self.want[j] && self.pos[j] == NONE {
                self.append(w, j);
            }
        }
        let mut iterations = 0u32;
        loop {
            // Stationary point of the working set.
            let k = self.fac.len();
            for a in 0..k {
                self.x[a] = -q[self.fac[a]];
            }
            self.factor_solve();
            // Ratio test along p = x - lambda_F.
            let mut alpha = 1.0;
            let mut block: Option<usize> = None;
            for a in 0..k {
                let r = self.fac[a];
                self.p[a] = self.x[a] - lambda[r];
                if kinds[r] == RowKind::Unilateral && self.p[a] < 0.0 {
                    let ratio = lambda[r] / -self.p[a];
                    let better = match block {
                        None => ratio < alpha,
                        Some(b) => ratio < alpha || (ratio == alpha && r < self.fac[b]),
                    };
                    if better {
                        alpha = ratio;
                        block = Some(a);
                    }
                }
            }
            if !self.x[..k].iter().all(|v| v.is_finite()) {
                return Err(LcpError::NonFinite("multiplier"));
            }
            match block {
                Some(b) => {
                    for a in 0..k {
                        let r = self.fac[a];
                        lambda[r] += alpha * self.p[a];
                    }
                    lambda[self.fac[b]] = 0.0;
                    self.remove(b);
                }
                None => {
                    for a in 0..k {
                        let r = self.fac[a];
                        // Rounding may leave -0-ish values where the ratio
                        // test allowed the full step.
                        lambda[r] = match kinds[r] {
                            RowKind::Unilateral => self.x[a].max(0.0),
                            _ => self.x[a],
                        };
                    }
                    // The most negative gap of a row held at zero.
                    let mut enter: Option<(usize, f64)> = None;
                    for j in 0..n {
                        if kinds[j] != RowKind::Unilateral || self.pos[j] != NONE {
                            continue;
                        }
                        let row = &w[j * self.stride..j * self.stride + n];
                        let mut g = q[j];
                        for &r in &self.fac {
                            g += row[r] * lambda[r];
                        }
                        if g < -tol.gap_m && enter.is_none_or(|(_, best)| g < best) {
                            enter = Some((j, g));
                        }
                    }
                    match enter {
                        None => break,
                        Some((j, _)) => self.append(w, j),
                    }
                }
            }
            iterations += 1;
            if iterations > tol.max_iterations {
                let violation_m = self.violation(w, n, q, kinds, lambda);
                return Err(LcpError::NotConverged {
                    iterations,
                    violation_m,
                });
            }
        }
        Ok(Report {
            iterations,
            ..Default::default()
        })
    }

    fn violation(&self, w: &[f64], n: usize, q: &[f64], kinds: &[RowKind], lambda: &[f64]) -> f64 {
        let mut worst: f64 = 0.0;
        for i in 0..n {
            if kinds[i] == RowKind::Off {
                continue;
            }
            let g = q[i]
                + dot_rows(&w[i * self.stride..i * self.stride + n], lambda, kinds)
                + REGULARIZATION * w[i * self.stride + i] * lambda[i];
            worst = worst.max(match kinds[i] {
                RowKind::Unilateral => (-g).max(0.0),
                RowKind::Bilateral => g.abs(),
                _ => 0.0,
            });
        }
        worst
    }

    fn gauss_seidel(
        &mut self,
        w: &[f64],
        n: usize,
        q: &[f64],
        kinds: &[RowKind],
        lambda: &mut [f64],
        tol: &Tolerances,
    ) -> Result<Report, LcpError> {
        // Groups: each unilateral row with its tangent rows (if any), and
        // every bilateral row alone.
        self.groups.clear();
        for i in 0..n {
            match kinds[i] {
                RowKind::Unilateral | RowKind::Bilateral => {
                    self.groups.push(Group { n: i, t: None })
                }
                _ => {}
            }
        }
        for i in 0..n {
            if let RowKind::Tangent { normal, mu } = kinds[i] {
                let Some(g) = self.groups.iter_mut().find(|g| g.n == normal as usize) else {
                    continue;
                };
                g.t = match g.t {
                    None => Some((i, usize::MAX, mu)),
                    Some((t1, usize::MAX, _)) => Some((t1, i, mu)),
                    Some(_) => {
                        return Err(LcpError::Shape(format!(
                            "normal row {normal} has more than two tangent rows"
                        )));
                    }
                };
            }
        }
        if let Some(g) = self
            .groups
            .iter()
            .find(|g| matches!(g.t, Some((_, usize::MAX, _))))
        {
            return Err(LcpError::Shape(format!(
                "normal row {} has one tangent row (needs two)",
                g.n
            )));
        }
        for i in 0..n {
            if kinds[i] == RowKind::Unilateral && lambda[i] < 0.0 {
                lambda[i] = 0.0;
            }
        }
        // Gaps of the warm start, kept current as multipliers change.
        for i in 0..n {
            self.g[i] = if kinds[i] == RowKind::Off {
                0.0
            } else {
                q[i] + dot_rows(&w[i * self.stride..i * self.stride + n], lambda, kinds)
                    + REGULARIZATION * w[i * self.stride + i] * lambda[i]
            };
        }
        let mut sweeps = 0u32;
        let mut next_polish = FIRST_POLISH_SWEEP;
        let mut polished = false;
        loop {
            let mut change: f64 = 0.0;
            let mut scale: f64 = 0.0;
            for gi in 0..self.groups.len() {
                let g = self.groups[gi];
                let i = g.n;
                let wii = w[i * self.stride + i] * (1.0 + REGULARIZATION);
                let old_n = lambda[i];
                match (kinds[i], g.t) {
                    (RowKind::Bilateral, _) => {
                        let new = old_n - self.g[i] / wii;
                        self.apply(w, n, kinds, lambda, i, new);
                    }
                    (_, None) => {
                        let new = (old_n - self.g[i] / wii).max(0.0);
                        self.apply(w, n, kinds, lambda, i, new);
                    }
                    (_, Some((t1, t2, mu))) => {
                        let new_n = (old_n - self.g[i] / wii).max(0.0);
                        self.apply(w, n, kinds, lambda, i, new_n);
                        // Stick trial on the tangent pair: W_tt dl = -g_t.
                        let (a, b, d) = (
                            w[t1 * self.stride + t1] * (1.0 + REGULARIZATION),
                            w[t1 * self.stride + t2],
                            w[t2 * self.stride + t2] * (1.0 + REGULARIZATION),
                        );
                        let det = a * d - b * b;
                        let (g1, g2) = (self.g[t1], self.g[t2]);
                        let (mut l1, mut l2) = if det > 0.0 {
                            (
                                lambda[t1] - (d * g1 - b * g2) / det,
                                lambda[t2] - (a * g2 - b * g1) / det,
                            )
                        } else {
                            (lambda[t1] - g1 / a, lambda[t2] - g2 / d)
                        };
                        let limit = mu * lambda[i];
                        let norm = l1.hypot(l2);
                        if norm > limit {
                            let s = if norm > 0.0 { limit / norm } else { 0.0 };
                            l1 *= s;
                            l2 *= s;
                        }
                        let (o1, o2) = (lambda[t1], lambda[t2]);
                        self.apply(w, n, kinds, lambda, t1, l1);
                        self.apply(w, n, kinds, lambda, t2, l2);
                        change = change.max((l1 - o1).abs()).max((l2 - o2).abs());
                    }
                }
                change = change.max((lambda[i] - old_n).abs());
                scale = scale.max(lambda[i].abs());
            }
            sweeps += 1;
            if !(change.is_finite()) {
                return Err(LcpError::NonFinite("multiplier"));
            }
            if change <= tol.sweep_rel * scale.max(f64::MIN_POSITIVE) {
                break;
            }
            if sweeps >= next_polish {
                next_polish = next_polish.saturating_mul(4);
                if self.polish(w, n, q, kinds, lambda, tol) {
                    polished = true;
                    break;
                }
            }
            // Then the conditions themselves, once the sweeps have nearly
            // settled: on rows that depend on each other (a triangle held at
            // its vertices and at points on it) the split of the multipliers
            // drifts at about 1e-10 of their size long after the gaps and
            // the forces have converged, so the change alone may never reach
            // `sweep_rel`, and the polish may cycle between sticking and
            // slipping. An iterate that meets every condition is an answer
            // ([`Self::check`] decides, as it does at the limit).
            if sweeps % CONDITIONS_EVERY == 0 && change <= CONDITIONS_REL * scale {
                let mut probe = Report {
                    iterations: sweeps,
                    ..Default::default()
                };
                if self.check(w, n, q, kinds, lambda, tol, &mut probe).is_ok() {
                    break;
                }
            }
            // At the limit the answer stands if it meets the conditions
            // ([`Self::check`] decides): rows that depend on each other (a
            // triangle held at its vertices and at points on it) make the
            // split of the multipliers among them drift slowly while the
            // gaps and the forces have converged.
            if sweeps >= tol.max_iterations {
                break;
            }
        }
        Ok(Report {
            iterations: sweeps,
            polished,
            ..Default::default()
        })
    }

    /// Polishes the Gauss-Seidel iterate `lambda` by an active-set
    /// method on the contact states. Each contact starts in the state the
    /// iterate shows: open (zero multiplier), closed (frictionless or
    /// bilateral), sticking (strictly inside its cone) or slipping (on it,
    /// with the direction `d` of its tangential force). The conditions of
    /// the states are linear: closed rows `g = 0`, sticking tangent rows
    /// `g_t = 0`, slipping ones `lambda_t = mu lambda_n d`; that square
    /// system (in the closed multipliers and the sticking tangential ones)
    /// is solved by LU with partial pivoting. Then every contact whose
    /// state the answer contradicts changes it: a closed row pulling
    /// (`lambda_n < 0`) opens, an open one penetrating (`g_n < -gap_m`)
    /// closes and sticks, a sticking force outside the cone slips along
    /// itself, and a slipping contact takes the direction of Gauss-Seidel's
    /// stick trial on it (`lambda_t - W_tt^-1 g_t`; inside the cone it
    /// sticks again). A contact changes state at most twice, so the passes
    /// cannot cycle: a third change ends the polish unsuccessful. When no
    /// state changes within [`POLISH_PASSES`] solves, the answer replaces
    /// `lambda` once [`Self::candidate_holds`] confirms it (which also
    /// refuses a slipping contact sliding along its force); otherwise the sweeps go on
    /// from their iterate, unchanged.
    fn polish(
        &mut self,
        w: &[f64],
        n: usize,
        q: &[f64],
        kinds: &[RowKind],
        lambda: &mut [f64],
        tol: &Tolerances,
    ) -> bool {
        let s = self.stride;
        let wr = |i: usize, j: usize| {
            let v = w[i * s + j];
            if i == j {
                v * (1.0 + REGULARIZATION)
            } else {
                v
            }
        };
        self.state.clear();
        for gi in 0..self.groups.len() {
            let g = self.groups[gi];
            let i = g.n;
            let st = match (kinds[i], g.t) {
                (RowKind::Bilateral, _) => State::Closed,
                _ if !(lambda[i] > 0.0) => State::Open,
                (_, None) => State::Closed,
                (_, Some((t1, t2, mu))) => {
                    let lt = lambda[t1].hypot(lambda[t2]);
                    if mu > 0.0 && lt < mu * lambda[i] * (1.0 - 1e-6) {
                        State::Stick
                    } else if lt > 0.0 {
                        State::Slip {
                            a1: mu * lambda[t1] / lt,
                            a2: mu * lambda[t2] / lt,
                        }
                    } else {
                        State::Slip { a1: 0.0, a2: 0.0 }
                    }
                }
            };
            self.state.push(st);
        }
        self.flipped.clear();
        self.flipped.resize(self.groups.len(), 0);
        if self.cand.len() < n {
            self.cand.resize(n, 0.0);
            self.cand_g.resize(n, 0.0);
        }
        for _ in 0..POLISH_PASSES {
            // The unknowns of the states: column c is unknown c's row of
            // W, plus `a1 W[:, t1] + a2 W[:, t2]` for a slipping normal.
            self.unknown_rows.clear();
            self.slip.clear();
            for (g, st) in self.groups.iter().zip(&self.state) {
                match *st {
                    State::Open => {}
                    State::Closed => {
                        self.unknown_rows.push(g.n);
                        self.slip.push(Slip::NONE);
                    }
                    State::Stick => {
                        let (t1, t2, _) = g.t.expect("a sticking contact has tangent rows");
                        for r in [g.n, t1, t2] {
                            self.unknown_rows.push(r);
                            self.slip.push(Slip::NONE);
                        }
                    }
                    State::Slip { a1, a2 } => {
                        let (t1, t2, _) = g.t.expect("a slipping contact has tangent rows");
                        self.unknown_rows.push(g.n);
                        self.slip.push(Slip { t1, t2, a1, a2 });
                    }
                }
            }
            let m = self.unknown_rows.len();
            if self.lu.len() < m * m {
                self.lu.resize(m * m, 0.0);
            }
            if self.rhs.len() < m {
                self.rhs.resize(m, 0.0);
                self.piv.resize(m, 0);
            }
            for a in 0..m {
                let ra = self.unknown_rows[a];
                for c in 0..m {
                    let sl = self.slip[c];
                    let mut v = wr(ra, self.unknown_rows[c]);
                    if sl.t1 != usize::MAX {
                        v += sl.a1 * wr(ra, sl.t1) + sl.a2 * wr(ra, sl.t2);
                    }
                    self.lu[a * m + c] = v;
                }
                self.rhs[a] = -q[ra];
            }
            if !lu_solve(
                &mut self.lu[..m * m],
                m,
                &mut self.piv[..m],
                &mut self.rhs[..m],
            ) {
                return false;
            }
            self.cand[..n].fill(0.0);
            for c in 0..m {
                let (r, x, sl) = (self.unknown_rows[c], self.rhs[c], self.slip[c]);
                self.cand[r] = x;
                if sl.t1 != usize::MAX {
                    self.cand[sl.t1] = sl.a1 * x;
                    self.cand[sl.t2] = sl.a2 * x;
                }
            }
            for i in 0..n {
                self.cand_g[i] = if kinds[i] == RowKind::Off {
                    0.0
                } else {
                    let mut g = q[i];
                    for j in 0..n {
                        if self.cand[j] != 0.0 {
                            g += wr(i, j) * self.cand[j];
                        }
                    }
                    g
                };
            }
            // States the answer contradicts.
            let mut changed = false;
            for gi in 0..self.groups.len() {
                let g = self.groups[gi];
                if kinds[g.n] == RowKind::Bilateral {
                    continue;
                }
                let (ln, gn) = (self.cand[g.n], self.cand_g[g.n]);
                let st = self.state[gi];
                let next = match (st, g.t) {
                    (State::Open, t) => {
                        if gn < -tol.gap_m {
                            if t.is_some() {
                                State::Stick
                            } else {
                                State::Closed
                            }
                        } else {
                            st
                        }
                    }
                    _ if ln < 0.0 => State::Open,
                    (State::Stick, Some((t1, t2, mu))) => {
                        let (l1, l2) = (self.cand[t1], self.cand[t2]);
                        let lt = l1.hypot(l2);
                        if lt > mu * ln * (1.0 + 1e-9) {
                            State::Slip {
                                a1: mu * l1 / lt,
                                a2: mu * l2 / lt,
                            }
                        } else {
                            st
                        }
                    }
                    (State::Slip { a1, a2 }, Some((t1, t2, mu))) if mu > 0.0 => {
                        // Gauss-Seidel's own step on this contact, the
                        // others held: the stick trial `lambda_t - W_tt^-1
                        // g_t`; inside the cone the contact sticks, outside
                        // it slips along the trial.
                        let (l1, l2) = (self.cand[t1], self.cand[t2]);
                        let (g1, g2) = (self.cand_g[t1], self.cand_g[t2]);
                        let (wa, wb, wd) = (wr(t1, t1), wr(t1, t2), wr(t2, t2));
                        let det = wa * wd - wb * wb;
                        let (x1, x2) = if det > 0.0 {
                            (
                                l1 - (wd * g1 - wb * g2) / det,
                                l2 - (wa * g2 - wb * g1) / det,
                            )
                        } else {
                            (l1 - g1 / wa, l2 - g2 / wd)
                        };
                        let xt = x1.hypot(x2);
                        if xt < mu * ln * (1.0 - 1e-6) {
                            State::Stick
                        } else {
                            let (b1, b2) = (mu * x1 / xt, mu * x2 / xt);
                            if (b1 - a1).hypot(b2 - a2) > 1e-9 * mu {
                                State::Slip { a1: b1, a2: b2 }
                            } else {
                                st
                            }
                        }
                    }
                    _ => st,
                };
                if next != st {
                    // A contact changes its state (open, closed, sticking,
                    // slipping) at most twice per polish: more is a cycle.
                    if std::mem::discriminant(&next) != std::mem::discriminant(&st) {
                        if self.flipped[gi] >= 2 {
                            return false;
                        }
                        self.flipped[gi] += 1;
                    }
                    self.state[gi] = next;
                    changed = true;
                }
            }
            if !changed {
                if !self.candidate_holds(n, kinds, tol) {
                    return false;
                }
                lambda[..n].copy_from_slice(&self.cand[..n]);
                self.g[..n].copy_from_slice(&self.cand_g[..n]);
                return true;
            }
        }
        false
    }

    /// Whether the polish's candidate (`cand`, gaps `cand_g`) meets the
    /// conditions: multipliers of unilateral rows >= 0 and their gaps >=
    /// `-gap_m`, tangential forces inside their cones, and a slipping
    /// contact sliding against its force.
    fn candidate_holds(&self, n: usize, kinds: &[RowKind], tol: &Tolerances) -> bool {
        let (lam, g) = (&self.cand, &self.cand_g);
        for i in 0..n {
            if !lam[i].is_finite() || !g[i].is_finite() {
                return false;
            }
            if kinds[i] == RowKind::Unilateral && (lam[i] < 0.0 || g[i] < -tol.gap_m) {
                return false;
            }
        }
        for gr in &self.groups {
            let Some((t1, t2, mu)) = gr.t else { continue };
            let lt = lam[t1].hypot(lam[t2]);
            let limit = mu * lam[gr.n];
            if lt > limit * (1.0 + 1e-9) {
                return false;
            }
            if lt >= limit * (1.0 - 1e-6) && lt > 0.0 {
                let along = (g[t1] * lam[t1] + g[t2] * lam[t2]) / lt;
                if along > tol.gap_m {
                    return false;
                }
            }
        }
        true
    }

    /// Sets `lambda[i] = new` and updates the kept gaps.
    fn apply(
        &mut self,
        w: &[f64],
        n: usize,
        kinds: &[RowKind],
        lambda: &mut [f64],
        i: usize,
        new: f64,
    ) {
        let d = new - lambda[i];
        if d == 0.0 {
            return;
        }
        lambda[i] = new;
        let col = &w[i * self.stride..i * self.stride + n];
        for j in 0..n {
            if kinds[j] != RowKind::Off {
                self.g[j] += col[j] * d;
            }
        }
        self.g[i] += REGULARIZATION * col[i] * d;
    }

    /// Checks the answer against the conditions from scratch (`g = q + W
    /// lambda` recomputed) and fills the report's measures.
    #[allow(clippy::too_many_arguments)]
    fn check(
        &mut self,
        w: &[f64],
        n: usize,
        q: &[f64],
        kinds: &[RowKind],
        lambda: &[f64],
        tol: &Tolerances,
        report: &mut Report,
    ) -> Result<(), LcpError> {
        let mut active = 0;
        let (mut gap_v, mut comp, mut cone): (f64, f64, f64) = (0.0, 0.0, 0.0);
        for i in 0..n {
            if kinds[i] == RowKind::Off {
                continue;
            }
            if !lambda[i].is_finite() {
                return Err(LcpError::NonFinite("multiplier"));
            }
            if lambda[i] != 0.0 {
                active += 1;
            }
            let g = q[i]
                + dot_rows(&w[i * self.stride..i * self.stride + n], lambda, kinds)
                + REGULARIZATION * w[i * self.stride + i] * lambda[i];
            self.g[i] = g;
            match kinds[i] {
                RowKind::Unilateral => {
                    gap_v = gap_v.max((-g).max(0.0));
                    if lambda[i] < 0.0 {
                        return Err(LcpError::NotConverged {
                            iterations: report.iterations,
                            violation_m: gap_v,
                        });
                    }
                    comp = comp.max((lambda[i] * g).abs());
                }
                RowKind::Bilateral => gap_v = gap_v.max(g.abs()),
                _ => {}
            }
        }
        // Friction: the cone, and no slip inside it.
        for gi in 0..self.groups.len() {
            let g = self.groups[gi];
            if let (RowKind::Unilateral, Some((t1, t2, mu))) = (kinds[g.n], g.t) {
                if t2 >= n {
                    continue;
                }
                let lt = lambda[t1].hypot(lambda[t2]);
                let limit = mu * lambda[g.n];
                cone = cone.max(lt - limit);
                if lt < limit * (1.0 - 1e-6) {
                    gap_v = gap_v.max(self.g[t1].hypot(self.g[t2]));
                } else if lt > 0.0 {
                    // A slipping contact slides against its force: the
                    // slip's component along the force is a violation.
                    let along = (self.g[t1] * lambda[t1] + self.g[t2] * lambda[t2]) / lt;
                    gap_v = gap_v.max(along.max(0.0));
                }
            }
        }
        report.active = active;
        report.max_gap_violation_m = gap_v;
        report.max_complementarity = comp;
        report.max_cone_excess_n = cone.max(0.0);
        let lambda_scale = lambda.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        // Friction converges to the sweep tolerance, not exactly: its gap
        // test scales with the sweep's last change.
        let friction = kinds.iter().any(|k| matches!(k, RowKind::Tangent { .. }));
        let gap_tol = if friction {
            let wmax = (0..n)
                .filter(|&i| kinds[i] != RowKind::Off)
                .map(|i| w[i * self.stride + i])
                .fold(0.0, f64::max);
            tol.gap_m + 1e3 * tol.sweep_rel * lambda_scale * wmax
        } else {
            tol.gap_m
        };
        if gap_v > gap_tol || comp > gap_tol * lambda_scale.max(f64::MIN_POSITIVE) {
            return Err(LcpError::NotConverged {
                iterations: report.iterations,
                violation_m: gap_v,
            });
        }
        if cone > 1e-9 * lambda_scale {
            return Err(LcpError::NotConverged {
                iterations: report.iterations,
                violation_m: gap_v,
            });
        }
        Ok(())
    }

    /// The gaps `g = q + W lambda` of the last answer (m), per row.
    pub fn gaps(&self, n: usize) -> &[f64] {
        &self.g[..n]
    }
}

/// Most solves of one polish (its active-set passes over the contact
/// states).
const POLISH_PASSES: u32 = 6;

/// A contact's state in the polish.
#[derive(Debug, Clone, Copy, PartialEq)]
enum State {
    /// Every multiplier of the contact is zero.
    Open,
    /// A frictionless unilateral row in contact, or a bilateral row: `g = 0`.
    Closed,
    /// In contact and sticking: `g_n = 0`, `g_t = 0`.
    Stick,
    /// In contact and slipping: `g_n = 0`, `lambda_t = (a1, a2) lambda_n`
    /// (`a = mu d`, `d` the unit direction of the tangential force).
    Slip { a1: f64, a2: f64 },
}

/// Solves `A x = b` in place (`a` row-major `m x m`, overwritten by its LU
/// factors; `b` becomes `x`) by Gaussian elimination with partial
/// pivoting. Hand-written for the solver's workspace (the force loop does
/// not allocate); `false` when a pivot is zero or not finite.
fn lu_solve(a: &mut [f64], m: usize, piv: &mut [usize], b: &mut [f64]) -> bool {
    for k in 0..m {
        let mut p = k;
        let mut best = a[k * m + k].abs();
        for r in k + 1..m {
            let v = a[r * m + k].abs();
            if v > best {
                best = v;
                p = r;
            }
        }
        if !(best > 0.0 && best.is_finite()) {
            return false;
        }
        piv[k] = p;
        if p != k {
            for c in 0..m {
                a.swap(k * m + c, p * m + c);
            }
            b.swap(k, p);
        }
        let d = a[k * m + k];
        for r in k + 1..m {
            let f = a[r * m + k] / d;
            if f == 0.0 {
                continue;
            }
            a[r * m + k] = f;
            for c in k + 1..m {
                a[r * m + c] -= f * a[k * m + c];
            }
            b[r] -= f * b[k];
        }
    }
    for k in (0..m).rev() {
        let mut v = b[k];
        for c in k + 1..m {
            v -= a[k * m + c] * b[c];
        }
        b[k] = v / a[k * m + k];
    }
    b.iter().all(|v| v.is_finite())
}

fn dot_rows(row: &[f64], lambda: &[f64], kinds: &[RowKind]) -> f64 {
    let mut s = 0.0;
    for ((w, l), k) in row.iter().zip(lambda).zip(kinds) {
        if *k != RowKind::Off && *l != 0.0 {
            s += w * l;
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small SPD compliance (m/N) like a patch of surface vertices:
    /// strong positive coupling between neighbours.
    fn patch(n: usize, seed: u64) -> Vec<f64> {
        let mut next = crate::test_rng::unit(seed);
        let pts: Vec<(f64, f64)> = (0..n).map(|_| (next(), next())).collect();
        let mut w = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..n {
                let d = ((pts[i].0 - pts[j].0).powi(2) + (pts[i].1 - pts[j].1).powi(2)).sqrt();
                w[i * n + j] = 1e-3 / (1.0 + 8.0 * d);
            }
            w[i * n + i] += 2e-4;
        }
        w
    }

    /// Every subset of rows: the unique answer of a P-matrix LCP by
    /// enumeration (small n only).
    fn brute(w: &[f64], n: usize, q: &[f64]) -> Vec<f64> {
        for mask in 0u32..(1 << n) {
            let f: Vec<usize> = (0..n).filter(|i| mask & (1 << i) != 0).collect();
            let m = f.len();
            let mut lambda = vec![0.0; n];
            if m > 0 {
                let a = nalgebra::DMatrix::from_fn(m, m, |r, c| w[f[r] * n + f[c]]);
                let b = nalgebra::DVector::from_fn(m, |r, _| -q[f[r]]);
                let Some(x) = a.lu().solve(&b) else { continue };
                for (r, &i) in f.iter().enumerate() {
                    lambda[i] = x[r];
                }
            }
            let ok = (0..n).all(|i| {
                let g: f64 = q[i] + (0..n).map(|j| w[i * n + j] * lambda[j]).sum::<f64>();
                lambda[i] >= -1e-12 && g >= -1e-12
            });
            if ok {
                return lambda;
            }
        }
        panic!("no solution")
    }

    /// The Signorini conditions hold and the answer is the unique one
    /// (enumeration), from a cold start and from every warm start.
    #[test]
    fn frictionless_answer_is_the_unique_complementary_one() {
        for seed in 1..40u64 {
            let n = 9;
            let w = patch(n, seed);
            let q: Vec<f64> = (0..n)
                .map(|i| 1e-3 * (((seed * 7 + i as u64 * 13) % 11) as f64 - 6.0) / 5.0)
                .collect();
            let want = brute(&w, n, &q);
            let kinds = vec![RowKind::Unilateral; n];
            let tol = Tolerances::for_gaps(&q, &kinds);
            let mut s = ContactSolver::new();
            let mut lambda = vec![0.0; n];
            let rep = s.solve(&w, n, n, &q, &kinds, &mut lambda, &tol).unwrap();
            let scale = want.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-9);
            // The solver's 1e-9 regularisation moves the answer by about
            // that much relative to the exact one.
            for i in 0..n {
                assert!((lambda[i] - want[i]).abs() < 1e-6 * scale, "seed {seed}");
            }
            assert!(rep.max_gap_violation_m <= tol.gap_m);
            // Warm starts: the answer itself (no change), and a wrong one.
            let rep2 = s.solve(&w, n, n, &q, &kinds, &mut lambda, &tol).unwrap();
            assert_eq!(
                rep2.iterations, 0,
                "a warm start at the answer is the answer"
            );
            let mut wrong: Vec<f64> = (0..n).map(|i| (i % 3) as f64).collect();
            s.solve(&w, n, n, &q, &kinds, &mut wrong, &tol).unwrap();
            for i in 0..n {
                assert!((wrong[i] - lambda[i]).abs() < 1e-9 * scale, "seed {seed}");
            }
        }
    }

    /// Changing rows one at a time (kept factor with reported changes)
    /// gives the answer a fresh solver gives.
    #[test]
    fn reported_changes_keep_the_factor_exact() {
        let n = 12;
        let w0 = patch(n, 3);
        let mut s = ContactSolver::new();
        let mut kinds = vec![RowKind::Unilateral; n];
        let mut lambda = vec![0.0; n];
        for step in 0..60usize {
            let q: Vec<f64> = (0..n)
                .map(|i| 1e-3 * (((step + 3 * i) % 7) as f64 - 4.0) / 4.0)
                .collect();
            // Turn a row off now and then and back on.
            let off = step % 5;
            for (i, k) in kinds.iter_mut().enumerate() {
                *k = if i == off && step % 2 == 0 {
                    RowKind::Off
                } else {
                    RowKind::Unilateral
                };
            }
            // Scale one row and column of W (a changed row).
            let mut w = w0.clone();
            let r = (step * 5) % n;
            let f = 1.0 + 0.1 * (step % 3) as f64;
            for j in 0..n {
                w[r * n + j] *= f;
                w[j * n + r] *= f;
            }
            s.changed(r);
            if step > 0 {
                s.changed((step * 5 - 5) % n);
            }
            let tol = Tolerances::for_gaps(&q, &kinds);
            s.solve(&w, n, n, &q, &kinds, &mut lambda, &tol).unwrap();
            let mut fresh = vec![0.0; n];
            ContactSolver::new()
                .solve(&w, n, n, &q, &kinds, &mut fresh, &tol)
                .unwrap();
            for i in 0..n {
                assert!(
                    (lambda[i] - fresh[i]).abs() <= 1e-9 * fresh[i].abs().max(1.0),
                    "step {step} row {i}: {} vs {}",
                    lambda[i],
                    fresh[i]
                );
            }
        }
    }

    /// Bilateral rows are met exactly whatever the sign of their force.
    #[test]
    fn bilateral_rows_are_met_with_either_sign() {
        let n = 6;
        let w = patch(n, 9);
        let q = vec![1e-3, -1e-3, 2e-3, -5e-4, 0.0, 1e-4];
        let kinds = vec![RowKind::Bilateral; n];
        let mut lambda = vec![0.0; n];
        let mut s = ContactSolver::new();
        let tol = Tolerances::for_gaps(&q, &kinds);
        s.solve(&w, n, n, &q, &kinds, &mut lambda, &tol).unwrap();
        assert!(lambda.iter().any(|&l| l < 0.0) && lambda.iter().any(|&l| l > 0.0));
        for g in s.gaps(n) {
            assert!(g.abs() <= tol.gap_m);
        }
    }

    /// A row that duplicates another (a vertex held twice along one
    /// direction) is solved, with both gaps closed.
    #[test]
    fn a_duplicated_row_does_not_break_the_factor() {
        let n = 4;
        let mut w = patch(n, 5);
        // Row 3 := row 2.
        for j in 0..n {
            w[3 * n + j] = w[2 * n + j];
            w[j * n + 3] = w[j * n + 2];
        }
        w[3 * n + 3] = w[2 * n + 2];
        let q = vec![1e-3, -1e-3, -2e-3, -2e-3];
        let kinds = vec![RowKind::Unilateral; n];
        let mut lambda = vec![0.0; n];
        let tol = Tolerances::for_gaps(&q, &kinds);
        ContactSolver::new()
            .solve(&w, n, n, &q, &kinds, &mut lambda, &tol)
            .unwrap();
        assert!(lambda[2] + lambda[3] > 0.0);
    }

    /// Friction: one contact pressed and dragged. Below the cone it sticks
    /// (the tangential gap closes); above, it slips with |l_t| = mu l_n.
    #[test]
    fn one_frictional_contact_sticks_then_slips() {
        // Isotropic compliance with a little normal-tangential coupling.
        let w = vec![
            1e-3, 1e-4, 0.0, //
            1e-4, 1e-3, 0.0, //
            0.0, 0.0, 1e-3,
        ];
        let mu = 0.5;
        let kinds = [
            RowKind::Unilateral,
            RowKind::Tangent { normal: 0, mu },
            RowKind::Tangent { normal: 0, mu },
        ];
        let mut s = ContactSolver::new();
        for (drag, sticks) in [(1e-4, true), (1e-3, false)] {
            let q = [-1e-3, drag, 0.0];
            let mut lambda = [0.0; 3];
            let tol = Tolerances::for_gaps(&q, &kinds);
            s.solve(&w, 3, 3, &q, &kinds, &mut lambda, &tol).unwrap();
            let lt = lambda[1].hypot(lambda[2]);
            assert!(lambda[0] > 0.0);
            if sticks {
                assert!(lt < mu * lambda[0]);
                assert!(s.gaps(3)[1].abs() < 1e-9);
            } else {
                assert!((lt - mu * lambda[0]).abs() < 1e-9 * lambda[0]);
                // The force opposes the drag.
                assert!(lambda[1] < 0.0);
            }
        }
    }

    /// Friction on rows that depend on each other, as under a plate: the
    /// vertices of a patch and the midpoints of neighbouring pairs, each
    /// pressed 1 mm and dragged by a different amount, so that some
    /// contacts stick and some slip. The answer meets Coulomb's law, as
    /// the test recomputes it: `g_n >= 0`, `lambda_n >= 0`, `lambda_n g_n =
    /// 0`, `|lambda_t| <= mu lambda_n`; inside the cone no slip; on it the
    /// slip runs against the force. The sweeps alone crawl here; the
    /// polish ends them.
    #[test]
    fn dependent_frictional_rows_stick_and_slip_by_coulomb() {
        let mu = 0.3;
        let mut totals = (0, 0, 0);
        for seed in 1..12u64 {
            let nv = 12;
            let k = patch(nv, seed);
            // Contacts: every vertex, then midpoints of (i, i + 1).
            let mut h: Vec<Vec<(usize, f64)>> = (0..nv).map(|i| vec![(i, 1.0)]).collect();
            for i in 0..nv - 1 {
                h.push(vec![(i, 0.5), (i + 1, 0.5)]);
            }
            let nc = h.len();
            let n = 3 * nc;
            let mut w = vec![0.0; n * n];
            for c in 0..nc {
                for d in 0..nc {
                    let mut v = 0.0;
                    for &(a, wa) in &h[c] {
                        for &(b, wb) in &h[d] {
                            v += wa * wb * k[a * nv + b];
                        }
                    }
                    for ax in 0..3 {
                        w[(3 * c + ax) * n + 3 * d + ax] = v;
                    }
                }
            }
            let mut kinds = vec![RowKind::Off; n];
            let mut q = vec![0.0; n];
            for c in 0..nc {
                kinds[3 * c] = RowKind::Unilateral;
                for t in 1..3 {
                    kinds[3 * c + t] = RowKind::Tangent {
                        normal: 3 * c as u32,
                        mu,
                    };
                }
                q[3 * c] = -1e-3 * (0.6 + 0.4 * ((c * 7 % 5) as f64 / 4.0));
                // A drag that grows along the patch: the far end slips.
                q[3 * c + 1] = 4e-4 * (c % nv) as f64 / nv as f64;
                q[3 * c + 2] = -1e-4 * ((c * 3 % 4) as f64 - 1.5);
            }
            let mut lambda = vec![0.0; n];
            let tol = Tolerances::for_gaps(&q, &kinds);
            let mut s = ContactSolver::new();
            let report = s
                .solve(&w, n, n, &q, &kinds, &mut lambda, &tol)
                .unwrap_or_else(|e| panic!("seed {seed}: {e}"));
            assert!(
                report.iterations < tol.max_iterations,
                "seed {seed}: {report:?}"
            );
            let g: Vec<f64> = (0..n)
                .map(|i| {
                    q[i] + (0..n).map(|j| w[i * n + j] * lambda[j]).sum::<f64>()
                        + REGULARIZATION * w[i * n + i] * lambda[i]
                })
                .collect();
            let gap_tol = 1e-8;
            let (mut sticks, mut slips) = (0, 0);
            for c in 0..nc {
                let (ln, l1, l2) = (lambda[3 * c], lambda[3 * c + 1], lambda[3 * c + 2]);
                let (gn, g1, g2) = (g[3 * c], g[3 * c + 1], g[3 * c + 2]);
                assert!(ln >= 0.0 && gn >= -gap_tol, "seed {seed} contact {c}");
                assert!(
                    (ln * gn).abs() <= gap_tol * ln.max(1e-30),
                    "seed {seed} contact {c}"
                );
                let lt = l1.hypot(l2);
                assert!(
                    lt <= mu * ln * (1.0 + 1e-9),
                    "seed {seed} contact {c}: outside the cone"
                );
                if ln == 0.0 {
                    continue;
                }
                if lt < mu * ln * (1.0 - 1e-6) {
                    sticks += 1;
                    assert!(
                        g1.hypot(g2) < gap_tol,
                        "seed {seed} contact {c}: slips inside the cone"
                    );
                } else {
                    slips += 1;
                    assert!(
                        (g1 * l1 + g2 * l2) / lt <= gap_tol,
                        "seed {seed} contact {c}: slides along its friction force"
                    );
                }
            }
            totals.0 += sticks;
            totals.1 += slips;
            totals.2 += usize::from(report.polished);
        }
        let (sticks, slips, polished) = totals;
        assert!(sticks > 5 && slips > 5, "{sticks} stick, {slips} slip");
        assert!(
            polished >= 3,
            "the polish answered {polished} of 11 problems"
        );
    }

    #[test]
    fn bad_input_is_reported() {
        let mut s = ContactSolver::new();
        let kinds = [RowKind::Unilateral];
        let tol = Tolerances::for_gaps(&[0.0], &kinds);
        assert!(matches!(
            s.solve(&[0.0], 1, 1, &[1e-3], &kinds, &mut [0.0], &tol),
            Err(LcpError::BadDiagonal { row: 0, .. })
        ));
        assert!(matches!(
            s.solve(&[1.0], 1, 1, &[f64::NAN], &kinds, &mut [0.0], &tol),
            Err(LcpError::NonFinite(_))
        ));
        assert!(matches!(
            s.solve(&[1.0], 1, 1, &[0.0, 0.0], &kinds, &mut [0.0], &tol),
            Err(LcpError::Shape(_))
        ));
    }
}
