//! One configuration of the study: the knobs that trade speed for accuracy
//! (mesh preset, strategy, tolerance, source nodes a face, region of
//! interest, ray-casting backend, threads) and the material and speed knobs
//! of the stability sweep.

use fissure_engine::fem::{Element, Strategy};
use fissure_engine::scene::{
    CollisionMethod, ContactLaw, DEFAULT_CSF_GAP_M, Scene, SceneError, SkullSpec, SkullSurfaceSpec,
};
use serde::{Deserialize, Serialize};

/// Where and how rays are cast.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Backend {
    /// CPU BVH (the default).
    CpuBvh,
    /// CPU brute force over all triangles.
    CpuBrute,
    /// GPU linear BVH through wgpu (CPU BVH when no adapter).
    GpuBvh,
}

impl Backend {
    /// Name as in the table.
    pub fn name(self) -> &'static str {
        match self {
            Self::CpuBvh => "cpu-bvh",
            Self::CpuBrute => "cpu-brute",
            Self::GpuBvh => "gpu-bvh",
        }
    }
}

/// How the brain is held.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Support {
    /// The brain stem fixed only (the scene's foundation removed): the
    /// stability sweep's support, under which the force is linear in E.
    #[default]
    Stem,
    /// The brain stem fixed and the scene's elastic foundation as bundled
    /// (the product's default).
    Foundation,
    /// The brain stem fixed and a rigid skull: the outer surface offset
    /// outward by the default CSF gap (1.5 mm), open where the scene's
    /// foundation is open (the craniotomy window, the fissure's walls), in
    /// place of the foundation.
    SkullSurface,
}

impl Support {
    /// All supports, in the order the study's tables list them.
    pub const ALL: [Support; 3] = [Self::Foundation, Self::SkullSurface, Self::Stem];

    /// Name as in the table.
    pub fn name(self) -> &'static str {
        match self {
            Self::Stem => "stem",
            Self::Foundation => "foundation",
            Self::SkullSurface => "skull-surface",
        }
    }
}

/// One configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Config {
    /// Short unique label, e.g. `48k/compliance/150`.
    pub label: String,
    /// Which sweep it belongs to (`baseline`, `preset`, `strategy`, ...).
    pub sweep: String,
    /// Phantom preset.
    pub preset: String,
    /// Solver strategy.
    #[serde(serialize_with = "ser_strategy", deserialize_with = "de_strategy")]
    pub strategy: Strategy,
    /// Relative residual tolerance of the iterative strategies.
    pub tolerance: f64,
    /// Source nodes a spatula face.
    pub nodes_per_face: u32,
    /// Region of interest: keep the tetrahedra within this distance (m) of the
    /// fissure centre, cut fixed; `None` is the whole brain.
    pub roi_m: Option<f64>,
    /// Ray-casting backend.
    pub backend: Backend,
    /// Threads of the rayon pool the run executes in.
    pub threads: usize,
    /// Young's modulus, Pa.
    pub youngs_pa: f64,
    /// Poisson's ratio.
    pub nu: f64,
    /// Time scale of the trajectory (`> 1` slower).
    pub time_scale: f64,
    /// The contact law (the reference's is frictionless).
    #[serde(serialize_with = "ser_law")]
    pub contact_law: ContactLaw,
    /// Coulomb's friction coefficient `mu` of the `coulomb` law (none for
    /// the others).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub friction_coefficient: Option<f64>,
    /// The element formulation (`tet4` unless a run names another).
    #[serde(
        default,
        serialize_with = "ser_element",
        deserialize_with = "de_element"
    )]
    pub element: Element,
    /// How the brain is held (`stem` unless a run names another).
    #[serde(default)]
    pub support: Support,
    /// Mesh the preset with the proven mesher (the whole surface at the
    /// preset's finest spacing: paper-48k becomes the 204k-tetrahedron
    /// level).
    #[serde(default)]
    pub proven: bool,
    /// The phantom's finest lattice spacing, m, in place of the preset's
    /// (`scene.model.spacing_m`); `None`: the preset's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub spacing_m: Option<f64>,
    /// Uniform refinements of the meshed phantom (`scene.model.refine`:
    /// each tetrahedron into eight, the shape kept exactly); 0: none.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub refine: u32,
    /// Local refinements after `refine`, in order: the tetrahedra within
    /// each radius, m, of [`FISSURE_CENTRE_M`] split into eight, closed
    /// conformingly (`scene.model.refine_near`); empty: none. Written as a
    /// number when there is one.
    #[serde(
        default,
        skip_serializing_if = "Vec::is_empty",
        serialize_with = "ser_radii",
        deserialize_with = "de_radii"
    )]
    pub refine_near_m: Vec<f64>,
}

fn ser_radii<S: serde::Serializer>(r: &[f64], ser: S) -> Result<S::Ok, S::Error> {
    match r {
        [one] => ser.serialize_f64(*one),
        many => many.serialize(ser),
    }
}

