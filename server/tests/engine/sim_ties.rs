//! A scene's ties (`[[ties]]`) on the phantom's Sylvian fissure, through
//! the deformation step: placement (reproducible, on facing walls, at the
//! declared density), the force of opening against them (more than against
//! the bulk alone), tearing at the rupture criterion (not before), and the
//! errors of bad declarations.

use fissure_engine::fem::compliance::ColumnPolicy;
use fissure_engine::fem::ties::{Rupture, TieKind};
use fissure_engine::scene::Scene;
use fissure_engine::sim::core::engine::{Model, StepEngine};
use fissure_engine::sim::core::snapshot::TieCause;
use fissure_engine::sim::core::stepped::home_pose;
use nalgebra::{Isometry3, Translation3, Vector3};
use std::sync::Arc;

/// The `sylvian` scene on the coarse phantom, one instrument (`left`),
/// with `ties` appended (TOML).
fn scene(ties: &str) -> Scene {
    let text = include_str!("../../scenes/sylvian.toml").replace("paper-48k", "coarse");
    // Keep the first instrument only.
    let cut = text.rfind("[[instrument]]").unwrap();
    let text = format!("{}\n{ties}", &text[..cut]);
    Scene::parse(&text, "test").unwrap()
}

fn trabeculae(density: f64, extra: &str) -> String {
    format!(
        "[[ties]]\nkind = \"trabecula\"\nregion = {{ landmark = \"sylvian-left\" }}\ndensity_per_mm2 = {density}\nseed = 11\nstiffness_n_per_m = 0.5\nmax_gap_m = 0.010\n{extra}\n"
    )
}

fn model(scene: &Scene) -> Arc<Model> {
    Arc::new(Model::build(scene).unwrap())
}

#[test]
fn ties_are_placed_reproducibly_across_the_fissure_at_the_declared_density() {
    let s = scene(&trabeculae(0.2, "rupture_strain = 1.0"));
    let a = model(&s);
    let b = model(&s);
    assert!(!a.ties.is_empty());
    assert_eq!(a.ties, b.ties, "the same scene places the same ties");
    // The walls face +-z, 6.5 mm apart on the coarse phantom: each tie
    // crosses the mid-plane, its rest length is about the gap.
    for t in &a.ties {
        let (xa, xb) = (a.mesh.nodes[t.a as usize], a.mesh.nodes[t.b as usize]);
        assert!(xa.z * xb.z < 0.0, "{xa} and {xb} on one side");
        assert!(
            t.rest_length_m > 0.006 && t.rest_length_m < 0.010,
            "{}",
            t.rest_length_m
        );
        assert_eq!(t.kind, TieKind::Trabecula);
        assert_eq!(t.rupture, Rupture::Strain(1.0));
    }
    // Twice the density, twice the ties (to the rounding of the count).
    let double = model(&scene(&trabeculae(0.4, "rupture_strain = 1.0")));
    let ratio = double.ties.len() as f64 / a.ties.len() as f64;
    assert!((ratio - 2.0).abs() < 0.02, "{ratio}");
    // Another seed, another placement.
    let other = model(&scene(
        &trabeculae(0.2, "rupture_strain = 1.0").replace("seed = 11", "seed = 12"),
    ));
    assert_eq!(other.ties.len(), a.ties.len());
    assert_ne!(other.ties, a.ties);
}

/// The left spatula inserted 20 mm and lifted by `lift_m` along +z (its
/// face A pushes the fissure's upper wall).
fn lifted(scene: &Scene, lift_m: f64) -> Isometry3<f64> {
    Translation3::from(Vector3::new(0.020, 0.0, lift_m)) * home_pose(scene, 0)
}

