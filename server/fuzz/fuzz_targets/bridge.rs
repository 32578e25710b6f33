//! Fuzzes the UDP bridge's datagram codecs (`fissure_cli::client::bridge`, the format
//! is documented there): the pose parser `parse_datagram` (binary `FSP1` and
//! JSON), the force decoder `decode_force`, and the JSON answer line written
//! for what the parser accepted.
//!
//! Beyond "no panic, no hang, no huge allocation", it checks:
//! - a refusal names the right cause (`Empty` only for blank input,
//!   `TooLong` only over `MAX_DATAGRAM`, `Version` only after the magic...);
//! - an accepted binary pose is exactly 80 bytes and re-encodes with
//!   `encode_pose` to the same bytes, the reserved bytes 6..8 aside;
//! - an accepted JSON pose agrees field by field with serde_json's own
//!   reading of the object (`serde_json::Value`), and its answer line is one
//!   JSON object naming the instrument and sequence as given;
//! - a decoded force datagram re-encodes to the same bytes, the reserved
//!   bytes 104..112 aside.
#![no_main]

use fissure_cli::client::bridge::{
    DatagramError, FORCE_LEN, ForceDatagram, Format, InstrumentRef, MAX_DATAGRAM, POSE_LEN,
    POSE_MAGIC, VERSION, decode_force, encode_force, encode_force_json, encode_pose,
    parse_datagram,
};
use libfuzzer_sys::fuzz_target;
use serde_json::Value;

fn check_json(data: &[u8], d: &fissure_cli::client::bridge::PoseDatagram<'_>) {
    let v: Value = serde_json::from_slice(data).expect("accepted JSON is JSON");
    let o = v.as_object().expect("accepted JSON is an object");
    let absent = |k: &str| o.get(k).is_none_or(Value::is_null);
    assert_eq!(o["seq"].as_u64(), Some(d.sequence));
    // The same number parser reads both: equal values (0 and -0 compare equal).
    assert_eq!(o["t_s"].as_f64(), Some(d.t_s));
    for (key, got) in [("p", &d.position_m[..]), ("q", &d.orientation[..])] {
        let a = o[key].as_array().expect("an array");
        assert_eq!(a.len(), got.len());
        for (x, y) in a.iter().zip(got) {
            assert_eq!(x.as_f64(), Some(*y));
        }
    }
    let name = match d.instrument {
        InstrumentRef::Name(n) => {
            assert_eq!(o["instrument"].as_str(), Some(n));
            assert!(absent("i"));
            n
        }
        InstrumentRef::Index(i) => {
            assert_eq!(o["i"].as_u64(), Some(u64::from(i)));
            assert!(absent("instrument"));
            ""
        }
    };
    // The answer line the bridge would send back.
    let f = ForceDatagram {
        instrument: 0,
        status: 1,
        sequence: d.sequence,
        t_s: d.t_s,
        force_n: d.position_m,
        torque_nm: [d.orientation[1], d.orientation[2], d.orientation[3]],
        contact_count: 0,
        safety_flags: 0,
        model_frame: 0,
        model_age_s: d.orientation[0],
        server_compute_us: 0.0,
    };
    let mut line = Vec::new();
    encode_force_json(&f, name, Some(name), &mut line).expect("writing to a Vec");
    assert_eq!(line.last(), Some(&b'\n'));
    assert!(!line[..line.len() - 1].contains(&b'\n'), "one line");
    let a: Value = serde_json::from_slice(&line).expect("the answer line is JSON");
    assert_eq!(a["instrument"].as_str(), Some(name));
    assert_eq!(a["message"].as_str(), Some(name));
    assert_eq!(a["seq"].as_u64(), Some(d.sequence));
    assert!(a["t_s"].is_number());
    // `t_s` is written as Rust's shortest round-trip decimal: a correctly
    // rounding reader gets the pose's value back exactly (serde_json's
    // default float reader is not correctly rounded for long digit strings,
    // so the text is read here with `str::parse`). A name is written
    // escaped, so `,"t_s":` cannot occur in it.
    let text = std::str::from_utf8(&line).expect("the answer line is UTF-8");
    let at = text.find(",\"t_s\":").expect("a t_s field") + 7;
    let end = at + text[at..].find(',').expect("a field after t_s");
    let t: f64 = text[at..end].parse().expect("t_s is a decimal number");
    assert_eq!(t.to_bits(), d.t_s.to_bits(), "{}", &text[at..end]);
}

fuzz_target!(|data: &[u8]| {
    let first = data.iter().position(|b| !b.is_ascii_whitespace());
    match parse_datagram(data) {
        Ok(d) => match d.format {
            Format::Binary => {
                assert_eq!(data.len(), POSE_LEN);
                let InstrumentRef::Index(i) = d.instrument else {
                    panic!("a binary pose names its instrument by index");
                };
                let mut again = encode_pose(i, d.sequence, d.t_s, d.position_m, d.orientation);
                again[6..8].copy_from_slice(&data[6..8]);
                assert_eq!(&again[..], data);
            }
            Format::Json => {
                assert!(data.len() <= MAX_DATAGRAM);
                assert_eq!(first.map(|k| data[k]), Some(b'{'));
                check_json(data, &d);
            }
        },
        Err(DatagramError::Empty) => assert!(first.is_none()),
        Err(DatagramError::TooLong { got }) => {
            assert_eq!(got, data.len());
            assert!(got > MAX_DATAGRAM);
        }
        Err(e) => {
            assert!(data.len() <= MAX_DATAGRAM);
            let is_json = first.map(|k| data[k]) == Some(b'{');
            match e {
                DatagramError::Json(_) => assert!(is_json),
                DatagramError::Magic(m) => {
                    assert!(!is_json);
                    assert_ne!(m, POSE_MAGIC);
                    let n = data.len().min(4);
                    assert_eq!(&m[..n], &data[..n]);
                }
                DatagramError::Version(v) => {
                    assert_eq!(data[..4], POSE_MAGIC);
                    assert_eq!(data[4], v);
                    assert_ne!(v, VERSION);
                }
                DatagramError::Length { got } => {
                    assert_eq!(got, data.len());
                    assert_ne!(got, POSE_LEN);
                    assert_eq!(data[..4], POSE_MAGIC);
                }
                DatagramError::Empty | DatagramError::TooLong { .. } => unreachable!(),
            }
        }
    }
    if let Some(f) = decode_force(data) {
        assert_eq!(data.len(), FORCE_LEN);
        let mut again = [0u8; FORCE_LEN];
        encode_force(&f, &mut again);
        again[104..].copy_from_slice(&data[104..]);
        assert_eq!(&again[..], data);
    }
});
