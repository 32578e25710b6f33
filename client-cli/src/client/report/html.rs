//! `fissure report --html`: one self-contained page a teacher opens in a
//! browser. Nothing is fetched: the plots are inline SVG drawn by
//! `plotters`' SVG backend, the strain picture an inline PNG (a `data:`
//! URL) drawn by the project's rasteriser, the style inline; the page has
//! no script.
//!
//! It holds the score table (each measure against its levels, pass, warn
//! or fail), force, retraction pressure and strain against time per
//! instrument with the levels drawn, the brain at the frame of the worst
//! strain coloured by it, and the events with their times. With an expert's
//! session beside it (`--compare`), both sessions share every table and
//! every axis (the expert dashed).
//!
//! The page is written to a temporary file beside the target and renamed
//! over it, so a failure never leaves half a page.

use super::Report;
use super::assess::Score;
use crate::client::render::frame::{Caption, FrameRenderer};
use crate::client::render::plot::palette;
use crate::client::watch::view::SessionView;
use anyhow::Context;
use fissure_shared::assessment::{Grade, PA_PER_MMHG};
use plotters::prelude::*;
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;

/// Points of a force curve drawn at most (the samples are thinned by
/// keeping each bucket's smallest and largest value, so peaks stay).
const MAX_POINTS: usize = 1500;

/// Plot size, px.
const PLOT_W: u32 = 820;
const PLOT_H: u32 = 300;

/// Picture size, px.
const PICTURE_W: u32 = 640;
const PICTURE_H: u32 = 420;

/// Writes the page of `trainee` (and `expert` beside it) to `out`.
pub fn write(
    out: &Path,
    trainee: &Report,
    trainee_name: &str,
    expert: Option<(&Report, &str)>,
) -> anyhow::Result<()> {
    let page = page(trainee, trainee_name, expert)?;
    let dir = out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let mut tmp = tempfile::NamedTempFile::new_in(dir)
        .with_context(|| format!("cannot create a temporary file in {}", dir.display()))?;
    tmp.write_all(page.as_bytes())
        .and_then(|_| tmp.flush())
        .with_context(|| format!("cannot write {}", tmp.path().display()))?;
    // A page to share: readable by others, as a file written directly is
    // (the temporary file is private).
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        tmp.as_file()
            .set_permissions(std::fs::Permissions::from_mode(0o644))
            .with_context(|| format!("cannot set the permissions of {}", tmp.path().display()))?;
    }
    tmp.persist(out)
        .with_context(|| format!("cannot write {}", out.display()))?;
    Ok(())
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

fn grade_cell(g: Grade) -> String {
    format!("<td class=\"{0}\">{0}</td>", g.name())
}

/// The whole page.
pub fn page(
    trainee: &Report,
    trainee_name: &str,
    expert: Option<(&Report, &str)>,
) -> anyhow::Result<String> {
    let mut h = String::new();
    let title = format!("fissure session report: {}", escape(&trainee.scene));
    let _ = write!(
        h,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <meta http-equiv=\"Content-Security-Policy\" content=\"default-src 'none'; img-src data:; style-src 'unsafe-inline'\">\
         <title>{title}</title><style>{STYLE}</style></head><body>\n<h1>{title}</h1>\n"
    );
    let overall = |r: &Report| r.assessment.grade.unwrap_or(Grade::Pass);
    let _ = write!(
        h,
        "<p class=\"lead\">Session <b>{}</b>: {:.2} s, {} frames. Overall: <span class=\"{g}\">{g}</span>.",
        escape(trainee_name),
        trainee.duration_s,
        trainee.frames,
        g = overall(trainee).name()
    );
    if let Some((e, name)) = expert {
        let _ = write!(
            h,
            " Beside it, <b>{}</b> (dashed in the plots): {:.2} s, overall <span class=\"{g}\">{g}</span>.",
            escape(name),
            e.duration_s,
            g = overall(e).name()
        );
    }
    h.push_str("</p>\n");
    if !trainee.assessment.thresholds_from_scene {
        h.push_str(
            "<p class=\"note\">This recording carries no thresholds (an older version): \
             the defaults are used.</p>\n",
        );
    }
    h.push_str(&scores_table(trainee, expert.map(|e| e.0)));
    h.push_str(&plots(trainee, expert.map(|e| e.0))?);
    h.push_str(&pictures(trainee, trainee_name, expert)?);
    h.push_str("<h2>Events</h2>\n");
    h.push_str(&events_table(trainee, trainee_name));
    if let Some((e, name)) = expert {
        h.push_str(&events_table(e, name));
    }
    h.push_str(NOTES);
    h.push_str("</body></html>\n");
    Ok(h)
}

