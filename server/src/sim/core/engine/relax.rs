//! Aitken's dynamic relaxation of the step's contact geometry.
//!
//! On the solved shape a search finds each polygon corner's tissue point
//! again (a point row's barycentric weights `w` on its triangle), and the
//! tissue point depends on the shape it pushed: the step iterates
//! `x_{k+1} = x_k + omega_k r_k` with `x` the weights of every point row
//! in the problem and `r_k = g(x_k) - x_k` what the search on the shape of
//! `x_k` moves them by. A fixed `omega` fails both ways: with `omega = 1`
//! the plain iteration can swing between two shapes, and half-steps
//! (`omega = 1/2`, what the step did before) contract only by
//! `|1 + omega (d - 1)|` for a map of slope `d`: by one half where the
//! search hardly depends on the shape (`d ~ 0`: 8 rounds left `w` 4e-4
//! off), and not at all where it swings (`d ~ -3`: on the cube's
//! press-hold-retract run at 2 mm the weights stayed 0.03 to 0.07 apart
//! after 8 rounds, so the step's answer depended on where it started, 13 %
//! of the peak force apart between a chain of 1 ms steps and one of 20 ms
//! steps).
//!
//! Aitken's rule (as in partitioned fluid-structure coupling, Kuettler and
//! Wall 2008) estimates the slope from the last two residuals, a secant
//! along the last step:
//!
//! `omega_k = -omega_{k-1} (r_{k-1} . (r_k - r_{k-1})) / |r_k - r_{k-1}|^2`,
//!
//! which is `1 / (1 - d)` for a linear map of slope `d` (`1` for `d = 0`,
//! `1/4` for `d = -3`), the factor that lands on the fixed point. The dot
//! products run over the rows (by key) present in both rounds; a round
//! with none in common, or a degenerate secant, falls back to
//! [`OMEGA_START`]. `omega` is kept within `[OMEGA_MIN, 1]`: a round never
//! moves the rows past what its search found. Where the map jumps (a
//! corner's contact opening and closing from one round to the next) the
//! secant is no slope and the rounds need not converge; the step then ends
//! after its last search (see `CONTACT_SEARCHES`).
//!
//! Written here rather than taken from a crate: the rule is one formula
//! over the step's own rows, matched by key.

use std::collections::HashMap;

/// The relaxation of the first round (and after a reset): half-way.
pub const OMEGA_START: f64 = 0.5;
/// The least relaxation: a search never moves the rows by less than this
/// share of what it found.
pub const OMEGA_MIN: f64 = 0.05;

/// The relaxation's state within one step.
#[derive(Debug, Clone)]
pub struct Relaxation {
    omega: f64,
    /// The last round's residual of each point row, by key.
    last: HashMap<u64, [f64; 3]>,
}

impl Default for Relaxation {
    fn default() -> Self {
        Self {
            omega: OMEGA_START,
            last: HashMap::new(),
        }
    }
}

impl Relaxation {
    /// Forgets the rounds before (a new step, or a problem rebuilt).
    pub fn reset(&mut self) {
        self.omega = OMEGA_START;
        self.last.clear();
    }

    /// The relaxation for this round's residuals `r` (point rows' weight
    /// changes `g(x) - x`, by key), remembered for the next round.
    pub fn omega(&mut self, r: &[(u64, [f64; 3])]) -> f64 {
        let (mut num, mut den, mut common) = (0.0, 0.0, 0usize);
        for (key, rk) in r {
            if let Some(prev) = self.last.get(key) {
                common += 1;
                for a in 0..3 {
                    let dr = rk[a] - prev[a];
                    num += prev[a] * dr;
                    den += dr * dr;
                }
            }
        }
        self.omega = if common > 0 && den > 0.0 && num.is_finite() && den.is_finite() {
            (-self.omega * num / den).clamp(OMEGA_MIN, 1.0)
        } else {
            OMEGA_START
        };
        self.last.clear();
        self.last.extend(r.iter().copied());
        self.omega
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Iterates `x <- x + omega (g(x) - x)` for the affine map
    /// `g(x) = x* + d (x - x*)` on one row of three weights and returns how
    /// far from `x*` it ends after `rounds` rounds.
    fn iterate(d: f64, rounds: usize, relax: bool) -> f64 {
        let target = [0.2, 0.3, 0.5];
        let mut x = [0.3, 0.25, 0.45];
        let mut rel = Relaxation::default();
        for _ in 0..rounds {
            let r = [0, 1, 2].map(|a| target[a] + d * (x[a] - target[a]) - x[a]);
            let omega = if relax {
                rel.omega(&[(7, r)])
            } else {
                OMEGA_START
            };
            for a in 0..3 {
                x[a] += omega * r[a];
            }
        }
        (0..3).map(|a| (x[a] - target[a]).abs()).fold(0.0, f64::max)
    }

    #[test]
    fn aitken_lands_on_the_fixed_point_of_a_linear_map_where_half_steps_do_not() {
        // (Slopes in (0, 1) would ask for more than a whole step, which
        // the bound refuses.)
        for d in [0.0, -1.0, -3.0, -6.0] {
            let aitken = iterate(d, 3, true);
            assert!(aitken < 1e-12, "slope {d}: {aitken:e} off after 3 rounds");
        }
        // Half-steps: one half a round at slope 0, none at slope -3.
        assert!(iterate(0.0, 8, false) > 1e-4);
        assert!(iterate(-3.0, 8, false) > 1e-2);
    }

    #[test]
    fn rows_in_one_round_only_do_not_enter_the_secant() {
        let mut rel = Relaxation::default();
        assert_eq!(rel.omega(&[(1, [0.1, 0.0, -0.1])]), OMEGA_START);
        // Key 1 gone, key 2 new: nothing in common, back to the start.
        assert_eq!(rel.omega(&[(2, [0.1, 0.0, -0.1])]), OMEGA_START);
        // Key 2 again, its residual halved (slope 0 under half-steps).
        let w = rel.omega(&[(2, [0.05, 0.0, -0.05]), (3, [9.0, 9.0, 9.0])]);
        assert!((w - 1.0).abs() < 1e-12, "{w}");
        // A residual that did not change: no secant, the start value.
        assert_eq!(rel.omega(&[(2, [0.05, 0.0, -0.05])]), OMEGA_START);
    }

    #[test]
    fn omega_stays_within_its_bounds() {
        let mut rel = Relaxation::default();
        rel.omega(&[(1, [1.0, 0.0, 0.0])]);
        // Residual grew the same way: the secant asks for a negative factor.
        assert_eq!(rel.omega(&[(1, [2.0, 0.0, 0.0])]), OMEGA_MIN);
        rel.reset();
        rel.omega(&[(1, [1.0, 0.0, 0.0])]);
        // Residual nearly unchanged, shrinking: the secant asks for far
        // more than 1.
        assert_eq!(rel.omega(&[(1, [0.999, 0.0, 0.0])]), 1.0);
    }
}
