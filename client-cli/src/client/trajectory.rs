//! Pose trajectories: CSV (`t_s,x_m,y_m,z_m,qw,qx,qy,qz`, one header line) and
//! JSON (an array of objects with the same keys), and the bundled ones.
//!
//! Times are seconds, positions metres (the instrument's handle point in the
//! scene frame), orientations unit quaternions (w, x, y, z). Errors name the
//! file, the line and the column that are wrong.
//!
//! Several instruments in one file ([`load_set`]):
//! * CSV with a leading `instrument` column,
//!   `instrument,t_s,x_m,y_m,z_m,qw,qx,qy,qz`; rows of the instruments may be
//!   interleaved, each instrument's rows keep their order and their times
//!   must not go back;
//! * JSON object keyed by instrument, each value an array of waypoints:
//!   `{"left": [{"t_s": 0, "x_m": ..., ...}, ...], "right": [...]}`.
//!
//! The bundled trajectories (`client-cli/trajectories/*.csv`, written by
//! `generate.py` there or by hand) are registered in [`BUNDLED`] with the
//! scene and instrument they were made for.

use std::path::Path;

/// One pose of a trajectory.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Waypoint {
    /// Time, s.
    pub t_s: f64,
    /// Handle position x, m.
    pub x_m: f64,
    /// Handle position y, m.
    pub y_m: f64,
    /// Handle position z, m.
    pub z_m: f64,
    /// Orientation quaternion w.
    pub qw: f64,
    /// Orientation quaternion x.
    pub qx: f64,
    /// Orientation quaternion y.
    pub qy: f64,
    /// Orientation quaternion z.
    pub qz: f64,
}

/// A trajectory: waypoints in non-decreasing time.
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    /// The waypoints.
    pub points: Vec<Waypoint>,
}

/// Errors reading a trajectory.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum TrajectoryError {
    /// I/O.
    #[error("{file}: {message}")]
    Io { file: String, message: String },
    /// Wrong header.
    #[error("{file}:1: the header must be `{expected}`, got `{got}`")]
    Header {
        file: String,
        expected: String,
        got: String,
    },
    /// A bad value.
    #[error("{file}:{line}: column `{column}`: {message}")]
    Value {
        file: String,
        line: usize,
        column: String,
        message: String,
    },
    /// JSON syntax or shape.
    #[error("{file}: {message}")]
    Json { file: String, message: String },
    /// No waypoint.
    #[error("{file}: the trajectory has no waypoint")]
    Empty { file: String },
    /// Arguments that do not name a trajectory per instrument.
    #[error("{message}")]
    Usage { message: String },
}

/// The CSV header.
pub const CSV_HEADER: &str = "t_s,x_m,y_m,z_m,qw,qx,qy,qz";

/// The CSV header of a file holding several instruments.
pub const MULTI_CSV_HEADER: &str = "instrument,t_s,x_m,y_m,z_m,qw,qx,qy,qz";

