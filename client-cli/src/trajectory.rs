//! Pose trajectories: CSV (`t_s,x_m,y_m,z_m,qw,qx,qy,qz`, one header line) and
//! JSON (an array of objects with the same keys), and the bundled ones.
//!
//! Times are seconds, positions metres (the instrument's handle point in the
//! scene frame), orientations unit quaternions (w, x, y, z). Errors name the
//! file, the line and the column that are wrong.

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
}

/// The CSV header.
pub const CSV_HEADER: &str = "t_s,x_m,y_m,z_m,qw,qx,qy,qz";

/// The bundled trajectories, by name: `(name, scene, instrument, csv)`.
pub const BUNDLED: &[(&str, &str, &str, &str)] = &[
    (
        "sylvian-open-left",
        "sylvian",
        "left",
        include_str!("../trajectories/sylvian-open-left.csv"),
    ),
    (
        "sylvian-open-right",
        "sylvian",
        "right",
        include_str!("../trajectories/sylvian-open-right.csv"),
    ),
    (
        "cube-press-left",
        "cube",
        "left",
        include_str!("../trajectories/cube-press-left.csv"),
    ),
    (
        "cube-press-right",
        "cube",
        "right",
        include_str!("../trajectories/cube-press-right.csv"),
    ),
];

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
        let columns: Vec<&str> = CSV_HEADER.split(',').collect();
        let mut points = Vec::new();
        for (i, line) in lines {
            let line_no = i + 1;
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let fields: Vec<&str> = line.split(',').map(str::trim).collect();
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
            points.push((
                line_no,
                Waypoint {
                    t_s: v[0],
                    x_m: v[1],
                    y_m: v[2],
                    z_m: v[3],
                    qw: v[4],
                    qx: v[5],
                    qy: v[6],
                    qz: v[7],
                },
            ));
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
}
