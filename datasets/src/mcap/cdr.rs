//! OMG CDR (XCDR1), the serialization of ROS 2 messages in MCAP files (`message_encoding`
//! `cdr`).
//!
//! A message starts with a 4-byte encapsulation header: `00 01 00 00` for little-endian
//! (what ROS 2 writes), `00 00 00 00` for big-endian. Every primitive is aligned to its own
//! size, counted from the end of that header; strings and sequences are a `u32` count
//! followed by their elements (a string's count includes its terminating NUL).

/// A CDR message that cannot be read: what was expected and the byte offset (from the
/// message's start) where reading stopped.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct CdrError(pub String);

/// Reads the fields of one CDR message in order.
pub struct CdrReader<'a> {
    body: &'a [u8],
    pos: usize,
    little: bool,
}

/// Sequences longer than this are refused as corrupt before anything is allocated
/// (the largest image field is far below it).
const MAX_SEQUENCE_LEN: usize = 1 << 30;

impl<'a> CdrReader<'a> {
    /// Starts reading `data`, checking its encapsulation header.
    pub fn new(data: &'a [u8]) -> Result<Self, CdrError> {
        let (Some(header), Some(body)) = (data.get(..4), data.get(4..)) else {
            return Err(CdrError(format!(
                "{} bytes: too short for a CDR encapsulation header",
                data.len()
            )));
        };
        let little = match (header[0], header[1]) {
            (0, 1) => true,
            (0, 0) => false,
            (a, b) => {
                return Err(CdrError(format!(
                    "encapsulation {a:02x} {b:02x} is not plain CDR (00 00 or 00 01); \
                     XCDR2 and parameter lists are not supported"
                )))
            }
        };
        Ok(Self {
            body,
            pos: 0,
            little,
        })
    }

    /// Bytes not read yet.
    pub fn remaining(&self) -> usize {
        self.body.len().saturating_sub(self.pos)
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], CdrError> {
        let end = self.pos.checked_add(n);
        match end.and_then(|e| self.body.get(self.pos..e)) {
            Some(s) => {
                self.pos += n;
                Ok(s)
            }
            None => Err(CdrError(format!(
                "truncated: {what} needs {n} bytes at offset {}, {} left",
                self.pos + 4,
                self.remaining()
            ))),
        }
    }

    fn align(&mut self, n: usize, what: &str) -> Result<(), CdrError> {
        let pad = (n - self.pos % n) % n;
        self.take(pad, what).map(|_| ())
    }

    fn array<const N: usize>(&mut self, what: &str) -> Result<[u8; N], CdrError> {
        self.align(N, what)?;
        let s = self.take(N, what)?;
        let mut out = [0u8; N];
        out.copy_from_slice(s);
        if !self.little {
            out.reverse();
        }
        Ok(out)
    }

    /// An unsigned byte (also `bool` and `char`).
    pub fn u8(&mut self, what: &str) -> Result<u8, CdrError> {
        Ok(self.take(1, what)?[0])
    }

    /// A 32-bit unsigned integer.
    pub fn u32(&mut self, what: &str) -> Result<u32, CdrError> {
        Ok(u32::from_le_bytes(self.array::<4>(what)?))
    }

    /// A 32-bit signed integer.
    pub fn i32(&mut self, what: &str) -> Result<i32, CdrError> {
        Ok(i32::from_le_bytes(self.array::<4>(what)?))
    }

    /// A 32-bit float.
    pub fn f32(&mut self, what: &str) -> Result<f32, CdrError> {
        Ok(f32::from_le_bytes(self.array::<4>(what)?))
    }

    /// A 64-bit float.
    pub fn f64(&mut self, what: &str) -> Result<f64, CdrError> {
        Ok(f64::from_le_bytes(self.array::<8>(what)?))
    }

    /// `N` 64-bit floats (a fixed-size array: no count).
    pub fn f64_array<const N: usize>(&mut self, what: &str) -> Result<[f64; N], CdrError> {
        let mut out = [0.0; N];
        for v in &mut out {
            *v = self.f64(what)?;
        }
        Ok(out)
    }

    fn count(&mut self, what: &str) -> Result<usize, CdrError> {
        let n = self.u32(what)? as usize;
        if n > MAX_SEQUENCE_LEN || n > self.remaining().saturating_mul(8) + 8 {
            return Err(CdrError(format!(
                "{what}: a length of {n} at offset {} exceeds the message",
                self.pos
            )));
        }
        Ok(n)
    }

    /// A string (UTF-8; the terminating NUL is dropped).
    pub fn string(&mut self, what: &str) -> Result<String, CdrError> {
        let n = self.count(what)?;
        let bytes = self.take(n, what)?;
        let bytes = bytes.strip_suffix(&[0]).unwrap_or(bytes);
        String::from_utf8(bytes.to_vec())
            .map_err(|_| CdrError(format!("{what}: the string is not UTF-8")))
    }

