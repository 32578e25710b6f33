//! The datagrams of `fissure bridge` (the layouts are in the module above):
//! parsing a pose (binary or JSON; never panics, names what is wrong) and
//! encoding the force answer in the pose's format.

use fissure_proto::v1 as pb;
use std::io::Write;

/// Magic of a binary pose datagram.
pub const POSE_MAGIC: [u8; 4] = *b"FSP1";
/// Magic of a binary force datagram.
pub const FORCE_MAGIC: [u8; 4] = *b"FSF1";
/// Format version.
pub const VERSION: u8 = 1;
/// Length of a binary pose datagram, bytes.
pub const POSE_LEN: usize = 80;
/// Length of a binary force datagram, bytes.
pub const FORCE_LEN: usize = 112;
/// Magic of a binary tie datagram.
pub const TIE_MAGIC: [u8; 4] = *b"FST1";
/// Length of a binary tie datagram, bytes.
pub const TIE_LEN: usize = 64;
/// Magic of a binary assessment alert datagram.
pub const ALERT_MAGIC: [u8; 4] = *b"FSA1";
/// Length of a binary assessment alert datagram, bytes.
pub const ALERT_LEN: usize = 32;
/// Largest datagram read, bytes (longer ones are refused).
pub const MAX_DATAGRAM: usize = 1024;

/// Status of a force answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u16)]
pub enum Status {
    /// Served.
    Ok = 0,
    /// The server rejected the pose (force zero).
    Rejected = 1,
    /// The bridge could not forward the pose (force zero).
    NotForwarded = 2,
}

/// Which instrument a datagram is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InstrumentRef<'a> {
    /// Index into the bridge's instruments.
    Index(u8),
    /// Name.
    Name(&'a str),
}

/// The encoding of a datagram (replies use the pose's).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// The fixed little-endian layout.
    Binary,
    /// One JSON object.
    Json,
}

/// A parsed pose datagram (borrows the instrument name from the datagram).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseDatagram<'a> {
    /// Encoding.
    pub format: Format,
    /// Instrument.
    pub instrument: InstrumentRef<'a>,
    /// Sequence number.
    pub sequence: u64,
    /// Time, s.
    pub t_s: f64,
    /// Handle position, m.
    pub position_m: [f64; 3],
    /// Orientation (w, x, y, z).
    pub orientation: [f64; 4],
}

/// Why a datagram was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DatagramError {
    /// Empty datagram.
    #[error("empty datagram")]
    Empty,
    /// Neither the binary magic nor a JSON object.
    #[error("bad magic {0:02x?}: expected b\"FSP1\" (binary) or '{{' (JSON)")]
    Magic([u8; 4]),
    /// Unsupported binary version.
    #[error("version {0} is not supported (expected 1)")]
    Version(u8),
    /// Wrong binary length.
    #[error("binary pose datagram of {got} bytes, expected {POSE_LEN}")]
    Length {
        /// Bytes received.
        got: usize,
    },
    /// Longer than [`MAX_DATAGRAM`] (the bridge's receive buffer holds one
    /// byte more, so `got` is then `MAX_DATAGRAM + 1`: at least that many).
    #[error("datagram of {got} bytes is over the {MAX_DATAGRAM}-byte limit")]
    TooLong {
        /// Bytes received (a lower bound when the receive was cut short).
        got: usize,
    },
    /// The JSON object is malformed or misses a field.
    #[error("JSON pose: {0}")]
    Json(String),
}

fn f64_at(b: &[u8], at: usize) -> f64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[at..at + 8]);
    f64::from_le_bytes(a)
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[at..at + 8]);
    u64::from_le_bytes(a)
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct JsonPose<'a> {
    #[serde(borrow, default)]
    instrument: Option<&'a str>,
    #[serde(default)]
    i: Option<u8>,
    seq: u64,
    t_s: f64,
    p: [f64; 3],
    q: [f64; 4],
}

