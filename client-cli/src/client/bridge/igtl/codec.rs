//! OpenIGTLink messages: the 58-byte header, its CRC-64, and the bodies the
//! bridge reads (TRANSFORM, POSITION) and writes (SENSOR, STATUS, POLYDATA),
//! each read as well as written so that the round trips are tested.
//!
//! Written here rather than taken from the `openigtlink-rust` crate (0.4.1,
//! MIT), which does not hold up on either count that matters here. Its
//! POLYDATA is not the protocol's: it writes and reads a count before each
//! array instead of the ten-field POLYDATA header, so neither Slicer nor
//! the reference library can read the surface it would send. On bad input
//! it can panic or abort: the body end is `58 + body_size` unchecked (a
//! huge size wraps), the content size of a version-3 body is a subtraction
//! of the metadata sizes unchecked, and POLYDATA reserves the declared
//! point count before checking the bytes (4 billion points declared in a
//! 40-byte body ask for about 50 GB). It also guesses an extended header from a
//! body's first two bytes whatever the header version says. The formats
//! are small; the layouts below follow the reference C library's headers
//! (`igtl_header.h`, `igtl_sensor.h`, `igtl_unit.h`, `igtl_polydata.h`,
//! `igtlStatusMessage.h`) and are checked against that library and against
//! `pyigtl` in `client-cli/tests/cli/igtl_peers.rs`.
//!
//! Everything is big-endian. Parsing never panics and never allocates more
//! than the bytes at hand justify: every refusal is an [`IgtlError`] naming
//! its cause. The parser is fuzzed (`server/fuzz`, target `igtl`).
//!
//! | offset | type      | header field                                     |
//! |-------:|-----------|--------------------------------------------------|
//! | 0      | u16       | header version: 1 (protocol 1 and 2), 2 (protocol 3, extended header in the body) |
//! | 2      | char[12]  | message type, NUL-padded ASCII                   |
//! | 14     | char[20]  | device name, NUL-padded ASCII                    |
//! | 34     | u64       | timestamp: seconds (high 32 bits) . fraction (low 32 bits, / 2^32) |
//! | 42     | u64       | body size, bytes                                 |
//! | 50     | u64       | CRC-64 (ECMA-182 polynomial, initial 0, not reflected) of the body |

/// Length of a message header, bytes.
pub const HEADER_LEN: usize = 58;
/// Largest body the bridge reads, bytes: a larger declared size ends the
/// connection, since skipping it would stall the reader indefinitely and
/// nothing the bridge consumes comes near it.
pub const MAX_BODY_BYTES: u64 = 16 << 20;
/// Length of a TRANSFORM body, bytes.
pub const TRANSFORM_LEN: usize = 48;
/// Length of the extended header of a version-2 header, bytes.
pub const EXTENDED_HEADER_LEN: usize = 12;
/// Length of the fixed part of a STATUS body, bytes (code, subcode, error name).
pub const STATUS_FIXED_LEN: usize = 30;
/// Length of the fixed part of a SENSOR body, bytes (larray, status, unit).
pub const SENSOR_FIXED_LEN: usize = 10;
/// Length of the POLYDATA header (ten u32 counts and sizes), bytes.
pub const POLYDATA_HEADER_LEN: usize = 40;

/// The CRC-64 generator polynomial of OpenIGTLink (ECMA-182).
pub const CRC64_POLY: u64 = 0x42F0_E1EB_A9EA_3693;

const fn crc_table() -> [u64; 256] {
    let mut t = [0u64; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = (i as u64) << 56;
        let mut k = 0;
        while k < 8 {
            c = if c & (1 << 63) != 0 {
                (c << 1) ^ CRC64_POLY
            } else {
                c << 1
            };
            k += 1;
        }
        t[i] = c;
        i += 1;
    }
    t
}

static CRC_TABLE: [u64; 256] = crc_table();

/// The CRC-64 of `data` as OpenIGTLink computes it (MSB first, initial 0,
/// no final xor).
pub fn crc64(data: &[u8]) -> u64 {
    data.iter().fold(0u64, |crc, &b| {
        CRC_TABLE[((crc >> 56) as u8 ^ b) as usize] ^ (crc << 8)
    })
}

/// Why a message (or its header) was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum IgtlError {
    /// Fewer bytes than a header.
    #[error("header of {got} bytes, expected {HEADER_LEN}")]
    ShortHeader {
        /// Bytes at hand.
        got: usize,
    },
    /// A header version other than 1 or 2.
    #[error("header version {0} is not supported (1 or 2)")]
    Version(u16),
    /// The type field is not NUL-padded printable ASCII.
    #[error("message type {0:?} is not NUL-padded printable ASCII")]
    TypeName(String),
    /// The device name field is not NUL-padded printable ASCII.
    #[error("device name {0:?} is not NUL-padded printable ASCII")]
    DeviceName(String),
    /// The declared body is over [`MAX_BODY_BYTES`].
    #[error("body of {0} bytes is over the {MAX_BODY_BYTES}-byte limit")]
    BodyTooLarge(u64),
    /// The bytes after the header are not the declared body size.
    #[error("body of {got} bytes, the header declares {declared}")]
    BodyLength {
        /// Bytes at hand.
        got: u64,
        /// Bytes declared.
        declared: u64,
    },
    /// The body's CRC does not match the header's.
    #[error("CRC {got:#018x} of the body, the header says {declared:#018x}")]
    Crc {
        /// Computed.
        got: u64,
        /// Declared.
        declared: u64,
    },
    /// A version-2 extended header that does not fit the body.
    #[error("extended header: {0}")]
    ExtendedHeader(&'static str),
    /// A type the codec does not read.
    #[error("message type {0:?} is not read by the bridge")]
    UnknownType(String),
    /// A fixed-size body of the wrong size.
    #[error("{kind} body of {got} bytes, expected {expected}")]
    ContentLength {
        /// Message type.
        kind: &'static str,
        /// Bytes at hand.
        got: usize,
        /// Bytes expected (for POSITION: 12, 24 or 28).
        expected: &'static str,
    },
    /// A number that is NaN or infinite where a finite one is needed.
    #[error("{kind}: {field} is not finite")]
    NotFinite {
        /// Message type.
        kind: &'static str,
        /// Which number.
        field: &'static str,
    },
    /// A TRANSFORM whose 3x3 part is not a rotation.
    #[error("TRANSFORM: the 3x3 part is not a rotation (|R^T R - I| = {0:.3e}, det = {1:.4})")]
    NotRotation(f64, f64),
    /// A SENSOR body whose data does not match its array length.
    #[error("SENSOR: {larray} values declared, {got} bytes of data")]
    SensorLength {
        /// Values declared.
        larray: u8,
        /// Data bytes at hand.
        got: usize,
    },
    /// A STATUS string without its terminating NUL, or not UTF-8.
    #[error("STATUS: {0}")]
    Status(&'static str),
    /// A POLYDATA body that does not hold what its header declares.
    #[error("POLYDATA: {0}")]
    PolyData(String),
}

impl IgtlError {
    /// A short name of the cause (the fuzz corpus's file names use it).
    pub fn kind(&self) -> &'static str {
        match self {
            Self::ShortHeader { .. } => "short-header",
            Self::Version(_) => "version",
            Self::TypeName(_) => "type-name",
            Self::DeviceName(_) => "device-name",
            Self::BodyTooLarge(_) => "body-too-large",
            Self::BodyLength { .. } => "body-length",
            Self::Crc { .. } => "crc",
            Self::ExtendedHeader(_) => "extended-header",
            Self::UnknownType(_) => "unknown-type",
            Self::ContentLength { .. } => "content-length",
            Self::NotFinite { .. } => "not-finite",
            Self::NotRotation(..) => "not-rotation",
            Self::SensorLength { .. } => "sensor-length",
            Self::Status(_) => "status",
            Self::PolyData(_) => "polydata",
        }
    }
}

