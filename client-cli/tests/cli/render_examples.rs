//! The pictures fissure shows, drawn from the paper's V-valley block, a
//! 16k-triangle brain-like surface and synthetic forces. Each test checks what
//! a viewer would (sizes, that things are where they should be, that the GIF
//! decodes) and writes its pictures to `$FISSURE_RENDER_OUT` when set (else a
//! temporary folder), printing how long each took.

use fissure_cli::client::render::anim::{GifOptions, save_gif};
use fissure_cli::client::render::frame::{
    CameraPreset, Caption, FrameRenderer, Plate, Scene, bounds,
};
use fissure_cli::client::render::plot::{
    Axis, InstrumentForces, Marker, ScatterGroup, ScatterPlot, force_plot, palette,
};
use fissure_cli::client::render::raster::{
    Camera, Colouring, EdgeStyle, MeshRef, RenderOptions, Renderer,
};
use fissure_cli::client::render::{Image, colormap::Colormap};
use fissure_engine::mesh::blocks::v_valley;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use std::path::PathBuf;
use std::time::Instant;

fn out_dir() -> (PathBuf, Option<tempfile::TempDir>) {
    match std::env::var_os("FISSURE_RENDER_OUT") {
        Some(d) => {
            let d = PathBuf::from(d);
            std::fs::create_dir_all(&d).unwrap();
            (d, None)
        }
        None => {
            let t = tempfile::tempdir().unwrap();
            (t.path().to_path_buf(), Some(t))
        }
    }
}

/// The spatula in the V groove: a plate 1 x 12 x 40 mm, tip 2 mm above the
/// groove's bottom, tilted 6 degrees, shifted `push` m towards +x.
fn spatula(push: f64, force: Option<Vector3<f64>>) -> Plate {
    let rot = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 6f64.to_radians());
    Plate {
        name: "right".into(),
        pose: Isometry3::from_parts(Translation3::new(0.03 + push, 0.015, 0.032), rot),
        half_extents: Vector3::new(0.0005, 0.006, 0.02),
        outline: None,
        cutting_edge: None,
        touching: force.is_some(),
        force,
    }
}

/// Displacements |moved - rest|, mm.
fn displacement_mm(rest: &[Point3<f64>], moved: &[Point3<f64>]) -> Vec<f64> {
    rest.iter()
        .zip(moved)
        .map(|(r, m)| (m - r).norm() * 1e3)
        .collect()
}

/// The camera of the valley pictures: framing the surface and the plate.
fn camera(
    surface: &[Point3<f64>],
    plate: &Plate,
    azimuth_deg: f64,
    elevation_deg: f64,
) -> CameraPreset {
    let (lo, hi) = bounds(surface);
    let c = plate.pose.translation.vector;
    let h = plate.half_extents.norm();
    let (plo, phi) = (
        Point3::from(c.add_scalar(-h)),
        Point3::from(c.add_scalar(h)),
    );
    CameraPreset {
        azimuth_deg,
        elevation_deg,
        frame_box: (lo.inf(&plo), hi.sup(&phi)),
    }
}

fn caption(title: &str, subtitle: String, range_mm: f64) -> Caption {
    Caption {
        title: title.into(),
        subtitle,
        range_mm,
        force_scale: None,
    }
}

/// Surface of the V valley, with the groove's +x wall pushed by up to `push`
/// m around the spatula (a smooth synthetic bump, not a solve).
/// Rest positions, moved positions and triangles of a surface.
type Surface = (Vec<Point3<f64>>, Vec<Point3<f64>>, Vec<[u32; 3]>);

fn valley_surface(push: f64) -> Surface {
    let mesh = v_valley();
    let b = mesh.boundary();
    let mut rest = Vec::new();
    b.gather(&mesh.nodes, &mut rest);
    let moved = rest
        .iter()
        .map(|p| {
            let wall = p.x >= 0.03 && p.z > 0.0095 && p.x < 0.05;
            if !wall {
                return *p;
            }
            let dy = (p.y - 0.015) / 0.009;
            let dz = (p.z - 0.018) / 0.012;
            let dx = (p.x - 0.031) / 0.012;
            let w = (-(dy * dy + dz * dz + dx * dx)).exp();
            Point3::new(p.x + push * w, p.y, p.z - 0.15 * push * w)
        })
        .collect();
    (rest, moved, b.triangles)
}

