//! Outputs of the study: CSV, a markdown report, PNG plots.
//!
//! * `grid.csv`, `stability.csv`: one row per run (units in the headers);
//!   `convergence.csv`: one row per mesh level of the reference, with its
//!   family (`mesher`, or `refined <level>` for one shape refined
//!   uniformly) and the change into it from the family's coarser level;
//! * `study.md`: the tables and the stability checks;
//! * `error-vs-step-time.png`: RMS surface error against time per deformation
//!   step, the Pareto front marked; `force-error-vs-step-time.png` likewise
//!   for the force;
//! * `forces/<label>.png`: net force on each spatula against time, per
//!   configuration; `forces-all.png`: the left spatula's |F| of every
//!   configuration on one plot.

use super::convergence::{Convergence, Richardson};
use super::incompressible::Incompressible;
use super::stability::StabilityRow;
use super::{Row, StudyError, StudyResult};
use crate::client::render::plot::{
    Axis, InstrumentForces, LinePlot, Marker, ScatterGroup, ScatterPlot, Series, force_plot,
    palette,
};
use std::fmt::Write as _;
use std::path::Path;

fn io_err(path: &Path, e: impl std::fmt::Display) -> StudyError {
    StudyError::Output {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

fn write(path: &Path, text: &str) -> Result<(), StudyError> {
    std::fs::write(path, text).map_err(|e| io_err(path, e))
}

/// A file-name-safe version of a label.
pub fn slug(label: &str) -> String {
    label
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '.' || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

const GRID_HEADER: &str = "label,sweep,preset,proven,strategy,element,contact_law,friction_coefficient,support,tolerance,nodes_per_face,roi_mm,backend,threads,tets,nodes,steps,ms_per_step,collision_ms,us_per_sample,us_per_sample_p99,setup_ms,iterations_mean,iterations_max,min_det_f,finite,failed_steps,haptic_local_model,haptic_max_err_pct,haptic_rms_err_pct,haptic_checked,rms_err_mm,max_err_mm,ref_max_mm,force_err_left_n,force_err_left_pct,force_err_right_n,force_err_right_pct,final_force_err_left_pct,final_force_err_right_pct,final_force_left_n,final_force_right_n,mean_match_mm";

fn grid_csv_row(r: &Row) -> String {
    let c = &r.config;
    let e = r.errors.unwrap_or_default();
    format!(
        "{},{},{},{},{},{},{},{},{},{:e},{},{},{},{},{},{},{},{:.3},{:.3},{:.1},{:.1},{:.0},{:.2},{},{:.4},{},{},{},{},{},{},{:.4},{:.4},{:.4},{:.4},{:.2},{:.4},{:.2},{:.2},{:.2},{:.4},{:.4},{:.3}",
        c.label,
        c.sweep,
        c.preset,
        c.proven,
        c.strategy.name(),
        c.element.name(),
        c.contact_law.name(),
        c.friction_coefficient
            .map_or(String::new(), |mu| mu.to_string()),
        c.support.name(),
        c.tolerance,
        c.nodes_per_face,
        c.roi_m.map_or(String::new(), |d| format!("{:.0}", d * 1e3)),
        r.backend_used.replace(',', ";"),
        c.threads,
        r.tets,
        r.nodes,
        r.steps,
        r.ms_per_step,
        r.collision_ms,
        r.us_per_sample,
        r.us_per_sample_p99,
        r.setup_ms,
        r.iterations_mean,
        r.iterations_max,
        r.min_det_f,
        r.finite,
        r.failed_steps,
        r.haptic_local_model,
        r.haptic
            .map_or(String::new(), |h| format!("{:.3}", h.max_pct)),
        r.haptic
            .map_or(String::new(), |h| format!("{:.3}", h.rms_pct)),
        r.haptic.map_or(0, |h| h.checked),
        e.rms_mm,
        e.max_mm,
        e.ref_max_mm,
        e.force_rms_n[0],
        e.force_rms_pct[0],
        e.force_rms_n[1],
        e.force_rms_pct[1],
        e.final_force_pct[0],
        e.final_force_pct[1],
        r.final_force_n[0],
        r.final_force_n[1],
        e.mean_match_mm,
    )
}

const STAB_HEADER: &str = "label,dimension,strategy,element,youngs_pa,nu,speed_mps,steps,finite,min_det_f,iterations_mean,iterations_max,failed_steps,final_force_left_n,final_force_right_n,force_ratio,force_error_pct,stable,reason,ms_per_step";

fn stab_csv_row(s: &StabilityRow) -> String {
    let r = &s.row;
    format!(
        "{},{},{},{},{},{},{:.4},{},{},{:.4},{:.2},{},{},{:.5},{:.5},{:.4},{},{},\"{}\",{:.3}",
        r.config.label,
        s.dimension,
        r.config.strategy.name(),
        r.config.element.name(),
        r.config.youngs_pa,
        r.config.nu,
        r.speed_mps,
        r.steps,
        r.finite,
        r.min_det_f,
        r.iterations_mean,
        r.iterations_max,
        r.failed_steps,
        r.final_force_n[0],
        r.final_force_n[1],
        s.force_ratio,
        s.force_error_pct
            .map_or(String::new(), |e| format!("{e:.3}")),
        s.stable,
        s.reason.clone().unwrap_or_default().replace('"', "'"),
        r.ms_per_step,
    )
}

/// The markdown tables and checks.
pub fn markdown(res: &StudyResult) -> String {
    let mut md = String::new();
    let _ = writeln!(
        md,
        "Scenario: bundled Sylvian opening, nominal window 0-{:.2} s, deformation step every {} ms, force samples at {} Hz; {}, the runs took {:.0} s in all.\n",
        res.window_s,
        res.dt_s * 1e3,
        res.rate_hz,
        if res.quick {
            "quick variant"
        } else {
            "full study"
        },
        res.total_s
    );
    if !res.absent.is_empty() {
        let _ = writeln!(
            md,
            "**Incomplete: {} planned runs have no result and are left out:**\n",
            res.absent.len()
        );
        for a in &res.absent {
            let _ = writeln!(
                md,
                "- {} (index {}): {}",
                a.id,
                a.index,
                a.failure.as_deref().unwrap_or("missing")
            );
        }
        let _ = writeln!(md);
    }
    if !res.grid.is_empty() {
        let _ = writeln!(
            md,
            "### Speed against accuracy (errors against the reference, surface within {:.0} mm of the fissure centre)\n",
            super::compare::ERROR_RADIUS_M * 1e3
        );
        let _ = writeln!(
            md,
            "| configuration | sweep | tets | ms/step | us/force sample | iterations (mean/max) | RMS err (mm) | max err (mm) | force err L (N, %) | force err R (N, %) | min det F | failed steps | haptic local model | haptic err max / RMS (% peak) |"
        );
        let _ = writeln!(
            md,
            "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|"
        );
        for r in res.reference.iter().chain(&res.grid) {
            let e = r.errors.unwrap_or_default();
            let _ = writeln!(
                md,
                "| {}{} | {} | {} | {:.1} | {:.0} | {:.1} / {} | {:.3} | {:.3} | {:.3}, {:.1}% | {:.3}, {:.1}% | {:.3} | {} | {} | {} |",
                r.config.label,
                if r.backend_used.starts_with(r.config.backend.name()) {
                    String::new()
                } else {
                    format!(" ({})", r.backend_used)
                },
                r.config.sweep,
                r.tets,
                r.ms_per_step,
                r.us_per_sample,
                r.iterations_mean,
                r.iterations_max,
                e.rms_mm,
                e.max_mm,
                e.force_rms_n[0],
                e.force_rms_pct[0],
                e.force_rms_n[1],
                e.force_rms_pct[1],
                r.min_det_f,
                r.failed_steps,
                if r.haptic_local_model { "yes" } else { "no" },
                r.haptic.map_or("-".into(), |h| format!(
                    "{:.2} / {:.2}",
                    h.max_pct, h.rms_pct
                )),
            );
        }
        let failed: Vec<&Row> = res
            .reference
            .iter()
            .chain(&res.grid)
            .filter(|r| r.failed_steps > 0)
            .collect();
        if !failed.is_empty() {
            let _ = writeln!(
                md,
                "\nRuns with failed steps (each failed step keeps the last good state, so their errors measure the failure, not the configuration):\n"
            );
            for r in failed {
                let _ = writeln!(
                    md,
                    "- {}: {} of {} steps; first: {}",
                    r.config.label,
                    r.failed_steps,
                    r.steps,
                    r.failure.as_deref().unwrap_or("-")
                );
            }
        }
        if let Some(r) = &res.reference {
            let e = r.errors.unwrap_or_default();
            let _ = writeln!(
                md,
                "\nReference: {} ({} region points; largest reference displacement there {:.2} mm; final net force L {:.3} N, R {:.3} N).\n",
                r.config.label, e.points, e.ref_max_mm, r.final_force_n[0], r.final_force_n[1]
            );
        }
    }
    if !res.contact_rules.is_empty() {
        rules_markdown(&mut md, &res.contact_rules);
    }
    if let Some(c) = &res.convergence {
        convergence_markdown(&mut md, c);
    }
    if let Some(n) = &res.incompressible {
        incompressible_markdown(&mut md, n);
    }
    if !res.stability.is_empty() {
        let _ = writeln!(md, "### Stability at the extremes\n");
        let _ = writeln!(
            md,
            "| run | strategy (element) | E (Pa) | nu | speed (mm/s) | finite | min det F | iterations (mean/max) | F/F0 | force err | verdict |"
        );
        let _ = writeln!(md, "|---|---|---:|---:|---:|---|---:|---:|---:|---:|---|");
        for s in &res.stability {
            let r = &s.row;
            let _ = writeln!(
                md,
                "| {} | {} ({}) | {} | {} | {:.1} | {} | {:.3} | {:.1} / {} | {:.3} | {} | {} |",
                r.config.label,
                r.config.strategy.name(),
                r.config.element.name(),
                r.config.youngs_pa,
                r.config.nu,
                r.speed_mps * 1e3,
                if r.finite { "yes" } else { "NO" },
                r.min_det_f,
                r.iterations_mean,
                r.iterations_max,
                s.force_ratio,
                s.force_error_pct.map_or("-".into(), |e| format!("{e:.2}%")),
                if s.stable {
                    "stable".to_string()
                } else {
                    format!("FAILS: {}", s.reason.clone().unwrap_or_default())
                },
            );
        }
        let _ = writeln!(md, "\nChecks:\n");
        for c in &res.checks {
            let _ = writeln!(
                md,
                "- [{}] {} ({})",
                if c.passed { "x" } else { " " },
                c.name,
                c.detail
            );
        }
    }
    md
}

fn pct_pair(e: &Option<super::compare::Errors>) -> String {
    e.map_or("-".into(), |e| {
        format!("{:.1} / {:.1}", e.force_rms_pct[0], e.force_rms_pct[1])
    })
}

fn mm_pair(e: &Option<super::compare::Errors>) -> String {
    e.map_or("-".into(), |e| format!("{:.3} / {:.3}", e.rms_mm, e.max_mm))
}

/// A section's heading, its paragraph and a table's header row.
fn table_head(md: &mut String, heading: &str, intro: &str, columns: &[&str], align: &str) {
    let _ = writeln!(md, "{heading}\n\n{intro}\n");
    let _ = writeln!(md, "| {} |", columns.join(" | "));
    let _ = writeln!(md, "{align}");
}

fn rules_markdown(md: &mut String, rows: &[super::rules::RuleRow]) {
    table_head(
        md,
        "### The contact rule under each support",
        "Each law beside the frictionless run of the same configuration and support (its twin): the error against the twin is the rule's own; the error against the reference adds the mesh's and the support's. Force errors are RMS over the steps, % of the compared run's peak (left / right); displacement errors RMS / max, mm.",
        &[
            "support",
            "rule",
            "ms/step",
            "failed steps",
            "final force L / R (N)",
            "force err vs reference (%)",
            "displ. err vs reference (mm)",
            "force err vs frictionless twin (%)",
            "displ. err vs twin (mm)",
        ],
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    );
    for r in rows {
        let law = match r.friction_coefficient {
            Some(mu) => format!("{} (mu {mu})", r.law),
            None => r.law.to_string(),
        };
        let _ = writeln!(
            md,
            "| {} | {law} | {:.1} | {} | {:.4} / {:.4} | {} | {} | {} | {} |",
            r.support,
            r.ms_per_step,
            r.failed_steps,
            r.final_force_n[0],
            r.final_force_n[1],
            pct_pair(&r.vs_reference),
            mm_pair(&r.vs_reference),
            pct_pair(&r.vs_frictionless),
            mm_pair(&r.vs_frictionless),
        );
    }
    let paper: Vec<_> = rows.iter().filter(|r| r.law == "paper").collect();
    if paper.is_empty() {
        return;
    }
    let _ = writeln!(md);
    table_head(
        md,
        "### The paper rule's error",
        "The paper's projection (all three components of every paired triangle's vertices fixed on the face plane) against frictionless contact on the same mesh and support, and against the reference.",
        &[
            "support",
            "force err vs frictionless L / R (N)",
            "(% of peak)",
            "final force change L / R (%)",
            "displ. err RMS / max (mm)",
            "force err vs reference (%)",
        ],
        "|---|---:|---:|---:|---:|---:|",
    );
    for r in paper {
        let twin = r.vs_frictionless;
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} |",
            r.support,
            twin.map_or("-".into(), |e| format!(
                "{:.4} / {:.4}",
                e.force_rms_n[0], e.force_rms_n[1]
            )),
            pct_pair(&twin),
            twin.map_or("-".into(), |e| format!(
                "{:.1} / {:.1}",
                e.final_force_pct[0], e.final_force_pct[1]
            )),
            mm_pair(&twin),
            pct_pair(&r.vs_reference),
        );
    }
    let _ = writeln!(md);
}

/// A Richardson estimate in words; `unit` follows the limit (`" N"`, or
/// empty for a ratio).
fn richardson_text(r: &Richardson, unit: &str) -> String {
    match *r {
        Richardson::Asymptotic {
            order,
            limit,
            finest_error_pct,
        } => format!(
            "order {order:.2}, limit {limit:.4}{unit} (finest level {finest_error_pct:.2}% from it)"
        ),
        Richardson::NotAsymptotic {
            change_ratio,
            order,
        } => format!(
            "not in the asymptotic range (change ratio (F0-F1)/(F1-F2) = {change_ratio:.3}{})",
            order.map_or(String::new(), |p| format!(", order {p:.1}"))
        ),
    }
}

fn convergence_markdown(md: &mut String, c: &Convergence) {
    let _ = writeln!(md, "### Convergence of the reference over the mesh\n");
    if !c.levels.is_empty() {
        let _ = writeln!(md, "The mesher's levels (each meshes the shape anew):\n");
        chain_markdown(md, c);
    }
    for f in &c.refined {
        let _ = writeln!(
            md,
            "One shape refined uniformly ({}: each tetrahedron into eight, h halved):\n",
            f.levels.first().map_or("", |l| l.label.as_str())
        );
        chain_markdown(md, f);
    }
}

fn chain_markdown(md: &mut String, c: &Convergence) {
    let _ = writeln!(
        md,
        "| level | tets | nodes | h (mm) | final force L / R (N) | peak force L / R (N) | ms/step | iterations (mean) | failed steps |"
    );
    let _ = writeln!(md, "|---|---:|---:|---:|---:|---:|---:|---:|---:|");
    for l in &c.levels {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {:.3} | {:.4} / {:.4} | {:.4} / {:.4} | {:.0} | {:.2} | {} |",
            l.label,
            l.tets,
            l.nodes,
            l.h_mm,
            l.final_force_n[0],
            l.final_force_n[1],
            l.peak_force_n[0],
            l.peak_force_n[1],
            l.ms_per_step,
            l.iterations_mean,
            l.failed_steps,
        );
    }
    let _ = writeln!(
        md,
        "\n| from | to | final force change L / R (%) | peak force change L / R (%) | displacement difference RMS / max (mm) | finer level's largest displacement (mm) | rest surfaces apart RMS / max (mm) | region points |"
    );
    let _ = writeln!(md, "|---|---|---:|---:|---:|---:|---:|---:|");
    for ch in &c.changes {
        let _ = writeln!(
            md,
            "| {} | {} | {:.2} / {:.2} | {:.2} / {:.2} | {:.3} / {:.3} | {:.2} | {:.3} / {:.3} | {} |",
            ch.from,
            ch.to,
            ch.final_force_change_pct[0],
            ch.final_force_change_pct[1],
            ch.peak_force_change_pct[0],
            ch.peak_force_change_pct[1],
            ch.rms_mm,
            ch.max_mm,
            ch.ref_max_mm,
            ch.rest_rms_mm,
            ch.rest_max_mm,
            ch.points,
        );
    }
    let _ = writeln!(md);
    for (name, r) in [("final", &c.richardson_final), ("peak", &c.richardson_peak)] {
        if let Some([l, r]) = r {
            let _ = writeln!(
                md,
                "- Richardson, {name} net force: left {}; right {}",
                richardson_text(l, " N"),
                richardson_text(r, " N")
            );
        }
    }
    for t in &c.two_level {
        let _ = writeln!(
            md,
            "- two levels, assumed order {}: limit L {:.4} N, R {:.4} N (finest level {:.2}% / {:.2}% from it)",
            t.order, t.limit_n[0], t.limit_n[1], t.finest_error_pct[0], t.finest_error_pct[1]
        );
    }
    let _ = writeln!(
        md,
        "- [{}] the final net force changes by under {}% between the last two levels on both spatulas\n",
        if c.met { "x" } else { " " },
        c.criterion_pct
    );
}