/// A message header.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    /// Header version (1 or 2).
    pub version: u16,
    /// Message type, NUL-padded.
    pub type_name: [u8; 12],
    /// Device name, NUL-padded.
    pub device_name: [u8; 20],
    /// 32.32 fixed-point seconds (0: the sender gives no time).
    pub timestamp: u64,
    /// Body size, bytes.
    pub body_size: u64,
    /// CRC-64 of the body.
    pub crc: u64,
}

fn field_str(b: &[u8]) -> &str {
    let end = b.iter().position(|&c| c == 0).unwrap_or(b.len());
    // Checked printable ASCII by `parse_header`; the fallback is for
    // headers built by hand.
    std::str::from_utf8(&b[..end]).unwrap_or("")
}

/// Whether `b` is printable ASCII up to its first NUL and NUL after it.
fn padded_ascii(b: &[u8]) -> bool {
    let end = b.iter().position(|&c| c == 0).unwrap_or(b.len());
    b[..end].iter().all(|c| (0x20..0x7f).contains(c)) && b[end..].iter().all(|&c| c == 0)
}

/// Copies `s` into a NUL-padded field; `None` when it does not fit or is
/// not printable ASCII.
pub fn name_field<const N: usize>(s: &str) -> Option<[u8; N]> {
    if s.len() > N || !s.bytes().all(|c| (0x20..0x7f).contains(&c)) {
        return None;
    }
    let mut f = [0u8; N];
    f[..s.len()].copy_from_slice(s.as_bytes());
    Some(f)
}

impl Header {
    /// The message type.
    pub fn type_str(&self) -> &str {
        field_str(&self.type_name)
    }

    /// The device name.
    pub fn device(&self) -> &str {
        field_str(&self.device_name)
    }

    /// The timestamp, s (0 when the sender gives none).
    pub fn timestamp_s(&self) -> f64 {
        timestamp_to_s(self.timestamp)
    }

    /// Writes the header to `out[..HEADER_LEN]`.
    pub fn write(&self, out: &mut [u8]) {
        out[0..2].copy_from_slice(&self.version.to_be_bytes());
        out[2..14].copy_from_slice(&self.type_name);
        out[14..34].copy_from_slice(&self.device_name);
        out[34..42].copy_from_slice(&self.timestamp.to_be_bytes());
        out[42..50].copy_from_slice(&self.body_size.to_be_bytes());
        out[50..58].copy_from_slice(&self.crc.to_be_bytes());
    }
}

/// 32.32 fixed-point seconds to seconds.
pub fn timestamp_to_s(ts: u64) -> f64 {
    (ts >> 32) as f64 + (ts & 0xffff_ffff) as f64 / 4_294_967_296.0
}

/// Seconds (0 up to 2^32) to 32.32 fixed point (clamped; NaN gives 0).
pub fn s_to_timestamp(t_s: f64) -> u64 {
    if t_s.is_nan() || t_s <= 0.0 {
        return 0;
    }
    let secs = t_s.floor().min(u32::MAX as f64);
    let frac = ((t_s - secs) * 4_294_967_296.0)
        .round()
        .min(u32::MAX as f64);
    ((secs as u64) << 32) | frac as u64
}

fn u16_at(b: &[u8], at: usize) -> u16 {
    u16::from_be_bytes([b[at], b[at + 1]])
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    let mut a = [0u8; 4];
    a.copy_from_slice(&b[at..at + 4]);
    u32::from_be_bytes(a)
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[at..at + 8]);
    u64::from_be_bytes(a)
}

fn f32_at(b: &[u8], at: usize) -> f32 {
    f32::from_bits(u32_at(b, at))
}

/// Reads a header from `b[..HEADER_LEN]`: the version, the two name fields
/// and the body size are checked; the CRC is checked against the body by
/// [`content`].
pub fn parse_header(b: &[u8]) -> Result<Header, IgtlError> {
    if b.len() < HEADER_LEN {
        return Err(IgtlError::ShortHeader { got: b.len() });
    }
    let version = u16_at(b, 0);
    if version != 1 && version != 2 {
        return Err(IgtlError::Version(version));
    }
    let mut type_name = [0u8; 12];
    type_name.copy_from_slice(&b[2..14]);
    if !padded_ascii(&type_name) || type_name[0] == 0 {
        return Err(IgtlError::TypeName(
            String::from_utf8_lossy(&type_name).into_owned(),
        ));
    }
    let mut device_name = [0u8; 20];
    device_name.copy_from_slice(&b[14..34]);
    if !padded_ascii(&device_name) {
        return Err(IgtlError::DeviceName(
            String::from_utf8_lossy(&device_name).into_owned(),
        ));
    }
    let body_size = u64_at(b, 42);
    if body_size > MAX_BODY_BYTES {
        return Err(IgtlError::BodyTooLarge(body_size));
    }
    Ok(Header {
        version,
        type_name,
        device_name,
        timestamp: u64_at(b, 34),
        body_size,
        crc: u64_at(b, 50),
    })
}

