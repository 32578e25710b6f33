//! A haptic client's stream, on the engine's side: the thread that runs one
//! claim's force loop over the poses a transport delivers.
//!
//! The transport (the gRPC service, [`HapticPort`]) reads its stream on its
//! own and hands the loop one [`Inbound`] at a time; the loop, for each pose:
//!
//! 1. free-running only: takes it from the stream's pose budget
//!    ([`super::budget`], `MAX_POSE_RATE_FACTOR` times the scene's haptic
//!    rate); a pose over it is refused at once ([`Rejection::OverRate`],
//!    nothing computed, nothing applied) and counted as rejected. Stepped mode
//!    has no budget: its force loop waits for the deformation loop anyway;
//! 2. has the transport decode it ([`HapticPort::raw`]; a missing field is
//!    a rejected pose) and answers it ([`super::Claim::force_sample`]);
//! 3. reports an answered pose to the session's journal
//!    ([`super::journal::Journal::sample`]), then hands the answer (or the
//!    rejection) back to the transport. When the transport says the stream is
//!    over (the client went away or stopped reading) the loop ends.
//!
//! The claim lives on the loop's thread and is released when it ends.

use super::budget::{MAX_POSE_RATE_FACTOR, PoseBudget};
use super::pose::{PoseError, RawPose};
use super::{Claim, ForceOut};

/// What the reader of a haptic stream hands its force loop.
#[derive(Debug)]
pub enum Inbound<P, F> {
    /// The next pose, as the transport received it.
    Pose(P),
    /// The client ended its stream.
    End,
    /// The stream failed (e.g. a message over the size limit).
    Failed(F),
    /// The server is shutting down.
    Stopping,
}

/// Why a pose was not applied.
#[derive(Debug, Clone, Copy)]
pub enum Rejection<'a> {
    /// The stream is over its pose budget, `rate_hz` poses a second.
    OverRate { rate_hz: f64 },
    /// The pose is malformed, or the engine refused it.
    Pose(&'a PoseError),
}

/// A transport's end of one haptic stream.
pub trait HapticPort {
    /// A pose as the transport delivers it.
    type Pose;
    /// Why the transport ended a stream (sent back to its client).
    type Failure: std::fmt::Display;
    /// Waits for the stream's next event; shutdown goes before poses already
    /// queued.
    fn next(&mut self) -> Inbound<Self::Pose, Self::Failure>;
    /// The engine's pose from a transport's pose; a missing field is an
    /// error naming it.
    fn raw(&self, pose: &Self::Pose) -> Result<RawPose, PoseError>;
    /// Sends the answer to `pose` (its force sample, or why it was refused);
    /// false when the stream is over.
    fn answer(&mut self, pose: &Self::Pose, answer: Result<&ForceOut, Rejection<'_>>) -> bool;
    /// Ends the stream because the transport failed with `failure`.
    fn fail(&mut self, failure: Self::Failure);
    /// Ends the stream because the server is shutting down.
    fn stopping(&mut self);
}

/// Runs `claim`'s force loop over `port`'s poses on the calling thread,
/// until the stream ends; then releases the claim.
pub fn run<P: HapticPort>(mut claim: Claim, mut port: P) {
    claim.enter_force_thread();
    let sim = claim.sim.clone();
    let mut budget = (!sim.is_stepped())
        .then(|| PoseBudget::new(MAX_POSE_RATE_FACTOR * sim.scene().loops.haptic_rate_hz));
    loop {
        let pose = match port.next() {
            Inbound::Pose(p) => p,
            Inbound::End => break,
            Inbound::Failed(failure) => {
                tracing::debug!(instrument = %claim.name, %failure, "haptic stream ended with an error");
                port.fail(failure);
                break;
            }
            Inbound::Stopping => {
                port.stopping();
                break;
            }
        };
        let over_rate = budget.as_mut().is_some_and(|b| !b.take());
        if let Some(b) = budget.as_ref().filter(|_| over_rate) {
            sim.record_rejection();
            let why = Rejection::OverRate { rate_hz: b.rate_hz };
            if !port.answer(&pose, Err(why)) {
                break;
            }
            continue;
        }
        let raw = port.raw(&pose);
        if raw.is_err() {
            sim.record_rejection();
        }
        let open = match raw.and_then(|raw| Ok((claim.force_sample(&raw)?, raw))) {
            Ok((out, raw)) => {
                if let Some(journal) = sim.recorder() {
                    journal.sample(&claim.name, &raw, &out);
                }
                port.answer(&pose, Ok(&out))
            }
            Err(e) => {
                tracing::debug!(instrument = %claim.name, error = %e, "pose rejected");
                port.answer(&pose, Err(Rejection::Pose(&e)))
            }
        };
        if !open {
            break;
        }
    }
    drop(claim);
}

/// Starts [`run`] on a thread of its own, `force-loop-<instrument>`.
pub fn spawn<P: HapticPort + Send + 'static>(
    claim: Claim,
    port: P,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    std::thread::Builder::new()
        .name(format!("force-loop-{}", claim.name))
        .spawn(move || run(claim, port))
}