const STYLE: &str = "body{font-family:sans-serif;margin:2em auto;max-width:900px;color:#222}\
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:4px 8px;text-align:left}\
th{background:#eee}.pass{background:#d7f0d2}.warn{background:#fbe7b5}.fail{background:#f6c4c0;font-weight:bold}\
span.pass,span.warn,span.fail{padding:2px 8px;border-radius:4px}\
.lead{font-size:1.1em}.note{color:#555;font-size:.9em}figure{margin:1em 0}img{max-width:100%}";

const NOTES: &str = "<h2>Where the levels come from</h2>\n<p class=\"note\">\
Retraction pressure: 20 mmHg warns and 30 mmHg fails (Rosenørn and Diemer, J. Neurosurg. 63:608, 1985: \
15 min of retractor pressure infarcted 1 of 6 rat brains at 20 mmHg, 5 of 6 at 30 mmHg); \
15 min above the warning pressure fails, 5 min warns (assumed); the pressure-time product fails at \
300 mmHg min (20 mmHg for 15 min), warns at 100 (assumed). Strain: the largest principal Green-Lagrange \
strain warns at 0.14 and fails at 0.21 (Bain and Meaney, J. Biomech. Eng. 122:615, 2000, conservative and \
optimal thresholds of morphological axonal injury); the volume above 0.14 warns at 1 mm³ and fails at \
100 mm³ (assumed). A scene's <code>[assessment]</code> may set its own. The pressure is the contact \
solve's normal force over the area it pushes; its peak at the plate's edges depends on the mesh, \
so the levels are stated for the mean.</p>\n";

fn scores_table(t: &Report, e: Option<&Report>) -> String {
    let mut h = String::from(
        "<h2>Scores</h2>\n<table><tr><th>measure</th><th>instrument</th><th>session</th><th>grade</th>",
    );
    if e.is_some() {
        h.push_str("<th>beside it</th><th>grade</th>");
    }
    h.push_str("<th>warns at</th><th>fails at</th></tr>\n");
    let find = |r: &Report, s: &Score| -> Option<Score> {
        r.assessment
            .scores
            .iter()
            .find(|o| o.measure == s.measure && o.instrument == s.instrument)
            .cloned()
    };
    for s in &t.assessment.scores {
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{}</td><td>{}</td>{}",
            escape(&s.measure),
            escape(s.instrument.as_deref().unwrap_or("")),
            escape(&s.shown(s.value)),
            grade_cell(s.grade)
        );
        if let Some(e) = e {
            match find(e, s) {
                Some(o) => {
                    let _ = write!(
                        h,
                        "<td>{}</td>{}",
                        escape(&o.shown(o.value)),
                        grade_cell(o.grade)
                    );
                }
                None => h.push_str("<td>—</td><td></td>"),
            }
        }
        let _ = writeln!(
            h,
            "<td>{}</td><td>{}</td></tr>",
            escape(&s.shown(s.levels.warn)),
            escape(&s.shown(s.levels.fail))
        );
    }
    h.push_str("</table>\n");
    h
}

fn events_table(r: &Report, name: &str) -> String {
    let events = &r.assessment.events;
    if events.is_empty() {
        return format!(
            "<p>{}: no event (no tie released, no force clamped, no pose jump).</p>\n",
            escape(name)
        );
    }
    let mut h = format!(
        "<table><caption>{}</caption><tr><th>time (s)</th><th>instrument</th><th>what</th></tr>\n",
        escape(name)
    );
    for e in events {
        let _ = writeln!(
            h,
            "<tr{}><td>{:.3}</td><td>{}</td><td>{}{}</td></tr>",
            if e.injury { " class=\"fail\"" } else { "" },
            e.t_s,
            escape(&e.instrument),
            escape(&e.what),
            if e.injury { " (an injury)" } else { "" }
        );
    }
    h.push_str("</table>\n");
    h
}

/// Thins `points` to about [`MAX_POINTS`], keeping each bucket's lowest
/// and highest value in time order.
fn thin(points: &[[f64; 2]]) -> Vec<[f64; 2]> {
    if points.len() <= MAX_POINTS {
        return points.to_vec();
    }
    let per = points.len().div_ceil(MAX_POINTS / 2);
    let mut out = Vec::with_capacity(MAX_POINTS + 2);
    for chunk in points.chunks(per) {
        let lo = chunk.iter().min_by(|a, b| a[1].total_cmp(&b[1])).copied();
        let hi = chunk.iter().max_by(|a, b| a[1].total_cmp(&b[1])).copied();
        if let (Some(lo), Some(hi)) = (lo, hi) {
            if lo[0] <= hi[0] {
                out.extend([lo, hi]);
            } else {
                out.extend([hi, lo]);
            }
        }
    }
    out
}