    /// A byte sequence (`uint8[]`), borrowed from the message.
    pub fn bytes(&mut self, what: &str) -> Result<&'a [u8], CdrError> {
        let n = self.count(what)?;
        self.take(n, what)
    }

    /// A sequence of 64-bit floats (`float64[]`).
    pub fn f64_seq(&mut self, what: &str) -> Result<Vec<f64>, CdrError> {
        let n = self.count(what)?;
        (0..n).map(|_| self.f64(what)).collect()
    }

    /// A sequence of 32-bit floats (`float32[]`).
    pub fn f32_seq(&mut self, what: &str) -> Result<Vec<f32>, CdrError> {
        let n = self.count(what)?;
        (0..n).map(|_| self.f32(what)).collect()
    }

    /// The count of a sequence of structures, checked against the bytes left (each element
    /// takes at least `min_element_bytes`).
    pub fn seq_len(&mut self, what: &str, min_element_bytes: usize) -> Result<usize, CdrError> {
        let n = self.count(what)?;
        if n.saturating_mul(min_element_bytes.max(1)) > self.remaining() {
            return Err(CdrError(format!(
                "{what}: {n} elements cannot fit in the {} bytes left",
                self.remaining()
            )));
        }
        Ok(n)
    }
}

/// Writes a little-endian CDR message, as ROS 2 does.
pub struct CdrWriter {
    buf: Vec<u8>,
}

impl Default for CdrWriter {
    fn default() -> Self {
        Self::new()
    }
}

impl CdrWriter {
    /// An empty little-endian message (the encapsulation header written).
    pub fn new() -> Self {
        Self::with_capacity(64)
    }

    /// As [`Self::new`], with room for `bytes` bytes of fields.
    pub fn with_capacity(bytes: usize) -> Self {
        let mut buf = Vec::with_capacity(bytes + 4);
        buf.extend_from_slice(&[0, 1, 0, 0]);
        Self { buf }
    }

    fn align(&mut self, n: usize) {
        let pos = self.buf.len() - 4;
        let pad = (n - pos % n) % n;
        self.buf.resize(self.buf.len() + pad, 0);
    }

    /// An unsigned byte.
    pub fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }

    /// A 32-bit unsigned integer.
    pub fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// A 32-bit signed integer.
    pub fn i32(&mut self, v: i32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// A 32-bit float.
    pub fn f32(&mut self, v: f32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// A 64-bit float.
    pub fn f64(&mut self, v: f64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// 64-bit floats as a fixed-size array (no count).
    pub fn f64_array(&mut self, v: &[f64]) {
        for &x in v {
            self.f64(x);
        }
    }

    fn count(&mut self, n: usize) {
        self.u32(u32::try_from(n).unwrap_or(u32::MAX));
    }

    /// A string, NUL-terminated.
    pub fn string(&mut self, s: &str) {
        self.count(s.len() + 1);
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
    }

    /// A byte sequence.
    pub fn bytes(&mut self, b: &[u8]) {
        self.count(b.len());
        self.buf.extend_from_slice(b);
    }

    /// A sequence of 64-bit floats.
    pub fn f64_seq(&mut self, v: &[f64]) {
        self.count(v.len());
        self.f64_array(v);
    }

    /// A sequence of 32-bit floats.
    pub fn f32_seq(&mut self, v: &[f32]) {
        self.count(v.len());
        for &x in v {
            self.f32(x);
        }
    }

    /// The count of a sequence of structures (their fields follow).
    pub fn seq_len(&mut self, n: usize) {
        self.count(n);
    }

    /// The finished message.
    pub fn finish(self) -> Vec<u8> {
        self.buf
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fields_round_trip_with_alignment() {
        let mut w = CdrWriter::new();
        w.u8(7);
        w.f64(-1.5);
        w.string("cam");
        w.u32(640);
        w.bytes(&[1, 2, 3]);
        w.f64_seq(&[0.25, 4.0]);
        w.f32_seq(&[2.5]);
        let data = w.finish();
        // 1 byte, 7 of padding, 8 for the f64: the f64 starts at body offset 8.
        assert_eq!(&data[..4], &[0, 1, 0, 0]);
        assert_eq!(&data[12..20], &(-1.5f64).to_le_bytes());
        let mut r = CdrReader::new(&data).unwrap();
        assert_eq!(r.u8("a").unwrap(), 7);
        assert_eq!(r.f64("b").unwrap(), -1.5);
        assert_eq!(r.string("c").unwrap(), "cam");
        assert_eq!(r.u32("d").unwrap(), 640);
        assert_eq!(r.bytes("e").unwrap(), &[1, 2, 3]);
        assert_eq!(r.f64_seq("f").unwrap(), vec![0.25, 4.0]);
        assert_eq!(r.f32_seq("g").unwrap(), vec![2.5]);
        assert_eq!(r.remaining(), 0);
    }

    #[test]
    fn big_endian_messages_are_read() {
        // header 00 00 (CDR_BE), then u32 0x01020304 and a string "a".
        let data = [0, 0, 0, 0, 1, 2, 3, 4, 0, 0, 0, 2, b'a', 0];
        let mut r = CdrReader::new(&data).unwrap();
        assert_eq!(r.u32("x").unwrap(), 0x0102_0304);
        assert_eq!(r.string("s").unwrap(), "a");
    }

    #[test]
    fn truncated_and_foreign_messages_are_errors() {
        assert!(CdrReader::new(&[0, 1]).is_err());
        let e = CdrReader::new(&[0, 7, 0, 0]).err().unwrap();
        assert!(e.0.contains("not plain CDR"), "{e}");
        let mut r = CdrReader::new(&[0, 1, 0, 0, 1, 0]).unwrap();
        let e = r.u32("height").unwrap_err();
        assert!(e.0.contains("height needs 4 bytes"), "{e}");
        // A sequence count far beyond the message is refused before allocating.
        let mut w = CdrWriter::new();
        w.u32(u32::MAX);
        let data = w.finish();
        let e = CdrReader::new(&data).unwrap().bytes("data").unwrap_err();
        assert!(e.0.contains("exceeds the message"), "{e}");
    }
}