/// The force on the spatula (N, along z) over a lift in `steps` steps to
/// `lift_m`, with the ties' events.
fn open(
    scene: &Scene,
    lift_m: f64,
    steps: usize,
) -> (
    Vec<f64>,
    Vec<fissure_engine::sim::core::snapshot::TieEvent>,
    u32,
) {
    let model = model(scene);
    let mut engine =
        StepEngine::new(scene, model.clone(), ColumnPolicy::Compute, None, None).unwrap();
    let mut snap = engine.rest(0.0);
    let mut forces = Vec::new();
    let mut events = Vec::new();
    for k in 0..=steps {
        let pose = lifted(scene, lift_m * k as f64 / steps as f64);
        let (next, report) = engine.step(&snap, 0.02 * (k + 1) as f64, &[pose], vec![None]);
        assert!(report.is_some(), "step {k}: {:?}", next.solver_error);
        snap = next;
        let f = &snap.frame_summary;
        forces.push(f.instruments[0].force_n.z);
        events.extend(f.ties.events.iter().copied());
    }
    let intact = snap.frame_summary.ties.trabeculae_intact;
    (forces, events, intact)
}

/// The laws of opening against ties, with the scenes of one strategy:
/// `bare` (no ties), `strong` (ties that hold) and `weak` (ties torn at
/// strain `rupture`). At every lift in contact the push on the plate (-z)
/// is at least the bare one, and at the last by the factor `more`; every
/// tie holds in `strong`; in `weak` ties tear, each by the spatula at its
/// rupture strain and not before, and the push falls below the strong
/// ties'.
fn opening_laws(bare: &Scene, strong: &Scene, weak: &Scene, rupture: f64, more: f64) {
    // The plate (1 mm) touches a wall after 2.75 mm of lift.
    let lift = 0.005;
    let (f_bare, e_bare, _) = open(bare, lift, 6);
    let (f_ties, e_ties, intact) = open(strong, lift, 6);
    assert!(e_bare.is_empty() && e_ties.is_empty());
    assert_eq!(intact as usize, model(strong).ties.len());
    let last = f_bare.len() - 1;
    assert!(f_bare[last] < 0.0, "{f_bare:?}");
    assert!(
        f_ties[last] < f_bare[last] * more,
        "with ties {f_ties:?}, without {f_bare:?}"
    );
    for (w, wo) in f_ties.iter().zip(&f_bare) {
        assert!(w <= &(wo + 1e-12), "with ties {w} N, without {wo} N");
    }
    let (f_weak, torn, intact) = open(weak, lift, 6);
    assert!(!torn.is_empty(), "no tie tore: {f_weak:?}");
    assert_eq!(intact as usize + torn.len(), model(weak).ties.len());
    for e in &torn {
        assert!(matches!(e.cause, TieCause::Torn { instrument: 0 }));
        assert!(e.strain >= rupture, "tore at strain {}", e.strain);
    }
    assert!(f_weak[last] > f_ties[last], "{f_weak:?} vs {f_ties:?}");
}

/// On the foundation the ties hold the lifted wall back: 5 % more push.
#[test]
fn opening_against_ties_takes_more_force_and_a_tie_tears_at_its_rupture_strain() {
    opening_laws(
        &scene(""),
        &scene(&trabeculae(0.2, "rupture_strain = 10.0")),
        &scene(&trabeculae(0.2, "rupture_strain = 0.2")),
        0.2,
        1.05,
    );
}

fn refused(ties: &str) -> String {
    let text = include_str!("../../scenes/sylvian.toml").replace("paper-48k", "coarse");
    let text = format!("{text}\n{ties}");
    match Scene::parse(&text, "test") {
        Err(e) => e.to_string(),
        Ok(s) => match Model::build(&s) {
            Err(e) => e.to_string(),
            Ok(_) => panic!("accepted: {ties}"),
        },
    }
}

