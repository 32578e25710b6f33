//! Where a session's deformation frames go: the outputs that `fissure watch`
//! and `fissure demo` share, behind one trait, [`FrameSink`].
//!
//! * [`VtuSink`]: the VTU series of the surface and its `.pvd` index;
//! * [`PngSink`]: PNG pictures of chosen frames ([`PngPick`]: the first and
//!   the last, all, or a set of labelled snapshots);
//! * [`GifSink`]: the animated GIF, thinned by a [`GifBuffer`].
//!
//! A sink takes the frames in order, one at a time, each with the colour
//! scale to draw it with, and writes as they come; [`FrameSink::finish`]
//! completes what needs the end (the `.pvd` index, the last PNG, the GIF).
//! The watcher streams: its scale grows with the largest value seen so far
//! (or is fixed by `--range-mm`) and its GIF thins as it goes. The demo has
//! every frame of its run before it writes, so it makes its choices in a
//! first pass (one scale for the run, which frame is "during", the GIF's
//! stride) and then pushes the frames through the same sinks: the files of
//! both commands come from one code path.

use super::gif::{GifBuffer, gif_delay_cs};
use super::view::{SessionView, caption_of};
use super::vtu::VtuSeries;
use crate::client::render::anim;
use crate::client::render::frame::FrameRenderer;
use fissure_proto::v1 as pb;
use std::path::{Path, PathBuf};

/// Where a session's deformation frames go: each output a person opens
/// afterwards. `Send`, so that the watcher's sinks live in its task.
pub trait FrameSink: Send {
    /// Takes the next frame (in order), drawn with `view` on the colour
    /// scale `0..range_mm`.
    fn frame(
        &mut self,
        view: &SessionView,
        frame: &pb::DeformationFrame,
        range_mm: f64,
    ) -> anyhow::Result<()>;

    /// Completes the output (the `.pvd` index, the last PNG, the GIF) and
    /// returns the files written, in the order written.
    fn finish(self: Box<Self>, view: &SessionView) -> anyhow::Result<Vec<PathBuf>>;
}

/// The VTU series of the surface (`<stem>-NNNNNN.vtu`, one per frame) and
/// its index `<stem>.pvd` (written at the end, if a frame came).
#[derive(Debug)]
pub struct VtuSink {
    series: VtuSeries,
    /// Whether the returned files list every frame's VTU (else the index
    /// alone).
    list_frames: bool,
    files: Vec<PathBuf>,
}

impl VtuSink {
    /// A series in `dir` named after `stem`; `list_frames`: whether
    /// [`FrameSink::finish`] returns every VTU written with the index.
    pub fn new(dir: &Path, stem: &str, list_frames: bool) -> Self {
        Self {
            series: VtuSeries::new(dir, stem),
            list_frames,
            files: Vec::new(),
        }
    }
}

impl FrameSink for VtuSink {
    fn frame(
        &mut self,
        view: &SessionView,
        frame: &pb::DeformationFrame,
        _range_mm: f64,
    ) -> anyhow::Result<()> {
        let path = self.series.write(view, frame)?;
        if self.list_frames {
            self.files.push(path);
        }
        Ok(())
    }

    fn finish(mut self: Box<Self>, _view: &SessionView) -> anyhow::Result<Vec<PathBuf>> {
        if !self.series.is_empty() {
            self.files.push(self.series.finish()?);
        }
        Ok(self.files)
    }
}

/// Which frames a [`PngSink`] draws.
#[derive(Debug, Clone, PartialEq)]
pub enum PngPick {
    /// The first and the last (`frame-NNNNNN.png`, NNNNNN the frame's
    /// number); the last is drawn at the end, on the scale it came with.
    FirstAndLast,
    /// Every frame (`frame-NNNNNN.png`).
    All,
    /// Chosen frames with their own names and labels, in the order of
    /// their indices.
    Chosen(Vec<Snapshot>),
}

/// A chosen picture: a frame by its index among those the sink takes.
#[derive(Debug, Clone, PartialEq)]
pub struct Snapshot {
    /// Index of the frame (0 the first taken).
    pub index: usize,
    /// File name in the sink's folder.
    pub file: String,
    /// Added to the title (`fissure — <scene> — <label>`).
    pub label: String,
}

/// PNG pictures of the frames chosen by a [`PngPick`].
pub struct PngSink {
    dir: PathBuf,
    renderer: FrameRenderer,
    pick: PngPick,
    seen: usize,
    /// The newest frame after the first, with its scale
    /// ([`PngPick::FirstAndLast`]).
    last: Option<(pb::DeformationFrame, f64)>,
    files: Vec<PathBuf>,
}

impl PngSink {
    /// Pictures drawn by `renderer` into `dir`.
    pub fn new(dir: &Path, renderer: FrameRenderer, pick: PngPick) -> Self {
        Self {
            dir: dir.to_owned(),
            renderer,
            pick,
            seen: 0,
            last: None,
            files: Vec::new(),
        }
    }

