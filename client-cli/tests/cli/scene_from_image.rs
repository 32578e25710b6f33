//! From an image to a running demo: `fissure scene from-image` on a
//! synthetic image whose brain is a block with a slot (the fissure) finds
//! the slot's plane and entry, writes a scene the server loads, and the
//! demo runs both spatulas through it. The law checked on the run: a plate
//! pushing its wall away feels the wall push back along the wall's normal
//! and never pulls (frictionless contact is unilateral), and a plate out of
//! the tissue feels nothing.

use fissure_cli::lab::scene::{FromImageArgs, from_image};
use std::path::Path;

/// Block half-size, mm; slot half-width, mm; the slot runs from the top
/// (z = +HALF) down to z = -BOTTOM.
const HALF: f64 = 20.0;
const SLOT: f64 = 2.5;
const BOTTOM: f64 = 12.0;

/// Writes a NIfTI-1 mask (uint8, 1 mm voxels, sform = translation so that
/// the grid's centre is the scanner origin) of the slotted block.
fn write_slotted_block(path: &Path) {
    let n = 48usize;
    let origin = -(n as f64 - 1.0) / 2.0;
    let mut h = vec![0u8; 352];
    let put_i16 =
        |h: &mut Vec<u8>, at: usize, v: i16| h[at..at + 2].copy_from_slice(&v.to_le_bytes());
    let put_f32 =
        |h: &mut Vec<u8>, at: usize, v: f32| h[at..at + 4].copy_from_slice(&v.to_le_bytes());
    h[0..4].copy_from_slice(&348i32.to_le_bytes());
    for (k, d) in [3, n as i16, n as i16, n as i16, 1, 1, 1, 1]
        .into_iter()
        .enumerate()
    {
        put_i16(&mut h, 40 + 2 * k, d);
    }
    put_i16(&mut h, 70, 2); // uint8
    put_i16(&mut h, 72, 8);
    for (k, v) in [1.0f32, 1.0, 1.0, 1.0].into_iter().enumerate() {
        put_f32(&mut h, 76 + 4 * k, v);
    }
    put_f32(&mut h, 108, 352.0);
    put_f32(&mut h, 112, 1.0);
    h[123] = 2; // mm
    put_i16(&mut h, 254, 1); // sform_code: scanner
    for (row, at) in [(0usize, 280usize), (1, 296), (2, 312)] {
        let mut r = [0f32; 4];
        r[row] = 1.0;
        r[3] = origin as f32;
        for (k, v) in r.into_iter().enumerate() {
            put_f32(&mut h, at + 4 * k, v);
        }
    }
    h[344..348].copy_from_slice(b"n+1\0");
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let [x, y, z] = [i, j, k].map(|c| origin + c as f64);
                let block = x.abs() < HALF && y.abs() < HALF && z.abs() < HALF;
                let slot = x.abs() < SLOT && z > -BOTTOM;
                h.push(u8::from(block && !slot));
            }
        }
    }
    std::fs::write(path, h).unwrap();
}

#[test]
fn a_scene_made_from_an_image_finds_the_slot_and_runs_both_spatulas() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let image = dir.path().join("block.nii");
    write_slotted_block(&image);
    let out = dir.path().join("slotted");
    let made = from_image(&FromImageArgs {
        images: vec![image],
        mesh: None,
        labels: None,
        threshold: 0.5,
        spacing_mm: 2.5,
        levels: 1,
        fissure_near: vec![0.0, 0.0, 0.0],
        out: out.clone(),
        name: None,
        fixed_label: None,
        fixed_height_mm: 6.0,
        fixed_half_width_mm: 15.0,
        tissue: Vec::new(),
        insertion_mm: 15.0,
        push_mm: 1.5,
        roi_mm: 0.0,
    })?;
    let f = made.fissure.landmark;
    // The slot's mid-plane is x = 0 and it opens at the top (+z).
    assert!(f.normal.x.abs() > 0.99, "normal {:?}", f.normal);
    assert!(f.direction.z < -0.99, "direction {:?}", f.direction);
    assert!(
        (f.entry.z - HALF * 1e-3).abs() < 3e-3,
        "entry {:?}",
        f.entry
    );
    assert!(f.entry.x.abs() < 1e-3, "entry {:?}", f.entry);
    assert!(
        (f.width - 2.0 * SLOT * 1e-3).abs() < 2.5e-3,
        "gap {}",
        f.width
    );
    assert!(made.files.fixed_nodes >= 3);
    // Both plates fit in the slot, side by side.
    assert_eq!(made.files.grazing, 0.0);
    assert!(made.files.across_m[0] > 0.0 && made.files.across_m[1] < 0.0);
    // A straight slot needs no turn; each plate opens to its wall (the
    // half-gap less its half-thickness, within the 0.1 mm march) plus the
    // push.
    assert_eq!(made.files.turn_deg, [0.0, 0.0]);
    for open in made.files.open_m {
        let want = 0.5 * f.width - 0.0005 + 1.5e-3;
        assert!(
            (open - want).abs() < 0.25e-3,
            "opens {open} m, want {want} m"
        );
    }
    let (scene, _) = fissure_engine::scene::Scene::load(&made.files.scene.display().to_string())?;
    assert_eq!(scene.name, "slotted");
    assert_eq!(scene.instruments.len(), 2);

    let demo = dir.path().join("demo");
    let report = crate::assessment::run_demo(
        &demo,
        &made.files.scene.display().to_string(),
        &[made.files.trajectory.display().to_string()],
    )?;
    assert_eq!(report.forces.len(), 2);
    let n = f.normal.into_inner();
    for (name, rows) in &report.forces {
        // The left plate opens along +n, the right along -n: the wall each
        // pushes pushes back along -n and +n.
        let out_n = if name == "left" { n } else { -n };
        let along: Vec<f64> = rows
            .iter()
            .map(|r| nalgebra::Vector3::from(r.force_n).dot(&out_n))
            .collect();
        let peak = along.iter().copied().fold(f64::INFINITY, f64::min);
        assert!(
            peak < -1e-3,
            "{name}: the wall never pushed back ({peak} N)"
        );
        let pulled = along.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        assert!(
            pulled < 1e-3 * peak.abs(),
            "{name}: the tissue pulled ({pulled} N)"
        );
        let last = rows.last().unwrap();
        assert_eq!(last.force_n, [0.0; 3], "{name}: force after retraction");
    }
    // A wall pushed 1.5 mm by a rigid plate moves about that much: no node
    // of the tissue goes farther than the push (with a margin for the
    // bulge about the plate's edges).
    assert!(
        report.max_displacement_m < 1.5 * 1.5e-3,
        "largest displacement {} mm under a 1.5 mm push",
        report.max_displacement_m * 1e3
    );
    Ok(())
}