#[test]
fn bad_tie_declarations_are_refused_naming_what_is_wrong() {
    let e = refused(&trabeculae(0.2, "rupture_strain = 1.0").replace("= 0.5", "= -0.5"));
    assert!(e.contains("ties[0].stiffness_n_per_m"), "{e}");
    let e = refused(&trabeculae(
        0.2,
        "rupture_strain = 1.0 \nrupture_force_n = 0.1",
    ));
    assert!(
        e.contains("ties[0]") && e.contains("exactly one rupture"),
        "{e}"
    );
    let e = refused(&trabeculae(0.2, "").replace("density_per_mm2 = 0.2\n", ""));
    assert!(e.contains("ties[0]"), "{e}");
    let e = refused(
        &trabeculae(0.2, "rupture_strain = 1.0").replace("sylvian-left", "no-such-fissure"),
    );
    assert!(
        e.contains("ties[0].region") && e.contains("no-such-fissure"),
        "{e}"
    );
    // A region with no facing walls: the brain stem's sphere.
    let e = refused(&trabeculae(0.2, "rupture_strain = 1.0").replace("sylvian-left", "brain-stem"));
    assert!(
        e.contains("ties[0]") && e.contains("no facing walls"),
        "{e}"
    );
    let e = refused(&trabeculae(1.0e6, "rupture_strain = 1.0"));
    assert!(
        e.contains("ties[0]") && e.contains("density_per_mm2"),
        "{e}"
    );
}

/// `scene(ties)` solved by `corotational`, held at the stem alone (the
/// scene's foundation is dropped).
fn corotational(ties: &str) -> Scene {
    let text = include_str!("../../scenes/sylvian.toml")
        .replace("paper-48k", "coarse")
        .replace("strategy = \"compliance\"", "strategy = \"corotational\"");
    let start = text.find("[foundation]").unwrap();
    let end = text[start..].find("\n# The paper's skull").unwrap() + start;
    let text = format!("{}{}", &text[..start], &text[end..]);
    let cut = text.rfind("[[instrument]]").unwrap();
    let text = format!("{}\n{ties}", &text[..cut]);
    Scene::parse(&text, "test").unwrap()
}

/// The nonlinear strategies hold ties as springs of their energy, at
/// their true length and direction, and the same laws hold. Held at the
/// stem alone (no foundation), the lifted wall carries the hemisphere with
/// it and stretches the ties less than 1 % (the compliance strategy on the
/// same scene gives the same): stiffer ties (5 N/m) make their share plain
/// (0.5 % more push), and the weak ones tear at 0.2 %.
#[test]
fn a_nonlinear_strategy_opens_against_ties_and_tears_them_at_their_rupture_strain() {
    opening_laws(
        &corotational(""),
        &corotational(&trabeculae(0.2, "rupture_strain = 10.0").replace("= 0.5", "= 5.0")),
        &corotational(&trabeculae(0.2, "rupture_strain = 0.002")),
        0.002,
        1.005,
    );
}

#[test]
fn ties_from_a_pairs_file_attach_at_the_nearest_surface_vertices_and_bad_lines_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("pairs.txt");
    // One pair across the Sylvian fissure (entry x = -65.7 mm, y = 10 mm,
    // walls at z = +-3.25 mm on the coarse phantom), 10 mm in.
    std::fs::write(
        &path,
        "# a tie\n-0.0557 0.010 0.00325  -0.0557 0.010 -0.00325\n\n",
    )
    .unwrap();
    let decl = format!(
        "[[ties]]\nkind = \"vessel\"\npairs_file = {:?}\nstiffness_n_per_m = 200.0\nrupture_strain = 0.5\nmax_gap_m = 0.010\n",
        path.display().to_string()
    );
    let m = model(&scene(&decl));
    assert_eq!(m.ties.len(), 1);
    let t = m.ties[0];
    assert_eq!(t.kind, TieKind::Vessel);
    let (a, b) = (m.mesh.nodes[t.a as usize], m.mesh.nodes[t.b as usize]);
    assert!(a.z > 0.0 && b.z < 0.0, "{a} {b}");
    assert!((t.rest_length_m - (b - a).norm()).abs() < 1e-15);
    std::fs::write(&path, "# a tie\n-0.0557 0.010 0.00325 oops\n").unwrap();
    let e = refused(&decl);
    assert!(
        e.contains("ties[0].pairs_file") && e.contains("line 2"),
        "{e}"
    );
}

