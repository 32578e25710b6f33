//! The ties (arachnoid trabeculae, bridging vessels) cut or torn, as the
//! bridges announce them to their peers: one [`TieNotice`] per tie, from
//! the deformation frames' events, and one for a tie the frames' cumulative
//! `released` list names that no event announced (its frame was skipped:
//! the watch is latest-wins).

use fissure_proto::v1 as pb;
use std::collections::HashSet;

/// Whether the server's scene has ties (then the bridges announce them).
pub async fn scene_has_ties(
    client: &mut pb::fissure_client::FissureClient<tonic::transport::Channel>,
) -> anyhow::Result<bool> {
    use anyhow::Context;
    Ok(!client
        .get_scene(pb::GetSceneRequest {})
        .await
        .context("GetScene")?
        .into_inner()
        .ties
        .is_empty())
}

/// How a tie went.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TieHow {
    /// A blade cut it.
    Cut,
    /// Its tension reached its rupture criterion.
    Torn,
    /// Cut or torn in a frame the bridge did not receive.
    Released,
}

/// One tie cut or torn.
#[derive(Debug, Clone, PartialEq)]
pub struct TieNotice {
    /// The tie's index in the scene.
    pub tie: u32,
    /// What it was (`None`: not known, a [`TieHow::Released`] notice).
    pub kind: Option<pb::TieKind>,
    /// How it went.
    pub how: TieHow,
    /// The instrument that cut it, or (torn) the pushing one whose tip was
    /// nearest.
    pub instrument: String,
    /// Simulation time, s (NaN when not known).
    pub sim_time_s: f64,
    /// Its midpoint when it went, scene frame, m (NaN when not known).
    pub position_m: [f64; 3],
    /// Its strain when it went (NaN when not known).
    pub strain: f64,
}

impl TieNotice {
    /// The tie's kind as a word: `trabecula`, `vessel` or `tie`.
    pub fn kind_name(&self) -> &'static str {
        match self.kind {
            Some(pb::TieKind::Trabecula) => "trabecula",
            Some(pb::TieKind::Vessel) => "vessel",
            _ => "tie",
        }
    }

    /// Whether it is an injury (a torn vessel).
    pub fn is_injury(&self) -> bool {
        self.how == TieHow::Torn && self.kind == Some(pb::TieKind::Vessel)
    }
}

/// The notices of a stream of frames, each tie once.
#[derive(Debug, Default)]
pub struct TieNotices {
    announced: HashSet<u32>,
}

impl TieNotices {
    /// The notices of one frame's tie summary: its events, then the
    /// released ties no event announced.
    pub fn of(&mut self, ties: &pb::TieSummary) -> Vec<TieNotice> {
        let mut out = Vec::new();
        for e in &ties.events {
            if !self.announced.insert(e.tie) {
                continue;
            }
            out.push(TieNotice {
                tie: e.tie,
                kind: pb::TieKind::try_from(e.kind).ok(),
                how: if e.cause == pb::TieCause::Cut as i32 {
                    TieHow::Cut
                } else {
                    TieHow::Torn
                },
                instrument: e.instrument.clone(),
                sim_time_s: e.sim_time_s,
                position_m: e
                    .position_m
                    .as_ref()
                    .map_or([f64::NAN; 3], |v| [v.x, v.y, v.z]),
                strain: e.strain,
            });
        }
        for &t in &ties.released {
            if self.announced.insert(t) {
                out.push(TieNotice {
                    tie: t,
                    kind: None,
                    how: TieHow::Released,
                    instrument: String::new(),
                    sim_time_s: f64::NAN,
                    position_m: [f64::NAN; 3],
                    strain: f64::NAN,
                });
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One notice per event, a tie once whatever the frames repeat, and a
    /// released tie whose event was in a skipped frame caught up, once.
    #[test]
    fn each_tie_is_announced_once_and_skipped_events_are_caught_up() {
        let event = |tie: u32, kind: pb::TieKind, cause: pb::TieCause| pb::TieEvent {
            sim_time_s: 1.25,
            tie,
            kind: kind as i32,
            cause: cause as i32,
            instrument: "blade".into(),
            position_m: Some(pb::Vec3 {
                x: 0.01,
                y: -0.02,
                z: 0.003,
            }),
            strain: 0.125,
        };
        let mut n = TieNotices::default();
        let first = pb::TieSummary {
            trabeculae_intact: 10,
            vessels_intact: 0,
            events: vec![
                event(4, pb::TieKind::Trabecula, pb::TieCause::Cut),
                event(9, pb::TieKind::Vessel, pb::TieCause::Torn),
            ],
            released: vec![4, 9],
        };
        let s = n.of(&first);
        assert_eq!(s.len(), 2);
        assert_eq!(
            (s[0].tie, s[0].how, s[0].kind_name()),
            (4, TieHow::Cut, "trabecula")
        );
        assert!(!s[0].is_injury() && s[1].is_injury());
        assert_eq!(s[1].position_m, [0.01, -0.02, 0.003]);
        assert!(n.of(&first).is_empty());
        let later = pb::TieSummary {
            released: vec![4, 7, 9],
            ..Default::default()
        };
        let s = n.of(&later);
        assert_eq!(s.len(), 1);
        assert_eq!(
            (s[0].tie, s[0].how, s[0].kind_name()),
            (7, TieHow::Released, "tie")
        );
        assert!(s[0].sim_time_s.is_nan());
        assert!(n.of(&later).is_empty());
    }
}
