//! The session recorder on a disk that stalls: the queue to the writer stays
//! bounded (in entries and in heap bytes), producers never wait for the disk,
//! the file says where entries were dropped and how many, and `fissure report`
//! still reads it. Memory is the process's resident set, so these tests run
//! alone in the process (the `isolated` binary runs one test at a time).

use fissure_cli::client::report::{LostEntries, report};
use fissure_engine::sim::core::snapshot::{Frame, InstrumentReaction, StepTimings};
use fissure_proto::recording::{RecordingGap, RecordingGapExt, read_recording};
use fissure_proto::v1 as pb;
use fissure_server::recording::{QUEUE_CAPACITY, Recorder};
use nalgebra::Vector3;
use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, mpsc};
use std::time::{Duration, Instant};

use crate::reliability_common::rss_bytes;

/// Opens and closes the disk.
#[derive(Clone, Default)]
struct Gate(Arc<(Mutex<bool>, Condvar)>);

impl Gate {
    fn set_open(&self, open: bool) {
        *self.0.0.lock().unwrap() = open;
        self.0.1.notify_all();
    }

    fn wait_open(&self) {
        let mut open = self.0.0.lock().unwrap();
        while !*open {
            open = self.0.1.wait(open).unwrap();
        }
    }
}

/// A file whose writes block while the gate is closed, as on a stalled disk.
struct StallingFile {
    file: std::fs::File,
    gate: Gate,
    /// Set while a write waits at the gate.
    blocked: Arc<AtomicBool>,
}

impl StallingFile {
    fn wait(&self) {
        self.blocked.store(true, Ordering::SeqCst);
        self.gate.wait_open();
        self.blocked.store(false, Ordering::SeqCst);
    }
}

impl Write for StallingFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.wait();
        self.file.write(buf)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.wait();
        self.file.flush()
    }
}

fn scene() -> pb::SceneDescription {
    pb::SceneDescription {
        name: "cube".into(),
        ..Default::default()
    }
}

/// Pose `k` of `left`: 1 kHz, pressing down 1 um per sample.
fn pose(k: u64) -> pb::PoseSample {
    pb::PoseSample {
        t_s: k as f64 * 1e-3,
        sequence: k,
        position_m: Some(pb::Vec3 {
            x: 0.011,
            y: 0.005,
            z: 0.043 - k as f64 * 1e-6,
        }),
        orientation: Some(pb::Quaternion {
            w: 0.5,
            x: -0.5,
            y: 0.5,
            z: 0.5,
        }),
    }
}

fn force(k: u64) -> pb::ForceSample {
    pb::ForceSample {
        t_s: k as f64 * 1e-3,
        sequence: k,
        force_n: Some(pb::Vec3 {
            x: 0.0,
            y: 0.0,
            z: 0.1 + k as f64 * 1e-6,
        }),
        contact_count: 3,
        ..Default::default()
    }
}

/// A frame summary with both instruments, as the deformation loop records.
fn frame(k: u64) -> Frame {
    let reaction = |name: &str, x: f64| InstrumentReaction {
        name: name.into(),
        force_n: Vector3::new(0.0, 0.0, 0.1),
        torque_nm: Vector3::zeros(),
        pairs: 12,
        culled: 1,
        contact_vertices: 6,
        pending_vertices: 0,
        position_m: Vector3::new(x, 0.005, 0.043),
        orientation: [0.5, -0.5, 0.5, 0.5],
        pressure: Default::default(),
    };
    Frame {
        frame: k,
        sim_time_s: k as f64 * 0.025,
        positions: Arc::new(Vec::new()),
        instruments: vec![reaction("left", 0.011), reaction("right", 0.029)],
        timings: StepTimings::default(),
        solver_error: None,
        max_displacement_m: 1e-3,
        rigid: Default::default(),
        ties: Default::default(),
        strain: Default::default(),
        strain_picture: None,
    }
}

/// Records pose `k` with its force sample, and a frame every 25 samples
/// (frame `k / 25`), as a 1 kHz client beside a 40 Hz deformation loop does.
fn sample(rec: &Recorder, k: u64) {
    rec.pose("left", pose(k));
    rec.force("left", force(k));
    if k % 25 == 0 {
        rec.frame(&frame(k / 25));
    }
}

/// Runs `f` on a thread and waits for it at most `limit`: a producer that
/// waits on the stalled disk fails the test instead of hanging it.
fn within<T: Send + 'static>(
    limit: Duration,
    what: &str,
    f: impl FnOnce() -> T + Send + 'static,
) -> T {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    rx.recv_timeout(limit)
        .unwrap_or_else(|_| panic!("{what} did not return within {limit:?}"))
}

