//! NumPy `.npy` files of little-endian f32 or f64 values in C order (any rank; specgp uses 1-D
//! and 2-D): a reader and a streaming writer.
//!
//! The writer emits format version 1.0 (2.0 when the header does not fit in 64 KiB), pads the
//! header to a multiple of 64 bytes as NumPy does, and writes through a temporary file in the
//! target directory that [`NpyWriter::finish`] renames into place: an interrupted export leaves
//! nothing behind.

use std::io::Write;
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};
use crate::output::AtomicOutput;

const MAGIC: &[u8; 6] = b"\x93NUMPY";

/// Element type of an `.npy` file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NpyDtype {
    /// Little-endian f32 (`<f4`).
    F32,
    /// Little-endian f64 (`<f8`).
    F64,
}

impl NpyDtype {
    fn descr(self) -> &'static str {
        match self {
            Self::F32 => "<f4",
            Self::F64 => "<f8",
        }
    }

    fn size(self) -> usize {
        match self {
            Self::F32 => 4,
            Self::F64 => 8,
        }
    }
}

/// The values of an `.npy` file.
#[derive(Debug, Clone, PartialEq)]
pub enum NpyData {
    /// f32 values.
    F32(Vec<f32>),
    /// f64 values.
    F64(Vec<f64>),
}

/// An array read from an `.npy` file: shape (C order) and values.
#[derive(Debug, Clone, PartialEq)]
pub struct NpyArray {
    /// The shape, outermost axis first.
    pub shape: Vec<usize>,
    /// The values in C order.
    pub data: NpyData,
}

impl NpyArray {
    /// Number of values.
    pub fn len(&self) -> usize {
        match &self.data {
            NpyData::F32(v) => v.len(),
            NpyData::F64(v) => v.len(),
        }
    }

    /// Whether the array holds no value.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The values as f64.
    pub fn to_f64(&self) -> Vec<f64> {
        match &self.data {
            NpyData::F32(v) => v.iter().map(|&x| f64::from(x)).collect(),
            NpyData::F64(v) => v.clone(),
        }
    }

    /// The values as f32 (f64 values rounded).
    pub fn to_f32(&self) -> Vec<f32> {
        match &self.data {
            NpyData::F32(v) => v.clone(),
            NpyData::F64(v) => v.iter().map(|&x| x as f32).collect(),
        }
    }
}

/// Reads an `.npy` file of little-endian f32 or f64 values in C order.
pub fn read(path: impl AsRef<Path>) -> Result<NpyArray> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse(&bytes, path)
}

