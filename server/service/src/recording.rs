//! The session recorder: every accepted pose, every force sample and every
//! frame summary, appended as length-delimited `fissure.v1.RecordingEntry`
//! messages. It is the simulation's [`Journal`] when a session is recorded
//! ([`ToFile`] opens it): the engine reports values, this module encodes
//! them. Files are read with `fissure_proto::recording` (re-exported here).
//!
//! A writer thread owns the file; producers (the force loops and the
//! deformation loop) hand entries to it over a queue and never wait for the
//! disk. The writer flushes whenever its queue runs empty and at least every
//! [`FLUSH_INTERVAL`], so a crash loses at most the last few milliseconds.
//!
//! # Bounded queue, recorded loss
//!
//! The queue holds at most [`QUEUE_CAPACITY`] entries: 2 s of the heaviest
//! session the server runs (two instruments at 1 kHz, each accepted pose with
//! its force sample, 4,000 entries/s, plus the frame summaries). A disk that
//! keeps up never fills it. When the disk stalls for longer than that, a
//! producer finding the queue full drops its entry instead of waiting (the
//! 1 kHz force loop must not wait on a disk) and counts it by kind. The next
//! entry that gets into the queue carries those counts, and the writer puts a
//! [`RecordingGap`] entry just before it, so the file itself says where
//! entries are missing and how many of each kind; counts still pending when
//! the recording is finished go into a last gap entry. A warning is logged at
//! the first loss and then at most once a second while the loss goes on;
//! [`Recorder::stats`] gives the totals and the queue's depth.
//!
//! Memory is bounded by the queue: `QUEUE_CAPACITY` slots allocated once
//! (`size_of::<pb::RecordingEntry>()` plus 24 bytes each) and the heap parts
//! of the queued entries (an instrument name, a frame's per-instrument
//! summary); measured in `tests/tests/isolated/reliability_recording.rs`.
//!
//! A gap is the `gap` member (field 5) of `RecordingEntry`'s `oneof entry`,
//! a `fissure.v1.RecordingGap` (its sums in [`RecordingGapExt`]).

use fissure_engine::scene::Scene;
use fissure_engine::sim::ForceOut;
use fissure_engine::sim::core::engine::Model;
use fissure_engine::sim::core::pose::RawPose;
use fissure_engine::sim::core::snapshot::Frame;
use fissure_engine::sim::runtime::journal::{Journal, OpenJournal};
use fissure_proto::recording::gap_entry;
use fissure_proto::v1 as pb;
use prost::Message;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Longest time an entry waits in the writer's buffer.
pub const FLUSH_INTERVAL: Duration = Duration::from_millis(5);

/// Entries the queue to the writer holds: 2 s at 4,000 entries/s (two
/// instruments at 1 kHz, a pose and a force sample each), rounded up to a
/// power of two (frames add about 30 to 50 a second).
pub const QUEUE_CAPACITY: usize = 8192;

/// Longest [`Recorder::finish`] and [`Recorder::flush`] wait for the writer.
pub const FINISH_TIMEOUT: Duration = Duration::from_secs(5);

/// Shortest time between two warnings about dropped entries.
const WARN_INTERVAL: Duration = Duration::from_secs(1);

pub use fissure_proto::recording::{
    Gap, ReadError, Recording, RecordingGap, RecordingGapExt, read, read_recording,
};

/// The queue's and the writer's figures.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RecorderStats {
    /// Entries the queue holds at most.
    pub capacity: usize,
    /// Entries in the queue now (counted before they enter it, so it may
    /// exceed the true depth by the number of producers sending right now).
    pub queued: usize,
    /// Largest `queued` seen.
    pub peak_queued: usize,
    /// Entries handed to the file's buffer (the header and gap entries not
    /// counted).
    pub written: u64,
    /// Entries dropped because the queue was full or the writer had failed
    /// (an I/O error, returned by [`Recorder::finish`]), by kind, since the
    /// start.
    pub lost: RecordingGap,
}

#[derive(Clone, Copy)]
enum Kind {
    Pose = 0,
    Force = 1,
    Frame = 2,
}