/// A reference engine that mirrors another's ties ([`StepEngine::mirror_ties`],
/// what `fissure bench haptic` checks samples against) has that engine's
/// ties and tears none itself: stepped at the same poses after each of the
/// other's steps, it gives the same force (to the contact solver's
/// tolerance) and records no event, while the other tears weak ties.
#[test]
fn a_mirror_engine_has_the_others_ties_and_tears_none_itself() {
    let s = scene(&trabeculae(0.2, "rupture_strain = 0.2"));
    let model = model(&s);
    let mut a = StepEngine::new(&s, model.clone(), ColumnPolicy::Compute, None, None).unwrap();
    let mut b = StepEngine::new(&s, model.clone(), ColumnPolicy::Compute, None, None).unwrap();
    let (mut sa, mut sb) = (a.rest(0.0), b.rest(0.0));
    let mut torn = 0;
    for k in 0..=6 {
        let pose = lifted(&s, 0.005 * k as f64 / 6.0);
        let t = 0.02 * (k + 1) as f64;
        sa = a.step(&sa, t, &[pose], vec![None]).0;
        torn += sa.frame_summary.ties.events.len();
        b.mirror_ties(sa.force_model.ties.as_ref().unwrap());
        sb = b.step(&sb, t, &[pose], vec![None]).0;
        assert!(
            sb.frame_summary.ties.events.is_empty(),
            "step {k}: the mirror tore"
        );
        assert_eq!(
            sb.frame_summary.ties.trabeculae_intact,
            sa.frame_summary.ties.trabeculae_intact
        );
        let (fa, fb) = (
            sa.frame_summary.instruments[0].force_n,
            sb.frame_summary.instruments[0].force_n,
        );
        assert!(
            (fa - fb).norm() <= 1e-6 * fa.norm().max(1e-3),
            "step {k}: {fa} N against the mirror's {fb} N"
        );
    }
    assert!(torn > 0, "no tie tore");
}

/// A tear is blamed on the instrument that pushes the tissue: of those
/// with a loaded row, the one whose tip is nearest the tie (an idle
/// instrument nearer the tie is not blamed); with none pushing, the
/// nearest of all.
#[test]
fn a_tear_is_blamed_on_the_nearest_instrument_that_pushes() {
    use fissure_engine::sim::core::engine::TieStage;
    let text = include_str!("../../scenes/sylvian.toml").replace("paper-48k", "coarse");
    let s = Scene::parse(
        &format!("{text}\n{}", trabeculae(0.2, "rupture_strain = 0.2")),
        "test",
    )
    .unwrap();
    assert_eq!(s.instruments.len(), 2);
    let m = model(&s);
    let tie = m.ties[0];
    let (xa, xb) = (m.mesh.nodes[tie.a as usize], m.mesh.nodes[tie.b as usize]);
    // Tie 0's node pair stretched to twice the tie's rest length (strain 1
    // > 0.2).
    let mut u = vec![Vector3::zeros(); m.mesh.nodes.len()];
    u[tie.b as usize] = (xb - xa).normalize() * tie.rest_length_m;
    let mid = nalgebra::Point3::from(0.5 * (xa.coords + xb.coords));
    let far = mid + Vector3::new(0.0, 0.0, 0.05);
    let blamed = |pushing: &[bool]| {
        let mut stage = TieStage::new(&m);
        assert!(stage.tear(&m, &u, &[far, mid], pushing, 1.0));
        // Tie 0 and the ties on its node pair tear, at one place.
        let f = stage.frame(&m);
        assert!(f.events.iter().any(|e| e.tie == 0));
        let who: Vec<u16> = f
            .events
            .iter()
            .map(|e| match e.cause {
                TieCause::Torn { instrument } => instrument,
                c => panic!("{c:?}"),
            })
            .collect();
        assert!(who.iter().all(|&w| w == who[0]), "{:?}", f.events);
        who[0]
    };
    assert_eq!(blamed(&[true, false]), 0, "the pushing one, though farther");
    assert_eq!(blamed(&[false, false]), 1, "none pushing: the nearest");
    assert_eq!(blamed(&[true, true]), 1, "both pushing: the nearer");
}