    /// Draws `frame` into `dir/file`, with `label` added to the title.
    fn save(
        &mut self,
        view: &SessionView,
        frame: &pb::DeformationFrame,
        range_mm: f64,
        file: &str,
        label: Option<&str>,
    ) -> anyhow::Result<()> {
        let mut caption = caption_of(&view.scene, frame, range_mm);
        if let Some(label) = label {
            caption.title = format!("{} \u{2014} {label}", caption.title);
        }
        let path = self.dir.join(file);
        view.render(&mut self.renderer, frame, &caption)?
            .save_png(&path)?;
        self.files.push(path);
        Ok(())
    }
}

/// The file name of a frame's picture.
fn frame_png(frame: &pb::DeformationFrame) -> String {
    format!("frame-{:06}.png", frame.frame)
}

impl FrameSink for PngSink {
    fn frame(
        &mut self,
        view: &SessionView,
        frame: &pb::DeformationFrame,
        range_mm: f64,
    ) -> anyhow::Result<()> {
        let index = self.seen;
        self.seen += 1;
        match &self.pick {
            PngPick::All => self.save(view, frame, range_mm, &frame_png(frame), None),
            PngPick::FirstAndLast if index == 0 => {
                self.save(view, frame, range_mm, &frame_png(frame), None)
            }
            PngPick::FirstAndLast => {
                self.last = Some((frame.clone(), range_mm));
                Ok(())
            }
            PngPick::Chosen(chosen) => {
                let here: Vec<Snapshot> = chosen
                    .iter()
                    .filter(|s| s.index == index)
                    .cloned()
                    .collect();
                for s in here {
                    self.save(view, frame, range_mm, &s.file, Some(&s.label))?;
                }
                Ok(())
            }
        }
    }

    fn finish(mut self: Box<Self>, view: &SessionView) -> anyhow::Result<Vec<PathBuf>> {
        if let Some((frame, range_mm)) = self.last.take() {
            self.save(view, &frame, range_mm, &frame_png(&frame), None)?;
        }
        Ok(self.files)
    }
}

/// The animated GIF of the session: the frames its [`GifBuffer`] keeps,
/// drawn as they come and encoded at the end, each shown for the
/// simulation time between kept frames.
pub struct GifSink {
    path: PathBuf,
    renderer: FrameRenderer,
    buffer: GifBuffer,
    /// Simulation times of the first and the newest frame taken, s, and
    /// the number taken.
    times: Option<(f64, f64)>,
    taken: usize,
}

impl GifSink {
    /// A GIF at `path`, its frames drawn by `renderer` and thinned by
    /// `buffer`.
    pub fn new(path: PathBuf, renderer: FrameRenderer, buffer: GifBuffer) -> Self {
        Self {
            path,
            renderer,
            buffer,
            times: None,
            taken: 0,
        }
    }
}

impl FrameSink for GifSink {
    fn frame(
        &mut self,
        view: &SessionView,
        frame: &pb::DeformationFrame,
        range_mm: f64,
    ) -> anyhow::Result<()> {
        let img = if self.buffer.wants_next() {
            Some(view.render(
                &mut self.renderer,
                frame,
                &caption_of(&view.scene, frame, range_mm),
            )?)
        } else {
            None
        };
        self.buffer.push(img);
        let t = frame.sim_time_s;
        self.times = Some(self.times.map_or((t, t), |(first, _)| (first, t)));
        self.taken += 1;
        Ok(())
    }