fn wait_until(limit: Duration, what: &str, mut f: impl FnMut() -> bool) {
    let t0 = Instant::now();
    while !f() {
        assert!(t0.elapsed() < limit, "{what} not within {limit:?}");
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// Sequence numbers recorded for one kind: a run from 1, then a run from
/// `resume`; returns the end of the first run.
fn two_runs(got: &[u64], resume: u64, last: u64, kind: &str) -> u64 {
    let split = got.iter().position(|&s| s >= resume).unwrap_or(got.len());
    let (a, b) = got.split_at(split);
    assert!(
        a.iter().copied().eq(1..=a.len() as u64),
        "{kind}: the first run is not 1..={}",
        a.len()
    );
    assert!(
        b.iter().copied().eq(resume..=last),
        "{kind}: the run after the stall is not {resume}..={last}"
    );
    a.len() as u64
}

/// 1,000 samples on a working disk, then the disk stalls while 100,000 more
/// (200,000 poses and forces and 4,000 frames, 50 s of two instruments at
/// 1 kHz) are recorded, then it recovers for 1,000 more.
#[test]
fn a_stalled_disk_keeps_the_queue_bounded_and_the_file_records_the_loss() {
    let _alone = crate::alone_blocking();
    const BEFORE: u64 = 1_000;
    const STALLED: u64 = 100_000;
    const AFTER: u64 = 1_000;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("stalled.fsrec");
    let gate = Gate::default();
    gate.set_open(true);
    let blocked = Arc::new(AtomicBool::new(false));
    let rec = Arc::new(
        Recorder::with_writer(
            StallingFile {
                file: std::fs::File::create(&path).unwrap(),
                gate: gate.clone(),
                blocked: blocked.clone(),
            },
            &scene(),
            QUEUE_CAPACITY,
        )
        .unwrap(),
    );
    for k in 1..=BEFORE {
        sample(&rec, k);
    }
    assert!(rec.flush(), "the working disk takes a flush");
    assert_eq!(rec.stats().lost, RecordingGap::default());

    // The disk stalls: the writer blocks in its next write.
    gate.set_open(false);
    sample(&rec, BEFORE + 1);
    wait_until(Duration::from_secs(10), "the writer blocked", || {
        blocked.load(Ordering::SeqCst)
    });
    let rss_before = rss_bytes();
    let producer = rec.clone();
    let rss_peak = within(
        Duration::from_secs(60),
        "recording on a stalled disk",
        move || {
            let mut peak = 0;
            for k in BEFORE + 2..=BEFORE + STALLED {
                sample(&producer, k);
                if k % 5_000 == 0 {
                    peak = peak.max(rss_bytes());
                }
            }
            peak.max(rss_bytes())
        },
    );
    let growth = rss_peak.saturating_sub(rss_before);
    let stalled = rec.stats();
    let pushed = 2 * (STALLED - 1) + (BEFORE + STALLED) / 25 - (BEFORE + 1) / 25;
    let mib = |b: u64| b as f64 / (1 << 20) as f64;
    eprintln!(
        "stalled disk: {stalled:?}; {pushed} entries recorded; RSS {:.1} -> {:.1} MiB \
         (peak), +{:.2} MiB; an entry is {} B in its queue slot",
        mib(rss_before),
        mib(rss_peak),
        mib(growth),
        size_of::<pb::RecordingEntry>()
    );
    assert!(blocked.load(Ordering::SeqCst), "the writer stayed blocked");
    assert!(stalled.queued <= QUEUE_CAPACITY, "{stalled:?}");
    assert!(stalled.peak_queued <= QUEUE_CAPACITY + 1, "{stalled:?}");
    assert!(stalled.lost.poses > 0 && stalled.lost.forces > 0 && stalled.lost.frames > 0);
    // What did not fit in the queue was dropped (nothing waits anywhere
    // else): the queue may have held sample BEFORE + 1 when the burst began.
    let kept = pushed - stalled.lost.total();
    assert!(
        (QUEUE_CAPACITY as u64 - 2..=QUEUE_CAPACITY as u64).contains(&kept),
        "{kept} entries kept of {pushed}"
    );
    // Memory holds the queue, not the stall: the 200,000 entries dropped
    // would need 200,000 slots of 352 B and their heap parts, over 70 MiB
    // (the slots of the bounded queue are allocated and touched up front).
    assert!(
        growth < 8 << 20,
        "the resident set grew by {growth} B while the disk stalled"
    );

    // The disk recovers; the writer works through the full queue.
    gate.set_open(true);
    wait_until(Duration::from_secs(30), "the queue drained", || {
        rec.stats().queued == 0
    });
    let first_after = BEFORE + STALLED + 1;
    for k in first_after..first_after + AFTER {
        sample(&rec, k);
    }
    let finisher = rec.clone();
    within(Duration::from_secs(30), "finish", move || finisher.finish()).unwrap();
    let end = rec.stats();
    assert_eq!(end.lost, stalled.lost, "no loss once the disk is back");
    assert_eq!(end.queued, 0);

    // The file: the runs before and after the stall, and one gap between
    // them saying how many of each kind are missing.
    let r = read_recording(&path).unwrap();
    assert!(!r.truncated);
    assert_eq!(r.gaps.len(), 1, "{:?}", r.gaps);
    assert_eq!(r.lost(), end.lost);
    let last = first_after + AFTER - 1;
    let (mut poses, mut forces, mut frames) = (Vec::new(), Vec::new(), Vec::new());
    let mut before_gap = Vec::new();
    for (i, e) in r.entries.iter().enumerate().skip(1) {
        let seq = match e.entry.as_ref().expect("an entry") {
            pb::recording_entry::Entry::Pose(p) => {
                let s = p.pose.as_ref().unwrap().sequence;
                poses.push(s);
                s
            }
            pb::recording_entry::Entry::Force(f) => {
                let s = f.sample.as_ref().unwrap().sequence;
                forces.push(s);
                s
            }
            pb::recording_entry::Entry::Frame(f) => {
                frames.push(f.frame);
                f.frame * 25
            }
            pb::recording_entry::Entry::Header(_) => panic!("a second header"),
            pb::recording_entry::Entry::Gap(g) => panic!("a gap among the entries: {g:?}"),
        };
        if i < r.gaps[0].before {
            before_gap.push(seq);
        } else {
            assert!(seq >= first_after, "entry {i} ({seq}) after the gap");
        }
    }
    assert!(before_gap.iter().all(|&s| s < first_after));
    let p = two_runs(&poses, first_after, last, "poses");
    let f = two_runs(&forces, first_after, last, "forces");
    let fr = two_runs(&frames, first_after.div_ceil(25), last / 25, "frames");
    assert_eq!(
        r.gaps[0].lost,
        RecordingGap {
            poses: first_after - 1 - p,
            forces: first_after - 1 - f,
            frames: (first_after - 1) / 25 - fr,
        }
    );

    // `fissure report` reads it and says what is missing.
    let summary = report(&path, 1.0).unwrap();
    assert_eq!(summary.scene, "cube");
    assert!(!summary.truncated);
    assert_eq!(
        summary.lost,
        LostEntries {
            poses: end.lost.poses,
            forces: end.lost.forces,
            frames: end.lost.frames,
            gaps: 1,
        }
    );
    let table = fissure_cli::client::report::table(&summary);
    assert!(
        table.contains(&format!(
            "poses {}, force samples {}, frames {}, in 1 gap\n",
            end.lost.poses, end.lost.forces, end.lost.frames
        )),
        "{table}"
    );
    assert_eq!(summary.frames, frames.len());
    assert_eq!(summary.instruments.len(), 1);
    assert_eq!(summary.instruments[0].samples, forces.len());
    assert!((summary.duration_s - (last - 1) as f64 * 1e-3).abs() < 1e-9);
}

/// A disk that never comes back: finishing gives up after its timeout and
/// says how much is still queued; the writer completes the file on its own
/// once the disk returns.
#[test]
fn finishing_on_a_disk_that_does_not_return_gives_up_and_says_so() {
    let _alone = crate::alone_blocking();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("stuck.fsrec");
    let gate = Gate::default();
    gate.set_open(true);
    let blocked = Arc::new(AtomicBool::new(false));
    let rec = Arc::new(
        Recorder::with_writer(
            StallingFile {
                file: std::fs::File::create(&path).unwrap(),
                gate: gate.clone(),
                blocked: blocked.clone(),
            },
            &scene(),
            64,
        )
        .unwrap(),
    );
    gate.set_open(false);
    sample(&rec, 1);
    wait_until(Duration::from_secs(10), "the writer blocked", || {
        blocked.load(Ordering::SeqCst)
    });
    for k in 2..=100 {
        sample(&rec, k);
    }
    let s = rec.stats();
    assert!(s.queued <= 64 && s.lost.total() > 0, "{s:?}");
    let finisher = rec.clone();
    let e = within(Duration::from_secs(30), "finish_within", move || {
        finisher.finish_within(Duration::from_millis(200))
    })
    .unwrap_err();
    assert_eq!(e.kind(), std::io::ErrorKind::TimedOut);
    assert!(
        e.to_string()
            .contains(&format!("{} entries queued", s.queued)),
        "{e}"
    );
    // Finished: later entries are ignored and not counted as lost.
    sample(&rec, 101);
    assert_eq!(rec.stats().lost, s.lost);
    // The disk returns: the writer writes the queue and the last gap.
    gate.set_open(true);
    wait_until(Duration::from_secs(10), "the file completed", || {
        read_recording(&path).is_ok_and(|r| r.lost() == s.lost)
    });
    let r = read_recording(&path).unwrap();
    assert_eq!(r.entries.len() - 1, s.written as usize + s.queued);
    assert_eq!(r.gaps.len(), 1);
    assert_eq!(r.gaps[0].before, r.entries.len(), "the last gap at the end");
    let summary = report(&path, 1.0).unwrap();
    assert_eq!(summary.lost.total(), s.lost.total());
    assert_eq!(summary.lost.gaps, 1);
}