/// Parses one pose datagram (binary or JSON, see the module doc). Never
/// panics and never allocates for a binary datagram.
///
/// Checked here: the length (at most [`MAX_DATAGRAM`] bytes; a binary pose
/// is exactly [`POSE_LEN`]), the magic and version of a binary pose, and the
/// JSON object's fields (exactly one of `"instrument"` and `"i"`, no unknown
/// field, numbers of the right type; an instrument name is taken as written,
/// so it may not contain JSON escapes). The reserved bytes 6..8 of a binary
/// pose are ignored. Values are not range-checked here: a NaN or infinite
/// binary component, or a non-unit quaternion, is passed on bit for bit and
/// the server answers it with a rejection naming the field (JSON has no
/// literal for NaN or infinity, and a number beyond the f64 range is a JSON
/// error).
pub fn parse_datagram(bytes: &[u8]) -> Result<PoseDatagram<'_>, DatagramError> {
    if bytes.len() > MAX_DATAGRAM {
        return Err(DatagramError::TooLong { got: bytes.len() });
    }
    let first = bytes
        .iter()
        .position(|b| !b.is_ascii_whitespace())
        .ok_or(DatagramError::Empty)?;
    if bytes[first] == b'{' {
        let j: JsonPose<'_> =
            serde_json::from_slice(bytes).map_err(|e| DatagramError::Json(e.to_string()))?;
        let instrument = match (j.instrument, j.i) {
            (Some(n), None) => InstrumentRef::Name(n),
            (None, Some(i)) => InstrumentRef::Index(i),
            _ => {
                return Err(DatagramError::Json(
                    "give exactly one of \"instrument\" (name) and \"i\" (index)".into(),
                ));
            }
        };
        return Ok(PoseDatagram {
            format: Format::Json,
            instrument,
            sequence: j.seq,
            t_s: j.t_s,
            position_m: j.p,
            orientation: j.q,
        });
    }
    if bytes.len() < 4 {
        let mut m = [0u8; 4];
        m[..bytes.len()].copy_from_slice(bytes);
        return Err(DatagramError::Magic(m));
    }
    let magic = [bytes[0], bytes[1], bytes[2], bytes[3]];
    if magic != POSE_MAGIC {
        return Err(DatagramError::Magic(magic));
    }
    if bytes.len() < 5 || bytes[4] != VERSION {
        return Err(if bytes.len() < 5 {
            DatagramError::Length { got: bytes.len() }
        } else {
            DatagramError::Version(bytes[4])
        });
    }
    if bytes.len() != POSE_LEN {
        return Err(DatagramError::Length { got: bytes.len() });
    }
    Ok(PoseDatagram {
        format: Format::Binary,
        instrument: InstrumentRef::Index(bytes[5]),
        sequence: u64_at(bytes, 8),
        t_s: f64_at(bytes, 16),
        position_m: [f64_at(bytes, 24), f64_at(bytes, 32), f64_at(bytes, 40)],
        orientation: [
            f64_at(bytes, 48),
            f64_at(bytes, 56),
            f64_at(bytes, 64),
            f64_at(bytes, 72),
        ],
    })
}

/// Encodes a binary pose datagram (for device programs written in Rust and
/// for tests).
pub fn encode_pose(
    instrument: u8,
    sequence: u64,
    t_s: f64,
    position_m: [f64; 3],
    orientation: [f64; 4],
) -> [u8; POSE_LEN] {
    let mut b = [0u8; POSE_LEN];
    b[0..4].copy_from_slice(&POSE_MAGIC);
    b[4] = VERSION;
    b[5] = instrument;
    b[8..16].copy_from_slice(&sequence.to_le_bytes());
    b[16..24].copy_from_slice(&t_s.to_le_bytes());
    for (k, v) in position_m.iter().chain(&orientation).enumerate() {
        b[24 + 8 * k..32 + 8 * k].copy_from_slice(&v.to_le_bytes());
    }
    b
}

/// A force answer, decoded.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForceDatagram {
    /// Instrument index.
    pub instrument: u8,
    /// Status.
    pub status: u16,
    /// Sequence of the pose answered.
    pub sequence: u64,
    /// Time of the pose answered, s.
    pub t_s: f64,
    /// Force, N.
    pub force_n: [f64; 3],
    /// Torque about the handle point, N m.
    pub torque_nm: [f64; 3],
    /// Contact vertices.
    pub contact_count: u32,
    /// Safety flags.
    pub safety_flags: u32,
    /// Deformation frame used.
    pub model_frame: u64,
    /// Model age, s.
    pub model_age_s: f64,
    /// Server compute time, us.
    pub server_compute_us: f64,
}

impl ForceDatagram {
    /// An answer to the pose `sequence` at `t_s` (s) that carries no force:
    /// zero force and torque, no contact, no model (a pose not forwarded,
    /// or one the bridge answers itself).
    pub fn empty(instrument: u8, status: u16, sequence: u64, t_s: f64) -> Self {
        Self {
            instrument,
            status,
            sequence,
            t_s,
            force_n: [0.0; 3],
            torque_nm: [0.0; 3],
            contact_count: 0,
            safety_flags: 0,
            model_frame: 0,
            model_age_s: 0.0,
            server_compute_us: 0.0,
        }
    }
}

