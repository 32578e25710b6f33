//! The requests for compliance columns that the background column worker
//! serves ([`super::compliance::ColumnPolicy::Defer`]), most urgent first.
//!
//! A node's three columns of `K0^-1` cost one sparse solve with three
//! right-hand sides (tens of ms on the 48k phantom), and the worker runs
//! below the loops' priority, so it delivers a few tens of nodes a second
//! while a step may ask for hundreds (the force patch and the nodes ahead
//! of the plates). Served first in, first out, the nodes ahead of a plate
//! delayed the nodes a contact row needed now. The queue therefore keeps
//! one first-in-first-out line per [`Urgency`], serves the most urgent line
//! first, and raises a node that is asked again at a higher urgency while
//! it waits. A node is queued at most once per line and is never solved
//! twice for one request: a node taken by the worker is `in flight` until
//! the worker hands its columns back, and asks meanwhile are ignored.
//!
//! Written here rather than taken from a crate: it is a three-line
//! priority queue with per-node raising and an in-flight state, over a
//! `Mutex` and a `Condvar`; a general priority-queue crate would need the
//! same per-node bookkeeping around it.

use std::collections::VecDeque;
use std::sync::{Condvar, Mutex, MutexGuard};

/// How soon a node's columns are needed, least urgent first.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Urgency {
    /// A node near a plate but not yet in the force patch (asked ahead of
    /// contact).
    Ahead = 0,
    /// A node of the force loop's compliance patch (a contact may slide
    /// onto it within the interval).
    Patch = 1,
    /// A node of a contact row of the step: its row waits for it.
    Row = 2,
}

const LEVELS: usize = 3;
/// Per-node state: not queued.
const FREE: u8 = u8::MAX;
/// Per-node state: taken by the worker, columns not handed back yet.
const IN_FLIGHT: u8 = u8::MAX - 1;

/// The lines of waiting nodes and each node's state.
#[derive(Debug)]
pub struct ColumnQueue {
    /// One line per [`Urgency`]; an entry whose node has been raised to a
    /// higher line since is stale and skipped when reached.
    lines: [VecDeque<u32>; LEVELS],
    /// Per node: the line it waits in ([`Urgency`] as `u8`), [`FREE`] or
    /// [`IN_FLIGHT`].
    state: Vec<u8>,
    closed: bool,
}

impl ColumnQueue {
    /// An empty queue over `n_nodes` nodes.
    pub fn new(n_nodes: usize) -> Self {
        Self {
            lines: Default::default(),
            state: vec![FREE; n_nodes],
            closed: false,
        }
    }

    /// Queues `node` at `urgency`, or raises it there if it waits lower.
    /// Returns whether the queue changed (a node in flight, waiting at the
    /// same or a higher urgency, or out of range changes nothing).
    pub fn push(&mut self, node: u32, urgency: Urgency) -> bool {
        let Some(s) = self.state.get_mut(node as usize) else {
            return false;
        };
        let level = urgency as u8;
        if *s == IN_FLIGHT || (*s != FREE && *s >= level) {
            return false;
        }
        *s = level;
        self.lines[level as usize].push_back(node);
        true
    }

    /// Takes into `out` (cleared first) up to `max_of(urgency)` nodes of
    /// the most urgent line that holds a waiting node, oldest first, and
    /// marks them in flight; returns that line's urgency, or `None` when
    /// nothing waits. A batch never mixes lines, so a few urgent nodes are
    /// solved without waiting for a full batch of less urgent ones.
    pub fn take(
        &mut self,
        max_of: impl Fn(Urgency) -> usize,
        out: &mut Vec<u32>,
    ) -> Option<Urgency> {
        out.clear();
        for (level, urgency) in [(2, Urgency::Row), (1, Urgency::Patch), (0, Urgency::Ahead)] {
            let max = max_of(urgency).max(1);
            while out.len() < max {
                let Some(n) = self.lines[level].pop_front() else {
                    break;
                };
                // Stale: raised to a higher line since.
                if self.state[n as usize] == level as u8 {
                    self.state[n as usize] = IN_FLIGHT;
                    out.push(n);
                }
            }
            if !out.is_empty() {
                return Some(urgency);
            }
        }
        None
    }

    /// Marks `nodes` (taken earlier) as no longer in flight: a later ask
    /// queues them again.
    pub fn finish(&mut self, nodes: &[u32]) {
        for &n in nodes {
            if let Some(s) = self.state.get_mut(n as usize) {
                *s = FREE;
            }
        }
    }

    /// Nodes waiting (not in flight).
    pub fn waiting(&self) -> usize {
        self.state
            .iter()
            .filter(|&&s| (s as usize) < LEVELS)
            .count()
    }
}

/// A [`ColumnQueue`] shared between the solver (asks) and the worker
/// thread (takes, blocking while empty).
#[derive(Debug)]
pub struct SharedQueue {
    queue: Mutex<ColumnQueue>,
    ready: Condvar,
}

impl SharedQueue {
    /// An empty shared queue over `n_nodes` nodes.
    pub fn new(n_nodes: usize) -> Self {
        Self {
            queue: Mutex::new(ColumnQueue::new(n_nodes)),
            ready: Condvar::new(),
        }
    }

    fn lock(&self) -> MutexGuard<'_, ColumnQueue> {
        // A panic while holding the lock leaves the lines consistent
        // (every method finishes its bookkeeping before it can panic).
        self.queue.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Queues or raises `nodes` at `urgency` and wakes the worker.
    pub fn ask(&self, nodes: &[u32], urgency: Urgency) {
        let mut q = self.lock();
        let mut changed = false;
        for &n in nodes {
            changed |= q.push(n, urgency);
        }
        drop(q);
        if changed {
            self.ready.notify_one();
        }
    }

