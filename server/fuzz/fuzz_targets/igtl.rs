//! Fuzzes the OpenIGTLink codec of `fissure bridge --igtl-*`
//! (`fissure_cli::client::bridge::igtl::codec`): the header parser, the body check
//! (size, CRC-64, version-2 extended header) and the TRANSFORM, POSITION,
//! SENSOR, STATUS and POLYDATA readers.
//!
//! Beyond "no panic, no hang, no huge allocation", it checks:
//! - a refusal names the right cause (`ShortHeader` only under 58 bytes,
//!   `BodyLength` only when the bytes after the header are not the declared
//!   size, `Crc` only when the CRC really differs);
//! - an accepted message re-encodes to a message that parses to the same
//!   body (TRANSFORM, POSITION of 28 bytes, SENSOR, STATUS, POLYDATA
//!   without attributes);
//! - the input with its CRC recomputed reaches the body readers, so they
//!   are fuzzed past the CRC check.
#![no_main]

use fissure_cli::client::bridge::igtl::codec::{
    Body, HEADER_LEN, IgtlError, crc64, parse_content, parse_message,
    polydata_content, position_content, sensor_content, status_content, transform_content,
    write_message,
};
use libfuzzer_sys::fuzz_target;

fn check(data: &[u8]) {
    match parse_message(data) {
        Ok((h, body)) => {
            assert_eq!(data.len() as u64, HEADER_LEN as u64 + h.body_size);
            assert_eq!(crc64(&data[HEADER_LEN..]), h.crc);
            let mut again = Vec::new();
            let (t, d, ts) = (h.type_name, h.device_name, h.timestamp);
            match &body {
                Body::Transform(x) => write_message(&mut again, t, d, ts, |o| transform_content(x, o)),
                Body::Position(p) => write_message(&mut again, t, d, ts, |o| position_content(p, o)),
                Body::Sensor(s) => {
                    write_message(&mut again, t, d, ts, |o| sensor_content(s.status, s.unit, &s.data, o))
                }
                Body::Status(s) => write_message(&mut again, t, d, ts, |o| status_content(s, o)),
                Body::PolyData(p) => {
                    // The writer writes points, polygons and strips only.
                    if !p.attributes.is_empty() || p.vertices.count != 0 || p.lines.count != 0 {
                        return;
                    }
                    let flat: Vec<f32> = p.points.iter().flatten().copied().collect();
                    write_message(&mut again, t, d, ts, |o| {
                        polydata_content(&flat, &p.polygons, &p.strips, o)
                    })
                }
            }
            let (h2, body2) = parse_message(&again).expect("a re-encoded message parses");
            assert_eq!(h2.type_str(), h.type_str());
            assert_eq!(h2.device(), h.device());
            match (&body, &body2) {
                // SENSOR values may be NaN: compared bit for bit.
                (Body::Sensor(a), Body::Sensor(b)) => {
                    assert_eq!((a.status, a.unit), (b.status, b.unit));
                    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(&a.data), bits(&b.data));
                }
                // (A 12- or 24-byte POSITION comes back as 28 bytes holding
                // the completed quaternion: the same numbers.)
                (a, b) => assert_eq!(a, b),
            }
        }
        Err(IgtlError::ShortHeader { got }) => {
            assert!(got < HEADER_LEN);
            assert_eq!(got, data.len());
        }
        Err(IgtlError::BodyLength { got, declared }) => {
            assert_ne!(got, declared);
            assert_eq!(got, (data.len() - HEADER_LEN) as u64);
        }
        Err(IgtlError::Crc { got, declared }) => {
            assert_ne!(got, declared);
            assert_eq!(got, crc64(&data[HEADER_LEN..]));
        }
        Err(e) => {
            // Every other refusal names a cause in words.
            assert!(!e.to_string().is_empty());
        }
    }
}

fuzz_target!(|data: &[u8]| {
    check(data);
    // Past the CRC: the same bytes with the CRC made right.
    if data.len() >= HEADER_LEN {
        let mut x = data.to_vec();
        let crc = crc64(&x[HEADER_LEN..]);
        x[50..58].copy_from_slice(&crc.to_be_bytes());
        check(&x);
        // And the body alone, read as each type.
        for kind in ["TRANSFORM", "POSITION", "SENSOR", "STATUS", "POLYDATA"] {
            let _ = parse_content(kind, &x[HEADER_LEN..]);
        }
    }
});