/// Counters shared by the producers and the writer.
struct Shared {
    capacity: usize,
    /// Dropped, not yet carried into the file by a gap entry.
    pending: [AtomicU64; 3],
    /// Dropped since the start.
    lost: [AtomicU64; 3],
    queued: AtomicUsize,
    peak_queued: AtomicUsize,
    written: AtomicU64,
    /// The recorder's start, for `last_warn_ms`.
    start: Instant,
    /// Milliseconds after `start` of the last warning (`u64::MAX`: none).
    last_warn_ms: AtomicU64,
}

impl Shared {
    fn take_pending(&self) -> RecordingGap {
        let t = |k: usize| self.pending[k].swap(0, Ordering::AcqRel);
        RecordingGap {
            poses: t(0),
            forces: t(1),
            frames: t(2),
        }
    }

    fn put_pending(&self, g: &RecordingGap) {
        for (k, n) in [g.poses, g.forces, g.frames].into_iter().enumerate() {
            if n > 0 {
                self.pending[k].fetch_add(n, Ordering::AcqRel);
            }
        }
    }

    fn lost(&self) -> RecordingGap {
        let l = |k: usize| self.lost[k].load(Ordering::Acquire);
        RecordingGap {
            poses: l(0),
            forces: l(1),
            frames: l(2),
        }
    }

    /// Counts a dropped entry; warns at the first and then at most once a
    /// [`WARN_INTERVAL`].
    fn drop_entry(&self, kind: Kind, why: &str) {
        self.pending[kind as usize].fetch_add(1, Ordering::AcqRel);
        self.lost[kind as usize].fetch_add(1, Ordering::AcqRel);
        let now = self.start.elapsed().as_millis() as u64;
        let last = self.last_warn_ms.load(Ordering::Acquire);
        let due = last == u64::MAX || now >= last + WARN_INTERVAL.as_millis() as u64;
        if due
            && self
                .last_warn_ms
                .compare_exchange(last, now, Ordering::AcqRel, Ordering::Acquire)
                .is_ok()
        {
            let l = self.lost();
            tracing::warn!(
                lost_poses = l.poses,
                lost_forces = l.forces,
                lost_frames = l.frames,
                "recording: {why}; dropping entries (the file records how many, where)"
            );
        }
    }
}

enum Msg {
    /// An entry, and the entries dropped just before it.
    Entry(pb::RecordingEntry, RecordingGap),
    Flush(mpsc::Sender<()>),
}

/// Appends entries to a recording file from any thread.
pub struct Recorder {
    tx: Mutex<Option<mpsc::SyncSender<Msg>>>,
    thread: Mutex<Option<JoinHandle<std::io::Result<()>>>>,
    /// Disconnected when the writer thread has ended.
    ended: Mutex<Option<mpsc::Receiver<()>>>,
    shared: Arc<Shared>,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder")
            .field("stats", &self.stats())
            .finish_non_exhaustive()
    }
}

fn header(scene: &pb::SceneDescription, surface: Option<pb::SurfaceMesh>) -> pb::RecordingEntry {
    pb::RecordingEntry {
        entry: Some(pb::recording_entry::Entry::Header(pb::RecordingHeader {
            version: 1,
            scene: Some(scene.clone()),
            surface,
            started_unix_s: std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_secs_f64())
                .unwrap_or(0.0),
        })),
    }
}

impl Recorder {
    /// Creates (truncates) the file and writes the header; the queue holds
    /// [`QUEUE_CAPACITY`] entries. The file is synced when the recording is
    /// finished.
    pub fn create(
        path: &Path,
        scene: &pb::SceneDescription,
        surface: Option<pb::SurfaceMesh>,
    ) -> std::io::Result<Self> {
        let file = std::fs::File::create(path)?;
        Self::start(
            BufWriter::new(file),
            scene,
            surface,
            QUEUE_CAPACITY,
            |out| out.get_ref().sync_all(),
        )
    }

