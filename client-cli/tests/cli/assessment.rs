//! The assessment of a session, end to end: the bundled expert and careless
//! openings of `sylvian` run through the demo (stepped, in process), are
//! reported, and put side by side on one page.
//!
//! * the careless session scores worse than the expert one on every
//!   measure that either session moves: more force, more pressure, a
//!   larger pressure-time product, more strain, more strained tissue, and
//!   no less time above the warning pressure;
//! * the page renders in headless Chromium (Debian's `chromium`, which
//!   `.ci/run` installs; required where `CI` is set) without a console
//!   error, its screenshot shows the plots' curves (pixels of the
//!   instruments' colours), and it references nothing outside itself;
//! * a truncated recording is refused with the byte offset of its cut
//!   entry, and a page already there is left as it was.

use fissure_cli::client::replay::Pacing;
use fissure_cli::client::report::{self, Options, Report};
use fissure_cli::lab::demo::{DemoArgs, run};
use std::path::{Path, PathBuf};
use std::process::Command;

fn demo(out: &Path, who: &str) -> anyhow::Result<PathBuf> {
    demo_of(
        out,
        "sylvian",
        &[
            format!("sylvian-{who}-left"),
            format!("sylvian-{who}-right"),
        ],
    )
}

/// The demo of `scene` with `trajectory` (none: the scene's first ones;
/// bundled names or files), without pictures, run in a runtime of its own.
pub(crate) fn run_demo(
    out: &Path,
    scene: &str,
    trajectory: &[String],
) -> anyhow::Result<fissure_cli::lab::demo::DemoReport> {
    let args = DemoArgs {
        scene: scene.into(),
        out: out.into(),
        pacing: Pacing::Fast,
        trajectory: trajectory.to_vec(),
        list: false,
        azimuth_deg: None,
        elevation_deg: None,
        width: 400,
        height: 300,
        gif_frames: 2,
        colour_by: fissure_cli::client::watch::ColourBy::NonRigid,
        no_pictures: true,
        quiet: true,
    };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    rt.block_on(run(&args))
}

/// The demo of `scene` with `trajectory` (none: the scene's first ones),
/// without pictures: its recording.
fn demo_of(out: &Path, scene: &str, trajectory: &[String]) -> anyhow::Result<PathBuf> {
    run_demo(out, scene, trajectory)?;
    Ok(out.join("session.fsrec"))
}

fn value(r: &Report, measure: &str, instrument: Option<&str>) -> f64 {
    r.assessment
        .scores
        .iter()
        .find(|s| s.measure == measure && s.instrument.as_deref() == instrument)
        .unwrap_or_else(|| panic!("no score {measure} {instrument:?}"))
        .value
}

/// Where Chromium is: `chromium` on the path (Debian's package).
fn chromium() -> Option<PathBuf> {
    ["chromium", "chromium-browser"]
        .into_iter()
        .find_map(|name| {
            let out = Command::new("sh")
                .args(["-c", &format!("command -v {name}")])
                .output()
                .ok()?;
            let path = String::from_utf8(out.stdout).ok()?.trim().to_owned();
            (!path.is_empty()).then(|| PathBuf::from(path))
        })
}

