//! The VTU time series of the boundary surface (`surface-NNNNNN.vtu`, point
//! data `displacement` in m) and its ParaView index (`.pvd`, `timestep` = the
//! frame's simulation time, s).

use super::view::SessionView;
use anyhow::Context;
use fissure_proto::v1 as pb;
use nalgebra::{Point3, Vector3};
use std::io::Write;
use std::path::{Path, PathBuf};

/// A VTU time series of the surface with its `.pvd` index.
#[derive(Debug)]
pub struct VtuSeries {
    dir: PathBuf,
    stem: String,
    entries: Vec<(f64, String)>,
    positions: Vec<Point3<f64>>,
    displacement: Vec<Vector3<f64>>,
}

impl VtuSeries {
    /// A series written into `dir` as `<stem>-NNNNNN.vtu` and `<stem>.pvd`.
    pub fn new(dir: &Path, stem: &str) -> Self {
        Self {
            dir: dir.to_owned(),
            stem: stem.to_owned(),
            entries: Vec::new(),
            positions: Vec::new(),
            displacement: Vec::new(),
        }
    }

    /// Writes one frame: the deformed surface with point data
    /// `displacement` (m). Returns the file written.
    pub fn write(
        &mut self,
        view: &SessionView,
        frame: &pb::DeformationFrame,
    ) -> anyhow::Result<PathBuf> {
        view.positions_into(frame, &mut self.positions);
        self.displacement.clear();
        self.displacement
            .extend(self.positions.iter().zip(&view.rest).map(|(p, r)| p - r));
        let name = format!("{}-{:06}.vtu", self.stem, frame.frame);
        let path = self.dir.join(&name);
        let file =
            std::fs::File::create(&path).with_context(|| format!("creating {}", path.display()))?;
        let mut w = std::io::BufWriter::new(file);
        fissure_proto::vtu::write_vtu_surface(
            &mut w,
            &self.positions,
            &view.triangles,
            &[("displacement", &self.displacement)],
            &[],
        )
        .and_then(|_| w.flush())
        .with_context(|| format!("writing {}", path.display()))?;
        self.entries.push((frame.sim_time_s, name));
        Ok(path)
    }

    /// Number of frames written.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether no frame was written.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Writes the `.pvd` index (ParaView's collection of the frames, with
    /// their simulation times in s) and returns its path.
    pub fn finish(&self) -> anyhow::Result<PathBuf> {
        let path = self.dir.join(format!("{}.pvd", self.stem));
        std::fs::write(&path, pvd(&self.entries))
            .with_context(|| format!("writing {}", path.display()))?;
        Ok(path)
    }
}

/// A ParaView collection file of `(time s, file)` entries.
pub fn pvd(entries: &[(f64, String)]) -> String {
    let mut s = String::from(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">\n<Collection>\n",
    );
    for (t, f) in entries {
        s.push_str(&format!(
            "<DataSet timestep=\"{t:.6}\" group=\"\" part=\"0\" file=\"{f}\"/>\n"
        ));
    }
    s.push_str("</Collection>\n</VTKFile>\n");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pvd_lists_files_with_times() {
        let s = pvd(&[(0.0, "a-000000.vtu".into()), (0.02, "a-000001.vtu".into())]);
        assert!(s.contains(
            "<DataSet timestep=\"0.020000\" group=\"\" part=\"0\" file=\"a-000001.vtu\"/>"
        ));
        assert!(s.starts_with("<?xml"));
    }
}