/// Encodes a binary force datagram into `out`.
pub fn encode_force(f: &ForceDatagram, out: &mut [u8; FORCE_LEN]) {
    out.fill(0);
    out[0..4].copy_from_slice(&FORCE_MAGIC);
    out[4] = VERSION;
    out[5] = f.instrument;
    out[6..8].copy_from_slice(&f.status.to_le_bytes());
    out[8..16].copy_from_slice(&f.sequence.to_le_bytes());
    out[16..24].copy_from_slice(&f.t_s.to_le_bytes());
    for (k, v) in f.force_n.iter().chain(&f.torque_nm).enumerate() {
        out[24 + 8 * k..32 + 8 * k].copy_from_slice(&v.to_le_bytes());
    }
    out[72..76].copy_from_slice(&f.contact_count.to_le_bytes());
    out[76..80].copy_from_slice(&f.safety_flags.to_le_bytes());
    out[80..88].copy_from_slice(&f.model_frame.to_le_bytes());
    out[88..96].copy_from_slice(&f.model_age_s.to_le_bytes());
    out[96..104].copy_from_slice(&f.server_compute_us.to_le_bytes());
}

/// Decodes a binary force datagram (`None` when it is not one).
pub fn decode_force(b: &[u8]) -> Option<ForceDatagram> {
    if b.len() != FORCE_LEN || b[0..4] != FORCE_MAGIC || b[4] != VERSION {
        return None;
    }
    let u32_at = |at: usize| u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]]);
    Some(ForceDatagram {
        instrument: b[5],
        status: u16::from_le_bytes([b[6], b[7]]),
        sequence: u64_at(b, 8),
        t_s: f64_at(b, 16),
        force_n: [f64_at(b, 24), f64_at(b, 32), f64_at(b, 40)],
        torque_nm: [f64_at(b, 48), f64_at(b, 56), f64_at(b, 64)],
        contact_count: u32_at(72),
        safety_flags: u32_at(76),
        model_frame: u64_at(b, 80),
        model_age_s: f64_at(b, 88),
        server_compute_us: f64_at(b, 96),
    })
}

/// Writes the JSON answer line for `f` into `out` (cleared first; no
/// allocation once `out` has grown to a line's size). `message` is the
/// server's rejection text, if any.
pub fn encode_force_json(
    f: &ForceDatagram,
    name: &str,
    message: Option<&str>,
    out: &mut Vec<u8>,
) -> std::io::Result<()> {
    out.clear();
    let status = match f.status {
        0 => "ok",
        1 => "rejected",
        _ => "not-forwarded",
    };
    write!(out, "{{\"instrument\":")?;
    write_json_str(out, name)?;
    write!(
        out,
        ",\"seq\":{},\"t_s\":{},\"status\":\"{status}\",\"f\":[{:e},{:e},{:e}],\"torque\":[{:e},{:e},{:e}],\"contacts\":{},\"flags\":{},\"model_frame\":{},\"model_age_s\":{:e},\"server_us\":{:.1}",
        f.sequence,
        f.t_s,
        f.force_n[0],
        f.force_n[1],
        f.force_n[2],
        f.torque_nm[0],
        f.torque_nm[1],
        f.torque_nm[2],
        f.contact_count,
        f.safety_flags,
        f.model_frame,
        f.model_age_s,
        f.server_compute_us
    )?;
    if let Some(m) = message {
        write!(out, ",\"message\":")?;
        write_json_str(out, m)?;
    }
    writeln!(out, "}}")
}

/// A tie cut or torn, as a binary datagram ([`TIE_LEN`] bytes; layout in
/// the module above).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TieDatagram {
    /// Index of the instrument among the bridged ones (255: not bridged,
    /// or not known).
    pub instrument: u8,
    /// 1 trabecula, 2 vessel, 0 not known.
    pub kind: u8,
    /// 1 cut, 2 torn, 0 released in a frame the bridge did not receive.
    pub cause: u8,
    /// The tie's index in the scene.
    pub tie: u32,
    /// Simulation time, s (NaN: not known).
    pub t_s: f64,
    /// Midpoint, scene frame, m (NaN: not known).
    pub position_m: [f64; 3],
    /// Strain (NaN: not known).
    pub strain: f64,
}

impl TieDatagram {
    /// The datagram of `n`, its instrument at `instrument` of the bridged
    /// ones.
    pub fn of(n: &super::ties::TieNotice, instrument: Option<usize>) -> Self {
        use super::ties::TieHow;
        Self {
            instrument: instrument.and_then(|i| u8::try_from(i).ok()).unwrap_or(255),
            kind: match n.kind {
                Some(pb::TieKind::Trabecula) => 1,
                Some(pb::TieKind::Vessel) => 2,
                _ => 0,
            },
            cause: match n.how {
                TieHow::Cut => 1,
                TieHow::Torn => 2,
                TieHow::Released => 0,
            },
            tie: n.tie,
            t_s: n.sim_time_s,
            position_m: n.position_m,
            strain: n.strain,
        }
    }
}

