//! Little-endian packing of plain arrays for the caches that keep prepared tables between runs
//! (decoded references, render caches): a writer that appends and a reader that refuses to read
//! past its end, so a damaged entry is an error and never a panic.

/// Appends values in little-endian order.
#[derive(Debug, Default)]
pub struct ByteWriter {
    /// What was written.
    pub bytes: Vec<u8>,
}

impl ByteWriter {
    /// A writer with room for `capacity` bytes.
    pub fn with_capacity(capacity: usize) -> ByteWriter {
        ByteWriter {
            bytes: Vec::with_capacity(capacity),
        }
    }

    /// Raw bytes.
    pub fn raw(&mut self, b: &[u8]) {
        self.bytes.extend_from_slice(b);
    }

    /// One byte.
    pub fn u8(&mut self, v: u8) {
        self.bytes.push(v);
    }

    /// A `u32`.
    pub fn u32(&mut self, v: u32) {
        self.raw(&v.to_le_bytes());
    }

    /// A `u64`.
    pub fn u64(&mut self, v: u64) {
        self.raw(&v.to_le_bytes());
    }

    /// A length-prefixed array of `u32`.
    pub fn u32s(&mut self, v: &[u32]) {
        self.u64(v.len() as u64);
        for x in v {
            self.u32(*x);
        }
    }

    /// A length-prefixed array of `f32` (bit-exact, NaN included).
    pub fn f32s(&mut self, v: &[f32]) {
        self.u64(v.len() as u64);
        for x in v {
            self.raw(&x.to_le_bytes());
        }
    }

    /// A length-prefixed byte array.
    pub fn bytes(&mut self, v: &[u8]) {
        self.u64(v.len() as u64);
        self.raw(v);
    }
}

/// Reads what a [`ByteWriter`] wrote; every read past the end is `None`.
#[derive(Debug)]
pub struct ByteReader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> ByteReader<'a> {
    /// A reader at the start of `bytes`.
    pub fn new(bytes: &'a [u8]) -> ByteReader<'a> {
        ByteReader { bytes, at: 0 }
    }

    /// Bytes not read yet.
    pub fn remaining(&self) -> usize {
        self.bytes.len() - self.at
    }

    /// The next `n` bytes.
    pub fn raw(&mut self, n: usize) -> Option<&'a [u8]> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len())?;
        let s = &self.bytes[self.at..end];
        self.at = end;
        Some(s)
    }

    /// One byte.
    pub fn u8(&mut self) -> Option<u8> {
        self.raw(1).map(|b| b[0])
    }

    /// A `u32`.
    pub fn u32(&mut self) -> Option<u32> {
        let b = self.raw(4)?;
        Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    /// A `u64`.
    pub fn u64(&mut self) -> Option<u64> {
        let b = self.raw(8)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        Some(u64::from_le_bytes(a))
    }

    fn len(&mut self, size: usize) -> Option<usize> {
        let n = usize::try_from(self.u64()?).ok()?;
        // A length the rest cannot hold is damage, not a reason to allocate.
        (n.checked_mul(size)? <= self.remaining()).then_some(n)
    }

    /// A length-prefixed array of `u32`.
    pub fn u32s(&mut self) -> Option<Vec<u32>> {
        let n = self.len(4)?;
        let b = self.raw(4 * n)?;
        Some(
            b.chunks_exact(4)
                .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
        )
    }

    /// A length-prefixed array of `f32`.
    pub fn f32s(&mut self) -> Option<Vec<f32>> {
        let n = self.len(4)?;
        let b = self.raw(4 * n)?;
        Some(
            b.chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
        )
    }

    /// A length-prefixed byte array.
    pub fn bytes(&mut self) -> Option<&'a [u8]> {
        let n = self.len(1)?;
        self.raw(n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_round_trip_and_reads_past_the_end_are_refused() {
        let mut w = ByteWriter::default();
        w.u8(7);
        w.u32(0xdead_beef);
        w.u64(u64::MAX - 3);
        w.u32s(&[1, 2, 3]);
        w.f32s(&[f32::NAN, -0.0, 1.5e-30]);
        w.bytes(b"key");
        let mut r = ByteReader::new(&w.bytes);
        assert_eq!(r.u8(), Some(7));
        assert_eq!(r.u32(), Some(0xdead_beef));
        assert_eq!(r.u64(), Some(u64::MAX - 3));
        assert_eq!(r.u32s(), Some(vec![1, 2, 3]));
        let f = r.f32s().expect("floats");
        assert!(f[0].is_nan() && f[1].to_bits() == (-0.0f32).to_bits() && f[2] == 1.5e-30);
        assert_eq!(r.bytes(), Some(&b"key"[..]));
        assert_eq!(r.remaining(), 0);
        assert_eq!(r.u8(), None);
        // Every truncation fails somewhere, never panics.
        for cut in 0..w.bytes.len() {
            let mut r = ByteReader::new(&w.bytes[..cut]);
            let all = (|| {
                r.u8()?;
                r.u32()?;
                r.u64()?;
                r.u32s()?;
                r.f32s()?;
                r.bytes()
            })();
            assert!(all.is_none(), "cut {cut}");
        }
        // A huge length prefix is refused before any allocation.
        let mut w = ByteWriter::default();
        w.u64(u64::MAX / 2);
        assert!(ByteReader::new(&w.bytes).f32s().is_none());
    }
}
