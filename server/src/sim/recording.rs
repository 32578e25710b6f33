//! Session recordings: every accepted pose, every force sample and every frame
//! summary, appended as length-delimited `fissure.v1.RecordingEntry` messages.
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
//! summary); measured in `tests/tests/reliability_recording.rs`.
//!
//! A gap is the `gap` member (field 5) of `RecordingEntry`'s `oneof entry`,
//! a `fissure.v1.RecordingGap` (re-exported here as [`RecordingGap`], its
//! sums in [`RecordingGapExt`]). [`read_recording`] reports the gaps with
//! their places, [`read`] leaves them out; an entry of a later format version
//! (a member this build does not know) is read as an entry with no `entry`.

use fissure_proto::v1 as pb;
use prost::Message;
use std::io::{BufWriter, Read, Write};
use std::path::Path;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::snapshot::Frame;

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

/// Entries that could not be recorded (the queue to the writer was full),
/// by kind: poses, force samples, frame summaries. In a file, a gap sits
/// where the entries are missing (`fissure.v1.RecordingEntry.gap`).
pub use pb::RecordingGap;

/// Sums of a [`RecordingGap`]'s counts.
pub trait RecordingGapExt {
    /// All kinds together: `poses + forces + frames`.
    fn total(&self) -> u64;
    /// Adds `other`'s counts, kind by kind.
    fn add(&mut self, other: &RecordingGap);
}

impl RecordingGapExt for RecordingGap {
    fn total(&self) -> u64 {
        self.poses + self.forces + self.frames
    }

    fn add(&mut self, other: &RecordingGap) {
        self.poses += other.poses;
        self.forces += other.forces;
        self.frames += other.frames;
    }
}

/// The `RecordingEntry` holding a gap, as written.
fn gap_entry(gap: RecordingGap) -> pb::RecordingEntry {
    pb::RecordingEntry {
        entry: Some(pb::recording_entry::Entry::Gap(gap)),
    }
}

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