fn not_background_fraction(img: &Image) -> f64 {
    // The frame's background is a light grey-blue gradient, from
    // [250, 251, 253] at the top to [205, 212, 222] at the bottom.
    let bg = img
        .pixels()
        .iter()
        .filter(|p| p[0] >= 200 && p[2] >= 210 && (p[2] as i32 - p[0] as i32) < 20)
        .count();
    1.0 - bg as f64 / img.pixels().len() as f64
}

#[test]
fn v_valley_with_spatula_still() {
    let (dir, _keep) = out_dir();
    let (_, moved, tris) = valley_surface(0.0);
    let mut fr = FrameRenderer::new(1000, 700).unwrap();
    let plates = [spatula(0.0, None)];
    let height_mm: Vec<f64> = moved.iter().map(|p| p.z * 1e3).collect();
    let top_mm = height_mm.iter().copied().fold(0.0, f64::max);
    let scene = Scene {
        positions: &moved,
        triangles: &tris,
        values_mm: &height_mm,
        quantity: "height",
        unit: "(mm)",
        plates: &plates,
        ties: &[],
        camera: camera(&moved, &plates[0], -60.0, 35.0),
    };
    let t = Instant::now();
    let img = fr
        .render(
            &scene,
            &caption(
                "V-valley block with a spatula in the groove",
                format!("{} surface triangles   colour: height", tris.len()),
                top_mm,
            ),
        )
        .unwrap();
    eprintln!(
        "v-valley still 1000x700: {:.1} ms",
        t.elapsed().as_secs_f64() * 1e3
    );
    assert_eq!((img.width(), img.height()), (1000, 700));
    img.save_png(dir.join("v_valley_spatula.png")).unwrap();
    let f = not_background_fraction(&img);
    assert!(f > 0.15 && f < 0.8, "model covers {f}");
}

#[test]
fn v_valley_pushed_open_with_force_arrow() {
    let (dir, _keep) = out_dir();
    let (rest, moved, tris) = valley_surface(0.004);
    let mut fr = FrameRenderer::new(1000, 700).unwrap();
    let f = Vector3::new(-0.42, 0.03, 0.08);
    let plates = [spatula(0.004, Some(f))];
    let d = displacement_mm(&rest, &moved);
    let scene = Scene {
        positions: &moved,
        triangles: &tris,
        values_mm: &d,
        quantity: "displacement",
        unit: "(mm)",
        plates: &plates,
        ties: &[],
        camera: camera(&moved, &plates[0], -125.0, 38.0),
    };
    let img = fr
        .render(
            &scene,
            &caption(
                "Opening the groove: wall displacement",
                "synthetic deformation, 4 mm push".into(),
                4.0,
            ),
        )
        .unwrap();
    img.save_png(dir.join("v_valley_pushed.png")).unwrap();
    assert!(not_background_fraction(&img) > 0.15);
    // The force readout is written in the arrow's colour, bottom-left.
    let arrow = fissure_cli::client::render::frame::ARROWS[0];
    let readout = (0..500)
        .flat_map(|x| (img.height() - 40..img.height()).map(move |y| (x, y)))
        .filter(|&(x, y)| {
            let p = img.get(x, y).unwrap();
            p.iter()
                .zip(arrow)
                .all(|(a, b)| (*a as i32 - b as i32).abs() < 40)
        })
        .count();
    assert!(readout > 30, "{readout} readout pixels");
}