    /// Records to any writer (buffered here), with a queue of `capacity`
    /// entries (at least 1). Writes the header before returning.
    pub fn with_writer<W: Write + Send + 'static>(
        out: W,
        scene: &pb::SceneDescription,
        capacity: usize,
    ) -> std::io::Result<Self> {
        Self::start(BufWriter::new(out), scene, None, capacity, |_| Ok(()))
    }

    fn start<W: Write + Send + 'static>(
        mut out: BufWriter<W>,
        scene: &pb::SceneDescription,
        surface: Option<pb::SurfaceMesh>,
        capacity: usize,
        close: impl FnOnce(&mut BufWriter<W>) -> std::io::Result<()> + Send + 'static,
    ) -> std::io::Result<Self> {
        out.write_all(&header(scene, surface).encode_length_delimited_to_vec())?;
        out.flush()?;
        let capacity = capacity.max(1);
        let shared = Arc::new(Shared {
            capacity,
            pending: Default::default(),
            lost: Default::default(),
            queued: AtomicUsize::new(0),
            peak_queued: AtomicUsize::new(0),
            written: AtomicU64::new(0),
            start: Instant::now(),
            last_warn_ms: AtomicU64::new(u64::MAX),
        });
        let (tx, rx) = mpsc::sync_channel::<Msg>(capacity);
        let (ended_tx, ended_rx) = mpsc::channel::<()>();
        let writer = shared.clone();
        let thread = std::thread::Builder::new()
            .name("recorder".into())
            .spawn(move || {
                let _ended = ended_tx;
                let r = write_entries(&rx, &mut out, &writer).and_then(|()| close(&mut out));
                if let Err(e) = &r {
                    tracing::error!("recording: writing failed: {e}; the rest is not recorded");
                    drain_lost(&rx, &writer);
                }
                r
            })?;
        Ok(Self {
            tx: Mutex::new(Some(tx)),
            thread: Mutex::new(Some(thread)),
            ended: Mutex::new(Some(ended_rx)),
            shared,
        })
    }

    fn send(&self, kind: Kind, entry: pb::recording_entry::Entry) {
        let guard = self.tx.lock().expect("recorder lock");
        let Some(tx) = guard.as_ref() else {
            return;
        };
        let s = &*self.shared;
        let gap = s.take_pending();
        let depth = s.queued.fetch_add(1, Ordering::AcqRel) + 1;
        let msg = Msg::Entry(pb::RecordingEntry { entry: Some(entry) }, gap);
        match tx.try_send(msg) {
            Ok(()) => {
                s.peak_queued.fetch_max(depth, Ordering::AcqRel);
            }
            Err(e) => {
                s.queued.fetch_sub(1, Ordering::AcqRel);
                s.put_pending(&gap);
                s.drop_entry(
                    kind,
                    match e {
                        mpsc::TrySendError::Full(_) => "the queue to the disk is full",
                        // Only while the thread unwinds from a panic.
                        mpsc::TrySendError::Disconnected(_) => "the writer has stopped",
                    },
                );
            }
        }
    }

    /// Records an accepted pose.
    pub fn pose(&self, instrument: &str, pose: pb::PoseSample) {
        self.send(
            Kind::Pose,
            pb::recording_entry::Entry::Pose(pb::RecordedPose {
                instrument: instrument.to_owned(),
                pose: Some(pose),
            }),
        );
    }

    /// Records a force sample sent to a client.
    pub fn force(&self, instrument: &str, sample: pb::ForceSample) {
        self.send(
            Kind::Force,
            pb::recording_entry::Entry::Force(pb::RecordedForce {
                instrument: instrument.to_owned(),
                sample: Some(sample),
            }),
        );
    }

    /// Records a frame summary: without positions, with the strain picture
    /// where the frame has one (the report draws the worst frame's).
    pub fn frame(&self, frame: &Frame) {
        self.send(
            Kind::Frame,
            pb::recording_entry::Entry::Frame(super::convert::frame(frame, false, true)),
        );
    }

    /// The queue's and the writer's figures so far.
    pub fn stats(&self) -> RecorderStats {
        let s = &*self.shared;
        RecorderStats {
            capacity: s.capacity,
            queued: s.queued.load(Ordering::Acquire),
            peak_queued: s.peak_queued.load(Ordering::Acquire),
            written: s.written.load(Ordering::Acquire),
            lost: s.lost(),
        }
    }

    /// Writes everything queued so far to the file. Waits at most
    /// [`FINISH_TIMEOUT`] (a stalled disk): returns whether it was written.
    pub fn flush(&self) -> bool {
        let deadline = Instant::now() + FINISH_TIMEOUT;
        let (done_tx, done_rx) = mpsc::channel();
        let mut msg = Msg::Flush(done_tx);
        loop {
            let guard = self.tx.lock().expect("recorder lock");
            let Some(tx) = guard.as_ref() else {
                return false;
            };
            match tx.try_send(msg) {
                Ok(()) => break,
                Err(mpsc::TrySendError::Disconnected(_)) => return false,
                Err(mpsc::TrySendError::Full(m)) => msg = m,
            }
            drop(guard);
            if Instant::now() >= deadline {
                return false;
            }
            std::thread::sleep(FLUSH_INTERVAL);
        }
        done_rx
            .recv_timeout(deadline.saturating_duration_since(Instant::now()))
            .is_ok()
    }

    /// Closes the queue, lets the writer write what it holds (and a last
    /// gap entry if entries were dropped since the last one), then flushes,
    /// syncs and closes the file. Waits at most [`FINISH_TIMEOUT`].
    pub fn finish(&self) -> std::io::Result<()> {
        self.finish_within(FINISH_TIMEOUT)
    }

    /// [`Recorder::finish`], waiting at most `timeout` for the writer. When
    /// the writer is still blocked (a stalled disk) it is left to finish on
    /// its own and a `TimedOut` error says how many entries were still
    /// queued.
    pub fn finish_within(&self, timeout: Duration) -> std::io::Result<()> {
        drop(self.tx.lock().expect("recorder lock").take());
        let Some(thread) = self.thread.lock().expect("recorder lock").take() else {
            return Ok(());
        };
        let ended = self.ended.lock().expect("recorder lock").take();
        if let Some(ended) = ended {
            if let Err(mpsc::RecvTimeoutError::Timeout) = ended.recv_timeout(timeout) {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::TimedOut,
                    format!(
                        "the recording's writer is still blocked after {timeout:?}: \
                         {} entries queued are not written yet",
                        self.shared.queued.load(Ordering::Acquire)
                    ),
                ));
            }
        }
        thread
            .join()
            .map_err(|_| std::io::Error::other("recorder thread panicked"))?
    }
}