fn header(scene: &pb::SceneDescription) -> pb::RecordingEntry {
    pb::RecordingEntry {
        entry: Some(pb::recording_entry::Entry::Header(pb::RecordingHeader {
            version: 1,
            scene: Some(scene.clone()),
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
    pub fn create(path: &Path, scene: &pb::SceneDescription) -> std::io::Result<Self> {
        let file = std::fs::File::create(path)?;
        Self::start(BufWriter::new(file), scene, QUEUE_CAPACITY, |out| {
            out.get_ref().sync_all()
        })
    }

    /// Records to any writer (buffered here), with a queue of `capacity`
    /// entries (at least 1). Writes the header before returning.
    pub fn with_writer<W: Write + Send + 'static>(
        out: W,
        scene: &pb::SceneDescription,
        capacity: usize,
    ) -> std::io::Result<Self> {
        Self::start(BufWriter::new(out), scene, capacity, |_| Ok(()))
    }

    fn start<W: Write + Send + 'static>(
        mut out: BufWriter<W>,
        scene: &pb::SceneDescription,
        capacity: usize,
        close: impl FnOnce(&mut BufWriter<W>) -> std::io::Result<()> + Send + 'static,
    ) -> std::io::Result<Self> {
        out.write_all(&header(scene).encode_length_delimited_to_vec())?;
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

    /// Records a frame summary (without positions).
    pub fn frame(&self, frame: &Frame) {
        self.send(
            Kind::Frame,
            pb::recording_entry::Entry::Frame(crate::service::convert::frame(frame, false)),
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

impl Drop for Recorder {
    fn drop(&mut self) {
        let _ = self.finish();
    }
}

/// Errors reading a recording.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// I/O error.
    #[error("reading {path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    /// A malformed entry.
    #[error("{path}: entry {index} at byte {offset} is malformed: {reason}")]
    Malformed {
        path: String,
        index: usize,
        offset: usize,
        reason: String,
    },
    /// The file does not start with a header.
    #[error("{path}: not a fissure recording (no header entry)")]
    NoHeader { path: String },
}

/// Entries missing from a recording at one place.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gap {
    /// Index in [`Recording::entries`] of the first entry after the gap
    /// (`entries.len()` for a gap at the end).
    pub before: usize,
    /// What is missing there.
    pub lost: RecordingGap,
}

/// A recording as read.
#[derive(Debug, Clone, PartialEq)]
pub struct Recording {
    /// The entries, the header first (gap entries left out).
    pub entries: Vec<pb::RecordingEntry>,
    /// Whether the last entry was cut short (a crash mid-write) and dropped.
    pub truncated: bool,
    /// Where entries were dropped by the recorder (its queue was full).
    pub gaps: Vec<Gap>,
}

impl Recording {
    /// All entries dropped by the recorder, by kind.
    pub fn lost(&self) -> RecordingGap {
        let mut l = RecordingGap::default();
        for g in &self.gaps {
            l.add(&g.lost);
        }
        l
    }
}

/// Reads a whole recording. A truncated last entry (a crash mid-write) is
/// dropped and reported in the second value. Gap entries are left out (see
/// [`read_recording`]).
pub fn read(path: &Path) -> Result<(Vec<pb::RecordingEntry>, bool), ReadError> {
    let r = read_recording(path)?;
    Ok((r.entries, r.truncated))
}

/// Reads a whole recording, with the places where the recorder dropped
/// entries.
pub fn read_recording(path: &Path) -> Result<Recording, ReadError> {
    let name = path.display().to_string();
    let mut bytes = Vec::new();
    std::fs::File::open(path)
        .and_then(|mut f| f.read_to_end(&mut bytes))
        .map_err(|source| ReadError::Io {
            path: name.clone(),
            source,
        })?;
    let mut entries = Vec::new();
    let mut gaps = Vec::new();
    let mut buf = bytes.as_slice();
    let mut truncated = false;
    while !buf.is_empty() {
        let offset = bytes.len() - buf.len();
        let len = match prost::encoding::decode_varint(&mut buf) {
            Ok(l) => l as usize,
            Err(_) => {
                truncated = true;
                break;
            }
        };
        if len > buf.len() {
            truncated = true;
            break;
        }
        let malformed = |e: prost::DecodeError| ReadError::Malformed {
            path: name.clone(),
            index: entries.len() + gaps.len(),
            offset,
            reason: e.to_string(),
        };
        let entry = pb::RecordingEntry::decode(&buf[..len]).map_err(malformed)?;
        buf = &buf[len..];
        match entry.entry {
            Some(pb::recording_entry::Entry::Gap(lost)) => gaps.push(Gap {
                before: entries.len(),
                lost,
            }),
            // Also an entry of a later version (a member unknown here), kept
            // with no `entry`.
            _ => entries.push(entry),
        }
    }
    match entries.first().and_then(|e| e.entry.as_ref()) {
        Some(pb::recording_entry::Entry::Header(_)) => Ok(Recording {
            entries,
            truncated,
            gaps,
        }),
        _ => Err(ReadError::NoHeader { path: name }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene() -> pb::SceneDescription {
        pb::SceneDescription {
            name: "cube".into(),
            ..Default::default()
        }
    }

    fn pose(seq: u64) -> pb::PoseSample {
        pb::PoseSample {
            t_s: seq as f64 * 1e-3,
            sequence: seq,
            ..Default::default()
        }
    }

    fn entry(e: pb::recording_entry::Entry) -> Vec<u8> {
        pb::RecordingEntry { entry: Some(e) }.encode_length_delimited_to_vec()
    }

    /// The bytes of a gap entry: field 5 of `RecordingEntry` (tag `0x2a`,
    /// length-delimited) holding `poses` (tag `0x08`), `forces` (`0x10`),
    /// `frames` (`0x18`) as varints, zero counts left out: the layout files
    /// written before `RecordingGap` was in `fissure.proto` already have.
    #[test]
    fn gap_entries_encode_as_field_5_and_read_back_in_place() {
        let gap = RecordingGap {
            poses: 7,
            forces: 6,
            frames: 1,
        };
        assert_eq!(
            gap_entry(gap).encode_to_vec(),
            [0x2a, 6, 0x08, 7, 0x10, 6, 0x18, 1]
        );
        assert_eq!(
            gap_entry(RecordingGap {
                poses: 300,
                forces: 0,
                frames: 0
            })
            .encode_to_vec(),
            [0x2a, 3, 0x08, 0xac, 0x02]
        );
        // A gap with nothing in it still marks a place (an empty member).
        assert_eq!(
            gap_entry(RecordingGap::default()).encode_to_vec(),
            [0x2a, 0]
        );
        let header = pb::RecordingHeader {
            version: 1,
            scene: Some(scene()),
            started_unix_s: 0.0,
        };
        let recorded = |seq| {
            pb::recording_entry::Entry::Pose(pb::RecordedPose {
                instrument: "left".into(),
                pose: Some(pose(seq)),
            })
        };
        let mut file = entry(pb::recording_entry::Entry::Header(header));
        file.extend(entry(recorded(1)));
        // Written by hand, as a file of the earlier layout holds it.
        file.extend([8, 0x2a, 6, 0x08, 7, 0x10, 6, 0x18, 1]);
        file.extend(entry(recorded(9)));
        // A member of a later version (field 15): kept, with no `entry`.
        file.extend([3, 0x7a, 1, 0]);
        file.extend(gap_entry(gap).encode_length_delimited_to_vec());
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("gaps.fsrec");
        std::fs::write(&path, &file).unwrap();
        let r = read_recording(&path).unwrap();
        assert_eq!(r.entries.len(), 4);
        assert_eq!(r.entries[3], pb::RecordingEntry { entry: None });
        assert!(!r.truncated);
        assert_eq!(
            r.gaps,
            [
                Gap {
                    before: 2,
                    lost: gap
                },
                Gap {
                    before: 4,
                    lost: gap
                }
            ]
        );
        assert_eq!(
            r.lost(),
            RecordingGap {
                poses: 14,
                forces: 12,
                frames: 2
            }
        );
        assert_eq!(r.lost().total(), 28);
        let (entries, truncated) = read(&path).unwrap();
        assert_eq!((entries, truncated), (r.entries, false));
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
            &scene(),
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