#[test]
fn v_valley_opening_animation_gif() {
    let (dir, _keep) = out_dir();
    let (rest, _, tris) = valley_surface(0.0);
    let mut fr = FrameRenderer::new(480, 360).unwrap();
    let frames_n = 40;
    let mut frames = Vec::with_capacity(frames_n);
    let cam = camera(&rest, &spatula(0.0, None), -60.0, 35.0);
    let t = Instant::now();
    for k in 0..frames_n {
        let s = (k as f64 / (frames_n - 1) as f64 * std::f64::consts::PI).sin();
        let push = 0.004 * s;
        let (_, moved, _) = valley_surface(push);
        let d = displacement_mm(&rest, &moved);
        let plates = [spatula(push, Some(Vector3::new(-0.4 * s, 0.0, 0.05 * s)))];
        let scene = Scene {
            positions: &moved,
            triangles: &tris,
            values_mm: &d,
            quantity: "displacement",
            unit: "(mm)",
            plates: &plates,
            ties: &[],
            camera: cam,
        };
        let mut cap = caption(
            "Opening the V groove",
            format!("frame {k}   push {:.1} mm", push * 1e3),
            4.0,
        );
        cap.force_scale = Some(0.05);
        frames.push(fr.render(&scene, &cap).unwrap());
    }
    let render_ms = t.elapsed().as_secs_f64() * 1e3;
    let t = Instant::now();
    let path = dir.join("v_valley_opening.gif");
    save_gif(&frames, &path, &GifOptions::default()).unwrap();
    let size = std::fs::metadata(&path).unwrap().len();
    eprintln!(
        "gif: {frames_n} frames 480x360 rendered in {render_ms:.0} ms, encoded in {:.0} ms, {} KiB",
        t.elapsed().as_secs_f64() * 1e3,
        size / 1024
    );
    let bytes = std::fs::read(&path).unwrap();
    let mut dec = gif::DecodeOptions::new()
        .read_info(bytes.as_slice())
        .unwrap();
    assert_eq!((dec.width(), dec.height()), (480, 360));
    let mut n = 0;
    while dec.read_next_frame().unwrap().is_some() {
        n += 1;
    }
    assert_eq!(n, frames_n);
    assert!(size < 3 << 20, "GIF of {size} bytes");
}

/// A brain-like closed surface: an ellipsoid (70 x 55 x 45 mm half-axes)
/// with gyri-like ripples, `nu` x `nv` quads as triangles.
fn blob(nu: usize, nv: usize) -> (Vec<Point3<f64>>, Vec<[u32; 3]>) {
    let mut pos = Vec::new();
    for j in 0..=nv {
        let v = j as f64 / nv as f64 * std::f64::consts::PI;
        for i in 0..nu {
            let u = i as f64 / nu as f64 * std::f64::consts::TAU;
            let ripple = 1.0
                + 0.025 * (7.0 * u).sin() * (9.0 * v).sin()
                + 0.015 * (13.0 * u + 3.0 * v).cos();
            pos.push(Point3::new(
                0.07 * ripple * v.sin() * u.cos(),
                0.055 * ripple * v.sin() * u.sin(),
                0.045 * ripple * v.cos(),
            ));
        }
    }
    let id = |i: usize, j: usize| (j * nu + i % nu) as u32;
    let mut tris = Vec::new();
    for j in 0..nv {
        for i in 0..nu {
            tris.push([id(i, j), id(i, j + 1), id(i + 1, j + 1)]);
            tris.push([id(i, j), id(i + 1, j + 1), id(i + 1, j)]);
        }
    }
    (pos, tris)
}

#[test]
fn sixteen_thousand_triangles_at_800x600() {
    let (dir, _keep) = out_dir();
    let (pos, tris) = blob(128, 63);
    assert!(tris.len() >= 16_000, "{} triangles", tris.len());
    let opts = RenderOptions::new(800, 600);
    let cam = Camera::orbit_points(&pos, -50.0, 25.0, 30.0, opts.aspect());
    let mut r = Renderer::new(opts).unwrap();
    let values: Vec<f64> = pos.iter().map(|p| p.z * 1e3).collect();
    let mesh = MeshRef::new(
        &pos,
        &tris,
        Colouring::Scalar {
            values: &values,
            map: Colormap::Viridis,
            range: (-45.0, 45.0),
        },
    )
    .with_edges(EdgeStyle::default());
    let img = r.render(&cam, &[mesh]).unwrap();
    let runs = 5;
    let t = Instant::now();
    for _ in 0..runs {
        r.render(&cam, &[mesh]).unwrap();
    }
    eprintln!(
        "{} triangles at 800x600, 2x2 supersampling: {:.1} ms per frame",
        tris.len(),
        t.elapsed().as_secs_f64() * 1e3 / runs as f64
    );
    img.save_png(dir.join("blob_16k.png")).unwrap();
    let f = not_background_fraction(&img);
    assert!(f > 0.2 && f < 0.9, "surface covers {f}");
}