fn de_radii<'de, D: serde::Deserializer<'de>>(de: D) -> Result<Vec<f64>, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum Radii {
        One(f64),
        Many(Vec<f64>),
    }
    Ok(match Radii::deserialize(de)? {
        Radii::One(r) => vec![r],
        Radii::Many(v) => v,
    })
}

fn is_zero(n: &u32) -> bool {
    *n == 0
}

fn ser_element<S: serde::Serializer>(e: &Element, ser: S) -> Result<S::Ok, S::Error> {
    ser.serialize_str(e.name())
}

fn de_element<'de, D: serde::Deserializer<'de>>(de: D) -> Result<Element, D::Error> {
    let name = String::deserialize(de)?;
    name.parse().map_err(serde::de::Error::custom)
}

fn ser_law<S: serde::Serializer>(l: &ContactLaw, ser: S) -> Result<S::Ok, S::Error> {
    ser.serialize_str(l.name())
}

fn ser_strategy<S: serde::Serializer>(s: &Strategy, ser: S) -> Result<S::Ok, S::Error> {
    ser.serialize_str(s.name())
}

fn de_strategy<'de, D: serde::Deserializer<'de>>(de: D) -> Result<Strategy, D::Error> {
    let name = String::deserialize(de)?;
    name.parse().map_err(serde::de::Error::custom)
}

/// Centre of the region of interest and of the error region: the middle of
/// the left Sylvian fissure (entry at x = -65.7 mm, 25 mm deep along +x;
/// 50 mm long along y, centred at y = 10 mm), m.
pub const FISSURE_CENTRE_M: [f64; 3] = [-0.0532, 0.010, 0.0];

impl Config {
    /// The baseline: paper-48k, linear compliance, 150 nodes a face, whole
    /// brain, CPU BVH, 2 threads, E = 3 kPa, nu = 0.45, nominal speed.
    pub fn baseline() -> Self {
        Self {
            label: String::new(),
            sweep: "baseline".into(),
            preset: "paper-48k".into(),
            strategy: Strategy::Compliance,
            tolerance: 1e-6,
            nodes_per_face: 150,
            roi_m: None,
            backend: Backend::CpuBvh,
            threads: 2,
            youngs_pa: 3000.0,
            nu: 0.45,
            time_scale: 1.0,
            contact_law: ContactLaw::Frictionless,
            friction_coefficient: None,
            element: Element::Tet4,
            support: Support::Stem,
            proven: false,
            spacing_m: None,
            refine: 0,
            refine_near_m: Vec::new(),
        }
        .labelled()
    }

    /// Sets the label from the fields (only the ones that differ from the
    /// baseline's material and speed are named).
    pub fn labelled(mut self) -> Self {
        let preset = match (self.preset.as_str(), self.proven, self.spacing_m) {
            ("paper-48k", false, None) => "48k".to_string(),
            ("paper-48k", true, None) => "204k".to_string(),
            ("paper-34k", false, None) => "34k".to_string(),
            (other, false, None) => other.to_string(),
            (other, true, None) => format!("{other}-proven"),
            (other, proven, Some(h)) => format!(
                "{}{}-{:.1}mm",
                other.trim_start_matches("paper-"),
                if proven { "-proven" } else { "" },
                h * 1e3
            ),
        };
        let preset = match self.refine {
            0 => preset,
            r => format!("{preset}-r{r}"),
        };
        let preset = self
            .refine_near_m
            .iter()
            .fold(preset, |p, r| format!("{p}-near{:.0}mm", r * 1e3));
        let strategy = self.strategy.kind().label;
        let mut l = format!("{preset}/{strategy}");
        if !self.strategy.is_linear() {
            l.push_str(&format!("/tol{:.0e}", self.tolerance));
        }
        l.push_str(&format!("/n{}", self.nodes_per_face));
        if let Some(r) = self.roi_m {
            l.push_str(&format!("/roi{:.0}mm", r * 1e3));
        }
        if self.backend != Backend::CpuBvh {
            l.push_str(&format!("/{}", self.backend.name()));
        }
        if self.threads != 2 {
            l.push_str(&format!("/t{}", self.threads));
        }
        if self.youngs_pa != 3000.0 {
            l.push_str(&format!("/E{}", self.youngs_pa));
        }
        if self.nu != 0.45 {
            l.push_str(&format!("/nu{}", self.nu));
        }
        if self.element == Element::Tet4NodalPressure {
            l.push_str("/np");
        }
        if self.contact_law != ContactLaw::Frictionless {
            l.push_str(&format!("/{}", self.contact_law.name()));
        }
        if let Some(mu) = self.friction_coefficient {
            l.push_str(&format!("-mu{mu}"));
        }
        if self.time_scale != 1.0 {
            l.push_str(&format!("/x{:.3}", self.time_scale));
        }
        if self.support != Support::Stem {
            l.push_str(&format!("/{}", self.support.name()));
        }
        self.label = l;
        self
    }

