//! Sparse Cholesky `A = L L^T` of a symmetric positive definite matrix given by
//! its lower triangle on a [`Pattern`], with the symbolic analysis (AMD
//! ordering, supernodes) done once and workspaces kept, so that a numeric
//! re-factorization or a solve allocates nothing. A thin layer over
//! `faer::sparse::linalg::cholesky`.

use super::SolveError;
use super::assembly::Pattern;
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::SparseColMatRef;
use faer::sparse::linalg::cholesky::{LltRef, SymbolicCholesky, factorize_symbolic_cholesky};
use faer::{Conj, MatMut, Par, Side};
use std::sync::Arc;

/// A reusable sparse Cholesky factorization.
pub struct SparseLlt {
    symbolic: Arc<SymbolicCholesky<usize>>,
    l_values: Arc<Vec<f64>>,
    factor_buf: MemBuffer,
    solve_buf: MemBuffer,
    factored: bool,
    l_single: Vec<f32>,
    rhs_single: Vec<f32>,
    single_buf: MemBuffer,
}

impl std::fmt::Debug for SparseLlt {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SparseLlt")
            .field("n", &self.symbolic.nrows())
            .field("l_nnz", &self.l_values.len())
            .finish()
    }
}

impl SparseLlt {
    /// Symbolic analysis of `pattern`.
    pub fn new(pattern: &Pattern) -> Result<Self, SolveError> {
        let symbolic = factorize_symbolic_cholesky(
            pattern.symbolic(),
            Side::Lower,
            Default::default(),
            Default::default(),
        )
        .map_err(|source| SolveError::Sparse {
            matrix: "the stiffness (symbolic analysis)",
            source,
        })?;
        let factor_buf = MemBuffer::new(
            symbolic.factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default()),
        );
        let solve_buf = MemBuffer::new(symbolic.solve_in_place_scratch::<f64>(1, Par::Seq));
        let l_values = Arc::new(vec![0.0; symbolic.len_val()]);
        Ok(Self {
            symbolic: Arc::new(symbolic),
            l_values,
            factor_buf,
            solve_buf,
            factored: false,
            l_single: Vec::new(),
            rhs_single: Vec::new(),
            single_buf: MemBuffer::new(faer::dyn_stack::StackReq::EMPTY),
        })
    }

    /// Keeps a single-precision copy of the factor for
    /// [`SparseLlt::solve_single`] (half the memory traffic of a solve;
    /// `4 x nnz(L)` bytes). Call after [`SparseLlt::factorize`].
    pub fn keep_single(&mut self) {
        debug_assert!(self.factored);
        self.l_single.clear();
        self.l_single
            .extend(self.l_values.iter().map(|&v| v as f32));
        self.rhs_single.resize(self.symbolic.nrows(), 0.0);
        self.single_buf = MemBuffer::new(self.symbolic.solve_in_place_scratch::<f32>(1, Par::Seq));
    }

    /// Whether a single-precision copy is kept.
    pub fn has_single(&self) -> bool {
        !self.l_single.is_empty()
    }

    /// Solves `A x = b` in place approximately, with the single-precision
    /// copy of the factor (relative error about `cond(A) x 6e-8`; for a
    /// preconditioner). Falls back to [`SparseLlt::solve`] without a copy.
    pub fn solve_single(&mut self, rhs: &mut [f64]) {
        if self.l_single.is_empty() {
            self.solve(rhs);
            return;
        }
        // Scaled into f32 range (the solve is linear).
        let scale = rhs.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        if !(scale > 0.0 && scale.is_finite()) {
            if scale == 0.0 {
                return;
            }
            self.solve(rhs);
            return;
        }
        let inv = 1.0 / scale;
        for (s, &v) in self.rhs_single.iter_mut().zip(rhs.iter()) {
            *s = (v * inv) as f32;
        }
        let n = rhs.len();
        let mat = MatMut::from_column_major_slice_mut(&mut self.rhs_single, n, 1);
        LltRef::new(&self.symbolic, &self.l_single).solve_in_place_with_conj(
            Conj::No,
            mat,
            Par::Seq,
            MemStack::new(&mut self.single_buf),
        );
        for (v, &s) in rhs.iter_mut().zip(&self.rhs_single) {
            *v = s as f64 * scale;
        }
    }

    /// Whether the last [`SparseLlt::factorize`] succeeded (a factor is held).
    pub fn is_factored(&self) -> bool {
        self.factored
    }

    /// Nonzeros of the factor L.
    pub fn factor_nnz(&self) -> usize {
        self.l_values.len()
    }

    /// Numeric factorization of the matrix with lower triangle `values` on
    /// `pattern` (the pattern given to [`SparseLlt::new`]).
    pub fn factorize(&mut self, pattern: &Pattern, values: &[f64]) -> Result<(), SolveError> {
        self.factored = false;
        if !values.iter().all(|v| v.is_finite()) {
            return Err(SolveError::NonFinite("stiffness matrix entry".into()));
        }
        let a = SparseColMatRef::new(pattern.symbolic(), values);
        self.symbolic
            .factorize_numeric_llt(
                Arc::make_mut(&mut self.l_values).as_mut_slice(),
                a,
                Side::Lower,
                LltRegularization::default(),
                Par::Seq,
                MemStack::new(&mut self.factor_buf),
                Default::default(),
            )
            .map_err(|e| match e {
                faer::linalg::cholesky::llt::factor::LltError::NonPositivePivot { index } => {
                    SolveError::NotPositiveDefinite {
                        matrix: "the stiffness",
                        pivot: Some(index),
                        hint: "",
                    }
                }
            })?;
        self.factored = true;
        Ok(())
    }

    /// Solves `A x = b` in place for one right-hand side (no allocation).
    pub fn solve(&mut self, rhs: &mut [f64]) {
        debug_assert!(self.factored);
        let n = rhs.len();
        let mat = MatMut::from_column_major_slice_mut(rhs, n, 1);
        LltRef::new(&self.symbolic, &self.l_values).solve_in_place_with_conj(
            Conj::No,
            mat,
            Par::Seq,
            MemStack::new(&mut self.solve_buf),
        );
    }

    /// Solves `A X = B` in place for `ncols` right-hand sides stored column
    /// major in `rhs` (allocates a workspace for the block).
    pub fn solve_many(&self, rhs: &mut [f64], ncols: usize) {
        debug_assert!(self.factored);
        self.share().solve_many(rhs, ncols);
    }

    /// A read-only handle on the factor for another thread (shares the
    /// values: no copy). A later [`SparseLlt::factorize`] copies them
    /// first, so the handle keeps the factor it was made from.
    pub fn share(&self) -> SharedFactor {
        debug_assert!(self.factored);
        SharedFactor {
            symbolic: self.symbolic.clone(),
            l_values: self.l_values.clone(),
        }
    }
}

/// A factor shared read-only between threads ([`SparseLlt::share`]).
#[derive(Clone)]
pub struct SharedFactor {
    symbolic: Arc<SymbolicCholesky<usize>>,
    l_values: Arc<Vec<f64>>,
}

impl std::fmt::Debug for SharedFactor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SharedFactor")
            .field("n", &self.symbolic.nrows())
            .finish()
    }
}

impl SharedFactor {
    /// Rows of the factored matrix.
    pub fn nrows(&self) -> usize {
        self.symbolic.nrows()
    }

    /// Solves `A X = B` in place for `ncols` right-hand sides stored column
    /// major in `rhs` (allocates a workspace for the block).
    pub fn solve_many(&self, rhs: &mut [f64], ncols: usize) {
        let n = self.symbolic.nrows();
        let mat = MatMut::from_column_major_slice_mut(rhs, n, ncols);
        let mut buf = MemBuffer::new(self.symbolic.solve_in_place_scratch::<f64>(ncols, Par::Seq));
        LltRef::new(&self.symbolic, &self.l_values).solve_in_place_with_conj(
            Conj::No,
            mat,
            Par::Seq,
            MemStack::new(&mut buf),
        );
    }
}