/// Checks `body` against `h` (its size and CRC) and returns the content:
/// the whole body for header version 1; for version 2 the part between the
/// extended header and the metadata.
pub fn content<'a>(h: &Header, body: &'a [u8]) -> Result<&'a [u8], IgtlError> {
    if body.len() as u64 != h.body_size {
        return Err(IgtlError::BodyLength {
            got: body.len() as u64,
            declared: h.body_size,
        });
    }
    let got = crc64(body);
    if got != h.crc {
        return Err(IgtlError::Crc {
            got,
            declared: h.crc,
        });
    }
    if h.version == 1 {
        return Ok(body);
    }
    if body.len() < EXTENDED_HEADER_LEN {
        return Err(IgtlError::ExtendedHeader("shorter than 12 bytes"));
    }
    let ext = u16_at(body, 0) as usize;
    let meta_header = u16_at(body, 2) as usize;
    let meta = u32_at(body, 4) as usize;
    if ext < EXTENDED_HEADER_LEN {
        return Err(IgtlError::ExtendedHeader("its size is under 12 bytes"));
    }
    let end = body
        .len()
        .checked_sub(meta_header)
        .and_then(|e| e.checked_sub(meta))
        .filter(|&e| e >= ext)
        .ok_or(IgtlError::ExtendedHeader(
            "the extended header and the metadata are larger than the body",
        ))?;
    Ok(&body[ext..end])
}

/// A TRANSFORM: the upper 3x4 of a homogeneous transform, sender units
/// (millimetres by convention).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Transform {
    /// Rotation, `rotation[row][col]`.
    pub rotation: [[f32; 3]; 3],
    /// Translation.
    pub translation: [f32; 3],
}

/// A POSITION: a position and an orientation quaternion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Position {
    /// Position, sender units.
    pub position: [f32; 3],
    /// Quaternion `[x, y, z, w]` (OpenIGTLink's order; `[0, 0, 0, 1]`
    /// for a 12-byte body, `w` completed for a 24-byte body).
    pub quaternion: [f32; 4],
}

/// A SENSOR reading.
#[derive(Debug, Clone, PartialEq)]
pub struct Sensor {
    /// Sensor status (reserved by the protocol; the bridge writes 0).
    pub status: u8,
    /// Unit ([`Unit::pack`]).
    pub unit: u64,
    /// The values.
    pub data: Vec<f64>,
}

/// A STATUS.
#[derive(Debug, Clone, PartialEq)]
pub struct StatusMsg {
    /// Status code (1 = OK; [`status_code`]).
    pub code: u16,
    /// Device-specific subcode.
    pub subcode: i64,
    /// Error name (at most 20 bytes).
    pub error_name: String,
    /// Status text.
    pub message: String,
}

/// Status codes of OpenIGTLink STATUS messages used by the bridge.
pub mod status_code {
    /// Success.
    pub const OK: u16 = 1;
    /// An error not covered by the other codes.
    pub const UNKNOWN_ERROR: u16 = 2;
    /// File, configuration or device not found.
    pub const NOT_FOUND: u16 = 4;
    /// Busy.
    pub const BUSY: u16 = 6;
}

/// A cell array of POLYDATA: `count` cells, each `n i0 .. i(n-1)`.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Cells {
    /// Number of cells.
    pub count: u32,
    /// The flattened cells.
    pub data: Vec<u32>,
}

impl Cells {
    /// Triangles as a POLYGONS cell array.
    pub fn triangles(tris: &[[u32; 3]]) -> Self {
        let mut data = Vec::with_capacity(tris.len() * 4);
        for t in tris {
            data.extend_from_slice(&[3, t[0], t[1], t[2]]);
        }
        Self {
            count: tris.len() as u32,
            data,
        }
    }
}

/// A POLYDATA attribute.
#[derive(Debug, Clone, PartialEq)]
pub struct Attribute {
    /// Type (0x00-0x04 point data, 0x10-0x14 cell data).
    pub kind: u8,
    /// Components per value.
    pub components: u8,
    /// Number of values.
    pub n: u32,
    /// Name.
    pub name: String,
    /// `n * components` values.
    pub data: Vec<f32>,
}

/// A POLYDATA.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PolyData {
    /// Points, sender units.
    pub points: Vec<[f32; 3]>,
    /// VERTICES cells.
    pub vertices: Cells,
    /// LINES cells.
    pub lines: Cells,
    /// POLYGONS cells.
    pub polygons: Cells,
    /// TRIANGLE_STRIPS cells.
    pub strips: Cells,
    /// Attributes.
    pub attributes: Vec<Attribute>,
}

/// A message body the codec reads.
#[derive(Debug, Clone, PartialEq)]
pub enum Body {
    /// TRANSFORM.
    Transform(Transform),
    /// POSITION.
    Position(Position),
    /// SENSOR.
    Sensor(Sensor),
    /// STATUS.
    Status(StatusMsg),
    /// POLYDATA.
    PolyData(PolyData),
}

/// Reads the content of a message of type `kind`.
pub fn parse_content(kind: &str, c: &[u8]) -> Result<Body, IgtlError> {
    match kind {
        "TRANSFORM" => parse_transform(c).map(Body::Transform),
        "POSITION" => parse_position(c).map(Body::Position),
        "SENSOR" => parse_sensor(c).map(Body::Sensor),
        "STATUS" => parse_status(c).map(Body::Status),
        "POLYDATA" => parse_polydata(c).map(Body::PolyData),
        other => Err(IgtlError::UnknownType(other.to_owned())),
    }
}

/// Reads one whole message (header and body, nothing after it).
pub fn parse_message(b: &[u8]) -> Result<(Header, Body), IgtlError> {
    let h = parse_header(b)?;
    let c = content(&h, &b[HEADER_LEN..])?;
    Ok((h, parse_content(h.type_str(), c)?))
}

/// Reads a TRANSFORM body (12 f32: the rotation's columns, then the
/// translation); the numbers must be finite and the 3x3 part a rotation
/// within 1e-3.
pub fn parse_transform(c: &[u8]) -> Result<Transform, IgtlError> {
    if c.len() != TRANSFORM_LEN {
        return Err(IgtlError::ContentLength {
            kind: "TRANSFORM",
            got: c.len(),
            expected: "48",
        });
    }
    let v: [f32; 12] = std::array::from_fn(|i| f32_at(c, 4 * i));
    if v.iter().any(|x| !x.is_finite()) {
        return Err(IgtlError::NotFinite {
            kind: "TRANSFORM",
            field: "a matrix element",
        });
    }
    let mut rotation = [[0f32; 3]; 3];
    for (col, chunk) in v[..9].chunks_exact(3).enumerate() {
        for (row, &x) in chunk.iter().enumerate() {
            rotation[row][col] = x;
        }
    }
    let m = nalgebra::Matrix3::from_fn(|r, c| rotation[r][c] as f64);
    let err = (m.transpose() * m - nalgebra::Matrix3::identity())
        .abs()
        .max();
    let det = m.determinant();
    if err > 1e-3 || (det - 1.0).abs() > 1e-3 {
        return Err(IgtlError::NotRotation(err, det));
    }
    Ok(Transform {
        rotation,
        translation: [v[9], v[10], v[11]],
    })
}