/// The bundled trajectories, by name: `(name, scene, instrument, csv)`.
pub const BUNDLED: &[(&str, &str, &str, &str)] = &[
    (
        "sylvian-arachnoid-spatula",
        "sylvian-arachnoid",
        "spatula",
        include_str!("../../trajectories/sylvian-arachnoid-spatula.csv"),
    ),
    (
        "sylvian-arachnoid-blade",
        "sylvian-arachnoid",
        "blade",
        include_str!("../../trajectories/sylvian-arachnoid-blade.csv"),
    ),
    (
        "sylvian-arachnoid-careless-spatula",
        "sylvian-arachnoid",
        "spatula",
        include_str!("../../trajectories/sylvian-arachnoid-careless-spatula.csv"),
    ),
    (
        "sylvian-open-left",
        "sylvian",
        "left",
        include_str!("../../trajectories/sylvian-open-left.csv"),
    ),
    (
        "sylvian-open-right",
        "sylvian",
        "right",
        include_str!("../../trajectories/sylvian-open-right.csv"),
    ),
    (
        "sylvian-expert-left",
        "sylvian",
        "left",
        include_str!("../../trajectories/sylvian-expert-left.csv"),
    ),
    (
        "sylvian-expert-right",
        "sylvian",
        "right",
        include_str!("../../trajectories/sylvian-expert-right.csv"),
    ),
    (
        "sylvian-careless-left",
        "sylvian",
        "left",
        include_str!("../../trajectories/sylvian-careless-left.csv"),
    ),
    (
        "sylvian-careless-right",
        "sylvian",
        "right",
        include_str!("../../trajectories/sylvian-careless-right.csv"),
    ),
    // The `sylvian-open` pair, on the 204k-tetrahedron mesh of the same phantom.
    (
        "sylvian-204k-open-left",
        "sylvian-204k",
        "left",
        include_str!("../../trajectories/sylvian-open-left.csv"),
    ),
    (
        "sylvian-204k-open-right",
        "sylvian-204k",
        "right",
        include_str!("../../trajectories/sylvian-open-right.csv"),
    ),
    (
        "cube-press-left",
        "cube",
        "left",
        include_str!("../../trajectories/cube-press-left.csv"),
    ),
    (
        "cube-press-right",
        "cube",
        "right",
        include_str!("../../trajectories/cube-press-right.csv"),
    ),
    // Press the left plate 3 mm into the block over 0.5 s, hold 0.5 s, lift
    // over 1 s back home (2 mm above the top): the retraction retraces the
    // press for frictionless contact.
    (
        "cube-press-hold-retract-left",
        "cube",
        "left",
        include_str!("../../trajectories/cube-press-hold-retract-left.csv"),
    ),
    // Insert 20 mm into the inter-hemispheric fissure, then push the +x wall
    // 3 mm sideways with face A.
    (
        "interhemispheric-open-left",
        "interhemispheric",
        "left",
        include_str!("../../trajectories/interhemispheric-open-left.csv"),
    ),
    // Insert tip down into the V groove until both faces press both walls.
    (
        "v-valley-insert-left",
        "v-valley",
        "left",
        include_str!("../../trajectories/v-valley-insert-left.csv"),
    ),
    // Insert into the U groove, then rotate about the groove axis to -35 deg
    // (face A presses the +x wall) and +35 deg (face B presses the -x wall).
    (
        "u-valley-rotate-left",
        "u-valley",
        "left",
        include_str!("../../trajectories/u-valley-rotate-left.csv"),
    ),
    // Fast travel: the V insertion at 0.375 m/s, 7.5 mm (5 plate
    // thicknesses) per 20 ms deformation step.
    (
        "v-valley-fast-left",
        "v-valley",
        "left",
        include_str!("../../trajectories/v-valley-fast-left.csv"),
    ),
];

/// The bundled trajectories made for `scene`: `(name, instrument)`, in
/// registry order.
pub fn bundled_for(scene: &str) -> Vec<(&'static str, &'static str)> {
    BUNDLED
        .iter()
        .filter(|b| b.1 == scene)
        .map(|b| (b.0, b.2))
        .collect()
}

/// Trajectories of several instruments: `(instrument, trajectory)`, in the
/// order the instruments first appear (CSV) or by name (JSON).
pub type TrajectorySet = Vec<(String, Trajectory)>;

/// Reads a file of several instruments (see the module doc): JSON when the
/// extension is `.json`, CSV otherwise.
pub fn load_set(path: &str) -> Result<TrajectorySet, TrajectoryError> {
    let file = path.to_owned();
    let text = std::fs::read_to_string(path).map_err(|e| TrajectoryError::Io {
        file: file.clone(),
        message: e.to_string(),
    })?;
    if Path::new(path)
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"))
    {
        parse_set_json(&text, &file)
    } else {
        parse_set_csv(&text, &file)
    }
}