fn incompressible_markdown(md: &mut String, n: &Incompressible) {
    let _ = writeln!(
        md,
        "### Towards incompressibility on the 204k level ({})\n",
        n.level
    );
    let _ = writeln!(
        md,
        "F: both spatulas' final net force magnitudes summed; R = F(nu) / F(0.45).\n"
    );
    let _ = write!(md, "| nu |");
    for e in &n.elements {
        let _ = write!(md, " {0} F (N) | {0} R | {0} failed steps |", e.element);
    }
    let _ = writeln!(md);
    let _ = writeln!(md, "|---:|{}", "---:|---:|---:|".repeat(n.elements.len()));
    let f = |v: Option<f64>, d: usize| v.map_or("-".to_string(), |v| format!("{v:.d$}"));
    for (i, nu) in n.nus.iter().enumerate() {
        let _ = write!(md, "| {nu} |");
        for e in &n.elements {
            let _ = write!(
                md,
                " {} | {} | {} |",
                f(e.force_n[i], 4),
                f(e.ratio[i], 3),
                e.failed_steps[i].map_or("-".into(), |s| s.to_string())
            );
        }
        let _ = writeln!(md);
    }
    let _ = writeln!(
        md,
        "\nNodal-pressure R({}) per level:\n",
        n.nus[n.nus.len() - 1]
    );
    for (label, h, r) in &n.limit_by_level {
        let _ = writeln!(md, "- {label} (h {h:.3} mm): {r:.4}");
    }
    if let Some(r) = &n.richardson {
        let mut text = richardson_text(r, "");
        if matches!(r, Richardson::NotAsymptotic { .. }) {
            text.push_str(": the finest level's value stands for the limit");
        }
        let _ = writeln!(md, "- Richardson over the last three levels: {text}");
    }
    let _ = writeln!(
        md,
        "- converged nearly incompressible R: {}; the sweep level's R deviates by {} (tet4) and {} (nodal pressure)",
        f(n.converged_ratio, 4),
        n.deviation_pct[0].map_or("-".into(), |d| format!("{d:.1}%")),
        n.deviation_pct[1].map_or("-".into(), |d| format!("{d:.1}%")),
    );
    let _ = writeln!(
        md,
        "- [{}] nodal pressure within {}% of the converged answer\n",
        if n.met { "x" } else { " " },
        n.tolerance_pct
    );
}