/// Encodes a binary tie datagram into `out`.
pub fn encode_tie(t: &TieDatagram, out: &mut [u8; TIE_LEN]) {
    out.fill(0);
    out[0..4].copy_from_slice(&TIE_MAGIC);
    out[4] = VERSION;
    out[5] = t.instrument;
    out[6] = t.kind;
    out[7] = t.cause;
    out[8..12].copy_from_slice(&t.tie.to_le_bytes());
    out[16..24].copy_from_slice(&t.t_s.to_le_bytes());
    for (k, v) in t.position_m.iter().enumerate() {
        out[24 + 8 * k..32 + 8 * k].copy_from_slice(&v.to_le_bytes());
    }
    out[48..56].copy_from_slice(&t.strain.to_le_bytes());
}

/// Decodes a binary tie datagram (`None` when it is not one).
pub fn decode_tie(b: &[u8]) -> Option<TieDatagram> {
    if b.len() != TIE_LEN || b[0..4] != TIE_MAGIC || b[4] != VERSION {
        return None;
    }
    Some(TieDatagram {
        instrument: b[5],
        kind: b[6],
        cause: b[7],
        tie: u32::from_le_bytes([b[8], b[9], b[10], b[11]]),
        t_s: f64_at(b, 16),
        position_m: [f64_at(b, 24), f64_at(b, 32), f64_at(b, 40)],
        strain: f64_at(b, 48),
    })
}

/// Writes the JSON line of a tie notice into `out` (cleared first):
/// `{"event":"tie","tie":4,"cause":"cut","kind":"trabecula","instrument":"blade","t_s":1.25,"p":[x,y,z],"strain":0.125}`;
/// a tie released unseen has only `"event"`, `"tie"` and `"cause":"released"`.
pub fn encode_tie_json(n: &super::ties::TieNotice, out: &mut Vec<u8>) -> std::io::Result<()> {
    use super::ties::TieHow;
    out.clear();
    let cause = match n.how {
        TieHow::Cut => "cut",
        TieHow::Torn => "torn",
        TieHow::Released => "released",
    };
    write!(
        out,
        "{{\"event\":\"tie\",\"tie\":{},\"cause\":\"{cause}\"",
        n.tie
    )?;
    if n.how != TieHow::Released {
        write!(out, ",\"kind\":\"{}\",\"instrument\":", n.kind_name())?;
        write_json_str(out, &n.instrument)?;
        let p = n.position_m;
        write!(
            out,
            ",\"t_s\":{},\"p\":[{:e},{:e},{:e}],\"strain\":{:e}",
            n.sim_time_s, p[0], p[1], p[2], n.strain
        )?;
    }
    writeln!(out, "}}")
}

/// A measure of the assessment reaching a level, as a binary datagram
/// ([`ALERT_LEN`] bytes; layout in the module above).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AlertDatagram {
    /// 1 warn, 2 fail.
    pub grade: u8,
    /// 1 mean retraction pressure (Pa), 2 time above the warning pressure
    /// (s), 3 pressure-time product (Pa s), 4 principal strain, 5 tissue
    /// volume above the warning strain (m^3); 0 another.
    pub measure: u8,
    /// Index of the instrument among the bridged ones (255: the tissue's,
    /// or not bridged).
    pub instrument: u8,
    /// Simulation time, s.
    pub t_s: f64,
    /// The value, SI.
    pub value: f64,
    /// The level reached, SI.
    pub level: f64,
}

impl AlertDatagram {
    /// The datagram of `a`, its instrument at `instrument` of the bridged
    /// ones.
    pub fn of(a: &crate::client::report::assess::Alert, instrument: Option<usize>) -> Self {
        use fissure_shared::assessment::Grade;
        Self {
            grade: match a.grade {
                Grade::Fail => 2,
                Grade::Warn => 1,
                Grade::Pass => 0,
            },
            measure: match a.measure {
                "mean retraction pressure" => 1,
                "time above the warning pressure" => 2,
                "pressure-time product" => 3,
                "principal strain" => 4,
                "tissue volume above the warning strain" => 5,
                _ => 0,
            },
            instrument: instrument.and_then(|i| u8::try_from(i).ok()).unwrap_or(255),
            t_s: a.t_s,
            value: a.value,
            level: a.level,
        }
    }
}

/// Encodes a binary alert datagram into `out`.
pub fn encode_alert(a: &AlertDatagram, out: &mut [u8; ALERT_LEN]) {
    out.fill(0);
    out[0..4].copy_from_slice(&ALERT_MAGIC);
    out[4] = VERSION;
    out[5] = a.grade;
    out[6] = a.measure;
    out[7] = a.instrument;
    out[8..16].copy_from_slice(&a.t_s.to_le_bytes());
    out[16..24].copy_from_slice(&a.value.to_le_bytes());
    out[24..32].copy_from_slice(&a.level.to_le_bytes());
}