/// Writes a TRANSFORM body.
pub fn transform_content(t: &Transform, out: &mut Vec<u8>) {
    for col in 0..3 {
        for row in 0..3 {
            out.extend_from_slice(&t.rotation[row][col].to_be_bytes());
        }
    }
    for x in t.translation {
        out.extend_from_slice(&x.to_be_bytes());
    }
}

/// Reads a POSITION body: 12 bytes (position), 24 (and x, y, z of the
/// quaternion; w >= 0 completes it) or 28 (the whole quaternion).
pub fn parse_position(c: &[u8]) -> Result<Position, IgtlError> {
    let n = match c.len() {
        12 => 3,
        24 => 6,
        28 => 7,
        got => {
            return Err(IgtlError::ContentLength {
                kind: "POSITION",
                got,
                expected: "12, 24 or 28",
            });
        }
    };
    let v: Vec<f32> = (0..n).map(|i| f32_at(c, 4 * i)).collect();
    if v.iter().any(|x| !x.is_finite()) {
        return Err(IgtlError::NotFinite {
            kind: "POSITION",
            field: "a coordinate",
        });
    }
    let quaternion = match n {
        3 => [0.0, 0.0, 0.0, 1.0],
        6 => {
            let s = v[3] * v[3] + v[4] * v[4] + v[5] * v[5];
            if s > 1.0 + 1e-3 {
                return Err(IgtlError::NotFinite {
                    kind: "POSITION",
                    field: "the quaternion's w (x^2 + y^2 + z^2 > 1)",
                });
            }
            [v[3], v[4], v[5], (1.0 - s).max(0.0).sqrt()]
        }
        _ => [v[3], v[4], v[5], v[6]],
    };
    Ok(Position {
        position: [v[0], v[1], v[2]],
        quaternion,
    })
}

/// Writes a 28-byte POSITION body.
pub fn position_content(p: &Position, out: &mut Vec<u8>) {
    for x in p.position.iter().chain(&p.quaternion) {
        out.extend_from_slice(&x.to_be_bytes());
    }
}

/// An OpenIGTLink unit: a prefix and up to six SI units with exponents,
/// packed in 64 bits (`igtl_unit.h`: prefix in bits 63-60, then six 10-bit
/// fields, each a 6-bit unit and a 4-bit two's-complement exponent).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Unit {
    /// Prefix (0 none, 0xB milli, ...).
    pub prefix: u8,
    /// Units and exponents (unit 0 ends the list).
    pub units: [(u8, i8); 6],
}

impl Unit {
    /// SI base unit: metre.
    pub const METER: u8 = 0x01;
    /// SI derived unit: newton.
    pub const NEWTON: u8 = 0x0B;

    /// Newton.
    pub const fn newton() -> Self {
        Self {
            prefix: 0,
            units: [(Self::NEWTON, 1), (0, 0), (0, 0), (0, 0), (0, 0), (0, 0)],
        }
    }

    /// Newton metre.
    pub const fn newton_meter() -> Self {
        Self {
            prefix: 0,
            units: [
                (Self::NEWTON, 1),
                (Self::METER, 1),
                (0, 0),
                (0, 0),
                (0, 0),
                (0, 0),
            ],
        }
    }

    /// The 64-bit encoding.
    pub fn pack(&self) -> u64 {
        let mut p = ((self.prefix & 0xf) as u64) << 60;
        for (i, &(u, e)) in self.units.iter().enumerate() {
            let field = (((u & 0x3f) as u64) << 4) | ((e as u8 & 0xf) as u64);
            p |= field << ((5 - i) * 10);
        }
        p
    }

    /// Decodes the 64-bit encoding.
    pub fn unpack(p: u64) -> Self {
        let mut units = [(0u8, 0i8); 6];
        for (i, u) in units.iter_mut().enumerate() {
            let field = (p >> ((5 - i) * 10)) & 0x3ff;
            let e = (field & 0xf) as i8;
            *u = ((field >> 4) as u8, if e >= 8 { e - 16 } else { e });
        }
        Self {
            prefix: (p >> 60) as u8,
            units,
        }
    }
}

/// Reads a SENSOR body (larray u8, status u8, unit u64, larray f64).
pub fn parse_sensor(c: &[u8]) -> Result<Sensor, IgtlError> {
    if c.len() < SENSOR_FIXED_LEN {
        return Err(IgtlError::ContentLength {
            kind: "SENSOR",
            got: c.len(),
            expected: "at least 10",
        });
    }
    let larray = c[0];
    let data = &c[SENSOR_FIXED_LEN..];
    if data.len() != larray as usize * 8 {
        return Err(IgtlError::SensorLength {
            larray,
            got: data.len(),
        });
    }
    Ok(Sensor {
        status: c[1],
        unit: u64_at(c, 2),
        data: data
            .chunks_exact(8)
            .map(|b| f64::from_bits(u64_at(b, 0)))
            .collect(),
    })
}

/// Writes a SENSOR body; at most 255 values (the rest are not written).
pub fn sensor_content(status: u8, unit: u64, data: &[f64], out: &mut Vec<u8>) {
    let data = &data[..data.len().min(255)];
    out.push(data.len() as u8);
    out.push(status);
    out.extend_from_slice(&unit.to_be_bytes());
    for x in data {
        out.extend_from_slice(&x.to_be_bytes());
    }
}

/// Reads a STATUS body (code u16, subcode i64, error name char[20], a
/// NUL-terminated string).
pub fn parse_status(c: &[u8]) -> Result<StatusMsg, IgtlError> {
    if c.len() < STATUS_FIXED_LEN + 1 {
        return Err(IgtlError::ContentLength {
            kind: "STATUS",
            got: c.len(),
            expected: "at least 31",
        });
    }
    let text = &c[STATUS_FIXED_LEN..];
    let end = text.iter().position(|&b| b == 0).ok_or(IgtlError::Status(
        "the status string has no terminating NUL",
    ))?;
    let name = &c[10..30];
    let name_end = name.iter().position(|&b| b == 0).unwrap_or(name.len());
    Ok(StatusMsg {
        code: u16_at(c, 0),
        subcode: u64_at(c, 2) as i64,
        error_name: std::str::from_utf8(&name[..name_end])
            .map_err(|_| IgtlError::Status("the error name is not UTF-8"))?
            .to_owned(),
        message: std::str::from_utf8(&text[..end])
            .map_err(|_| IgtlError::Status("the status string is not UTF-8"))?
            .to_owned(),
    })
}