const CONVERGENCE_HEADER: &str = "family,label,tets,nodes,h_mm,final_force_left_n,final_force_right_n,peak_force_left_n,peak_force_right_n,ms_per_step,iterations_mean,failed_steps,final_change_left_pct,final_change_right_pct,peak_change_left_pct,peak_change_right_pct,rms_diff_mm,max_diff_mm,rest_rms_mm,rest_max_mm";

fn convergence_csv(c: &Convergence) -> String {
    let mut csv = String::from(CONVERGENCE_HEADER);
    csv.push('\n');
    chain_csv(&mut csv, "mesher", c);
    for f in &c.refined {
        let family = f.levels.first().map_or("", |l| l.label.as_str());
        chain_csv(&mut csv, &format!("refined {family}"), f);
    }
    csv
}

/// The rows of one chain of levels, each named by `family`.
fn chain_csv(csv: &mut String, family: &str, c: &Convergence) {
    for (i, l) in c.levels.iter().enumerate() {
        // The change into this level from the coarser one (none for the first).
        let ch = i.checked_sub(1).and_then(|j| c.changes.get(j));
        let opt =
            |v: Option<f64>, digits: usize| v.map_or(String::new(), |v| format!("{v:.digits$}"));
        let _ = writeln!(
            csv,
            "{family},{},{},{},{:.4},{:.6},{:.6},{:.6},{:.6},{:.1},{:.2},{},{},{},{},{},{},{},{},{}",
            l.label,
            l.tets,
            l.nodes,
            l.h_mm,
            l.final_force_n[0],
            l.final_force_n[1],
            l.peak_force_n[0],
            l.peak_force_n[1],
            l.ms_per_step,
            l.iterations_mean,
            l.failed_steps,
            opt(ch.map(|c| c.final_force_change_pct[0]), 3),
            opt(ch.map(|c| c.final_force_change_pct[1]), 3),
            opt(ch.map(|c| c.peak_force_change_pct[0]), 3),
            opt(ch.map(|c| c.peak_force_change_pct[1]), 3),
            opt(ch.map(|c| c.rms_mm), 4),
            opt(ch.map(|c| c.max_mm), 4),
            opt(ch.map(|c| c.rest_rms_mm), 4),
            opt(ch.map(|c| c.rest_max_mm), 4),
        );
    }
}

