//! Session recordings (`.fsrec` files): reading them, and the gap entries
//! that say where a recorder dropped entries.
//!
//! A recording is a sequence of length-delimited `fissure.v1.RecordingEntry`
//! messages: a header (the scene as run) first, then every accepted pose,
//! every force sample and every frame summary, in the order the server
//! recorded them. The server's recorder never waits for its disk: when its
//! queue is full it drops entries, counts them by kind, and writes a
//! [`RecordingGap`] (the `gap` member, field 5, of `RecordingEntry`'s `oneof
//! entry`) just before the next entry it records, so the file itself says
//! where entries are missing and how many of each kind (sums in
//! [`RecordingGapExt`]).
//!
//! [`read_recording`] reports the gaps with their places, [`read`] leaves
//! them out; an entry of a later format version (a member this build does not
//! know) is read as an entry with no `entry`. A truncated last entry (a crash
//! mid-write) is dropped and reported. Clients read recordings with this
//! module alone: it needs the generated types, not the server.

use crate::v1 as pb;
use prost::Message;
use std::io::Read;
use std::path::Path;

/// Entries that could not be recorded (the recorder's queue was full), by
/// kind: poses, force samples, frame summaries. In a file, a gap sits where
/// the entries are missing (`fissure.v1.RecordingEntry.gap`).
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
pub fn gap_entry(gap: RecordingGap) -> pb::RecordingEntry {
    pb::RecordingEntry {
        entry: Some(pb::recording_entry::Entry::Gap(gap)),
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
    #[error("{path}: entry {index} at byte {offset} is malformed: {source}")]
    Malformed {
        path: String,
        index: usize,
        offset: usize,
        source: prost::DecodeError,
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
    /// Where the dropped entry starts, bytes from the file's start.
    pub truncated_at: Option<usize>,
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
    let mut truncated_at = None;
    while !buf.is_empty() {
        let offset = bytes.len() - buf.len();
        let len = match prost::encoding::decode_varint(&mut buf) {
            Ok(l) => l as usize,
            Err(_) => {
                truncated_at = Some(offset);
                break;
            }
        };
        if len > buf.len() {
            truncated_at = Some(offset);
            break;
        }
        let malformed = |e: prost::DecodeError| ReadError::Malformed {
            path: name.clone(),
            index: entries.len() + gaps.len(),
            offset,
            source: e,
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
            truncated: truncated_at.is_some(),
            truncated_at,
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
            surface: None,
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
}
