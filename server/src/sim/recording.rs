//! Session recordings: every accepted pose, every force sample and every frame
//! summary, appended as length-delimited `fissure.v1.RecordingEntry` messages.
//!
//! A writer thread owns the file; producers send entries on a channel and never
//! wait for the disk. The writer flushes whenever its queue runs empty and at
//! least every [`FLUSH_INTERVAL`], so a crash loses at most the last few
//! milliseconds.

use fissure_proto::v1 as pb;
use prost::Message;
use std::io::{BufWriter, Read, Write};
use std::path::Path;
use std::sync::Mutex;
use std::sync::mpsc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::snapshot::Frame;

/// Longest time an entry waits in the writer's buffer.
pub const FLUSH_INTERVAL: Duration = Duration::from_millis(5);

enum Msg {
    Entry(pb::RecordingEntry),
    Flush(mpsc::Sender<()>),
}

/// Appends entries to a recording file from any thread.
#[derive(Debug)]
pub struct Recorder {
    tx: Mutex<Option<mpsc::Sender<Msg>>>,
    thread: Mutex<Option<JoinHandle<std::io::Result<()>>>>,
}

impl Recorder {
    /// Creates (truncates) the file and writes the header.
    pub fn create(path: &Path, scene: &pb::SceneDescription) -> std::io::Result<Self> {
        let file = std::fs::File::create(path)?;
        let mut out = BufWriter::new(file);
        let header = pb::RecordingEntry {
            entry: Some(pb::recording_entry::Entry::Header(pb::RecordingHeader {
                version: 1,
                scene: Some(scene.clone()),
                started_unix_s: std::time::SystemTime::now()
                    .duration_since(std::time::UNIX_EPOCH)
                    .map(|d| d.as_secs_f64())
                    .unwrap_or(0.0),
            })),
        };
        out.write_all(&header.encode_length_delimited_to_vec())?;
        out.flush()?;
        let (tx, rx) = mpsc::channel::<Msg>();
        let thread = std::thread::Builder::new()
            .name("recorder".into())
            .spawn(move || {
                let mut last_flush = Instant::now();
                let mut buf = Vec::with_capacity(4096);
                loop {
                    let msg = match rx.recv_timeout(FLUSH_INTERVAL) {
                        Ok(m) => Some(m),
                        Err(mpsc::RecvTimeoutError::Timeout) => None,
                        Err(mpsc::RecvTimeoutError::Disconnected) => break,
                    };
                    match msg {
                        Some(Msg::Entry(e)) => {
                            buf.clear();
                            e.encode_length_delimited(&mut buf)
                                .map_err(std::io::Error::other)?;
                            out.write_all(&buf)?;
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
                out.flush()?;
                out.get_ref().sync_all()
            })?;
        Ok(Self {
            tx: Mutex::new(Some(tx)),
            thread: Mutex::new(Some(thread)),
        })
    }

    fn send(&self, entry: pb::recording_entry::Entry) {
        if let Some(tx) = self.tx.lock().expect("recorder lock").as_ref() {
            let _ = tx.send(Msg::Entry(pb::RecordingEntry { entry: Some(entry) }));
        }
    }

    /// Records an accepted pose.
    pub fn pose(&self, instrument: &str, pose: pb::PoseSample) {
        self.send(pb::recording_entry::Entry::Pose(pb::RecordedPose {
            instrument: instrument.to_owned(),
            pose: Some(pose),
        }));
    }

    /// Records a force sample sent to a client.
    pub fn force(&self, instrument: &str, sample: pb::ForceSample) {
        self.send(pb::recording_entry::Entry::Force(pb::RecordedForce {
            instrument: instrument.to_owned(),
            sample: Some(sample),
        }));
    }

    /// Records a frame summary (without positions).
    pub fn frame(&self, frame: &Frame) {
        self.send(pb::recording_entry::Entry::Frame(
            crate::service::convert::frame(frame, false),
        ));
    }

    /// Writes everything queued so far to the file.
    pub fn flush(&self) {
        let (done_tx, done_rx) = mpsc::channel();
        if let Some(tx) = self.tx.lock().expect("recorder lock").as_ref() {
            if tx.send(Msg::Flush(done_tx)).is_ok() {
                let _ = done_rx.recv_timeout(Duration::from_secs(5));
            }
        }
    }

    /// Flushes, syncs and closes the file.
    pub fn finish(&self) -> std::io::Result<()> {
        drop(self.tx.lock().expect("recorder lock").take());
        match self.thread.lock().expect("recorder lock").take() {
            Some(t) => t
                .join()
                .map_err(|_| std::io::Error::other("recorder thread panicked"))?,
            None => Ok(()),
        }
    }
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

/// Reads a whole recording. A truncated last entry (a crash mid-write) is
/// dropped and reported in the second value.
pub fn read(path: &Path) -> Result<(Vec<pb::RecordingEntry>, bool), ReadError> {
    let name = path.display().to_string();
    let mut bytes = Vec::new();
    std::fs::File::open(path)
        .and_then(|mut f| f.read_to_end(&mut bytes))
        .map_err(|source| ReadError::Io {
            path: name.clone(),
            source,
        })?;
    let mut entries = Vec::new();
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
        let entry = pb::RecordingEntry::decode(&buf[..len]).map_err(|e| ReadError::Malformed {
            path: name.clone(),
            index: entries.len(),
            offset,
            reason: e.to_string(),
        })?;
        buf = &buf[len..];
        entries.push(entry);
    }
    match entries.first().and_then(|e| e.entry.as_ref()) {
        Some(pb::recording_entry::Entry::Header(_)) => Ok((entries, truncated)),
        _ => Err(ReadError::NoHeader { path: name }),
    }
}