fn pareto_plot(
    res: &StudyResult,
    title: &str,
    y_title: &str,
    y: impl Fn(&Row) -> f64,
) -> ScatterPlot {
    let mut plot = ScatterPlot::new(
        title,
        Axis::log("time per deformation step (ms)"),
        Axis::log(y_title),
    );
    let mut sweeps: Vec<&str> = Vec::new();
    for r in &res.grid {
        if !sweeps.contains(&r.config.sweep.as_str()) {
            sweeps.push(&r.config.sweep);
        }
    }
    let markers = [Marker::Circle, Marker::Square, Marker::Diamond];
    for (i, sw) in sweeps.iter().enumerate() {
        let rows: Vec<&Row> = res
            .grid
            .iter()
            .filter(|r| r.config.sweep == *sw && r.ms_per_step > 0.0 && y(r) > 0.0)
            .collect();
        if rows.is_empty() {
            continue;
        }
        plot.add(ScatterGroup {
            label: (*sw).to_string(),
            points: rows.iter().map(|r| [r.ms_per_step, y(r)]).collect(),
            point_labels: rows.iter().map(|r| r.config.label.clone()).collect(),
            colour: palette(i),
            marker: markers[i % markers.len()],
        });
    }
    plot
}

/// Writes every output into `dir`.
pub fn write_all(
    dir: &Path,
    res: &StudyResult,
    forces: &[(String, Vec<InstrumentForces>)],
) -> Result<(), StudyError> {
    std::fs::create_dir_all(dir.join("forces")).map_err(|e| io_err(dir, e))?;
    if res.reference.is_some() || !res.grid.is_empty() {
        let mut csv = String::from(GRID_HEADER);
        csv.push('\n');
        for r in res.reference.iter().chain(&res.grid) {
            csv.push_str(&grid_csv_row(r));
            csv.push('\n');
        }
        write(&dir.join("grid.csv"), &csv)?;
    }
    // The Pareto plots need errors: none without the reference (a merge
    // with --allow-missing whose reference is missing).
    if res.reference.is_some() && !res.grid.is_empty() {
        let p = dir.join("error-vs-step-time.png");
        pareto_plot(
            res,
            "Surface error against time per step (Pareto front)",
            "RMS surface displacement error (mm)",
            |r| r.errors.map_or(f64::NAN, |e| e.rms_mm),
        )
        .save_png(&p)
        .map_err(|e| io_err(&p, e))?;
        let p = dir.join("force-error-vs-step-time.png");
        pareto_plot(
            res,
            "Force error against time per step (Pareto front)",
            "RMS net force error, left spatula (% of peak)",
            |r| r.errors.map_or(f64::NAN, |e| e.force_rms_pct[0]),
        )
        .save_png(&p)
        .map_err(|e| io_err(&p, e))?;
    }
    if let Some(c) = &res.convergence {
        write(&dir.join("convergence.csv"), &convergence_csv(c))?;
    }
    if !forces.is_empty() {
        let mut all = LinePlot::new(
            "Net force on the left spatula, every configuration",
            Axis::linear("time (s)"),
            Axis::linear("|F| (N)"),
        );
        for (i, (label, f)) in forces.iter().enumerate() {
            let p = dir.join("forces").join(format!("{}.png", slug(label)));
            force_plot(&format!("Net forces: {label}"), f, true, None)
                .save_png(&p)
                .map_err(|e| io_err(&p, e))?;
            if let Some(left) = f.first() {
                let pts = left
                    .time
                    .iter()
                    .zip(&left.force)
                    .map(|(t, v)| [*t, (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()])
                    .collect();
                all.add(
                    Series::new(label.clone(), pts, palette(i)).width(if i == 0 {
                        3.0
                    } else {
                        1.4
                    }),
                );
            }
        }
        let p = dir.join("forces-all.png");
        all.save_png(&p).map_err(|e| io_err(&p, e))?;
    }
    if !res.stability.is_empty() {
        let mut csv = String::from(STAB_HEADER);
        csv.push('\n');
        for s in &res.stability {
            csv.push_str(&stab_csv_row(s));
            csv.push('\n');
        }
        write(&dir.join("stability.csv"), &csv)?;
    }
    write(&dir.join("study.md"), &markdown(res))?;
    let json = serde_json::to_string_pretty(res).map_err(|e| io_err(dir, e))?;
    write(&dir.join("study.json"), &json)?;
    Ok(())
}