/// Parses a CSV of several instruments (header [`MULTI_CSV_HEADER`]).
pub fn parse_set_csv(text: &str, file: &str) -> Result<TrajectorySet, TrajectoryError> {
    let mut lines = text.lines().enumerate();
    let header = lines.next().map(|(_, l)| l.trim()).unwrap_or("");
    let header_norm: String = header.chars().filter(|c| !c.is_whitespace()).collect();
    if header_norm != MULTI_CSV_HEADER {
        return Err(TrajectoryError::Header {
            file: file.into(),
            expected: MULTI_CSV_HEADER.into(),
            got: header.into(),
        });
    }
    let mut groups: Vec<(String, Vec<(usize, Waypoint)>)> = Vec::new();
    for (i, line) in lines {
        let line_no = i + 1;
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let (name, rest) = line.split_once(',').unwrap_or((line, ""));
        let name = name.trim();
        if name.is_empty() {
            return Err(TrajectoryError::Value {
                file: file.into(),
                line: line_no,
                column: "instrument".into(),
                message: "the instrument name is empty".into(),
            });
        }
        let p = parse_row(rest, file, line_no)?;
        match groups.iter_mut().find(|g| g.0 == name) {
            Some(g) => g.1.push((line_no, p)),
            None => groups.push((name.to_owned(), vec![(line_no, p)])),
        }
    }
    if groups.is_empty() {
        return Err(TrajectoryError::Empty { file: file.into() });
    }
    groups
        .into_iter()
        .map(|(name, pts)| Ok((name, Trajectory::checked(pts, file)?)))
        .collect()
}

/// Parses a JSON object keyed by instrument, each value an array of
/// waypoints.
pub fn parse_set_json(text: &str, file: &str) -> Result<TrajectorySet, TrajectoryError> {
    // Instruments come out sorted by name (a JSON object has no order).
    let map: std::collections::BTreeMap<String, Vec<Waypoint>> = serde_json::from_str(text)
        .map_err(|e| TrajectoryError::Json {
            file: file.into(),
            message: format!(
                "{e} (expected an object keyed by instrument, each value an array of {{\"t_s\", \"x_m\", \"y_m\", \"z_m\", \"qw\", \"qx\", \"qy\", \"qz\"}})"
            ),
        })?;
    if map.is_empty() {
        return Err(TrajectoryError::Empty { file: file.into() });
    }
    map.into_iter()
        .map(|(name, pts)| {
            let f = format!("{file} [{name:?}]");
            let t = Trajectory::checked(
                pts.into_iter()
                    .enumerate()
                    .map(|(i, p)| (i + 1, p))
                    .collect(),
                &f,
            )?;
            Ok((name, t))
        })
        .collect()
}

/// Parses the eight numbers of a row (`t_s,x_m,...,qz`) of line `line_no`.
fn parse_row(row: &str, file: &str, line_no: usize) -> Result<Waypoint, TrajectoryError> {
    let columns: Vec<&str> = CSV_HEADER.split(',').collect();
    let fields: Vec<&str> = row.split(',').map(str::trim).collect();
    if fields.len() != columns.len() {
        return Err(TrajectoryError::Value {
            file: file.into(),
            line: line_no,
            column: "*".into(),
            message: format!("expected {} values, got {}", columns.len(), fields.len()),
        });
    }
    let mut v = [0.0; 8];
    for (k, f) in fields.iter().enumerate() {
        v[k] = f
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| TrajectoryError::Value {
                file: file.into(),
                line: line_no,
                column: columns[k].into(),
                message: format!("{f:?} is not a finite number"),
            })?;
    }
    Ok(Waypoint {
        t_s: v[0],
        x_m: v[1],
        y_m: v[2],
        z_m: v[3],
        qw: v[4],
        qx: v[5],
        qy: v[6],
        qz: v[7],
    })
}

