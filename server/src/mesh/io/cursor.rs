//! A byte cursor shared by the readers: whitespace-separated tokens with line
//! numbers for text, fixed-width numbers for binary payloads, and count checks
//! that refuse to allocate for more items than the remaining bytes can hold.

use super::{Loc, ParseError};
use std::str::FromStr;

/// Position in an input buffer.
pub(crate) struct Cursor<'a> {
    pub data: &'a [u8],
    pub pos: usize,
    /// 1-based line of `pos` (text mode).
    pub line: usize,
    /// Report byte offsets instead of lines.
    pub binary: bool,
}

impl<'a> Cursor<'a> {
    pub fn new(data: &'a [u8]) -> Self {
        Self {
            data,
            pos: 0,
            line: 1,
            binary: false,
        }
    }

    pub fn loc(&self) -> Loc {
        if self.binary {
            Loc::Byte(self.pos)
        } else {
            Loc::Line(self.line)
        }
    }

    pub fn err(&self, field: &str, message: impl Into<String>) -> ParseError {
        ParseError {
            loc: self.loc(),
            field: field.to_string(),
            message: message.into(),
        }
    }

    pub fn remaining(&self) -> usize {
        self.data.len().saturating_sub(self.pos)
    }

    pub fn at_end(&self) -> bool {
        self.pos >= self.data.len()
    }

    pub fn skip_ws(&mut self) {
        while let Some(&b) = self.data.get(self.pos) {
            if !b.is_ascii_whitespace() {
                break;
            }
            if b == b'\n' {
                self.line += 1;
            }
            self.pos += 1;
        }
    }

    /// The next whitespace-separated token, or `None` at the end.
    pub fn token(&mut self) -> Option<&'a [u8]> {
        self.skip_ws();
        let start = self.pos;
        while let Some(&b) = self.data.get(self.pos) {
            if b.is_ascii_whitespace() {
                break;
            }
            self.pos += 1;
        }
        (self.pos > start).then(|| &self.data[start..self.pos])
    }

    /// The next token parsed as `T`.
    pub fn parse<T: FromStr>(&mut self, field: &str) -> Result<T, ParseError> {
        let tok = self
            .token()
            .ok_or_else(|| self.err(field, "missing (unexpected end of file)"))?;
        parse_token(tok)
            .ok_or_else(|| self.err(field, format!("'{}' is not a valid value", show(tok))))
    }

    /// The next token as a finite `f64`.
    pub fn f64(&mut self, field: &str) -> Result<f64, ParseError> {
        let x: f64 = self.parse(field)?;
        if x.is_finite() {
            Ok(x)
        } else {
            Err(self.err(field, "not a finite number"))
        }
    }

    /// Requires the next token to be `word`.
    pub fn expect(&mut self, word: &str) -> Result<(), ParseError> {
        match self.token() {
            Some(t) if t == word.as_bytes() => Ok(()),
            Some(t) => Err(self.err(word, format!("expected '{word}', found '{}'", show(t)))),
            None => Err(self.err(
                word,
                format!("expected '{word}', found the end of the file"),
            )),
        }
    }

    /// The rest of the current line without its line break, moving to the
    /// start of the next line; `None` at the end.
    pub fn line_bytes(&mut self) -> Option<&'a [u8]> {
        if self.at_end() {
            return None;
        }
        let start = self.pos;
        while let Some(&b) = self.data.get(self.pos) {
            if b == b'\n' {
                break;
            }
            self.pos += 1;
        }
        let mut end = self.pos;
        if self.pos < self.data.len() {
            self.pos += 1;
            self.line += 1;
        }
        if end > start && self.data[end - 1] == b'\r' {
            end -= 1;
        }
        Some(&self.data[start..end])
    }

    /// The next `n` bytes.
    pub fn take(&mut self, n: usize, field: &str) -> Result<&'a [u8], ParseError> {
        if n > self.remaining() {
            return Err(self.err(
                field,
                format!(
                    "needs {n} bytes, only {} left in the file",
                    self.remaining()
                ),
            ));
        }
        let s = &self.data[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    /// Moves past the next occurrence of `needle`, counting lines; `false`
    /// (and the cursor at the end) when there is none.
    pub fn skip_past(&mut self, needle: &[u8]) -> bool {
        let found = find(&self.data[self.pos.min(self.data.len())..], needle);
        let end = match found {
            Some(i) => self.pos + i + needle.len(),
            None => self.data.len(),
        };
        self.line += self.data[self.pos.min(end)..end]
            .iter()
            .filter(|&&b| b == b'\n')
            .count();
        self.pos = end;
        found.is_some()
    }

    /// Checks that `count` items of at least `min_bytes` each fit in the rest
    /// of the input, and returns the count as `usize`. This bounds every
    /// allocation by the file size.
    pub fn check_count(
        &self,
        count: u64,
        min_bytes: usize,
        field: &str,
    ) -> Result<usize, ParseError> {
        let fits = (count as u128) * (min_bytes.max(1) as u128) <= self.remaining() as u128 + 1;
        if fits {
            Ok(count as usize)
        } else {
            Err(self.err(
                field,
                format!(
                    "count {count} exceeds what the {} remaining bytes can hold",
                    self.remaining()
                ),
            ))
        }
    }

    pub fn bin_u32(&mut self, big: bool, field: &str) -> Result<u32, ParseError> {
        let b: [u8; 4] = self.take(4, field)?.try_into().unwrap_or([0; 4]);
        Ok(if big {
            u32::from_be_bytes(b)
        } else {
            u32::from_le_bytes(b)
        })
    }

    pub fn bin_i32(&mut self, big: bool, field: &str) -> Result<i32, ParseError> {
        Ok(self.bin_u32(big, field)? as i32)
    }

    pub fn bin_u64(&mut self, big: bool, field: &str) -> Result<u64, ParseError> {
        let b: [u8; 8] = self.take(8, field)?.try_into().unwrap_or([0; 8]);
        Ok(if big {
            u64::from_be_bytes(b)
        } else {
            u64::from_le_bytes(b)
        })
    }

    pub fn bin_f64(&mut self, big: bool, field: &str) -> Result<f64, ParseError> {
        let x = f64::from_bits(self.bin_u64(big, field)?);
        if x.is_finite() {
            Ok(x)
        } else {
            Err(self.err(field, "not a finite number"))
        }
    }

    pub fn bin_f32(&mut self, big: bool, field: &str) -> Result<f64, ParseError> {
        let x = f32::from_bits(self.bin_u32(big, field)?) as f64;
        if x.is_finite() {
            Ok(x)
        } else {
            Err(self.err(field, "not a finite number"))
        }
    }
}

/// Parses a token as `T` (ASCII only).
pub(crate) fn parse_token<T: FromStr>(tok: &[u8]) -> Option<T> {
    std::str::from_utf8(tok).ok()?.parse().ok()
}

/// First index of `needle` in `hay`.
pub(crate) fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    if needle.is_empty() || needle.len() > hay.len() {
        return None;
    }
    hay.windows(needle.len()).position(|w| w == needle)
}

/// A token for an error message: lossy UTF-8, at most 40 characters.
pub(crate) fn show(tok: &[u8]) -> String {
    let s = String::from_utf8_lossy(&tok[..tok.len().min(40)]).into_owned();
    if tok.len() > 40 { format!("{s}...") } else { s }
}
