//! The VTU time series of the boundary surface (`surface-NNNNNN.vtu`, point
//! data `displacement` in m; for a labelled model, cell data `label`, the
//! tissue of each triangle) and its ParaView index (`.pvd`, `timestep` = the
//! frame's simulation time, s); for scenes with ties, beside it the series of
//! the ties that hold (`<stem>-ties-NNNNNN.vtu`, line cells with cell data
//! `strain` and `vessel` (1 for a vessel, 0 for a trabecula), so that
//! ParaView can colour them; cut and torn ties are gone from it).

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
    tie_entries: Vec<(f64, String)>,
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
            tie_entries: Vec::new(),
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
        let labels: Vec<f64> = view.triangle_labels.iter().map(|&l| f64::from(l)).collect();
        let cell_data: &[(&str, &[f64])] = if labels.is_empty() {
            &[]
        } else {
            &[("label", &labels)]
        };
        fissure_shared::vtu::write_vtu_surface(
            &mut w,
            &self.positions,
            &view.triangles,
            &[("displacement", &self.displacement)],
            cell_data,
        )
        .and_then(|_| w.flush())
        .with_context(|| format!("writing {}", path.display()))?;
        self.entries.push((frame.sim_time_s, name));
        if !view.ties.is_empty() {
            self.write_ties(view, frame)?;
        }
        Ok(path)
    }

    /// Writes the frame's intact ties as line cells.
    fn write_ties(
        &mut self,
        view: &SessionView,
        frame: &pb::DeformationFrame,
    ) -> anyhow::Result<()> {
        let ties = super::view::intact_ties(&view.ties, frame, &self.positions);
        let points: Vec<Point3<f64>> = ties.iter().flat_map(|t| [t.0, t.1]).collect();
        let segments: Vec<[u32; 2]> = (0..ties.len() as u32).map(|i| [2 * i, 2 * i + 1]).collect();
        let strain: Vec<f64> = ties.iter().map(|t| t.3).collect();
        let vessel: Vec<f64> = ties
            .iter()
            .map(|t| f64::from(u8::from(t.2 == pb::TieKind::Vessel)))
            .collect();
        let name = format!("{}-ties-{:06}.vtu", self.stem, frame.frame);
        let path = self.dir.join(&name);
        let file =
            std::fs::File::create(&path).with_context(|| format!("creating {}", path.display()))?;
        let mut w = std::io::BufWriter::new(file);
        fissure_shared::vtu::write_vtu_lines(
            &mut w,
            &points,
            &segments,
            &[],
            &[("strain", &strain), ("vessel", &vessel)],
        )
        .and_then(|_| w.flush())
        .with_context(|| format!("writing {}", path.display()))?;
        self.tie_entries.push((frame.sim_time_s, name));
        Ok(())
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
        if !self.tie_entries.is_empty() {
            let ties = self.dir.join(format!("{}-ties.pvd", self.stem));
            std::fs::write(&ties, pvd(&self.tie_entries))
                .with_context(|| format!("writing {}", ties.display()))?;
        }
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

    #[test]
    fn a_labelled_surface_writes_its_tissue_labels_as_cell_data() {
        let surface = pb::SurfaceMesh {
            rest_positions_m: vec![
                0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.01,
            ],
            triangles: vec![0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3],
            triangle_labels: vec![3, 3, 42, 42],
        };
        let scene = pb::SceneDescription {
            name: "labelled".into(),
            ..Default::default()
        };
        let dir = tempfile::tempdir().unwrap();
        let frame = pb::DeformationFrame {
            frame: 1,
            ..Default::default()
        };
        let labelled = SessionView::new(&scene, &surface);
        let path = VtuSeries::new(dir.path(), "s")
            .write(&labelled, &frame)
            .unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.contains("NumberOfCells=\"4\""), "{text}");
        assert!(text.contains("Name=\"label\""), "{text}");
        // Without labels (or with a count that does not match) no label
        // array is written.
        let plain = SessionView::new(
            &scene,
            &pb::SurfaceMesh {
                triangle_labels: vec![1],
                ..surface
            },
        );
        assert!(plain.triangle_labels.is_empty());
        let path = VtuSeries::new(dir.path(), "p")
            .write(&plain, &frame)
            .unwrap();
        assert!(
            !std::fs::read_to_string(&path)
                .unwrap()
                .contains("Name=\"label\"")
        );
    }
}