/// One curve of a plot.
struct Curve {
    label: String,
    points: Vec<[f64; 2]>,
    colour: [u8; 3],
    dashed: bool,
}

/// A level drawn across a plot.
struct Level {
    y: f64,
    label: String,
    colour: RGBColor,
}

fn plots(t: &Report, e: Option<&Report>) -> anyhow::Result<String> {
    let sessions: Vec<(&Report, bool)> = std::iter::once((t, false))
        .chain(e.map(|e| (e, true)))
        .collect();
    let th = t.assessment.thresholds;
    let label = |name: &str, dashed: bool| {
        if dashed {
            format!("{name} (beside)")
        } else {
            name.to_owned()
        }
    };
    let mut force = Vec::new();
    let mut pressure = Vec::new();
    let mut strain = Vec::new();
    for (r, dashed) in &sessions {
        for (k, (name, pts)) in r.traces.force.iter().enumerate() {
            force.push(Curve {
                label: label(name, *dashed),
                points: thin(pts),
                colour: palette(k),
                dashed: *dashed,
            });
        }
        for (k, (name, pts)) in r.traces.pressure.iter().enumerate() {
            pressure.push(Curve {
                label: label(name, *dashed),
                points: thin(
                    &pts.iter()
                        .map(|p| [p[0], p[1] / PA_PER_MMHG])
                        .collect::<Vec<_>>(),
                ),
                colour: palette(k),
                dashed: *dashed,
            });
        }
        strain.push(Curve {
            label: label("tissue", *dashed),
            points: thin(&r.traces.strain),
            colour: palette(3),
            dashed: *dashed,
        });
    }
    let warn = RGBColor(214, 150, 0);
    let fail = RGBColor(200, 40, 30);
    let mut h = String::from("<h2>Against time</h2>\n");
    h.push_str(&svg_plot(
        "Force on each instrument",
        "force (N)",
        &force,
        &[Level {
            y: t.threshold_n,
            label: format!("safe force {:.2} N", t.threshold_n),
            colour: warn,
        }],
    )?);
    h.push_str(&svg_plot(
        "Mean retraction pressure under each instrument",
        "pressure (mmHg)",
        &pressure,
        &[
            Level {
                y: th.pressure_pa.warn / PA_PER_MMHG,
                label: format!("warns {:.0} mmHg", th.pressure_pa.warn / PA_PER_MMHG),
                colour: warn,
            },
            Level {
                y: th.pressure_pa.fail / PA_PER_MMHG,
                label: format!("fails {:.0} mmHg", th.pressure_pa.fail / PA_PER_MMHG),
                colour: fail,
            },
        ],
    )?);
    h.push_str(&svg_plot(
        "Largest principal strain of the tissue",
        "Green-Lagrange strain",
        &strain,
        &[
            Level {
                y: th.strain.warn,
                label: format!("warns {}", th.strain.warn),
                colour: warn,
            },
            Level {
                y: th.strain.fail,
                label: format!("fails {}", th.strain.fail),
                colour: fail,
            },
        ],
    )?);
    Ok(h)
}

/// A line plot against time as inline SVG: `curves` (solid or dashed),
/// `levels` dashed across, axes from all of them (y from 0).
fn svg_plot(
    title: &str,
    y_title: &str,
    curves: &[Curve],
    levels: &[Level],
) -> anyhow::Result<String> {
    let xs = curves.iter().flat_map(|c| c.points.iter().map(|p| p[0]));
    let (x0, x1) = xs.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
        (a.min(x), b.max(x))
    });
    let (x0, x1) = if x1 > x0 { (x0, x1) } else { (0.0, 1.0) };
    let y1 = curves
        .iter()
        .flat_map(|c| c.points.iter().map(|p| p[1]))
        .chain(levels.iter().map(|l| l.y))
        .filter(|y| y.is_finite())
        .fold(0.0, f64::max);
    let y1 = if y1 > 0.0 { y1 * 1.08 } else { 1.0 };
    crate::client::render::plot::chart::register_fonts()
        .map_err(|e| anyhow::anyhow!("fonts: {e}"))?;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (PLOT_W, PLOT_H)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        let mut ch = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 17))
            .margin(12)
            .x_label_area_size(42)
            .y_label_area_size(64)
            .build_cartesian_2d(x0..x1, 0.0..y1)
            .map_err(plot_err)?;
        ch.configure_mesh()
            .x_desc("time (s)")
            .y_desc(y_title)
            .label_style(("sans-serif", 13))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(plot_err)?;
        for c in curves {
            let [r, g, b] = c.colour;
            let style = ShapeStyle {
                color: RGBColor(r, g, b).to_rgba(),
                filled: false,
                stroke_width: 2,
            };
            let pts = c.points.iter().map(|p| (p[0], p[1]));
            let drawn = if c.dashed {
                ch.draw_series(DashedLineSeries::new(pts, 7, 4, style))
                    .map_err(plot_err)?
            } else {
                ch.draw_series(LineSeries::new(pts, style))
                    .map_err(plot_err)?
            };
            drawn
                .label(c.label.clone())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 22, y)], style));
        }
        for l in levels {
            let style = ShapeStyle {
                color: l.colour.to_rgba(),
                filled: false,
                stroke_width: 1,
            };
            ch.draw_series(DashedLineSeries::new([(x0, l.y), (x1, l.y)], 9, 5, style))
                .map_err(plot_err)?
                .label(l.label.clone())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 22, y)], style));
        }
        ch.configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(180, 180, 180))
            .label_font(("sans-serif", 12))
            .draw()
            .map_err(plot_err)?;
        root.present().map_err(plot_err)?;
    }
    Ok(format!("<figure>{svg}</figure>\n"))
}

