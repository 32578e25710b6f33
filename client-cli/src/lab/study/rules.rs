//! The contact rule under each support: the grid's runs that differ from a
//! frictionless run only in the contact law (Coulomb friction, the paper's
//! projection) are compared with that frictionless *twin* (the same mesh,
//! strategy, element and support), so the rule's own error is told from
//! the mesh's and the support's, which the comparison with the reference
//! mixes in.
//!
//! Frictionless (Signorini) contact is what the reference solves; a law's
//! error against its twin is therefore what choosing it costs in accuracy
//! on that configuration, and its error against the reference what the
//! configuration as a whole costs.

use super::Row;
use super::compare::{self, Errors};
use super::config::{Config, Support};
use super::driver::RunResult;
use fissure_engine::scene::ContactLaw;
use serde::Serialize;

/// One run of a contact law under a support.
#[derive(Debug, Clone, Serialize)]
pub struct RuleRow {
    /// The run's label.
    pub label: String,
    /// How the brain is held.
    pub support: &'static str,
    /// The contact law (`frictionless`, `coulomb`, `paper`).
    pub law: &'static str,
    /// Coulomb's coefficient, when the law has one.
    pub friction_coefficient: Option<f64>,
    /// Mean time per deformation step, ms.
    pub ms_per_step: f64,
    /// Failed steps (each keeps the last good state).
    pub failed_steps: usize,
    /// Net force magnitude on each instrument at the last step, N.
    pub final_force_n: [f64; 2],
    /// Errors against the study's reference.
    pub vs_reference: Option<Errors>,
    /// Errors against the frictionless run of the same configuration and
    /// support (`None` for the frictionless run itself).
    pub vs_frictionless: Option<Errors>,
}

/// The configuration with its contact law made frictionless and its names
/// blanked: equal for a run and its frictionless twin.
fn twin_key(c: &Config) -> Config {
    Config {
        label: String::new(),
        sweep: String::new(),
        contact_law: ContactLaw::Frictionless,
        friction_coefficient: None,
        ..c.clone()
    }
}

/// Where `x` stands in `all` (the tables' order).
fn order<T: PartialEq>(all: &[T], x: &T) -> usize {
    all.iter().position(|a| a == x).unwrap_or(all.len())
}

/// The rows of every grid run that has a frictionless twin with another
/// law beside it (and of those twins), ordered by support, then law.
pub fn evaluate(runs: &[(&RunResult, &Row)]) -> Vec<RuleRow> {
    let frictionless: Vec<&(&RunResult, &Row)> = runs
        .iter()
        .filter(|(r, _)| r.config.contact_law == ContactLaw::Frictionless)
        .collect();
    let twin_of = |c: &Config| {
        let key = twin_key(c);
        frictionless
            .iter()
            .find(|(f, _)| twin_key(&f.config) == key)
            .map(|(f, _)| *f)
    };
    let has_other_law = |f: &RunResult| {
        let key = twin_key(&f.config);
        runs.iter().any(|(r, _)| {
            r.config.contact_law != ContactLaw::Frictionless && twin_key(&r.config) == key
        })
    };
    let mut out: Vec<(usize, usize, RuleRow)> = Vec::new();
    for (run, row) in runs {
        let c = &run.config;
        let vs_frictionless = if c.contact_law == ContactLaw::Frictionless {
            if !has_other_law(run) {
                continue;
            }
            None
        } else {
            let Some(twin) = twin_of(c) else { continue };
            let region = compare::region_vertices(twin);
            Some(compare::compare(twin, &region, run))
        };
        out.push((
            order(&Support::ALL, &c.support),
            order(&ContactLaw::ALL, &c.contact_law),
            RuleRow {
                label: c.label.clone(),
                support: c.support.name(),
                law: c.contact_law.name(),
                friction_coefficient: c.friction_coefficient,
                ms_per_step: row.ms_per_step,
                failed_steps: row.failed_steps,
                final_force_n: row.final_force_n,
                vs_reference: row.errors,
                vs_frictionless,
            },
        ));
    }
    out.sort_by_key(|(s, l, _)| (*s, *l));
    out.into_iter().map(|(_, _, r)| r).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_law_and_its_frictionless_twin_share_a_key_and_another_support_does_not() {
        let base = Config {
            support: Support::Foundation,
            ..Config::baseline()
        }
        .labelled();
        let paper = Config {
            contact_law: ContactLaw::Paper,
            ..base.clone()
        }
        .labelled();
        let coulomb = Config {
            contact_law: ContactLaw::Coulomb,
            friction_coefficient: Some(0.2),
            ..base.clone()
        }
        .labelled();
        assert_ne!(base.label, paper.label);
        assert!(
            coulomb.label.ends_with("/coulomb-mu0.2/foundation"),
            "{}",
            coulomb.label
        );
        assert_eq!(twin_key(&paper), twin_key(&base));
        assert_eq!(twin_key(&coulomb), twin_key(&base));
        let stem_paper = Config {
            support: Support::Stem,
            ..paper.clone()
        };
        assert_ne!(twin_key(&stem_paper), twin_key(&base));
    }
}