/// Writes a STATUS body (the error name cut to 20 bytes, the text NUL-terminated).
pub fn status_content(s: &StatusMsg, out: &mut Vec<u8>) {
    out.extend_from_slice(&s.code.to_be_bytes());
    out.extend_from_slice(&s.subcode.to_be_bytes());
    let mut name = [0u8; 20];
    let n = floor_char_boundary(&s.error_name, 20);
    name[..n].copy_from_slice(&s.error_name.as_bytes()[..n]);
    out.extend_from_slice(&name);
    out.extend(s.message.bytes().filter(|&b| b != 0));
    out.push(0);
}

fn floor_char_boundary(s: &str, max: usize) -> usize {
    let mut n = s.len().min(max);
    while !s.is_char_boundary(n) {
        n -= 1;
    }
    n
}

fn polydata_err(what: impl Into<String>) -> IgtlError {
    IgtlError::PolyData(what.into())
}

/// Reads a cell array of `count` cells in `size` bytes at `c[at..]`,
/// checking every cell's length and indices.
fn parse_cells(
    c: &[u8],
    at: usize,
    count: u32,
    size: u32,
    npoints: u32,
    what: &str,
) -> Result<Cells, IgtlError> {
    if size % 4 != 0 {
        return Err(polydata_err(format!(
            "{what}: {size} bytes is not a whole number of u32"
        )));
    }
    let words = size as usize / 4;
    // Each cell takes at least its length word.
    if (count as usize) > words {
        return Err(polydata_err(format!(
            "{what}: {count} cells cannot fit in {words} words"
        )));
    }
    let mut data = Vec::with_capacity(words);
    data.extend((0..words).map(|i| u32_at(c, at + 4 * i)));
    let (mut i, mut cells) = (0usize, 0u32);
    while i < data.len() {
        let n = data[i] as usize;
        if n > data.len() - i - 1 {
            return Err(polydata_err(format!(
                "{what}: cell {cells} declares {n} points past the end of the array"
            )));
        }
        if let Some(&bad) = data[i + 1..i + 1 + n].iter().find(|&&p| p >= npoints) {
            return Err(polydata_err(format!(
                "{what}: cell {cells} uses point {bad} of {npoints}"
            )));
        }
        i += n + 1;
        cells += 1;
    }
    if cells != count {
        return Err(polydata_err(format!(
            "{what}: {cells} cells in the array, {count} declared"
        )));
    }
    Ok(Cells { count, data })
}

/// Reads a POLYDATA body. Every count is checked against the bytes present
/// before anything is allocated.
pub fn parse_polydata(c: &[u8]) -> Result<PolyData, IgtlError> {
    if c.len() < POLYDATA_HEADER_LEN {
        return Err(IgtlError::ContentLength {
            kind: "POLYDATA",
            got: c.len(),
            expected: "at least 40",
        });
    }
    let h: [u32; 10] = std::array::from_fn(|i| u32_at(c, 4 * i));
    let [
        npoints,
        nvert,
        svert,
        nlines,
        slines,
        npoly,
        spoly,
        nstrips,
        sstrips,
        nattr,
    ] = h;
    let fixed = [
        npoints as u64 * 12,
        svert as u64,
        slines as u64,
        spoly as u64,
        sstrips as u64,
    ];
    let mut at = POLYDATA_HEADER_LEN as u64;
    for s in fixed {
        at += s;
    }
    let attr_headers = nattr as u64 * 6;
    if at + attr_headers > c.len() as u64 {
        return Err(polydata_err(format!(
            "{npoints} points, cells of {} bytes and {nattr} attributes need more than the {} bytes of the body",
            svert as u64 + slines as u64 + spoly as u64 + sstrips as u64,
            c.len()
        )));
    }
    let mut at = POLYDATA_HEADER_LEN;
    let mut points = Vec::with_capacity(npoints as usize);
    for i in 0..npoints as usize {
        let p = [
            f32_at(c, at + 12 * i),
            f32_at(c, at + 12 * i + 4),
            f32_at(c, at + 12 * i + 8),
        ];
        if p.iter().any(|x| !x.is_finite()) {
            return Err(polydata_err(format!("point {i} is not finite")));
        }
        points.push(p);
    }
    at += npoints as usize * 12;
    let mut cells = Vec::with_capacity(4);
    for (count, size, what) in [
        (nvert, svert, "VERTICES"),
        (nlines, slines, "LINES"),
        (npoly, spoly, "POLYGONS"),
        (nstrips, sstrips, "TRIANGLE_STRIPS"),
    ] {
        cells.push(parse_cells(c, at, count, size, npoints, what)?);
        at += size as usize;
    }
    let mut heads = Vec::with_capacity(nattr as usize);
    for i in 0..nattr as usize {
        let b = at + 6 * i;
        heads.push((c[b], c[b + 1], u32_at(c, b + 2)));
    }
    at += nattr as usize * 6;
    // Names: NUL-terminated, the whole run padded to an even length.
    let mut names = Vec::with_capacity(nattr as usize);
    for i in 0..nattr {
        let rest = &c[at..];
        let end = rest
            .iter()
            .position(|&b| b == 0)
            .ok_or_else(|| polydata_err(format!("attribute {i}: its name has no NUL")))?;
        let name = std::str::from_utf8(&rest[..end])
            .map_err(|_| polydata_err(format!("attribute {i}: its name is not UTF-8")))?;
        names.push(name.to_owned());
        at += end + 1;
    }
    if nattr > 0 && at % 2 != 0 {
        at += 1;
    }
    let mut attributes = Vec::with_capacity(nattr as usize);
    for (i, ((kind, components, n), name)) in heads.into_iter().zip(names).enumerate() {
        if !matches!(kind, 0x00..=0x04 | 0x10..=0x14) {
            return Err(polydata_err(format!(
                "attribute {i}: unknown type {kind:#04x}"
            )));
        }
        let values = n as u64 * components as u64;
        if at as u64 + values * 4 > c.len() as u64 {
            return Err(polydata_err(format!(
                "attribute {i} ({name}): {n} x {components} values past the end of the body"
            )));
        }
        let data = (0..values as usize)
            .map(|k| f32_at(c, at + 4 * k))
            .collect();
        at += values as usize * 4;
        attributes.push(Attribute {
            kind,
            components,
            n,
            name,
            data,
        });
    }
    if at > c.len() {
        return Err(polydata_err(
            "the attribute names run past the end of the body",
        ));
    }
    if at != c.len() {
        return Err(polydata_err(format!(
            "{} bytes left after the declared content",
            c.len() - at
        )));
    }
    let mut cells = cells.into_iter();
    let mut next = || cells.next().unwrap_or_default();
    Ok(PolyData {
        points,
        vertices: next(),
        lines: next(),
        polygons: next(),
        strips: next(),
        attributes,
    })
}