/// Resolves the `--instrument` / `--trajectory` arguments of `fissure replay`
/// into one trajectory per instrument:
/// * `--instrument NAME --trajectory FILE_OR_BUNDLED`: one instrument;
/// * `--trajectory NAME=FILE_OR_BUNDLED` (repeatable): one per instrument;
/// * `--trajectory FILE` alone: a file of several instruments ([`load_set`]).
///
/// An instrument named twice is an error.
pub fn resolve(
    instrument: Option<&str>,
    specs: &[String],
) -> Result<TrajectorySet, TrajectoryError> {
    let usage = |message: String| TrajectoryError::Usage { message };
    let mut out: TrajectorySet = Vec::new();
    match (instrument, specs) {
        (_, []) => return Err(usage("give at least one --trajectory".into())),
        (Some(name), [one]) if !one.contains('=') => {
            out.push((name.to_owned(), Trajectory::load(one)?));
        }
        (Some(_), _) => {
            return Err(usage(
                "--instrument takes exactly one --trajectory FILE; for several instruments use --trajectory NAME=FILE".into(),
            ));
        }
        (None, [one]) if !one.contains('=') => out = load_set(one)?,
        (None, many) => {
            for s in many {
                let Some((name, file)) = s.split_once('=') else {
                    return Err(usage(format!(
                        "--trajectory {s:?}: with several trajectories each must be NAME=FILE"
                    )));
                };
                let name = name.trim();
                if out.iter().any(|(n, _)| n == name) {
                    return Err(usage(format!("instrument {name:?} is given twice")));
                }
                out.push((name.to_owned(), Trajectory::load(file.trim())?));
            }
        }
    }
    Ok(out)
}