    /// The sylvian scene edited to this configuration.
    pub fn scene(&self) -> Result<Scene, SceneError> {
        self.scene_in("sylvian")
    }

    /// The scene `source` (a bundled name or a file) edited to this
    /// configuration.
    pub fn scene_in(&self, source: &str) -> Result<Scene, SceneError> {
        let (mut scene, _) = Scene::load(source)?;
        // The stability sweep is held at the brain stem only: a foundation
        // of fixed stiffness would make the force no longer linear in E
        // (one of the study's checks). The reference and the grid's
        // baseline keep the scene's foundation.
        match self.support {
            Support::Stem => scene.foundation = None,
            Support::Foundation => {}
            Support::SkullSurface => {
                let open = scene.foundation.take().map(|f| f.open).unwrap_or_default();
                scene.skull = Some(SkullSpec {
                    containing: None,
                    excluding: None,
                    surface: Some(SkullSurfaceSpec {
                        csf_gap_m: DEFAULT_CSF_GAP_M,
                        band_m: None,
                        open,
                    }),
                });
            }
        }
        scene.model = fissure_engine::scene::ModelSpec::Phantom {
            preset: self.preset.clone(),
            proven: self.proven,
            spacing_m: self.spacing_m,
            refine: self.refine,
            refine_near: self
                .refine_near_m
                .iter()
                .map(|&r| fissure_engine::scene::SphereSpec {
                    centre_m: FISSURE_CENTRE_M,
                    radius_m: r,
                })
                .collect(),
        };
        scene.material.youngs_modulus_pa = self.youngs_pa;
        scene.material.poisson_ratio = self.nu;
        scene.solver.strategy = self.strategy;
        scene.solver.element = self.element;
        scene.solver.tolerance = self.tolerance;
        scene.contact.law = self.contact_law;
        scene.contact.friction_coefficient = self.friction_coefficient;
        scene.collision.method = match self.backend {
            Backend::CpuBrute => CollisionMethod::Brute,
            _ => CollisionMethod::Bvh,
        };
        for i in &mut scene.instruments {
            i.nodes_per_face = self.nodes_per_face;
        }
        scene.validate("study")?;
        Ok(scene)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_support_edits_the_scene_it_names() {
        let with = |support| {
            Config {
                support,
                ..Config::baseline()
            }
            .labelled()
        };
        let stem = with(Support::Stem);
        assert_eq!(stem.label, Config::baseline().label);
        let scene = stem.scene().expect("the stem scene");
        assert!(scene.foundation.is_none() && scene.skull.is_none());
        let f = with(Support::Foundation);
        assert!(f.label.ends_with("/foundation"), "{}", f.label);
        let bundled = Scene::load("sylvian").expect("bundled").0.foundation;
        assert_eq!(f.scene().expect("the foundation scene").foundation, bundled);
        let k = with(Support::SkullSurface);
        assert!(k.label.ends_with("/skull-surface"), "{}", k.label);
        let scene = k.scene().expect("the skull-surface scene");
        assert!(scene.foundation.is_none());
        let surface = scene
            .skull
            .and_then(|s| s.surface)
            .expect("a skull surface");
        assert_eq!(surface.csf_gap_m, DEFAULT_CSF_GAP_M);
        assert_eq!(Some(surface.open), bundled.map(|b| b.open));
    }

    #[test]
    fn an_old_configuration_reads_as_stem_held_on_the_graded_mesh() {
        let mut json = serde_json::to_value(Config::baseline()).expect("serialises");
        let map = json.as_object_mut().expect("an object");
        map.remove("support");
        map.remove("proven");
        map.remove("spacing_m");
        let back: Config = serde_json::from_value(json).expect("reads without the new fields");
        assert_eq!(back, Config::baseline());
    }

    /// Local refinement radii: one is written as a number (as the plans
    /// and result files that had only one), several as a list; both read
    /// back equal, and the label names each ball in order.
    #[test]
    fn refinement_radii_round_trip_as_a_number_or_a_list_and_name_the_label() {
        for (radii, text, label) in [
            (vec![0.02], "0.02", "48k-near20mm/"),
            (vec![0.03, 0.02], "[0.03,0.02]", "48k-near30mm-near20mm/"),
        ] {
            let c = Config {
                refine_near_m: radii.clone(),
                ..Config::baseline()
            }
            .labelled();
            assert!(c.label.starts_with(label), "{}", c.label);
            let json = serde_json::to_string(&c).unwrap();
            assert!(
                json.contains(&format!("\"refine_near_m\":{text}")),
                "{json}"
            );
            let back: Config = serde_json::from_str(&json).unwrap();
            assert_eq!(back, c);
            let scene = c.scene().unwrap();
            assert!(matches!(
                &scene.model,
                fissure_engine::scene::ModelSpec::Phantom { refine_near, .. } if refine_near.len() == radii.len()
            ));
        }
        // None: the field is left out.
        let json = serde_json::to_string(&Config::baseline()).unwrap();
        assert!(!json.contains("refine_near_m"), "{json}");
    }
}