    fn finish(self: Box<Self>, _view: &SessionView) -> anyhow::Result<Vec<PathBuf>> {
        if self.buffer.frames().is_empty() {
            return Ok(Vec::new());
        }
        let dt = match self.times {
            Some((first, last)) if self.taken > 1 => (last - first) / (self.taken - 1) as f64,
            _ => 0.04,
        };
        anim::save_gif(
            self.buffer.frames(),
            &self.path,
            &anim::GifOptions {
                delay_cs: gif_delay_cs(dt * self.buffer.stride() as f64),
                ..Default::default()
            },
        )?;
        Ok(vec![self.path])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tetrahedron of 1 cm.
    fn view() -> SessionView {
        let surface = pb::SurfaceMesh {
            rest_positions_m: vec![
                0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.01,
            ],
            triangles: vec![0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3],
            triangle_labels: Vec::new(),
        };
        let scene = pb::SceneDescription {
            name: "tetra".into(),
            ..Default::default()
        };
        SessionView::new(&scene, &surface)
    }

    fn frames(n: u64) -> Vec<pb::DeformationFrame> {
        (0..n)
            .map(|k| pb::DeformationFrame {
                frame: 10 + k,
                sim_time_s: 0.01 * k as f64,
                ..Default::default()
            })
            .collect()
    }

    fn names(files: &[PathBuf]) -> Vec<String> {
        files
            .iter()
            .map(|f| f.file_name().unwrap().to_string_lossy().into_owned())
            .collect()
    }

    fn pngs_in(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".png"))
            .collect();
        v.sort();
        v
    }

    /// The PNG sink draws exactly the frames its pick chooses: the first and
    /// the last; or the chosen indices under their names, one frame under
    /// two names when chosen twice, in the order of the choice.
    #[test]
    fn the_png_sink_writes_exactly_the_chosen_frames() {
        let view = view();
        let frames = frames(5);
        let dir = tempfile::tempdir().unwrap();
        let run = |dir: &Path, pick: PngPick| {
            let mut sink: Box<dyn FrameSink> = Box::new(PngSink::new(
                dir,
                FrameRenderer::new(320, 240).unwrap(),
                pick,
            ));
            for f in &frames {
                sink.frame(&view, f, 1.0).unwrap();
            }
            sink.finish(&view).unwrap()
        };
        let files = run(dir.path(), PngPick::FirstAndLast);
        assert_eq!(names(&files), ["frame-000010.png", "frame-000014.png"]);
        assert_eq!(pngs_in(dir.path()), names(&files));

        let dir = tempfile::tempdir().unwrap();
        let snap = |index: usize, file: &str| Snapshot {
            index,
            file: file.into(),
            label: file.into(),
        };
        let chosen = vec![snap(0, "a.png"), snap(3, "b.png"), snap(3, "c.png")];
        let files = run(dir.path(), PngPick::Chosen(chosen));
        assert_eq!(names(&files), ["a.png", "b.png", "c.png"]);
        assert_eq!(pngs_in(dir.path()), ["a.png", "b.png", "c.png"]);

        // One frame alone: the first is the last, drawn once.
        let dir = tempfile::tempdir().unwrap();
        let mut sink: Box<dyn FrameSink> = Box::new(PngSink::new(
            dir.path(),
            FrameRenderer::new(320, 240).unwrap(),
            PngPick::FirstAndLast,
        ));
        sink.frame(&view, &frames[2], 1.0).unwrap();
        assert_eq!(names(&sink.finish(&view).unwrap()), ["frame-000012.png"]);
    }

    /// The VTU sink lists its frames only when asked, the index always; no
    /// frame, no index.
    #[test]
    fn the_vtu_sink_writes_a_file_per_frame_and_the_index() {
        let view = view();
        let dir = tempfile::tempdir().unwrap();
        for list_frames in [true, false] {
            let mut sink: Box<dyn FrameSink> = Box::new(VtuSink::new(dir.path(), "s", list_frames));
            for f in &frames(3) {
                sink.frame(&view, f, 1.0).unwrap();
            }
            let files = names(&sink.finish(&view).unwrap());
            if list_frames {
                assert_eq!(
                    files,
                    ["s-000010.vtu", "s-000011.vtu", "s-000012.vtu", "s.pvd"]
                );
            } else {
                assert_eq!(files, ["s.pvd"]);
            }
        }
        let sink: Box<dyn FrameSink> = Box::new(VtuSink::new(dir.path(), "empty", true));
        assert!(sink.finish(&view).unwrap().is_empty());
        assert!(!dir.path().join("empty.pvd").exists());
    }

    /// The GIF sink with a fixed stride draws every `stride`-th frame and
    /// the last (10 frames, stride 4: frames 0, 4, 8, 9), each shown for
    /// `stride` frame intervals of simulation time (4 x 10 ms); with no
    /// frame it writes nothing.
    #[test]
    fn the_gif_sink_keeps_every_strideth_frame_and_the_last() {
        let view = view();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("session.gif");
        let mut sink: Box<dyn FrameSink> = Box::new(GifSink::new(
            path.clone(),
            FrameRenderer::new(320, 240).unwrap(),
            GifBuffer::every(4, 10),
        ));
        for f in &frames(10) {
            sink.frame(&view, f, 1.0).unwrap();
        }
        assert_eq!(sink.finish(&view).unwrap(), std::slice::from_ref(&path));
        let bytes = std::fs::read(&path).unwrap();
        let mut dec = gif::DecodeOptions::new()
            .read_info(bytes.as_slice())
            .unwrap();
        let mut delays = Vec::new();
        while let Some(f) = dec.read_next_frame().unwrap() {
            delays.push(f.delay);
        }
        assert_eq!(delays, [4, 4, 4, 4]);

        let empty: Box<dyn FrameSink> = Box::new(GifSink::new(
            dir.path().join("none.gif"),
            FrameRenderer::new(320, 240).unwrap(),
            GifBuffer::new(10),
        ));
        assert!(empty.finish(&view).unwrap().is_empty());
        assert!(!dir.path().join("none.gif").exists());
    }
}