/// The writer thread's loop: entries (each after the gap that precedes it)
/// until every sender is gone, then the last gap.
fn write_entries<W: Write>(
    rx: &mpsc::Receiver<Msg>,
    out: &mut BufWriter<W>,
    shared: &Shared,
) -> std::io::Result<()> {
    let mut last_flush = Instant::now();
    let mut buf = Vec::with_capacity(4096);
    loop {
        let msg = match rx.recv_timeout(FLUSH_INTERVAL) {
            Ok(m) => Some(m),
            Err(mpsc::RecvTimeoutError::Timeout) => None,
            Err(mpsc::RecvTimeoutError::Disconnected) => break,
        };
        match msg {
            Some(Msg::Entry(e, gap)) => {
                shared.queued.fetch_sub(1, Ordering::AcqRel);
                if gap.total() > 0 {
                    put(out, &mut buf, &gap_entry(gap))?;
                }
                put(out, &mut buf, &e)?;
                shared.written.fetch_add(1, Ordering::AcqRel);
            }
            Some(Msg::Flush(done)) => {
                out.flush()?;
                let _ = done.send(());
            }
            None => {}
        }
        if last_flush.elapsed() >= FLUSH_INTERVAL {
            out.flush()?;
            last_flush = Instant::now();
        }
    }
    let rest = shared.take_pending();
    if rest.total() > 0 {
        put(out, &mut buf, &gap_entry(rest))?;
    }
    out.flush()
}

/// After a write error: counts every entry still queued or sent later as
/// lost, until every sender is gone (producers never see a full queue).
fn drain_lost(rx: &mpsc::Receiver<Msg>, shared: &Shared) {
    while let Ok(msg) = rx.recv() {
        if let Msg::Entry(e, _) = msg {
            shared.queued.fetch_sub(1, Ordering::AcqRel);
            let kind = match e.entry {
                Some(pb::recording_entry::Entry::Pose(_)) => Kind::Pose,
                Some(pb::recording_entry::Entry::Force(_)) => Kind::Force,
                Some(pb::recording_entry::Entry::Frame(_)) => Kind::Frame,
                // Only poses, forces and frames are queued.
                Some(
                    pb::recording_entry::Entry::Header(_) | pb::recording_entry::Entry::Gap(_),
                )
                | None => continue,
            };
            shared.lost[kind as usize].fetch_add(1, Ordering::AcqRel);
        }
    }
}