fn plot_err<E: std::fmt::Display>(e: E) -> anyhow::Error {
    anyhow::anyhow!("drawing a plot: {e}")
}

fn pictures(t: &Report, t_name: &str, e: Option<(&Report, &str)>) -> anyhow::Result<String> {
    let mut h = String::from("<h2>The brain at the worst strain</h2>\n");
    let sessions: Vec<(&Report, &str)> = std::iter::once((t, t_name)).chain(e).collect();
    // One colour scale for both: the larger of the two worst strains.
    let top = sessions
        .iter()
        .filter_map(|(r, _)| r.traces.worst.as_ref())
        .filter_map(|w| w.strain.as_ref())
        .map(|s| s.max_principal)
        .fold(0.0, f64::max);
    for (r, name) in sessions {
        match picture(r, top)? {
            Some((png, caption)) => {
                let _ = writeln!(
                    h,
                    "<figure><img alt=\"{0}\" src=\"data:image/png;base64,{png}\"><figcaption>{0}</figcaption></figure>",
                    escape(&format!("{name}: {caption}"))
                );
            }
            None => {
                let _ = writeln!(
                    h,
                    "<p>{}: no strain picture in the recording (no frame strained the tissue by 0.01, or the recording predates pictures).</p>",
                    escape(name)
                );
            }
        }
    }
    Ok(h)
}

/// The worst strain picture of `r` on a colour scale to `top`, as a base64
/// PNG, with its caption.
fn picture(r: &Report, top: f64) -> anyhow::Result<Option<(String, String)>> {
    let (Some(scene), Some(surface), Some(worst)) =
        (&r.traces.scene, &r.traces.surface, &r.traces.worst)
    else {
        return Ok(None);
    };
    let Some(strain) = worst.strain.as_ref() else {
        return Ok(None);
    };
    let Some(field) = strain.picture.as_ref() else {
        return Ok(None);
    };
    let view = SessionView::new(scene, surface);
    let mut renderer =
        FrameRenderer::new(PICTURE_W, PICTURE_H).map_err(|e| anyhow::anyhow!("renderer: {e}"))?;
    let values: Vec<f64> = field
        .strain
        .iter()
        .map(|&s| (s as f64).max(0.0) * 100.0)
        .collect();
    let caption = Caption {
        title: format!(
            "largest principal strain {:.3} at t = {:.2} s",
            strain.max_principal, worst.sim_time_s
        ),
        // Pictures come when the largest strain grew by a quarter: the
        // last one may be below the session's largest.
        subtitle: format!(
            "frame {}, the last pictured (the session's largest strain: {:.3})",
            worst.frame, r.assessment.strain.peak
        ),
        range_mm: (top * 100.0).max(1e-3),
        force_scale: None,
    };
    let image = view
        .render_values(&mut renderer, worst, &values, "strain", "(%)", &caption)
        .map_err(|e| anyhow::anyhow!("drawing the strain picture: {e}"))?;
    let png = image.encode_png().context("encoding the strain picture")?;
    use base64::Engine as _;
    Ok(Some((
        base64::engine::general_purpose::STANDARD.encode(png),
        caption.title,
    )))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Thinning keeps every bucket's extremes: the peak survives.
    #[test]
    fn thinning_keeps_the_peak() {
        let pts: Vec<[f64; 2]> = (0..100_000)
            .map(|k| {
                [
                    k as f64 * 1e-3,
                    if k == 54_321 {
                        9.0
                    } else {
                        (k as f64 * 0.01).sin()
                    },
                ]
            })
            .collect();
        let t = thin(&pts);
        assert!(t.len() <= MAX_POINTS + 2);
        assert!(t.iter().any(|p| p[1] == 9.0));
        assert!(t.windows(2).all(|w| w[0][0] <= w[1][0]));
    }
}