/// Decodes a binary alert datagram (`None` when it is not one).
pub fn decode_alert(b: &[u8]) -> Option<AlertDatagram> {
    if b.len() != ALERT_LEN || b[0..4] != ALERT_MAGIC || b[4] != VERSION {
        return None;
    }
    Some(AlertDatagram {
        grade: b[5],
        measure: b[6],
        instrument: b[7],
        t_s: f64_at(b, 8),
        value: f64_at(b, 16),
        level: f64_at(b, 24),
    })
}

/// Writes the JSON line of an alert into `out` (cleared first):
/// `{"event":"assessment","grade":"warn","measure":"mean retraction pressure","instrument":"left","t_s":1.25,"value":2700.0,"level":2666.4,"unit":"Pa"}`
/// (`"instrument"` absent for the tissue's measures).
pub fn encode_alert_json(
    a: &crate::client::report::assess::Alert,
    out: &mut Vec<u8>,
) -> std::io::Result<()> {
    out.clear();
    write!(
        out,
        "{{\"event\":\"assessment\",\"grade\":\"{}\",\"measure\":",
        a.grade.name()
    )?;
    write_json_str(out, a.measure)?;
    if let Some(i) = &a.instrument {
        write!(out, ",\"instrument\":")?;
        write_json_str(out, i)?;
    }
    write!(
        out,
        ",\"t_s\":{},\"value\":{:e},\"level\":{:e},\"unit\":",
        a.t_s, a.value, a.level
    )?;
    write_json_str(out, a.unit)?;
    writeln!(out, "}}")
}

fn write_json_str(out: &mut Vec<u8>, s: &str) -> std::io::Result<()> {
    out.push(b'"');
    for c in s.chars() {
        match c {
            '"' => out.extend_from_slice(b"\\\""),
            '\\' => out.extend_from_slice(b"\\\\"),
            c if (c as u32) < 0x20 => write!(out, "\\u{:04x}", c as u32)?,
            c => {
                let mut b = [0u8; 4];
                out.extend_from_slice(c.encode_utf8(&mut b).as_bytes());
            }
        }
    }
    out.push(b'"');
    Ok(())
}