/// Appends `m`, length-delimited, through the reused buffer `buf`.
fn put<W: Write, M: Message>(
    out: &mut BufWriter<W>,
    buf: &mut Vec<u8>,
    m: &M,
) -> std::io::Result<()> {
    buf.clear();
    m.encode_length_delimited(buf)
        .map_err(std::io::Error::other)?;
    out.write_all(buf)
}

impl Journal for Recorder {
    fn frame(&self, frame: &Frame) {
        Recorder::frame(self, frame);
    }

    /// The pose as the client sent it (a pose is accepted only with both
    /// its position and its orientation), then its force sample.
    fn sample(&self, instrument: &str, pose: &RawPose, answer: &ForceOut) {
        self.pose(
            instrument,
            pb::PoseSample::new(pose.t_s, pose.sequence, pose.position_m, pose.orientation),
        );
        self.force(instrument, super::convert::force_sample(answer));
    }

    fn lost(&self) -> u64 {
        self.stats().lost.total()
    }

    fn flush(&self) -> bool {
        Recorder::flush(self)
    }

    fn finish(&self) -> std::io::Result<()> {
        Recorder::finish(self)
    }
}

/// Records a simulation's session to a file ([`Recorder::create`]), its
/// header describing the scene as run ([`super::convert::scene_description`]).
#[derive(Debug, Clone)]
pub struct ToFile(pub PathBuf);

impl ToFile {
    /// The opener of a recording to `path`, for `SimOptions::recording`.
    pub fn open_at(path: impl Into<PathBuf>) -> Arc<dyn OpenJournal> {
        Arc::new(Self(path.into()))
    }
}

impl OpenJournal for ToFile {
    fn path(&self) -> &Path {
        &self.0
    }

    fn open(&self, scene: &Scene, model: &Model) -> std::io::Result<Arc<dyn Journal>> {
        let header = super::convert::scene_description(scene, model);
        let surface = super::convert::surface(model);
        Ok(Arc::new(Recorder::create(&self.0, &header, Some(surface))?))
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        let _ = self.finish();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pose `seq` of a 1 kHz stream, at the origin.
    fn pose(seq: u64) -> pb::PoseSample {
        pb::PoseSample::new(seq as f64 * 1e-3, seq, [0.0; 3], [1.0, 0.0, 0.0, 0.0])
    }

    /// Accepts the header, then fails every write.
    struct FailAfterHeader {
        header_written: bool,
    }

    impl Write for FailAfterHeader {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            if self.header_written {
                return Err(std::io::Error::other("disk full"));
            }
            Ok(buf.len())
        }

        fn flush(&mut self) -> std::io::Result<()> {
            if std::mem::replace(&mut self.header_written, true) {
                return Err(std::io::Error::other("disk full"));
            }
            Ok(())
        }
    }

    #[test]
    fn a_failing_disk_is_reported_and_the_rest_counted_as_lost() {
        let rec = Recorder::with_writer(
            FailAfterHeader {
                header_written: false,
            },
            &pb::SceneDescription::default(),
            16,
        )
        .unwrap();
        rec.pose("left", pose(1));
        // The flush fails: the writer stops writing.
        assert!(!rec.flush());
        for k in 2..=40 {
            rec.pose("left", pose(k));
            rec.force("left", pb::ForceSample::default());
        }
        let e = rec.finish().unwrap_err();
        assert!(e.to_string().contains("disk full"), "{e}");
        let s = rec.stats();
        assert_eq!(s.written, 1);
        assert_eq!(
            s.lost,
            RecordingGap {
                poses: 39,
                forces: 39,
                frames: 0
            }
        );
        assert_eq!(s.queued, 0);
        // Finished: later entries are ignored, a second finish is a no-op.
        rec.pose("left", pose(41));
        assert_eq!(rec.stats().lost.poses, 39);
        rec.finish().unwrap();
    }
}
