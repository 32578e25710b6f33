//! Fuzzes what the server does with incoming pose messages before the engine
//! sees them: prost decoding of `PoseSample` (the input is a sequence of
//! length-delimited messages, as a stream delivers them), the conversion to an
//! engine pose (`service::convert::raw_pose`) and its validation
//! (`sim::core::pose::validate`) against the previous accepted pose. An accepted pose
//! must be finite with a unit rotation, and sequence and time must go forward.
#![no_main]

use fissure_proto::v1::PoseSample;
use fissure_server::convert::raw_pose;
use fissure_engine::sim::core::pose::{TimedPose, validate};
use libfuzzer_sys::fuzz_target;
use prost::Message;

fuzz_target!(|data: &[u8]| {
    // A single message, as a unary body would be.
    let _ = PoseSample::decode(data);
    let mut buf = data;
    let mut last: Option<TimedPose> = None;
    while !buf.is_empty() {
        let Ok(msg) = PoseSample::decode_length_delimited(&mut buf) else {
            break;
        };
        let Ok(raw) = raw_pose(&msg) else {
            continue;
        };
        if let Ok(p) = validate(&raw, last.as_ref()) {
            assert!(p.t_s.is_finite());
            assert!(p.pose.translation.vector.iter().all(|v| v.is_finite()));
            assert!((p.pose.rotation.norm() - 1.0).abs() < 1e-9);
            if let Some(l) = &last {
                assert!(p.sequence > l.sequence && p.t_s >= l.t_s);
            }
            last = Some(p);
        }
    }
});