#[test]
fn force_plot_of_two_spatulas() {
    let (dir, _keep) = out_dir();
    let n = 3000;
    let time: Vec<f64> = (0..n).map(|k| k as f64 * 1e-3).collect();
    let ramp = |t: f64, t0: f64| ((t - t0) / 1.2).clamp(0.0, 1.0);
    let left: Vec<[f64; 3]> = time
        .iter()
        .map(|&t| {
            let r = ramp(t, 0.3);
            [-0.45 * r + 0.02 * (9.0 * t).sin() * r, 0.05 * r, -0.12 * r]
        })
        .collect();
    let right: Vec<[f64; 3]> = time
        .iter()
        .map(|&t| {
            let r = ramp(t, 0.6);
            [0.38 * r, -0.04 * r + 0.015 * (7.0 * t).cos() * r, -0.1 * r]
        })
        .collect();
    let ins = [
        InstrumentForces {
            name: "left".into(),
            time: time.clone(),
            force: left,
        },
        InstrumentForces {
            name: "right".into(),
            time,
            force: right,
        },
    ];
    let plot = force_plot("Reaction forces on the spatulas", &ins, true, Some(0.5));
    let t = Instant::now();
    let (img, frame) = plot.render_with_frame().unwrap();
    eprintln!(
        "force plot 900x500, 8 series x 3000 samples: {:.1} ms",
        t.elapsed().as_secs_f64() * 1e3
    );
    // The left |F| curve at t = 2 s (about 0.48 N) is where the frame says.
    img.save_png(dir.join("forces.png")).unwrap();
    let fx = -0.45 + 0.02 * 18.0f64.sin();
    let mag = (fx * fx + 0.05f64.powi(2) + 0.12f64.powi(2)).sqrt();
    let p = frame.to_px([2.0, mag]);
    let c = img.get(p[0] as u32, p[1] as u32).unwrap();
    assert!(
        (c[0] as i32 - 31).abs() < 40 && (c[2] as i32 - 160).abs() < 50,
        "{c:?}"
    );
}

#[test]
fn accuracy_scatter_with_pareto_front() {
    let (dir, _keep) = out_dir();
    let mut plot = ScatterPlot::new(
        "Accuracy against cost per step",
        Axis::log("time per step (s)"),
        Axis::log("relative force error"),
    );
    let configs = [
        (
            "direct",
            Marker::Circle,
            vec![[0.35, 2e-4], [0.9, 6e-5], [2.8, 1.5e-5]],
        ),
        (
            "compliance",
            Marker::Square,
            vec![[0.004, 2.2e-4], [0.011, 6.5e-5], [0.03, 2.5e-5]],
        ),
        (
            "corotational",
            Marker::Diamond,
            vec![[0.02, 8e-5], [0.06, 2e-5], [0.2, 9e-6]],
        ),
        (
            "neo-Hookean",
            Marker::Triangle,
            vec![[0.5, 1e-5], [1.6, 3e-6]],
        ),
    ];
    for (i, (name, marker, pts)) in configs.into_iter().enumerate() {
        let labels = pts
            .iter()
            .enumerate()
            .map(|(k, _)| format!("{name} h{k}"))
            .collect();
        plot.add(ScatterGroup {
            label: name.into(),
            points: pts,
            point_labels: labels,
            colour: palette(i),
            marker,
        });
    }
    let (img, f) = plot.render_with_frame().unwrap();
    img.save_png(dir.join("pareto.png")).unwrap();
    assert_eq!(f.x_range, (1e-3, 10.0));
}