impl Trajectory {
    /// Reads a CSV or JSON file (by extension), or a bundled trajectory by name.
    pub fn load(name_or_path: &str) -> Result<Self, TrajectoryError> {
        if let Some((name, _, _, text)) = BUNDLED.iter().find(|b| b.0 == name_or_path) {
            return Self::parse_csv(text, name);
        }
        let path = Path::new(name_or_path);
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| TrajectoryError::Io {
            file: file.clone(),
            message: format!(
                "{e} (not a bundled trajectory either; bundled: {})",
                BUNDLED.iter().map(|b| b.0).collect::<Vec<_>>().join(", ")
            ),
        })?;
        if path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("json"))
        {
            Self::parse_json(&text, &file)
        } else {
            Self::parse_csv(&text, &file)
        }
    }

    /// Parses CSV text; `file` names it in errors.
    pub fn parse_csv(text: &str, file: &str) -> Result<Self, TrajectoryError> {
        let mut lines = text.lines().enumerate();
        let header = lines.next().map(|(_, l)| l.trim()).unwrap_or("");
        let header_norm: String = header.chars().filter(|c| !c.is_whitespace()).collect();
        if header_norm != CSV_HEADER {
            return Err(TrajectoryError::Header {
                file: file.into(),
                expected: CSV_HEADER.into(),
                got: header.into(),
            });
        }
        let mut points = Vec::new();
        for (i, line) in lines {
            let line_no = i + 1;
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            points.push((line_no, parse_row(line, file, line_no)?));
        }
        Self::checked(points, file)
    }

    /// Parses JSON text: an array of waypoint objects.
    pub fn parse_json(text: &str, file: &str) -> Result<Self, TrajectoryError> {
        let points: Vec<Waypoint> =
            serde_json::from_str(text).map_err(|e| TrajectoryError::Json {
                file: file.into(),
                message: e.to_string(),
            })?;
        Self::checked(
            points
                .into_iter()
                .enumerate()
                .map(|(i, p)| (i + 1, p))
                .collect(),
            file,
        )
    }

    fn checked(points: Vec<(usize, Waypoint)>, file: &str) -> Result<Self, TrajectoryError> {
        if points.is_empty() {
            return Err(TrajectoryError::Empty { file: file.into() });
        }
        let mut prev = f64::NEG_INFINITY;
        for (line, p) in &points {
            let bad = |column: &str, message: String| TrajectoryError::Value {
                file: file.into(),
                line: *line,
                column: column.into(),
                message,
            };
            for (name, v) in [
                ("t_s", p.t_s),
                ("x_m", p.x_m),
                ("y_m", p.y_m),
                ("z_m", p.z_m),
            ] {
                if !v.is_finite() {
                    return Err(bad(name, format!("{v} is not finite")));
                }
            }
            if p.t_s < prev {
                return Err(bad(
                    "t_s",
                    format!("time goes back ({} s after {} s)", p.t_s, prev),
                ));
            }
            prev = p.t_s;
            let norm = (p.qw * p.qw + p.qx * p.qx + p.qy * p.qy + p.qz * p.qz).sqrt();
            if !(norm - 1.0).abs().le(&1e-3) {
                return Err(bad(
                    "qw",
                    format!("the quaternion is not unit length (norm {norm})"),
                ));
            }
        }
        Ok(Self {
            points: points.into_iter().map(|(_, p)| p).collect(),
        })
    }

    /// Duration, s.
    pub fn duration_s(&self) -> f64 {
        self.points.last().map_or(0.0, |p| p.t_s) - self.points.first().map_or(0.0, |p| p.t_s)
    }

    /// Writes CSV text.
    pub fn to_csv(&self) -> String {
        let mut s = String::from(CSV_HEADER);
        s.push('\n');
        for p in &self.points {
            s.push_str(&format!(
                "{:.6},{:.9},{:.9},{:.9},{:.9},{:.9},{:.9},{:.9}\n",
                p.t_s, p.x_m, p.y_m, p.z_m, p.qw, p.qx, p.qy, p.qz
            ));
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bundled_parse() {
        for (name, ..) in BUNDLED {
            let t = Trajectory::load(name).unwrap();
            assert!(t.points.len() > 100, "{name}");
        }
    }

    #[test]
    fn errors_name_line_and_column() {
        let text = "t_s,x_m,y_m,z_m,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n0.001,0,abc,0,1,0,0,0\n";
        let e = Trajectory::parse_csv(text, "f.csv").unwrap_err();
        assert_eq!(
            e.to_string(),
            "f.csv:3: column `y_m`: \"abc\" is not a finite number"
        );
        let text = "t_s,x_m,y_m,z_m,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n-1,0,0,0,1,0,0,0\n";
        let e = Trajectory::parse_csv(text, "f.csv").unwrap_err();
        assert!(
            e.to_string()
                .starts_with("f.csv:3: column `t_s`: time goes back"),
            "{e}"
        );
        let e = Trajectory::parse_csv("t,x\n", "f.csv").unwrap_err();
        assert!(matches!(e, TrajectoryError::Header { .. }));
        let text = "t_s,x_m,y_m,z_m,qw,qx,qy,qz\n0,0,0,0,2,0,0,0\n";
        assert!(
            Trajectory::parse_csv(text, "f.csv")
                .unwrap_err()
                .to_string()
                .contains("not unit length")
        );
        let json = r#"[{"t_s":0,"x_m":0,"y_m":0,"z_m":0.1,"qw":1,"qx":0,"qy":0,"qz":0}]"#;
        assert_eq!(
            Trajectory::parse_json(json, "f.json").unwrap().points.len(),
            1
        );
        let round =
            Trajectory::parse_csv(&Trajectory::parse_json(json, "f").unwrap().to_csv(), "g")
                .unwrap();
        assert_eq!(round.points[0].z_m, 0.1);
    }

    #[test]
    fn bundled_registry_names_scene_and_instrument() {
        assert_eq!(
            bundled_for("v-valley"),
            vec![
                ("v-valley-insert-left", "left"),
                ("v-valley-fast-left", "left")
            ]
        );
        // The fast case moves 7.5 mm (5 x 1.5 mm) per 20 ms step at most.
        let t = Trajectory::load("v-valley-fast-left").unwrap();
        let per_step = t
            .points
            .windows(20)
            .map(|w| (w[19].z_m - w[0].z_m).abs() * 20.0 / 19.0)
            .fold(0.0, f64::max);
        assert!((per_step - 0.0075).abs() < 1e-4, "{per_step}");
    }

    #[test]
    fn multi_instrument_csv_groups_interleaved_rows() {
        let text = "instrument,t_s,x_m,y_m,z_m,qw,qx,qy,qz\n\
                    left,0,0,0,0.1,1,0,0,0\n\
                    right,0,0.01,0,0.1,1,0,0,0\n\
                    left,0.001,0,0,0.099,1,0,0,0\n";
        let set = parse_set_csv(text, "two.csv").unwrap();
        assert_eq!(set.len(), 2);
        assert_eq!(set[0].0, "left");
        assert_eq!(set[0].1.points.len(), 2);
        assert_eq!(set[0].1.points[1].z_m, 0.099);
        assert_eq!(set[1].1.points[0].x_m, 0.01);
        // Errors name the file, the line and the column.
        let bad = "instrument,t_s,x_m,y_m,z_m,qw,qx,qy,qz\nleft,0,0,0,0.1,1,0,0,0\nright,0,0,x,0.1,1,0,0,0\n";
        assert_eq!(
            parse_set_csv(bad, "two.csv").unwrap_err().to_string(),
            "two.csv:3: column `y_m`: \"x\" is not a finite number"
        );
        let back = "instrument,t_s,x_m,y_m,z_m,qw,qx,qy,qz\nleft,1,0,0,0.1,1,0,0,0\nright,0,0,0,0.1,1,0,0,0\nleft,0.5,0,0,0.1,1,0,0,0\n";
        assert!(
            parse_set_csv(back, "two.csv")
                .unwrap_err()
                .to_string()
                .starts_with("two.csv:4: column `t_s`: time goes back"),
        );
        let empty_name = "instrument,t_s,x_m,y_m,z_m,qw,qx,qy,qz\n,0,0,0,0.1,1,0,0,0\n";
        assert!(
            parse_set_csv(empty_name, "e.csv")
                .unwrap_err()
                .to_string()
                .contains("e.csv:2: column `instrument`")
        );
        // A single-instrument header is refused with the expected one named.
        assert!(matches!(
            parse_set_csv("t_s,x_m,y_m,z_m,qw,qx,qy,qz\n", "s.csv"),
            Err(TrajectoryError::Header { .. })
        ));
    }

    #[test]
    fn multi_instrument_json_and_resolve() {
        let json = r#"{"right": [{"t_s":0,"x_m":0,"y_m":0,"z_m":0.1,"qw":1,"qx":0,"qy":0,"qz":0}],
                       "left": [{"t_s":0,"x_m":0,"y_m":0,"z_m":0.2,"qw":1,"qx":0,"qy":0,"qz":0},
                                {"t_s":0.1,"x_m":0,"y_m":0,"z_m":0.2,"qw":1,"qx":0,"qy":0,"qz":0}]}"#;
        let set = parse_set_json(json, "s.json").unwrap();
        assert_eq!(set[0].0, "left");
        assert_eq!(set[0].1.points.len(), 2);
        assert_eq!(set[1].1.points[0].z_m, 0.1);
        let bad = r#"{"left": [{"t_s":0,"x_m":0,"y_m":0,"z_m":0.2,"qw":2,"qx":0,"qy":0,"qz":0}]}"#;
        let e = parse_set_json(bad, "s.json").unwrap_err().to_string();
        assert!(e.contains("s.json [\"left\"]:1: column `qw`"), "{e}");

        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("set.json");
        std::fs::write(&path, json).unwrap();
        let p = path.to_str().unwrap().to_owned();
        assert_eq!(resolve(None, std::slice::from_ref(&p)).unwrap().len(), 2);
        let two = [
            "left=cube-press-left".to_owned(),
            "right=cube-press-right".to_owned(),
        ];
        let set = resolve(None, &two).unwrap();
        assert_eq!((set[0].0.as_str(), set[1].0.as_str()), ("left", "right"));
        assert!(resolve(Some("left"), &two).is_err());
        assert!(resolve(None, &["left=a".into(), "left=b".into()]).is_err());
        assert!(resolve(None, &[]).is_err());
        let one = resolve(Some("left"), &["cube-press-left".into()]).unwrap();
        assert_eq!(one[0].0, "left");
    }
}