#[test]
fn the_careless_session_scores_worse_and_the_page_renders() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let expert = demo(&dir.path().join("expert"), "expert")?;
    let careless = demo(&dir.path().join("careless"), "careless")?;
    let options = Options::default();
    let e = report::report_with(&expert, &options)?;
    let c = report::report_with(&careless, &options)?;
    for i in ["left", "right"] {
        for m in [
            "peak force",
            "peak mean retraction pressure",
            "pressure-time product",
        ] {
            let (ve, vc) = (value(&e, m, Some(i)), value(&c, m, Some(i)));
            assert!(vc > ve, "{m} of {i}: careless {vc}, expert {ve}");
        }
        let m = "time above the warning pressure";
        let (ve, vc) = (value(&e, m, Some(i)), value(&c, m, Some(i)));
        assert!(vc >= ve, "{m} of {i}: careless {vc}, expert {ve}");
        assert_eq!(ve, 0.0, "the expert stays under the warning pressure");
    }
    for m in [
        "peak principal strain",
        "tissue volume above the warning strain",
    ] {
        let (ve, vc) = (value(&e, m, None), value(&c, m, None));
        assert!(vc > ve, "{m}: careless {vc}, expert {ve}");
    }
    assert!(c.assessment.grade >= e.assessment.grade);

    // The page, careless beside expert.
    let page = dir.path().join("page.html");
    report::command(&careless, &options, false, Some(&page), Some(&expert))?;
    let html = std::fs::read_to_string(&page)?;
    assert_eq!(html.matches("<svg").count(), 3, "three plots");
    assert_eq!(
        html.matches("data:image/png;base64,").count(),
        2,
        "two pictures"
    );
    // Nothing outside the page: no script, no link, no remote source (the
    // SVG namespace is a name, not a request).
    let without_ns = html.replace("xmlns=\"http://www.w3.org/2000/svg\"", "");
    for bad in ["<script", "<link", "http://", "https://", "url("] {
        assert!(!without_ns.contains(bad), "the page has {bad:?}");
    }
    let Some(chromium) = chromium() else {
        assert!(
            std::env::var_os("CI").is_none(),
            "CI must have chromium (.ci/run installs Debian's package)"
        );
        eprintln!("chromium not found: the page was not rendered");
        return Ok(());
    };
    let shot = dir.path().join("shot.png");
    let out = Command::new(&chromium)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--hide-scrollbars",
            "--enable-logging=stderr",
            "--v=0",
            "--window-size=1000,2400",
        ])
        .arg(format!("--screenshot={}", shot.display()))
        .arg(format!("file://{}", page.display()))
        .output()?;
    let log = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success() && shot.is_file(),
        "chromium failed: {log}"
    );
    let console: Vec<&str> = log.lines().filter(|l| l.contains(":CONSOLE")).collect();
    assert!(console.is_empty(), "console messages: {console:?}");
    // The curves: pixels of the first two palette colours (Tableau blue
    // and orange), plenty of each.
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&shot)?));
    let mut reader = decoder.read_info()?;
    let mut buf = vec![0; reader.output_buffer_size().expect("a size")];
    let info = reader.next_frame(&mut buf)?;
    let px = info.color_type.samples();
    let count = |rgb: [u8; 3]| {
        buf[..info.buffer_size()]
            .chunks_exact(px)
            .filter(|p| p[..3].iter().zip(rgb).all(|(&a, b)| a.abs_diff(b) <= 12))
            .count()
    };
    let blue = fissure_cli::client::render::plot::palette(0);
    let orange = fissure_cli::client::render::plot::palette(1);
    assert!(count(blue) > 500, "{} blue pixels", count(blue));
    assert!(count(orange) > 500, "{} orange pixels", count(orange));
    Ok(())
}

/// The byte offset of each length-delimited entry of a recording.
fn entry_offsets(bytes: &[u8]) -> Vec<usize> {
    let mut offsets = Vec::new();
    let mut at = 0;
    while at < bytes.len() {
        offsets.push(at);
        let (mut len, mut shift) = (0usize, 0);
        loop {
            let b = bytes[at];
            at += 1;
            len |= ((b & 0x7f) as usize) << shift;
            shift += 7;
            if b & 0x80 == 0 {
                break;
            }
        }
        at += len;
    }
    offsets
}

#[test]
fn a_truncated_recording_is_refused_and_leaves_the_page() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let good = demo_of(&dir.path().join("cube"), "cube", &[])?;
    let bytes = std::fs::read(&good)?;
    let last = *entry_offsets(&bytes).last().expect("entries");
    let cut = dir.path().join("cut.fsrec");
    std::fs::write(&cut, &bytes[..bytes.len() - 3])?;
    let page = dir.path().join("page.html");
    std::fs::write(&page, "an earlier page")?;
    let before: Vec<_> = std::fs::read_dir(dir.path())?
        .map(|e| e.map(|e| e.file_name()))
        .collect::<Result<_, _>>()?;
    let err = report::command(&cut, &Options::default(), false, Some(&page), None)
        .expect_err("a truncated recording is refused");
    let msg = format!("{err:#}");
    assert!(msg.contains(&format!("at byte {last}")), "{msg}");
    assert!(msg.contains("truncated"), "{msg}");
    assert_eq!(std::fs::read_to_string(&page)?, "an earlier page");
    let after: Vec<_> = std::fs::read_dir(dir.path())?
        .map(|e| e.map(|e| e.file_name()))
        .collect::<Result<_, _>>()?;
    assert_eq!(before, after, "no file left behind");
    // A corrupted entry (not a truncation) is named with its offset too,
    // and the expert page is not written either.
    let mut bad = bytes.clone();
    let second = entry_offsets(&bytes)[1];
    bad[second + 1..second + 9].fill(0xff);
    let broken = dir.path().join("broken.fsrec");
    std::fs::write(&broken, &bad)?;
    let err = report::command(
        &good,
        &Options::default(),
        false,
        Some(&page),
        Some(&broken),
    )
    .expect_err("a corrupted recording is refused");
    assert!(
        format!("{err:#}").contains(&format!("at byte {second}")),
        "{err:#}"
    );
    assert_eq!(std::fs::read_to_string(&page)?, "an earlier page");
    // Accepted on request: the entries before the cut.
    let r = report::report_with(
        &cut,
        &Options {
            accept_truncated: true,
            ..Default::default()
        },
    )?;
    assert!(r.truncated);
    Ok(())
}