/// Parses the bytes of an `.npy` file; `path` is only used in error messages.
pub fn parse(bytes: &[u8], path: impl AsRef<Path>) -> Result<NpyArray> {
    let path = path.as_ref();
    let bad = |reason: String| Error::Format {
        path: path.to_path_buf(),
        reason,
    };
    if bytes.len() < 10 || &bytes[..6] != MAGIC {
        return Err(bad("not an .npy file (missing \\x93NUMPY magic)".into()));
    }
    let (header_len, start): (usize, usize) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 => {
            if bytes.len() < 12 {
                return Err(bad("truncated .npy header".into()));
            }
            (
                u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
                12,
            )
        }
        v => {
            return Err(bad(format!(
                "unsupported .npy format version {v}.{}",
                bytes[7]
            )));
        }
    };
    let end = start
        .checked_add(header_len)
        .filter(|&e| e <= bytes.len())
        .ok_or_else(|| bad("truncated .npy header".into()))?;
    let header = std::str::from_utf8(&bytes[start..end])
        .map_err(|_| bad(".npy header is not text".into()))?;
    let descr = dict_value(header, "descr")
        .ok_or_else(|| bad(format!("no 'descr' in .npy header {header:?}")))?;
    let dtype = match descr.trim_matches(|c| c == '\'' || c == '"') {
        "<f4" => NpyDtype::F32,
        "<f8" => NpyDtype::F64,
        d => {
            return Err(bad(format!(
                "unsupported .npy dtype {d:?} (only little-endian f32 '<f4' and f64 '<f8')"
            )));
        }
    };
    let fortran = dict_value(header, "fortran_order")
        .ok_or_else(|| bad(format!("no 'fortran_order' in .npy header {header:?}")))?;
    if fortran.trim() != "False" {
        return Err(bad("Fortran-ordered .npy arrays are not supported".into()));
    }
    let shape_text = dict_value(header, "shape")
        .ok_or_else(|| bad(format!("no 'shape' in .npy header {header:?}")))?;
    let shape: Vec<usize> = shape_text
        .trim()
        .trim_start_matches('(')
        .trim_end_matches(')')
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<usize>()
                .map_err(|_| bad(format!("bad .npy shape {shape_text:?}")))
        })
        .collect::<Result<_>>()?;
    let count = shape
        .iter()
        .try_fold(1usize, |a, &n| a.checked_mul(n))
        .ok_or_else(|| bad(format!("shape {shape:?} overflows")))?;
    let body = &bytes[end..];
    if Some(body.len()) != count.checked_mul(dtype.size()) {
        return Err(bad(format!(
            "shape {shape:?} of {} needs {} data bytes, the file has {}",
            dtype.descr(),
            count.saturating_mul(dtype.size()),
            body.len()
        )));
    }
    let data = match dtype {
        NpyDtype::F32 => NpyData::F32(
            body.chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect(),
        ),
        NpyDtype::F64 => NpyData::F64(
            body.chunks_exact(8)
                .map(|b| {
                    let mut a = [0u8; 8];
                    a.copy_from_slice(b);
                    f64::from_le_bytes(a)
                })
                .collect(),
        ),
    };
    Ok(NpyArray { shape, data })
}

/// The raw text of `key`'s value in a Python dict literal (up to the next top-level comma).
fn dict_value<'a>(header: &'a str, key: &str) -> Option<&'a str> {
    let k1 = format!("'{key}'");
    let k2 = format!("\"{key}\"");
    let at = header.find(&k1).or_else(|| header.find(&k2))? + k1.len();
    let rest = header[at..].trim_start().strip_prefix(':')?;
    let mut depth = 0i32;
    for (i, c) in rest.char_indices() {
        match c {
            '(' | '[' => depth += 1,
            ')' | ']' => depth -= 1,
            ',' | '}' if depth == 0 => return Some(rest[..i].trim()),
            _ => {}
        }
    }
    None
}

fn header_bytes(dtype: NpyDtype, shape: &[usize]) -> Vec<u8> {
    let shape_text = match shape {
        [n] => format!("({n},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(ToString::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let dict = format!(
        "{{'descr': '{}', 'fortran_order': False, 'shape': {shape_text}, }}",
        dtype.descr()
    );
    // Pad with spaces and a final newline so that the data starts on a 64-byte boundary.
    let (version, prefix) = if dict.len() + 1 + 10 <= u16::MAX as usize {
        (1u8, 10)
    } else {
        (2u8, 12)
    };
    let total = (prefix + dict.len() + 1).div_ceil(64) * 64;
    let hlen = total - prefix;
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&[version, 0]);
    if version == 1 {
        out.extend_from_slice(&(hlen as u16).to_le_bytes());
    } else {
        out.extend_from_slice(&(hlen as u32).to_le_bytes());
    }
    out.extend_from_slice(dict.as_bytes());
    out.resize(total - 1, b' ');
    out.push(b'\n');
    out
}

/// A streaming `.npy` writer: the header first, then values in C order (e.g. one matrix row at a
/// time), then [`NpyWriter::finish`] checks the count and renames the file into place.
/// Dropping the writer without finishing deletes the temporary file. Output goes through
/// [`AtomicOutput`], so special files (`/dev/stdout`, a FIFO) are written in place.
#[derive(Debug)]
pub struct NpyWriter {
    path: PathBuf,
    dtype: NpyDtype,
    expected: usize,
    written: usize,
    out: std::io::BufWriter<AtomicOutput>,
}