/// Writes a POLYDATA body with points from `points` (x y z flattened) and
/// the given polygons (attributes are not written).
pub fn polydata_content(points: &[f32], polygons: &Cells, strips: &Cells, out: &mut Vec<u8>) {
    let npoints = (points.len() / 3) as u32;
    let words = |c: &Cells| (c.data.len() * 4) as u32;
    for v in [
        npoints,
        0,
        0,
        0,
        0,
        polygons.count,
        words(polygons),
        strips.count,
        words(strips),
        0,
    ] {
        out.extend_from_slice(&v.to_be_bytes());
    }
    for x in &points[..npoints as usize * 3] {
        out.extend_from_slice(&x.to_be_bytes());
    }
    for c in [polygons, strips] {
        for v in &c.data {
            out.extend_from_slice(&v.to_be_bytes());
        }
    }
}

/// Writes a whole version-1 message into `out` (cleared first): the body
/// by `body`, then the header with its size and CRC filled in. `type_name`
/// and `device` must be NUL-padded fields.
pub fn write_message(
    out: &mut Vec<u8>,
    type_name: [u8; 12],
    device: [u8; 20],
    timestamp: u64,
    body: impl FnOnce(&mut Vec<u8>),
) {
    out.clear();
    append_message(out, type_name, device, timestamp, body);
}

/// [`write_message`] after what `out` already holds (several messages in
/// one buffer, sent with one write).
pub fn append_message(
    out: &mut Vec<u8>,
    type_name: [u8; 12],
    device: [u8; 20],
    timestamp: u64,
    body: impl FnOnce(&mut Vec<u8>),
) {
    let start = out.len();
    out.resize(start + HEADER_LEN, 0);
    body(out);
    let b = &out[start + HEADER_LEN..];
    let h = Header {
        version: 1,
        type_name,
        device_name: device,
        timestamp,
        body_size: b.len() as u64,
        crc: crc64(b),
    };
    h.write(&mut out[start..start + HEADER_LEN]);
}

