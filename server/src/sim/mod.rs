//! The force loop and the deformation loop, their shared state and recording
//! (DESIGN.md section 4).
//!
//! * The **deformation loop** ([`engine::StepEngine`]) runs on its own
//!   thread: latest poses -> collision with culling for every instrument ->
//!   the contact rows -> the contact problem's solve -> a [`Snapshot`]
//!   swapped in atomically (latest wins) and a [`Frame`] sent on a `watch`
//!   channel (slow watchers see only the latest frame). The snapshot carries
//!   the compliance patch the force loops solve on and, with the CPU BVH, the
//!   tree refitted to its surface, which every force loop casts on
//!   read-only. The thread and its rayon pool run at a lower priority
//!   ([`priority`], [`SimOptions::deformation_nice`]) so that force samples
//!   preempt the solver; compliance it lacks is computed on a background
//!   thread lower still (contacts on such vertices are answered by a
//!   penalty and flagged meanwhile), so no step waits for it.
//! * The **force loop** of a claimed instrument ([`Claim::force_sample`],
//!   [`force_loop`]) runs in the caller's thread: a fresh collision query
//!   (sequential, on the snapshot's tree) against the latest snapshot's
//!   surface, the instrument's rows, and the contact problem coupled with
//!   the other instruments' latest rows, on the compliance of the last
//!   step. It never waits for the deformation loop.
//! * **Stepped mode** ([`stepped`]) makes runs reproducible: one thread runs
//!   a [`stepped::SteppedRunner`], which answers the poses of each time
//!   together once every claimed instrument has sent its next pose (and at
//!   least the [`Mode::Stepped`] clients have been claimed): deformation
//!   step `k` happens at `t_k = t_0 + k dt` (`t_0` the session's first pose
//!   time) with, per instrument, the latest pose with `t <= t_k`; a force
//!   sample at pose time `t` uses the last step strictly before `t`. Columns
//!   of the compliance are computed when a step needs them (the answers do
//!   not depend on timing). `fissure study` drives the same runner.

//!
//! `sim` is two layers:
//!
//! * [`core`]: what a step and a force sample compute, as functions over
//!   plain data (the model, the collision query, the contact rows and their
//!   rules, the deformation, the step's named stages, the force loop with its
//!   row exchange, the local model, the snapshot, the injury measures, pose
//!   validation, the stepped runner that `fissure study` drives directly);
//! * [`runtime`]: who runs them and when: the [`Simulation`]'s lifecycle,
//!   the free-running and stepped drivers (threads), the claims, the pose
//!   budget, the counters, the journal, the scheduling priorities.
//!
//! The runtime imports the core; the core imports nothing of the runtime.

pub mod core;
pub mod runtime;

pub use runtime::{
    Claim, ClaimError, DEFAULT_DEFORMATION_NICE, ForceOut, Mode, SimError, SimOptions, Simulation,
    WatcherGuard, flags,
};