impl NpyWriter {
    /// Starts an `.npy` file of `dtype` values with `shape` at `path` (written to a temporary
    /// file in the same directory until [`NpyWriter::finish`]).
    pub fn create(path: impl AsRef<Path>, dtype: NpyDtype, shape: &[usize]) -> Result<Self> {
        let path = path.as_ref().to_path_buf();
        let expected = shape
            .iter()
            .try_fold(1usize, |a, &n| a.checked_mul(n))
            .ok_or_else(|| Error::InvalidArgument {
                reason: format!("npy shape {shape:?} overflows"),
            })?;
        let tmp = AtomicOutput::create(&path)?;
        let mut out = std::io::BufWriter::with_capacity(1 << 20, tmp);
        out.write_all(&header_bytes(dtype, shape))
            .map_err(|e| Error::io(&path, e))?;
        Ok(Self {
            path,
            dtype,
            expected,
            written: 0,
            out,
        })
    }

    fn reserve(&mut self, n: usize) -> Result<()> {
        if self.written + n > self.expected {
            return Err(Error::InvalidArgument {
                reason: format!(
                    "{}: {} values written to an array of {}",
                    self.path.display(),
                    self.written + n,
                    self.expected
                ),
            });
        }
        self.written += n;
        Ok(())
    }

    /// Appends f32 values (widened to f64 for an f64 file).
    pub fn write_f32(&mut self, values: &[f32]) -> Result<()> {
        self.reserve(values.len())?;
        let r = match self.dtype {
            NpyDtype::F32 => values
                .iter()
                .try_for_each(|v| self.out.write_all(&v.to_le_bytes())),
            NpyDtype::F64 => values
                .iter()
                .try_for_each(|v| self.out.write_all(&f64::from(*v).to_le_bytes())),
        };
        r.map_err(|e| Error::io(&self.path, e))
    }

    /// Appends f64 values (rounded to f32 for an f32 file).
    pub fn write_f64(&mut self, values: &[f64]) -> Result<()> {
        self.reserve(values.len())?;
        let r = match self.dtype {
            NpyDtype::F32 => values
                .iter()
                .try_for_each(|v| self.out.write_all(&(*v as f32).to_le_bytes())),
            NpyDtype::F64 => values
                .iter()
                .try_for_each(|v| self.out.write_all(&v.to_le_bytes())),
        };
        r.map_err(|e| Error::io(&self.path, e))
    }

    /// Checks that every value was written, flushes and renames the file into place.
    pub fn finish(self) -> Result<()> {
        let path = self.path;
        if self.written != self.expected {
            return Err(Error::InvalidArgument {
                reason: format!(
                    "{}: only {} of {} values written",
                    path.display(),
                    self.written,
                    self.expected
                ),
            });
        }
        self.out
            .into_inner()
            .map_err(|e| Error::io(&path, e.into_error()))?
            .commit()
    }
}

/// Writes an f32 array of `shape` (C order) to `path` in one call.
pub fn write_f32(path: impl AsRef<Path>, shape: &[usize], values: &[f32]) -> Result<()> {
    let mut w = NpyWriter::create(path, NpyDtype::F32, shape)?;
    w.write_f32(values)?;
    w.finish()
}