    /// Waits for work and takes a batch ([`ColumnQueue::take`]); `None`
    /// once closed.
    pub fn wait_take(
        &self,
        max_of: impl Fn(Urgency) -> usize,
        out: &mut Vec<u32>,
    ) -> Option<Urgency> {
        let mut q = self.lock();
        loop {
            if q.closed {
                return None;
            }
            if let Some(u) = q.take(&max_of, out) {
                return Some(u);
            }
            q = self.ready.wait(q).unwrap_or_else(|e| e.into_inner());
        }
    }

    /// Marks `nodes` as handed back ([`ColumnQueue::finish`]).
    pub fn finish(&self, nodes: &[u32]) {
        self.lock().finish(nodes);
    }

    /// Stops the worker: its next [`Self::wait_take`] returns `None`.
    pub fn close(&self) {
        self.lock().closed = true;
        self.ready.notify_all();
    }

    /// Nodes waiting (not in flight).
    pub fn waiting(&self) -> usize {
        self.lock().waiting()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_most_urgent_line_is_served_first_oldest_first() {
        let mut q = ColumnQueue::new(10);
        for n in [1, 2, 3] {
            q.push(n, Urgency::Ahead);
        }
        q.push(4, Urgency::Patch);
        q.push(5, Urgency::Row);
        q.push(6, Urgency::Row);
        let mut out = Vec::new();
        assert_eq!(q.take(|_| 16, &mut out), Some(Urgency::Row));
        assert_eq!(out, [5, 6]);
        assert_eq!(q.take(|_| 16, &mut out), Some(Urgency::Patch));
        assert_eq!(out, [4]);
        assert_eq!(q.take(|_| 2, &mut out), Some(Urgency::Ahead));
        assert_eq!(out, [1, 2]);
        assert_eq!(q.take(|_| 2, &mut out), Some(Urgency::Ahead));
        assert_eq!(out, [3]);
        assert_eq!(q.take(|_| 2, &mut out), None);
        assert!(out.is_empty());
    }

    #[test]
    fn a_node_asked_again_more_urgently_is_raised_and_served_once() {
        let mut q = ColumnQueue::new(10);
        assert!(q.push(1, Urgency::Ahead));
        assert!(q.push(2, Urgency::Ahead));
        assert!(q.push(2, Urgency::Row));
        // Asking at the same or a lower urgency changes nothing.
        assert!(!q.push(2, Urgency::Row));
        assert!(!q.push(2, Urgency::Patch));
        assert_eq!(q.waiting(), 2);
        let mut out = Vec::new();
        assert_eq!(q.take(|_| 16, &mut out), Some(Urgency::Row));
        assert_eq!(out, [2]);
        // The stale entry of node 2 in the ahead line is skipped.
        assert_eq!(q.take(|_| 16, &mut out), Some(Urgency::Ahead));
        assert_eq!(out, [1]);
        assert_eq!(q.take(|_| 16, &mut out), None);
    }

    #[test]
    fn a_node_in_flight_is_not_queued_again_until_finished() {
        let mut q = ColumnQueue::new(4);
        q.push(3, Urgency::Patch);
        let mut out = Vec::new();
        q.take(|_| 16, &mut out);
        assert_eq!(out, [3]);
        assert!(!q.push(3, Urgency::Row));
        assert_eq!(q.take(|_| 16, &mut out), None);
        q.finish(&[3]);
        assert!(q.push(3, Urgency::Ahead));
        assert_eq!(q.take(|_| 16, &mut out), Some(Urgency::Ahead));
        assert_eq!(out, [3]);
        // Out of range: ignored, not a panic.
        assert!(!q.push(4, Urgency::Row));
    }

    #[test]
    fn each_batch_is_sized_by_its_line_and_the_rest_waits_in_order() {
        let q = SharedQueue::new(40);
        let ahead: Vec<u32> = (0..20).collect();
        q.ask(&ahead, Urgency::Ahead);
        q.ask(&[30, 31, 32], Urgency::Row);
        let size = |u: Urgency| if u == Urgency::Ahead { 8 } else { 16 };
        let mut out = Vec::new();
        assert_eq!(q.wait_take(size, &mut out), Some(Urgency::Row));
        assert_eq!(out, [30, 31, 32]);
        assert_eq!(q.wait_take(size, &mut out), Some(Urgency::Ahead));
        assert_eq!(out, (0..8).collect::<Vec<u32>>());
        assert_eq!(q.wait_take(size, &mut out), Some(Urgency::Ahead));
        assert_eq!(out, (8..16).collect::<Vec<u32>>());
        assert_eq!(q.waiting(), 4);
        q.close();
        assert!(q.wait_take(size, &mut out).is_none());
    }

    #[test]
    fn a_waiting_worker_wakes_for_an_ask_and_for_close() {
        let q = std::sync::Arc::new(SharedQueue::new(8));
        let worker = {
            let q = q.clone();
            std::thread::spawn(move || {
                let mut got = Vec::new();
                let mut out = Vec::new();
                while q.wait_take(|_| 4, &mut out).is_some() {
                    got.extend_from_slice(&out);
                    q.finish(&out);
                }
                got
            })
        };
        q.ask(&[7, 5], Urgency::Patch);
        // The worker takes both, then waits; close ends it.
        while q.waiting() > 0 {
            std::thread::yield_now();
        }
        q.close();
        assert_eq!(worker.join().expect("worker"), [7, 5]);
    }
}