/// A NUL-padded type field of a type name the bridge writes.
pub fn type_field(t: &'static str) -> [u8; 12] {
    name_field(t).unwrap_or([0; 12])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn msg(kind: &str, device: &str, ts: u64, body: impl FnOnce(&mut Vec<u8>)) -> Vec<u8> {
        let mut out = Vec::new();
        write_message(
            &mut out,
            name_field(kind).unwrap(),
            name_field(device).unwrap(),
            ts,
            body,
        );
        out
    }

    #[test]
    fn crc64_matches_the_ecma_182_check_value() {
        // The catalogued CRC-64/ECMA-182 check: "123456789".
        assert_eq!(crc64(b"123456789"), 0x6C40_DF5F_0B49_7347);
        assert_eq!(crc64(b""), 0);
        // The table's first entries are the reference library's.
        assert_eq!(CRC_TABLE[1], 0x42F0_E1EB_A9EA_3693);
        assert_eq!(CRC_TABLE[2], 0x85E1_C3D7_53D4_6D26);
    }

    #[test]
    fn appended_messages_parse_one_after_the_other() {
        let mut out = Vec::new();
        append_message(
            &mut out,
            type_field("SENSOR"),
            name_field("a").unwrap(),
            5,
            |o| sensor_content(0, 0, &[1.0], o),
        );
        let first = out.len();
        append_message(
            &mut out,
            type_field("STATUS"),
            name_field("b").unwrap(),
            6,
            |o| {
                status_content(
                    &StatusMsg {
                        code: 1,
                        subcode: 0,
                        error_name: "OK".into(),
                        message: String::new(),
                    },
                    o,
                )
            },
        );
        let (h1, _) = parse_message(&out[..first]).unwrap();
        let (h2, b2) = parse_message(&out[first..]).unwrap();
        assert_eq!((h1.device(), h1.timestamp), ("a", 5));
        assert_eq!((h2.device(), h2.timestamp), ("b", 6));
        assert!(matches!(b2, Body::Status(s) if s.error_name == "OK"));
    }

    #[test]
    fn timestamps_are_32_32_fixed_point() {
        assert_eq!(s_to_timestamp(1.5), (1 << 32) | 0x8000_0000);
        assert_eq!(timestamp_to_s((7 << 32) | 0x4000_0000), 7.25);
        let t = 1_700_000_000.123_456;
        assert!((timestamp_to_s(s_to_timestamp(t)) - t).abs() < 1e-6);
        assert_eq!(s_to_timestamp(f64::NAN), 0);
        assert_eq!(s_to_timestamp(-1.0), 0);
    }

    #[test]
    fn transform_round_trip_keeps_the_column_order() {
        let t = Transform {
            rotation: [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
            translation: [10.0, -20.5, 30.25],
        };
        let b = msg("TRANSFORM", "Tracker", s_to_timestamp(2.5), |o| {
            transform_content(&t, o)
        });
        assert_eq!(b.len(), HEADER_LEN + TRANSFORM_LEN);
        // The first three floats are the first column: R11 R21 R31.
        assert_eq!(f32_at(&b, HEADER_LEN + 4), 1.0);
        assert_eq!(f32_at(&b, HEADER_LEN + 36), 10.0);
        let (h, body) = parse_message(&b).unwrap();
        assert_eq!(
            (h.type_str(), h.device(), h.timestamp_s()),
            ("TRANSFORM", "Tracker", 2.5)
        );
        assert_eq!(body, Body::Transform(t));
    }

    #[test]
    fn position_bodies_of_every_size_are_read() {
        let p = Position {
            position: [1.0, 2.0, 3.0],
            quaternion: [0.0, 0.0, 0.6, 0.8],
        };
        let b = msg("POSITION", "Tool", 0, |o| position_content(&p, o));
        assert_eq!(parse_message(&b).unwrap().1, Body::Position(p));
        let mut c = Vec::new();
        position_content(&p, &mut c);
        let short = parse_position(&c[..24]).unwrap();
        assert!((short.quaternion[3] - 0.8).abs() < 1e-6);
        assert_eq!(
            parse_position(&c[..12]).unwrap().quaternion,
            [0.0, 0.0, 0.0, 1.0]
        );
        assert_eq!(
            parse_position(&c[..20]),
            Err(IgtlError::ContentLength {
                kind: "POSITION",
                got: 20,
                expected: "12, 24 or 28"
            })
        );
    }

    #[test]
    fn sensor_round_trip_and_units() {
        let b = msg("SENSOR", "left_force", 0, |o| {
            sensor_content(0, Unit::newton().pack(), &[0.5, -1.0, 2.0], o)
        });
        let (_, body) = parse_message(&b).unwrap();
        let Body::Sensor(s) = body else {
            panic!("{body:?}")
        };
        assert_eq!(s.data, vec![0.5, -1.0, 2.0]);
        assert_eq!(Unit::unpack(s.unit), Unit::newton());
        // Newton: unit 0x0B exponent 1 in the first field (bits 59-50).
        assert_eq!(Unit::newton().pack(), (0x0B << 4 | 1) << 50);
        let nm = Unit::newton_meter();
        assert_eq!(Unit::unpack(nm.pack()), nm);
        // The reference C library's `igtl_unit_pack` of the same units.
        assert_eq!(nm.pack(), 0x02C4_1100_0000_0000);
        let neg = Unit {
            prefix: 0xB,
            units: [(1, -2), (3, 7), (0, 0), (0, 0), (0, 0), (0, 0)],
        };
        assert_eq!(Unit::unpack(neg.pack()), neg);
        assert_eq!(neg.pack(), 0xB078_3700_0000_0000);
        let mut c = Vec::new();
        sensor_content(0, 0, &[1.0, 2.0], &mut c);
        assert_eq!(
            parse_sensor(&c[..c.len() - 1]),
            Err(IgtlError::SensorLength { larray: 2, got: 15 })
        );
    }

    #[test]
    fn status_round_trip() {
        let s = StatusMsg {
            code: status_code::UNKNOWN_ERROR,
            subcode: -3,
            error_name: "POSE_REJECTED".into(),
            message: "position is NaN".into(),
        };
        let b = msg("STATUS", "left", 0, |o| status_content(&s, o));
        assert_eq!(parse_message(&b).unwrap().1, Body::Status(s));
        let mut c = Vec::new();
        status_content(
            &StatusMsg {
                code: 1,
                subcode: 0,
                error_name: String::new(),
                message: "x".into(),
            },
            &mut c,
        );
        c.pop();
        assert_eq!(
            parse_status(&c),
            Err(IgtlError::Status(
                "the status string has no terminating NUL"
            ))
        );
    }

    #[test]
    fn polydata_round_trip_with_polygons_and_strips() {
        let points = [
            0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.5,
        ];
        let polys = Cells::triangles(&[[0, 1, 2], [1, 3, 2]]);
        let strips = Cells {
            count: 1,
            data: vec![4, 0, 1, 2, 3],
        };
        let b = msg("POLYDATA", "brain", 0, |o| {
            polydata_content(&points, &polys, &strips, o)
        });
        let (_, body) = parse_message(&b).unwrap();
        let Body::PolyData(p) = body else {
            panic!("{body:?}")
        };
        assert_eq!(p.points.len(), 4);
        assert_eq!(p.points[3], [1.0, 1.0, 0.5]);
        assert_eq!(p.polygons, polys);
        assert_eq!(p.strips, strips);
        assert!(p.attributes.is_empty());
        // Points only (topology sent before).
        let mut c = Vec::new();
        polydata_content(&points, &Cells::default(), &Cells::default(), &mut c);
        assert_eq!(c.len(), POLYDATA_HEADER_LEN + 48);
        assert_eq!(parse_polydata(&c).unwrap().polygons.count, 0);
    }

    #[test]
    fn polydata_attributes_are_read() {
        let mut c = Vec::new();
        for v in [2u32, 0, 0, 0, 0, 0, 0, 0, 0, 1] {
            c.extend_from_slice(&v.to_be_bytes());
        }
        for x in [0f32, 0.0, 0.0, 1.0, 1.0, 1.0] {
            c.extend_from_slice(&x.to_be_bytes());
        }
        c.extend_from_slice(&[0x00, 1]);
        c.extend_from_slice(&2u32.to_be_bytes());
        c.extend_from_slice(b"disp\0\0");
        for x in [0.25f32, 0.5] {
            c.extend_from_slice(&x.to_be_bytes());
        }
        let p = parse_polydata(&c).unwrap();
        assert_eq!(p.attributes.len(), 1);
        assert_eq!(p.attributes[0].name, "disp");
        assert_eq!(p.attributes[0].data, vec![0.25, 0.5]);
        // An unknown attribute type is named.
        let mut bad = c.clone();
        bad[POLYDATA_HEADER_LEN + 24] = 0x07;
        assert_eq!(
            parse_polydata(&bad),
            Err(IgtlError::PolyData("attribute 0: unknown type 0x07".into()))
        );
    }

    fn valid_transform() -> Vec<u8> {
        let t = Transform {
            rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            translation: [1.0, 2.0, 3.0],
        };
        msg("TRANSFORM", "Tracker", 0, |o| transform_content(&t, o))
    }

    #[test]
    fn malformed_headers_are_refused_with_their_cause() {
        let b = valid_transform();
        for n in 0..HEADER_LEN {
            assert_eq!(
                parse_header(&b[..n]),
                Err(IgtlError::ShortHeader { got: n })
            );
        }
        for v in [0u16, 3, 0xffff] {
            let mut x = b.clone();
            x[0..2].copy_from_slice(&v.to_be_bytes());
            assert_eq!(parse_message(&x), Err(IgtlError::Version(v)));
        }
        let mut x = b.clone();
        x[2] = 0;
        assert!(matches!(parse_message(&x), Err(IgtlError::TypeName(_))));
        let mut x = b.clone();
        x[5] = 0xff;
        assert!(matches!(parse_message(&x), Err(IgtlError::TypeName(_))));
        let mut x = b.clone();
        // A byte after the NUL padding.
        x[33] = b'x';
        assert!(matches!(parse_message(&x), Err(IgtlError::DeviceName(_))));
        let mut x = b.clone();
        x[42..50].copy_from_slice(&u64::MAX.to_be_bytes());
        assert_eq!(parse_message(&x), Err(IgtlError::BodyTooLarge(u64::MAX)));
    }

    #[test]
    fn bodies_that_do_not_match_their_header_are_refused() {
        let b = valid_transform();
        // Body length beyond the data, and short of it.
        assert_eq!(
            parse_message(&b[..b.len() - 1]),
            Err(IgtlError::BodyLength {
                got: 47,
                declared: 48
            })
        );
        let mut long = b.clone();
        long.push(0);
        assert_eq!(
            parse_message(&long),
            Err(IgtlError::BodyLength {
                got: 49,
                declared: 48
            })
        );
        // A flipped bit of the body: wrong CRC.
        let mut x = b.clone();
        x[HEADER_LEN + 40] ^= 1;
        assert!(matches!(parse_message(&x), Err(IgtlError::Crc { .. })));
        // A flipped bit of the CRC itself.
        let mut x = b.clone();
        x[57] ^= 0x80;
        assert!(matches!(parse_message(&x), Err(IgtlError::Crc { .. })));
        // Unknown types are named.
        let u = msg("GET_STATUS", "", 0, |_| {});
        assert_eq!(
            parse_message(&u),
            Err(IgtlError::UnknownType("GET_STATUS".into()))
        );
        // A TRANSFORM of the wrong size or with a scaled rotation.
        let t = msg("TRANSFORM", "x", 0, |o| o.extend_from_slice(&[0; 44]));
        assert!(matches!(
            parse_message(&t),
            Err(IgtlError::ContentLength { got: 44, .. })
        ));
        let t = msg("TRANSFORM", "x", 0, |o| {
            transform_content(
                &Transform {
                    rotation: [[2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                    translation: [0.0; 3],
                },
                o,
            )
        });
        assert!(matches!(parse_message(&t), Err(IgtlError::NotRotation(..))));
        let t = msg("TRANSFORM", "x", 0, |o| {
            transform_content(
                &Transform {
                    rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                    translation: [f32::NAN, 0.0, 0.0],
                },
                o,
            )
        });
        assert!(matches!(
            parse_message(&t),
            Err(IgtlError::NotFinite { .. })
        ));
    }

    #[test]
    fn version_2_bodies_give_the_content_between_extended_header_and_metadata() {
        let t = Transform {
            rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            translation: [4.0, 5.0, 6.0],
        };
        let meta = b"\x00\x01\x00\x03\x00\x03\x00\x00\x00\x01key1";
        let b = {
            let mut b = msg("TRANSFORM", "T", 0, |o| {
                o.extend_from_slice(&12u16.to_be_bytes());
                o.extend_from_slice(&10u16.to_be_bytes());
                o.extend_from_slice(&4u32.to_be_bytes());
                o.extend_from_slice(&7u32.to_be_bytes());
                transform_content(&t, o);
                o.extend_from_slice(meta);
            });
            b[0..2].copy_from_slice(&2u16.to_be_bytes());
            b
        };
        assert_eq!(parse_message(&b).unwrap().1, Body::Transform(t));
        // Metadata sizes larger than the body.
        let mut x = b.clone();
        x[HEADER_LEN + 4..HEADER_LEN + 8].copy_from_slice(&1000u32.to_be_bytes());
        let crc = crc64(&x[HEADER_LEN..]);
        x[50..58].copy_from_slice(&crc.to_be_bytes());
        assert!(matches!(
            parse_message(&x),
            Err(IgtlError::ExtendedHeader(_))
        ));
    }

    fn polydata_with(h: [u32; 10], rest: &[u8]) -> Vec<u8> {
        let mut c = Vec::new();
        for v in h {
            c.extend_from_slice(&v.to_be_bytes());
        }
        c.extend_from_slice(rest);
        c
    }

    #[test]
    fn huge_or_inconsistent_polydata_is_refused_without_allocating() {
        // Four billion points declared in a 40-byte body.
        let c = polydata_with(
            [u32::MAX, 0, 0, 0, 0, u32::MAX, u32::MAX, 0, 0, u32::MAX],
            &[],
        );
        assert!(
            matches!(parse_polydata(&c), Err(IgtlError::PolyData(m)) if m.contains("need more than"))
        );
        // One point; a triangle using point 5.
        let mut rest = vec![0u8; 12];
        for v in [3u32, 0, 0, 5] {
            rest.extend_from_slice(&v.to_be_bytes());
        }
        let c = polydata_with([1, 0, 0, 0, 0, 1, 16, 0, 0, 0], &rest);
        assert_eq!(
            parse_polydata(&c),
            Err(IgtlError::PolyData(
                "POLYGONS: cell 0 uses point 5 of 1".into()
            ))
        );
        // A cell whose length runs past its array.
        let mut rest = vec![0u8; 12];
        for v in [7u32, 0, 0, 0] {
            rest.extend_from_slice(&v.to_be_bytes());
        }
        let c = polydata_with([1, 0, 0, 0, 0, 1, 16, 0, 0, 0], &rest);
        assert!(
            matches!(parse_polydata(&c), Err(IgtlError::PolyData(m)) if m.contains("past the end"))
        );
        // A cell count that disagrees with the array.
        let mut rest = vec![0u8; 12];
        for v in [1u32, 0] {
            rest.extend_from_slice(&v.to_be_bytes());
        }
        let c = polydata_with([1, 0, 0, 0, 0, 2, 8, 0, 0, 0], &rest);
        assert!(
            matches!(parse_polydata(&c), Err(IgtlError::PolyData(m)) if m.contains("2 declared"))
        );
        // Sizes not a multiple of four, trailing bytes.
        let c = polydata_with([0, 0, 3, 0, 0, 0, 0, 0, 0, 0], &[0, 0, 0]);
        assert!(
            matches!(parse_polydata(&c), Err(IgtlError::PolyData(m)) if m.contains("whole number"))
        );
        let c = polydata_with([0; 10], &[0]);
        assert!(
            matches!(parse_polydata(&c), Err(IgtlError::PolyData(m)) if m.contains("left after"))
        );
        // A NaN point.
        let c = polydata_with(
            [1, 0, 0, 0, 0, 0, 0, 0, 0, 0],
            &f32::NAN.to_be_bytes().repeat(3),
        );
        assert!(
            matches!(parse_polydata(&c), Err(IgtlError::PolyData(m)) if m.contains("not finite"))
        );
    }

    /// Every prefix and every single-byte change of valid messages parses or
    /// is refused, without a panic.
    #[test]
    fn truncations_and_byte_flips_never_panic() {
        let points = [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
        let messages = [
            valid_transform(),
            msg("POLYDATA", "b", 0, |o| {
                polydata_content(
                    &points,
                    &Cells::triangles(&[[0, 1, 2]]),
                    &Cells::default(),
                    o,
                )
            }),
            msg("SENSOR", "s", 0, |o| sensor_content(0, 0, &[1.0], o)),
        ];
        for m in &messages {
            for n in 0..=m.len() {
                let _ = parse_message(&m[..n]);
            }
            for i in 0..m.len() {
                for flip in [0x01u8, 0x80, 0xff] {
                    let mut x = m.clone();
                    x[i] ^= flip;
                    let _ = parse_message(&x);
                    // With the CRC fixed up, the body parsers see the change.
                    if i >= HEADER_LEN {
                        let crc = crc64(&x[HEADER_LEN..]);
                        x[50..58].copy_from_slice(&crc.to_be_bytes());
                        let _ = parse_message(&x);
                    }
                }
            }
        }
    }
}