/// The pose message of a parsed datagram.
pub(super) fn pose_sample(d: &PoseDatagram<'_>) -> pb::PoseSample {
    pb::PoseSample::new(d.t_s, d.sequence, d.position_m, d.orientation)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn binary_pose_round_trip() {
        let b = encode_pose(1, 42, 0.5, [0.01, -0.02, 0.03], [1.0, 0.0, 0.0, 0.0]);
        let d = parse_datagram(&b).unwrap();
        assert_eq!(d.format, Format::Binary);
        assert_eq!(d.instrument, InstrumentRef::Index(1));
        assert_eq!(d.sequence, 42);
        assert_eq!(d.t_s, 0.5);
        assert_eq!(d.position_m, [0.01, -0.02, 0.03]);
        assert_eq!(d.orientation, [1.0, 0.0, 0.0, 0.0]);
        // The documented offsets.
        assert_eq!(&b[0..4], b"FSP1");
        assert_eq!(f64::from_le_bytes(b[32..40].try_into().unwrap()), -0.02);
    }

    fn valid() -> [u8; POSE_LEN] {
        encode_pose(0, 1, 0.0, [0.0; 3], [1.0, 0.0, 0.0, 0.0])
    }

    fn json_error(bytes: &[u8]) -> String {
        match parse_datagram(bytes) {
            Err(DatagramError::Json(m)) => m,
            other => panic!(
                "{:?}: expected a JSON error, got {other:?}",
                String::from_utf8_lossy(bytes)
            ),
        }
    }

    #[test]
    fn truncated_binary_poses_are_refused_at_every_length() {
        let b = valid();
        assert_eq!(parse_datagram(&[]), Err(DatagramError::Empty));
        assert_eq!(parse_datagram(b" \t\r\n"), Err(DatagramError::Empty));
        // Shorter than the magic: the magic as received, zero-padded.
        assert_eq!(
            parse_datagram(&b[..1]),
            Err(DatagramError::Magic(*b"F\0\0\0"))
        );
        assert_eq!(
            parse_datagram(&b[..3]),
            Err(DatagramError::Magic(*b"FSP\0"))
        );
        // Magic (and version) present: the length is named.
        for n in 4..POSE_LEN {
            assert_eq!(
                parse_datagram(&b[..n]),
                Err(DatagramError::Length { got: n }),
                "{n} bytes"
            );
        }
        assert!(parse_datagram(&b).is_ok());
        // One byte too many is as wrong as one too few.
        let mut long = b.to_vec();
        long.push(0);
        assert_eq!(
            parse_datagram(&long),
            Err(DatagramError::Length { got: 81 })
        );
        // A truncated JSON pose: every proper prefix fails.
        let json = br#"{"instrument":"left","seq":1,"t_s":0,"p":[0,0,0],"q":[1,0,0,0]}"#;
        for n in 1..json.len() {
            assert!(
                matches!(parse_datagram(&json[..n]), Err(DatagramError::Json(_))),
                "{n} bytes"
            );
        }
    }

    #[test]
    fn wrong_magic_or_version_is_named() {
        let mut b = valid();
        // A force answer looped back to the bridge.
        b[0..4].copy_from_slice(&FORCE_MAGIC);
        assert_eq!(parse_datagram(&b), Err(DatagramError::Magic(*b"FSF1")));
        b[0..4].copy_from_slice(b"fsp1");
        assert_eq!(parse_datagram(&b), Err(DatagramError::Magic(*b"fsp1")));
        assert_eq!(parse_datagram(b"XY"), Err(DatagramError::Magic(*b"XY\0\0")));
        for v in [0u8, 2, 255] {
            let mut b = valid();
            b[4] = v;
            assert_eq!(parse_datagram(&b), Err(DatagramError::Version(v)));
            // The version is checked before the length.
            assert_eq!(parse_datagram(&b[..10]), Err(DatagramError::Version(v)));
        }
        // The reserved bytes are not checked.
        let mut b = valid();
        b[6] = 0xff;
        b[7] = 0x01;
        assert_eq!(parse_datagram(&b), parse_datagram(&valid()));
        let e = parse_datagram(b"FSF1\x01").unwrap_err().to_string();
        assert!(e.contains("FSP1") && e.contains("[46, 53, 46, 31]"), "{e}");
    }

    #[test]
    fn nan_and_infinite_values_are_passed_on_bit_for_bit() {
        // Binary: the parser does not range-check; the server rejects such a
        // pose naming the field, and the bridge relays that answer.
        let nan = f64::from_bits(0x7ff8_0000_dead_beef);
        let b = encode_pose(
            3,
            u64::MAX,
            f64::NEG_INFINITY,
            [nan, f64::INFINITY, f64::MIN_POSITIVE / 4.0],
            [0.0, 0.0, 0.0, 0.0],
        );
        let d = parse_datagram(&b).unwrap();
        assert_eq!(d.instrument, InstrumentRef::Index(3));
        assert_eq!(d.sequence, u64::MAX);
        assert_eq!(d.t_s, f64::NEG_INFINITY);
        assert_eq!(d.position_m[0].to_bits(), nan.to_bits());
        assert_eq!(d.position_m[1], f64::INFINITY);
        assert_eq!(
            d.position_m[2].to_bits(),
            (f64::MIN_POSITIVE / 4.0).to_bits()
        );
        assert_eq!(d.orientation, [0.0; 4]);
        let s = pose_sample(&d);
        assert!(s.position_m.unwrap().x.is_nan());
        // JSON has no NaN or infinity; a number beyond f64 is an error too.
        for bad in [
            br#"{"i":0,"seq":1,"t_s":NaN,"p":[0,0,0],"q":[1,0,0,0]}"#.as_slice(),
            br#"{"i":0,"seq":1,"t_s":0,"p":[Infinity,0,0],"q":[1,0,0,0]}"#,
            br#"{"i":0,"seq":1,"t_s":0,"p":[0,0,0],"q":[1e400,0,0,0]}"#,
            br#"{"i":0,"seq":1,"t_s":0,"p":[0,0,-1e309],"q":[1,0,0,0]}"#,
            br#"{"i":0,"seq":1,"t_s":"nan","p":[0,0,0],"q":[1,0,0,0]}"#,
        ] {
            json_error(bad);
        }
        // The extremes of f64 are fine.
        let d = parse_datagram(
            br#"{"i":0,"seq":1,"t_s":1.7976931348623157e308,"p":[5e-324,0,-0.0],"q":[1,0,0,0]}"#,
        )
        .unwrap();
        assert_eq!(d.t_s, f64::MAX);
        assert_eq!(d.position_m[0], 5e-324);
        assert!(d.position_m[2].is_sign_negative());
    }

    #[test]
    fn oversized_datagrams_are_refused() {
        let mut b = valid().to_vec();
        b.resize(MAX_DATAGRAM + 1, 0);
        assert_eq!(
            parse_datagram(&b),
            Err(DatagramError::TooLong {
                got: MAX_DATAGRAM + 1
            })
        );
        // A JSON pose padded to the limit parses; one byte more does not.
        let json = br#"{"instrument":"left","seq":1,"t_s":0,"p":[0,0,0],"q":[1,0,0,0]}"#;
        let mut j = json.to_vec();
        j.resize(MAX_DATAGRAM, b' ');
        assert_eq!(
            parse_datagram(&j).unwrap().instrument,
            InstrumentRef::Name("left")
        );
        j.push(b'\n');
        assert_eq!(
            parse_datagram(&j),
            Err(DatagramError::TooLong {
                got: MAX_DATAGRAM + 1
            })
        );
        // 64 KiB (the largest UDP payload) of anything.
        assert_eq!(
            parse_datagram(&vec![b'{'; 65_507]),
            Err(DatagramError::TooLong { got: 65_507 })
        );
        assert!(
            DatagramError::TooLong { got: 1025 }
                .to_string()
                .contains("1024-byte limit")
        );
    }

    #[test]
    fn malformed_json_poses_are_named() {
        let cases: [(&[u8], &str); 13] = [
            (
                br#"{"seq":1,"t_s":0,"p":[0,0,0],"q":[1,0,0,0]}"#,
                "exactly one",
            ),
            (
                br#"{"instrument":"left","i":0,"seq":1,"t_s":0,"p":[0,0,0],"q":[1,0,0,0]}"#,
                "exactly one",
            ),
            (
                br#"{"i":0,"t_s":0,"p":[0,0,0],"q":[1,0,0,0]}"#,
                "missing field `seq`",
            ),
            (
                br#"{"i":0,"seq":1,"p":[0,0,0],"q":[1,0,0,0]}"#,
                "missing field `t_s`",
            ),
            (
                br#"{"i":0,"seq":1,"t_s":0,"p":[0,0],"q":[1,0,0,0]}"#,
                "array of length 3",
            ),
            (
                br#"{"i":0,"seq":1,"t_s":0,"p":[0,0,0],"q":[1,0,0,0,0]}"#,
                "trailing",
            ),
            (
                br#"{"i":256,"seq":1,"t_s":0,"p":[0,0,0],"q":[1,0,0,0]}"#,
                "256",
            ),
            (
                br#"{"i":0,"seq":-1,"t_s":0,"p":[0,0,0],"q":[1,0,0,0]}"#,
                "-1",
            ),
            (
                br#"{"i":0,"seq":1,"t_s":0,"p":[0,0,0],"q":[1,0,0,0],"x":1}"#,
                "unknown field `x`",
            ),
            (
                br#"{"i":0,"i":1,"seq":1,"t_s":0,"p":[0,0,0],"q":[1,0,0,0]}"#,
                "duplicate field `i`",
            ),
            (
                br#"{"i":0,"seq":1,"t_s":0,"p":[0,0,0],"q":[1,0,0,0]} {"#,
                "trailing characters",
            ),
            (
                br#"{"instrument":"le\"ft","seq":1,"t_s":0,"p":[0,0,0],"q":[1,0,0,0]}"#,
                "borrowed",
            ),
            (
                b"{\"instrument\":\"\xff\",\"seq\":1,\"t_s\":0,\"p\":[0,0,0],\"q\":[1,0,0,0]}",
                "invalid unicode",
            ),
        ];
        for (bytes, says) in cases {
            let m = json_error(bytes);
            assert!(
                m.contains(says),
                "{}: {m:?} should say {says:?}",
                String::from_utf8_lossy(bytes)
            );
        }
    }

    /// A tie datagram reads back as written, its unknowns NaN; the JSON
    /// line names the tie, its kind and cause, and a tie released unseen
    /// says only that.
    #[test]
    fn tie_events_encode_and_read_back() {
        use crate::client::bridge::ties::{TieHow, TieNotice};
        let n = TieNotice {
            tie: 41,
            kind: Some(pb::TieKind::Vessel),
            how: TieHow::Torn,
            instrument: "spatula".into(),
            sim_time_s: 1.28,
            position_m: [-0.055, 0.023, 0.001],
            strain: 0.51,
        };
        let d = TieDatagram::of(&n, Some(1));
        let mut b = [0u8; TIE_LEN];
        encode_tie(&d, &mut b);
        assert_eq!(&b[0..4], b"FST1");
        assert_eq!(decode_tie(&b), Some(d));
        assert_eq!((d.instrument, d.kind, d.cause, d.tie), (1, 2, 2, 41));
        assert_eq!(decode_tie(&b[..TIE_LEN - 1]), None);
        assert_eq!(
            decode_force(&b),
            None,
            "a tie datagram is not a force answer"
        );
        let mut json = Vec::new();
        encode_tie_json(&n, &mut json).unwrap();
        assert_eq!(
            String::from_utf8(json.clone()).unwrap(),
            "{\"event\":\"tie\",\"tie\":41,\"cause\":\"torn\",\"kind\":\"vessel\",\"instrument\":\"spatula\",\"t_s\":1.28,\"p\":[-5.5e-2,2.3e-2,1e-3],\"strain\":5.1e-1}\n"
        );
        let unseen = TieNotice {
            kind: None,
            how: TieHow::Released,
            instrument: String::new(),
            sim_time_s: f64::NAN,
            position_m: [f64::NAN; 3],
            strain: f64::NAN,
            ..n
        };
        let d = TieDatagram::of(&unseen, None);
        encode_tie(&d, &mut b);
        let back = decode_tie(&b).unwrap();
        assert_eq!((back.instrument, back.kind, back.cause), (255, 0, 0));
        assert!(back.t_s.is_nan() && back.strain.is_nan());
        encode_tie_json(&unseen, &mut json).unwrap();
        assert_eq!(
            String::from_utf8(json).unwrap(),
            "{\"event\":\"tie\",\"tie\":41,\"cause\":\"released\"}\n"
        );
    }

    #[test]
    fn json_pose_parses() {
        let d = parse_datagram(
            b" {\"instrument\":\"right\",\"seq\":7,\"t_s\":0.007,\"p\":[0.1,0.2,0.3],\"q\":[0,1,0,0]}\n",
        )
        .unwrap();
        assert_eq!(d.format, Format::Json);
        assert_eq!(d.instrument, InstrumentRef::Name("right"));
        assert_eq!((d.sequence, d.t_s), (7, 0.007));
        assert_eq!(d.orientation, [0.0, 1.0, 0.0, 0.0]);
        let d =
            parse_datagram(br#"{"i":1,"seq":8,"t_s":0.008,"p":[0,0,0],"q":[1,0,0,0]}"#).unwrap();
        assert_eq!(d.instrument, InstrumentRef::Index(1));
    }

    #[test]
    fn parse_never_panics_on_arbitrary_bytes() {
        // A deterministic xorshift stream of lengths and bytes, plus every
        // prefix and single-byte corruption of valid datagrams.
        let mut s: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut next = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        let mut buf = [0u8; 200];
        for _ in 0..20_000 {
            let n = (next() % 200) as usize;
            for b in &mut buf[..n] {
                *b = next() as u8;
            }
            let _ = parse_datagram(&buf[..n]);
        }
        let bin = encode_pose(0, 1, 0.0, [0.0; 3], [1.0, 0.0, 0.0, 0.0]);
        let json = br#"{"instrument":"left","seq":1,"t_s":0,"p":[0,0,0],"q":[1,0,0,0]}"#;
        for v in [&bin[..], &json[..]] {
            for n in 0..=v.len() {
                let _ = parse_datagram(&v[..n]);
            }
            for k in 0..v.len() {
                let mut c = v.to_vec();
                c[k] ^= next() as u8 | 1;
                let _ = parse_datagram(&c);
            }
        }
    }

    #[test]
    fn force_encodings() {
        let f = ForceDatagram {
            instrument: 1,
            status: 0,
            sequence: 9,
            t_s: 0.009,
            force_n: [0.1, -0.2, 0.3],
            torque_nm: [0.0, 1e-4, 0.0],
            contact_count: 5,
            safety_flags: 1,
            model_frame: 3,
            model_age_s: 0.002,
            server_compute_us: 35.0,
        };
        let mut b = [0u8; FORCE_LEN];
        encode_force(&f, &mut b);
        assert_eq!(decode_force(&b), Some(f));
        let mut json = Vec::new();
        encode_force_json(&f, "le\"ft", Some("bad\nquat"), &mut json).unwrap();
        let v: serde_json::Value = serde_json::from_slice(&json).unwrap();
        assert_eq!(v["instrument"], "le\"ft");
        assert_eq!(v["f"][1], -0.2);
        assert_eq!(v["contacts"], 5);
        assert_eq!(v["status"], "ok");
        assert_eq!(v["message"], "bad\nquat");
        assert_eq!(*json.last().unwrap(), b'\n');
    }

    /// An alert round-trips through its binary layout, and its JSON line
    /// parses with the fields named.
    #[test]
    fn an_alert_round_trips_and_its_json_line_parses() {
        use fissure_shared::assessment::Grade;
        let alert = crate::client::report::assess::Alert {
            t_s: 1.25,
            measure: "mean retraction pressure",
            instrument: Some("left".into()),
            value: 2700.0,
            unit: "Pa",
            grade: Grade::Warn,
            level: 2666.4,
        };
        let d = AlertDatagram::of(&alert, Some(0));
        let mut b = [0u8; ALERT_LEN];
        encode_alert(&d, &mut b);
        assert_eq!(&b[0..4], b"FSA1");
        assert_eq!(decode_alert(&b), Some(d));
        assert_eq!((d.grade, d.measure, d.instrument), (1, 1, 0));
        assert_eq!(decode_alert(&b[..ALERT_LEN - 1]), None);
        let mut json = Vec::new();
        encode_alert_json(&alert, &mut json).unwrap();
        let v: serde_json::Value = serde_json::from_slice(&json).unwrap();
        assert_eq!(v["event"], "assessment");
        assert_eq!(v["grade"], "warn");
        assert_eq!(v["instrument"], "left");
        assert_eq!(v["value"], 2700.0);
    }
}
