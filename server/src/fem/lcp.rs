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
//! by more than `1e-10` of the largest, or at the sweep limit; either way
//! the answer is checked.
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
    /// Row stride of `W` in the current solve.
    stride: usize,
}

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
            ..Default::default()
        })
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
        let mut x = seed;
        let mut next = || {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (x >> 11) as f64 / (1u64 << 53) as f64
        };
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