/// Writes an f64 array of `shape` (C order) to `path` in one call.
pub fn write_f64(path: impl AsRef<Path>, shape: &[usize], values: &[f64]) -> Result<()> {
    let mut w = NpyWriter::create(path, NpyDtype::F64, shape)?;
    w.write_f64(values)?;
    w.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An `.npy` export to a FIFO (as `/dev/stdout` in a pipeline) streams the same bytes as a
    /// file, and the FIFO stays a FIFO; a file export gets mode 0666 & !umask, not 0600.
    #[cfg(target_os = "linux")]
    #[test]
    fn writes_into_a_fifo_and_files_get_the_umask_mode() {
        use crate::output::test_util::{fifo, is_fifo, mode, umask};
        use std::io::Read;
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("a.npy");
        write_f32(&file, &[2, 3], &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]).unwrap();
        assert_eq!(mode(&file), 0o666 & !umask());
        let want = std::fs::read(&file).unwrap();
        let (p, mut reader) = fifo(dir.path(), "pipe");
        write_f32(&p, &[2, 3], &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]).unwrap();
        assert!(is_fifo(&p));
        let mut got = vec![0u8; want.len()];
        reader.read_exact(&mut got).unwrap();
        assert_eq!(got, want);
        assert_eq!(
            read(&file).unwrap().to_f32(),
            [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
        );
    }

    #[test]
    fn round_trip_1d_and_2d_streaming() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.npy");
        let mut w = NpyWriter::create(&p, NpyDtype::F32, &[2, 3]).unwrap();
        w.write_f32(&[1.0, 2.0, 3.0]).unwrap();
        w.write_f64(&[4.0, 5.5, -6.0]).unwrap();
        assert!(
            w.write_f32(&[7.0]).is_err(),
            "overflowing the shape is an error"
        );
        w.finish().unwrap();
        let bytes = std::fs::read(&p).unwrap();
        assert_eq!((bytes.len() - 24) % 64, 0, "header padded to 64 bytes");
        let a = read(&p).unwrap();
        assert_eq!(a.shape, vec![2, 3]);
        assert_eq!(a.data, NpyData::F32(vec![1.0, 2.0, 3.0, 4.0, 5.5, -6.0]));

        let q = dir.path().join("b.npy");
        write_f64(&q, &[3], &[0.1, 0.2, 0.3]).unwrap();
        let b = read(&q).unwrap();
        assert_eq!(b.shape, vec![3]);
        assert_eq!(b.to_f64(), vec![0.1, 0.2, 0.3]);
    }

    #[test]
    fn unfinished_writer_leaves_nothing_and_short_data_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.npy");
        let mut w = NpyWriter::create(&p, NpyDtype::F64, &[4]).unwrap();
        w.write_f64(&[1.0]).unwrap();
        assert!(w.finish().is_err());
        assert!(!p.exists());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }

    #[test]
    fn rejects_bad_files() {
        assert!(parse(b"hello", "x.npy").is_err());
        let mut h = header_bytes(NpyDtype::F32, &[2]);
        h.extend_from_slice(&1f32.to_le_bytes());
        let e = parse(&h, "x.npy").unwrap_err().to_string();
        assert!(
            e.contains("x.npy") && e.contains("needs 8 data bytes"),
            "{e}"
        );
        let mut b = header_bytes(NpyDtype::F32, &[1]);
        let at = b.windows(3).position(|w| w == b"<f4").unwrap();
        b[at] = b'>';
        b.extend_from_slice(&[0; 4]);
        assert!(parse(&b, "x.npy").unwrap_err().to_string().contains(">f4"));
    }

    /// Raw `.npy` bytes built by hand: magic, `version`.0, the header length (u16 for version
    /// 1, u32 for 2 and 3), `header` unpadded, then `data` (a path independent of the writer).
    fn raw_npy(version: u8, header: &str, data: &[u8]) -> Vec<u8> {
        let mut b = b"\x93NUMPY".to_vec();
        b.extend_from_slice(&[version, 0]);
        if version == 1 {
            b.extend_from_slice(&u16::try_from(header.len()).unwrap().to_le_bytes());
        } else {
            b.extend_from_slice(&u32::try_from(header.len()).unwrap().to_le_bytes());
        }
        b.extend_from_slice(header.as_bytes());
        b.extend_from_slice(data);
        b
    }

    /// Little-endian bytes of f64 values.
    fn f64_bytes(values: &[f64]) -> Vec<u8> {
        values.iter().flat_map(|v| v.to_le_bytes()).collect()
    }

    /// The error message of parsing `bytes` as `x.npy`.
    fn parse_err(bytes: &[u8]) -> String {
        parse(bytes, "x.npy").unwrap_err().to_string()
    }

    /// The writer's header is NumPy's, byte for byte: version 1.0, header length 118 (0x76,
    /// what `np.save` writes for 1-D and 2-D arrays: 10 + 118 = 128 bytes), the dict with `(3,)`
    /// for one axis, `(2, 3)` for two and `()` for none, space padding and a final newline; the
    /// values follow in little-endian order.
    #[test]
    fn written_headers_are_numpys_byte_for_byte() {
        let dir = tempfile::tempdir().unwrap();
        let cases: [(&[usize], NpyDtype, &str); 3] = [
            (&[3], NpyDtype::F64, "(3,)"),
            (&[2, 3], NpyDtype::F32, "(2, 3)"),
            (&[], NpyDtype::F64, "()"),
        ];
        for (shape, dtype, shape_text) in cases {
            let p = dir.path().join("h.npy");
            let count: usize = shape.iter().product();
            let values: Vec<f64> = (0..count).map(|i| i as f64 + 0.5).collect();
            let mut w = NpyWriter::create(&p, dtype, shape).unwrap();
            w.write_f64(&values).unwrap();
            w.finish().unwrap();
            let bytes = std::fs::read(&p).unwrap();
            let descr = if dtype == NpyDtype::F32 { "<f4" } else { "<f8" };
            let dict =
                format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape_text}, }}");
            assert_eq!(&bytes[..10], b"\x93NUMPY\x01\x00\x76\x00", "{shape:?}");
            assert_eq!(&bytes[10..10 + dict.len()], dict.as_bytes(), "{shape:?}");
            assert!(
                bytes[10 + dict.len()..127].iter().all(|&b| b == b' '),
                "{shape:?}"
            );
            assert_eq!(bytes[127], b'\n', "{shape:?}");
            let data: Vec<u8> = match dtype {
                NpyDtype::F32 => values
                    .iter()
                    .flat_map(|&v| (v as f32).to_le_bytes())
                    .collect(),
                NpyDtype::F64 => f64_bytes(&values),
            };
            assert_eq!(&bytes[128..], &data[..], "{shape:?}");
        }
    }

    /// A header too long for version 1.0's u16 length (a shape of 22 000 axes) is written as
    /// version 2.0 with a u32 length, still padded to 64 bytes, and reads back; a dict of 65 524
    /// bytes, the longest whose padded header (65 526 bytes) still fits the u16, stays 1.0 (as
    /// NumPy writes it).
    #[test]
    fn long_headers_switch_to_version_2_only_when_they_must() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("v2.npy");
        let shape = vec![1; 22_000];
        write_f32(&p, &shape, &[2.5]).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        assert_eq!(&bytes[6..8], &[2, 0]);
        let hlen = u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize;
        assert_eq!(12 + hlen + 4, bytes.len());
        assert_eq!((12 + hlen) % 64, 0);
        assert_eq!(bytes[12 + hlen - 1], b'\n');
        let a = read(&p).unwrap();
        assert_eq!((a.shape, a.data), (shape, NpyData::F32(vec![2.5])));

        // The dict is 53 bytes plus 3 per axis of one digit, 4 per axis of two: 21 821 axes of
        // 1 and two of 10 make 53 + 3 * 21 821 + 2 * 4 = 65 524 bytes.
        let mut shape = vec![1; 21_821];
        shape.extend([10, 10]);
        let values: Vec<f32> = (0..100).map(|i| i as f32).collect();
        write_f32(&p, &shape, &values).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        assert_eq!(
            &bytes[6..10],
            &[1, 0, 0xf6, 0xff],
            "version 1.0, length 65 526"
        );
        assert_eq!(bytes.len(), 65_536 + 400);
        assert_eq!(read(&p).unwrap().to_f32(), values);
    }

    /// Padding at a 64-byte boundary, by hand from the format (prefix 10 + dict + newline,
    /// rounded up to 64): a dict of 117 bytes (53 + 3 per one-digit axis + 4 per two-digit
    /// one: `(10, 1, ...)` with 20 ones) exactly fills 128 bytes, so the header (length 118)
    /// has no space before its newline; a dict of 118 (two 10s, 19 ones) leaves the newline
    /// one byte over, so the header grows to 192 bytes (length 182) with 63 spaces.
    #[test]
    fn headers_ending_at_or_one_byte_past_a_64_byte_boundary_are_padded_to_it() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("edge.npy");
        let one_ten: Vec<usize> = [10].into_iter().chain([1; 20]).collect();
        let two_tens: Vec<usize> = [10, 10].into_iter().chain([1; 19]).collect();
        let cases: [(Vec<usize>, usize, u16, usize); 2] =
            [(one_ten, 117, 118, 0), (two_tens, 118, 182, 63)];
        for (shape, dict_len, hlen, spaces) in cases {
            let count: usize = shape.iter().product();
            let values: Vec<f32> = (0..count).map(|i| i as f32 - 0.25).collect();
            write_f32(&p, &shape, &values).unwrap();
            let bytes = std::fs::read(&p).unwrap();
            let axes: Vec<String> = shape.iter().map(|n| n.to_string()).collect();
            let dict = format!(
                "{{'descr': '<f4', 'fortran_order': False, 'shape': ({}), }}",
                axes.join(", ")
            );
            assert_eq!(dict.len(), dict_len, "{dict}");
            let data_at = 10 + usize::from(hlen);
            assert_eq!(data_at % 64, 0);
            assert_eq!(&bytes[..8], b"\x93NUMPY\x01\x00", "{dict_len}");
            assert_eq!(&bytes[8..10], &hlen.to_le_bytes(), "{dict_len}");
            assert_eq!(&bytes[10..10 + dict_len], dict.as_bytes(), "{dict_len}");
            assert_eq!(
                &bytes[10 + dict_len..data_at - 1],
                &vec![b' '; spaces][..],
                "{dict_len}"
            );
            assert_eq!(bytes[data_at - 1], b'\n', "{dict_len}");
            assert_eq!(bytes.len(), data_at + 4 * count, "{dict_len}");
            assert_eq!(read(&p).unwrap().to_f32(), values, "{dict_len}");
        }
    }

    /// The first dicts too long for version 1.0, as NumPy decides it (its padding is 1 to 64
    /// bytes, never 0, so 10 + dict + 1 + padding must stay within 10 + 65 535): a dict of
    /// 65 525 bytes (21 824 axes of 1: 53 + 3 * 21 824) and one of 65 526 (one of them 10)
    /// are written as 2.0, where 12 + dict + 1 rounds up to 65 600 bytes, a u32 header length
    /// of 65 588 (0x0001_0034); both read back. (65 524 bytes stay 1.0, pinned above.)
    #[test]
    fn dicts_of_65525_and_65526_bytes_are_written_as_version_2() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("v2.npy");
        let ones = vec![1; 21_824];
        let one_ten: Vec<usize> = [10].into_iter().chain([1; 21_823]).collect();
        for (shape, count) in [(ones, 1), (one_ten, 10)] {
            let values: Vec<f32> = (0..count).map(|i| i as f32 + 0.5).collect();
            write_f32(&p, &shape, &values).unwrap();
            let bytes = std::fs::read(&p).unwrap();
            assert_eq!(
                &bytes[6..12],
                &[2, 0, 0x34, 0x00, 0x01, 0x00],
                "version 2.0, length 65 588 ({count} values)"
            );
            assert_eq!(bytes[65_599], b'\n', "{count} values");
            assert_eq!(bytes.len(), 65_600 + 4 * count);
            let a = read(&p).unwrap();
            assert_eq!((a.to_f32(), a.shape), (values, shape));
        }
    }

    /// Hand-made headers as other writers make them parse: version 2.0 and 3.0 (u32 length),
    /// double-quoted keys, another key order with the shape first and no trailing comma, extra
    /// spaces; f64 values are decoded in C order.
    #[test]
    fn parses_other_writers_headers() {
        let values = [1.5, -2.0, 0.1, 1e300, -0.0, 7.0];
        let headers = [
            (
                1,
                "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }\n",
            ),
            (
                2,
                "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }\n",
            ),
            (
                3,
                "{\"descr\": \"<f8\", \"fortran_order\": False, \"shape\": (2, 3)}",
            ),
            (
                1,
                "{'shape': ( 2 , 3 ),'fortran_order' :False,'descr':'<f8'}",
            ),
        ];
        for (version, header) in headers {
            let a = parse(&raw_npy(version, header, &f64_bytes(&values)), "x.npy").unwrap();
            assert_eq!(a.shape, [2, 3], "{header}");
            assert_eq!(a.data, NpyData::F64(values.to_vec()), "{header}");
        }
        // A scalar (shape `()`) holds one value.
        let a = parse(
            &raw_npy(
                1,
                "{'descr': '<f4', 'fortran_order': False, 'shape': ()}",
                &[0, 0, 0x80, 0x3f],
            ),
            "x.npy",
        )
        .unwrap();
        assert_eq!((a.shape.len(), a.data), (0, NpyData::F32(vec![1.0])));
    }

    /// An array with no values (a zero-length axis) is a header that ends the file: it parses,
    /// and is empty.
    #[test]
    fn zero_length_arrays_end_at_the_header() {
        for shape in ["(0,)", "(2, 0)"] {
            let header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape}, }}");
            let a = parse(&raw_npy(1, &header, &[]), "x.npy").unwrap();
            assert_eq!((a.len(), a.is_empty()), (0, true), "{shape}");
            assert_eq!(a.to_f64(), Vec::<f64>::new());
        }
    }

    /// Length, emptiness and conversions: f32 values widen exactly, f64 values round to the
    /// nearest f32 (0.1 is 0.100000001490116119384765625 as f32).
    #[test]
    fn arrays_report_their_length_and_convert() {
        let a = NpyArray {
            shape: vec![2],
            data: NpyData::F32(vec![0.1, -3.0]),
        };
        assert_eq!((a.len(), a.is_empty()), (2, false));
        assert_eq!(a.to_f64(), [0.10000000149011612, -3.0]);
        assert_eq!(a.to_f32(), [0.1, -3.0]);
        let b = NpyArray {
            shape: vec![3],
            data: NpyData::F64(vec![0.1, 1e-50, 2.0]),
        };
        assert_eq!((b.len(), b.is_empty()), (3, false));
        assert_eq!(b.to_f32(), [0.1f32, 0.0, 2.0]);
        assert_eq!(b.to_f64(), [0.1, 1e-50, 2.0]);
    }

    /// Files too short, of another kind or version, or with a header that does not hold what
    /// an array needs, are errors that name the file and the problem; the shortest files are
    /// judged by their header (10 bytes are a whole 1.0 prefix, 12 a 2.0 one).
    #[test]
    fn bad_headers_are_errors_naming_the_problem() {
        let magic_err = "not an .npy file (missing \\x93NUMPY magic)";
        assert_eq!(
            parse_err(b"\x93NUMPY\x01\x00\x00"),
            format!("x.npy: {magic_err}")
        );
        assert_eq!(
            parse_err(b"\x93NUMPZ\x01\x00\x00\x00"),
            format!("x.npy: {magic_err}")
        );
        // A whole (empty) header: judged by what it lacks.
        assert!(parse_err(&raw_npy(1, "", &[])).contains("no 'descr' in .npy header \"\""));
        assert!(parse_err(&raw_npy(2, "", &[])).contains("no 'descr'"));
        assert_eq!(
            parse_err(b"\x93NUMPY\x02\x00\x00\x00\x00"),
            "x.npy: truncated .npy header"
        );
        assert_eq!(
            parse_err(b"\x93NUMPY\x04\x01\x00\x00"),
            "x.npy: unsupported .npy format version 4.1"
        );
        let mut long = raw_npy(1, "{'descr': '<f4'}", &[]);
        long[8] += 1;
        assert_eq!(parse_err(&long), "x.npy: truncated .npy header");
        let mut not_text = raw_npy(1, "{'descr': '<f4'}", &[]);
        not_text[12] = 0xff;
        assert_eq!(parse_err(&not_text), "x.npy: .npy header is not text");
        let e = |header: &str| parse_err(&raw_npy(1, header, &[0; 8]));
        assert!(e("{'fortran_order': False, 'shape': (2,)}").contains("no 'descr'"));
        assert!(e("{'descr': '<f4', 'shape': (2,)}").contains("no 'fortran_order'"));
        assert!(e("{'descr': '<f4', 'fortran_order': False}").contains("no 'shape'"));
        // A value with nothing after it (no `,` or `}`) is missing.
        assert!(e("{'fortran_order': False, 'shape': (2,), 'descr': '<f4'").contains("no 'descr'"));
        assert_eq!(
            e("{'descr': '<f4', 'fortran_order': True, 'shape': (2,)}"),
            "x.npy: Fortran-ordered .npy arrays are not supported"
        );
        assert!(
            e("{'descr': '<i4', 'fortran_order': False, 'shape': (2,)}")
                .contains("unsupported .npy dtype \"<i4\"")
        );
        assert!(
            e("{'descr': '<f4', 'fortran_order': False, 'shape': (2, x)}")
                .contains("bad .npy shape \"(2, x)\"")
        );
        let huge = "{'descr': '<f4', 'fortran_order': False, 'shape': (4294967296, 4294967296)}";
        assert_eq!(e(huge), "x.npy: shape [4294967296, 4294967296] overflows");
        assert_eq!(
            e("{'descr': '<f8', 'fortran_order': False, 'shape': (3,)}"),
            "x.npy: shape [3] of <f8 needs 24 data bytes, the file has 8"
        );
        // A byte count beyond usize is reported saturated, not wrapped.
        let e = parse_err(&raw_npy(
            1,
            "{'descr': '<f8', 'fortran_order': False, 'shape': (4611686018427387904,)}",
            &[],
        ));
        assert!(
            e.ends_with(&format!("needs {} data bytes, the file has 0", usize::MAX)),
            "{e}"
        );
    }

    /// The writer refuses a shape whose count overflows before creating anything, a write past
    /// the shape's count, and a finish before it (errors naming the file and the counts); f32
    /// values written to an f64 file are widened exactly.
    #[test]
    fn writer_counts_values_and_widens_f32() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("w.npy");
        let e = NpyWriter::create(&p, NpyDtype::F32, &[usize::MAX, 2]).unwrap_err();
        assert!(matches!(e, Error::InvalidArgument { .. }), "{e}");
        assert!(e.to_string().contains("overflows"), "{e}");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);

        let mut w = NpyWriter::create(&p, NpyDtype::F64, &[3]).unwrap();
        w.write_f32(&[0.1, 2.0]).unwrap();
        let e = w.write_f64(&[1.0, 2.0]).unwrap_err().to_string();
        assert!(
            e.contains("w.npy: 4 values written to an array of 3"),
            "{e}"
        );
        w.write_f64(&[-1.0]).unwrap();
        w.finish().unwrap();
        assert_eq!(
            read(&p).unwrap().data,
            NpyData::F64(vec![0.10000000149011612, 2.0, -1.0])
        );

        let mut w = NpyWriter::create(&p, NpyDtype::F32, &[2, 2]).unwrap();
        w.write_f32(&[1.0]).unwrap();
        let e = w.finish().unwrap_err().to_string();
        assert!(e.contains("w.npy: only 1 of 4 values written"), "{e}");
        assert_eq!(
            read(&p).unwrap().data,
            NpyData::F64(vec![0.10000000149011612, 2.0, -1.0]),
            "the unfinished file does not replace the finished one"
        );
    }
}
