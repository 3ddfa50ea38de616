//! The RGL `tensor_file` container (Dupuy & Jakob 2018): reader and writer.
//!
//! Layout (all integers little-endian):
//! - 12 bytes magic `tensor_file\0`, 2 bytes version (major 1, minor 0), `u32` field count;
//! - per field: `u16` name length, the name (UTF-8, no terminator), `u16` rank, `u8` dtype,
//!   `u64` byte offset of the data from the start of the file, `rank` x `u64` shape;
//! - raw little-endian arrays, row-major (last axis contiguous), at their offsets.
//!
//! dtype codes: 1 u8, 2 i8, 3 u16, 4 i16, 5 u32, 6 i32, 7 u64, 8 i64, 9 f16, 10 f32, 11 f64.
//! The reader checks every length, offset and shape against the file size and never panics on bad
//! input; floating-point fields converted with [`Field::to_f64`] / [`Field::to_f32`] must be
//! finite. The writer aligns every array to 8 bytes and writes through a temporary file that is
//! renamed into place.

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

/// The magic bytes at the start of every tensor file.
pub const MAGIC: &[u8; 12] = b"tensor_file\0";

/// Element type of a field.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DType {
    /// Unsigned 8-bit integer (code 1).
    U8,
    /// Signed 8-bit integer (code 2).
    I8,
    /// Unsigned 16-bit integer (code 3).
    U16,
    /// Signed 16-bit integer (code 4).
    I16,
    /// Unsigned 32-bit integer (code 5).
    U32,
    /// Signed 32-bit integer (code 6).
    I32,
    /// Unsigned 64-bit integer (code 7).
    U64,
    /// Signed 64-bit integer (code 8).
    I64,
    /// IEEE half-precision float (code 9).
    F16,
    /// IEEE single-precision float (code 10).
    F32,
    /// IEEE double-precision float (code 11).
    F64,
}

impl DType {
    /// The dtype of a file code, if the code is valid.
    pub fn from_code(code: u8) -> Option<Self> {
        Some(match code {
            1 => Self::U8,
            2 => Self::I8,
            3 => Self::U16,
            4 => Self::I16,
            5 => Self::U32,
            6 => Self::I32,
            7 => Self::U64,
            8 => Self::I64,
            9 => Self::F16,
            10 => Self::F32,
            11 => Self::F64,
            _ => return None,
        })
    }

    /// The file code of this dtype.
    pub fn code(self) -> u8 {
        match self {
            Self::U8 => 1,
            Self::I8 => 2,
            Self::U16 => 3,
            Self::I16 => 4,
            Self::U32 => 5,
            Self::I32 => 6,
            Self::U64 => 7,
            Self::I64 => 8,
            Self::F16 => 9,
            Self::F32 => 10,
            Self::F64 => 11,
        }
    }

    /// Size of one element in bytes.
    pub fn size(self) -> usize {
        match self {
            Self::U8 | Self::I8 => 1,
            Self::U16 | Self::I16 | Self::F16 => 2,
            Self::U32 | Self::I32 | Self::F32 => 4,
            Self::U64 | Self::I64 | Self::F64 => 8,
        }
    }

    /// Whether this is a floating-point type.
    pub fn is_float(self) -> bool {
        matches!(self, Self::F16 | Self::F32 | Self::F64)
    }
}

/// One named array of a tensor file.
#[derive(Debug, Clone, PartialEq)]
pub struct Field {
    name: String,
    dtype: DType,
    shape: Vec<usize>,
    bytes: Vec<u8>,
}

impl Field {
    /// A field from raw little-endian bytes; `bytes.len()` must equal the element count times
    /// the dtype size.
    pub fn from_raw(
        name: impl Into<String>,
        dtype: DType,
        shape: Vec<usize>,
        bytes: Vec<u8>,
    ) -> Result<Self> {
        let name = name.into();
        let count = element_count(&shape).ok_or_else(|| Error::InvalidArgument {
            reason: format!("field {name:?}: shape {shape:?} overflows"),
        })?;
        let expected = count.checked_mul(dtype.size());
        if expected != Some(bytes.len()) {
            return Err(Error::InvalidArgument {
                reason: format!(
                    "field {name:?}: shape {shape:?} of {dtype:?} needs {} bytes, got {}",
                    expected.map_or_else(|| "too many".to_string(), |e| e.to_string()),
                    bytes.len()
                ),
            });
        }
        if name.len() > u16::MAX as usize || shape.len() > u16::MAX as usize {
            return Err(Error::InvalidArgument {
                reason: format!("field {name:?}: name or rank too long for a tensor file"),
            });
        }
        Ok(Self {
            name,
            dtype,
            shape,
            bytes,
        })
    }

    /// An `f32` field of the given shape.
    pub fn from_f32(name: impl Into<String>, shape: Vec<usize>, values: &[f32]) -> Result<Self> {
        let bytes = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        Self::from_raw(name, DType::F32, shape, bytes)
    }

    /// An `f64` field of the given shape.
    pub fn from_f64(name: impl Into<String>, shape: Vec<usize>, values: &[f64]) -> Result<Self> {
        let bytes = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        Self::from_raw(name, DType::F64, shape, bytes)
    }

    /// A `u8` field of the given shape (also used for text such as `description`).
    pub fn from_u8(name: impl Into<String>, shape: Vec<usize>, values: &[u8]) -> Result<Self> {
        Self::from_raw(name, DType::U8, shape, values.to_vec())
    }

    /// The field name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The element type.
    pub fn dtype(&self) -> DType {
        self.dtype
    }

    /// The shape, outermost axis first (the last axis is contiguous).
    pub fn shape(&self) -> &[usize] {
        &self.shape
    }

    /// Number of elements.
    pub fn len(&self) -> usize {
        self.bytes.len() / self.dtype.size()
    }

    /// Whether the field holds no element.
    pub fn is_empty(&self) -> bool {
        self.bytes.is_empty()
    }

    /// The raw little-endian bytes.
    pub fn bytes(&self) -> &[u8] {
        &self.bytes
    }

    /// Element `i` converted to f64 (integers exactly up to 2^53).
    fn get(&self, i: usize) -> f64 {
        let s = self.dtype.size();
        let b = &self.bytes[i * s..(i + 1) * s];
        let arr = |n: usize| {
            let mut a = [0u8; 8];
            a[..n].copy_from_slice(&b[..n]);
            a
        };
        match self.dtype {
            DType::U8 => f64::from(b[0]),
            DType::I8 => f64::from(b[0] as i8),
            DType::U16 => f64::from(u16::from_le_bytes([b[0], b[1]])),
            DType::I16 => f64::from(i16::from_le_bytes([b[0], b[1]])),
            DType::U32 => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            DType::I32 => f64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            DType::U64 => u64::from_le_bytes(arr(8)) as f64,
            DType::I64 => i64::from_le_bytes(arr(8)) as f64,
            DType::F16 => f64::from(half::f16::from_le_bytes([b[0], b[1]])),
            DType::F32 => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            DType::F64 => f64::from_le_bytes(arr(8)),
        }
    }

    /// All elements as f64; a NaN or infinite element is an error naming `path`, the field and
    /// the element index.
    pub fn to_f64(&self, path: &Path) -> Result<Vec<f64>> {
        let mut out = Vec::with_capacity(self.len());
        for i in 0..self.len() {
            let v = self.get(i);
            if !v.is_finite() {
                return Err(Error::Format {
                    path: path.to_path_buf(),
                    reason: format!(
                        "field {:?} holds a non-finite value ({v}) at element {i}",
                        self.name
                    ),
                });
            }
            out.push(v);
        }
        Ok(out)
    }

    /// All elements as f32 (rounded from f64 for f64 fields); non-finite values (also after
    /// rounding) are an error as in [`Field::to_f64`].
    pub fn to_f32(&self, path: &Path) -> Result<Vec<f32>> {
        let v = self.to_f64(path)?;
        let mut out = Vec::with_capacity(v.len());
        for (i, x) in v.into_iter().enumerate() {
            let y = x as f32;
            if !y.is_finite() {
                return Err(Error::Format {
                    path: path.to_path_buf(),
                    reason: format!("field {:?}: element {i} ({x}) overflows f32", self.name),
                });
            }
            out.push(y);
        }
        Ok(out)
    }

    /// The field as text (for `u8` fields such as `description`), lossily decoded as UTF-8.
    pub fn to_text(&self) -> Option<String> {
        (self.dtype == DType::U8).then(|| String::from_utf8_lossy(&self.bytes).into_owned())
    }
}

fn element_count(shape: &[usize]) -> Option<usize> {
    shape.iter().try_fold(1usize, |acc, &n| acc.checked_mul(n))
}

/// A parsed tensor file: its path and its fields in file order.
#[derive(Debug, Clone)]
pub struct TensorFile {
    path: PathBuf,
    fields: Vec<Field>,
}

/// A little cursor over the header that turns every short read into a format error.
struct Cursor<'a> {
    bytes: &'a [u8],
    pos: usize,
    path: &'a Path,
}

impl Cursor<'_> {
    fn take(&mut self, n: usize, what: &str) -> Result<&[u8]> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.bytes.len());
        match end {
            Some(end) => {
                let s = &self.bytes[self.pos..end];
                self.pos = end;
                Ok(s)
            }
            None => Err(Error::Format {
                path: self.path.to_path_buf(),
                reason: format!(
                    "truncated tensor file: {what} needs {n} bytes at offset {}, the file has {}",
                    self.pos,
                    self.bytes.len()
                ),
            }),
        }
    }

    fn u8(&mut self, what: &str) -> Result<u8> {
        Ok(self.take(1, what)?[0])
    }

    fn u16(&mut self, what: &str) -> Result<u16> {
        let b = self.take(2, what)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }

    fn u32(&mut self, what: &str) -> Result<u32> {
        let b = self.take(4, what)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    fn u64(&mut self, what: &str) -> Result<u64> {
        let b = self.take(8, what)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        Ok(u64::from_le_bytes(a))
    }
}

/// What a file that is not a tensor file is, when its first bytes say so (a file renamed or
/// given in the wrong place): a specgp dataset store, a NumPy array or a PNG image.
fn known_format(bytes: &[u8]) -> Option<&'static str> {
    if bytes.starts_with(&crate::store::MAGIC) {
        Some("a specgp dataset store, .sbrdf")
    } else if bytes.starts_with(b"\x93NUMPY") {
        Some("a NumPy array, .npy")
    } else if bytes.starts_with(b"\x89PNG") {
        Some("a PNG image")
    } else {
        None
    }
}

impl TensorFile {
    /// Reads and validates the tensor file at `path`.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        Self::from_bytes(&bytes, path)
    }

    /// Parses a tensor file held in memory; `path` is only used in error messages.
    pub fn from_bytes(bytes: &[u8], path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let bad = |reason: String| Error::Format {
            path: path.to_path_buf(),
            reason,
        };
        let mut cur = Cursor {
            bytes,
            pos: 0,
            path,
        };
        if !bytes.starts_with(MAGIC) {
            let what = known_format(bytes).map_or_else(String::new, |w| format!(" (it is {w})"));
            return Err(bad(format!(
                "not a tensor file{what}: the first 12 bytes are {:?}, expected \
                 \"tensor_file\\0\"",
                String::from_utf8_lossy(&bytes[..bytes.len().min(12)])
            )));
        }
        cur.take(12, "the magic bytes")?;
        let version = cur.take(2, "the version")?;
        if version != [1, 0] {
            return Err(bad(format!(
                "unsupported tensor file version {}.{} (this reader supports 1.0)",
                version[0], version[1]
            )));
        }
        let n_fields = cur.u32("the field count")? as usize;
        // Each field header needs at least 13 bytes: a wildly large count is a corrupt file.
        if n_fields > bytes.len() / 13 {
            return Err(bad(format!(
                "field count {n_fields} cannot fit in a file of {} bytes",
                bytes.len()
            )));
        }
        let mut fields = Vec::with_capacity(n_fields);
        let mut names = HashSet::new();
        for k in 0..n_fields {
            let what = format!("the header of field {k}");
            let name_len = cur.u16(&what)? as usize;
            let name = std::str::from_utf8(cur.take(name_len, &what)?)
                .map_err(|_| bad(format!("field {k}: the name is not valid UTF-8")))?
                .to_string();
            let rank = cur.u16(&what)? as usize;
            let code = cur.u8(&what)?;
            let offset = cur.u64(&what)?;
            let dtype = DType::from_code(code).ok_or_else(|| {
                bad(format!(
                    "field {name:?}: unknown dtype code {code} (valid: 1..=11)"
                ))
            })?;
            let mut shape = Vec::with_capacity(rank.min(64));
            for _ in 0..rank {
                let n = cur.u64(&what)?;
                let n = usize::try_from(n)
                    .map_err(|_| bad(format!("field {name:?}: axis length {n} overflows")))?;
                shape.push(n);
            }
            let size = element_count(&shape)
                .and_then(|c| c.checked_mul(dtype.size()))
                .ok_or_else(|| bad(format!("field {name:?}: shape {shape:?} overflows")))?;
            let start = usize::try_from(offset).ok();
            let end = start.and_then(|s| s.checked_add(size));
            let (start, end) = match (start, end) {
                (Some(s), Some(e)) if e <= bytes.len() => (s, e),
                _ => {
                    return Err(bad(format!(
                        "field {name:?}: data at offset {offset} with {size} bytes (shape {shape:?}, \
                         {dtype:?}) runs past the end of the file ({} bytes)",
                        bytes.len()
                    )));
                }
            };
            if !names.insert(name.clone()) {
                return Err(bad(format!("field {name:?} appears twice")));
            }
            fields.push(Field {
                name,
                dtype,
                shape,
                bytes: bytes[start..end].to_vec(),
            });
        }
        Ok(Self {
            path: path.to_path_buf(),
            fields,
        })
    }

    /// The path this file was read from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The fields in file order.
    pub fn fields(&self) -> &[Field] {
        &self.fields
    }

    /// The field called `name`, if present.
    pub fn get(&self, name: &str) -> Option<&Field> {
        self.fields.iter().find(|f| f.name == name)
    }

    /// The field called `name`; a missing field is an error naming the file and the fields it has.
    pub fn field(&self, name: &str) -> Result<&Field> {
        self.get(name).ok_or_else(|| Error::Format {
            path: self.path.clone(),
            reason: format!(
                "missing field {name:?} (the file has: {})",
                self.fields
                    .iter()
                    .map(|f| f.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        })
    }

    /// The field called `name` as f64 values (see [`Field::to_f64`]).
    pub fn field_f64(&self, name: &str) -> Result<Vec<f64>> {
        self.field(name)?.to_f64(&self.path)
    }

    /// The field called `name` as f32 values (see [`Field::to_f32`]).
    pub fn field_f32(&self, name: &str) -> Result<Vec<f32>> {
        self.field(name)?.to_f32(&self.path)
    }

    /// Serialises `fields` into the bytes of a version-1.0 tensor file (arrays 8-byte aligned).
    pub fn to_bytes(fields: &[Field]) -> Result<Vec<u8>> {
        let mut names = HashSet::new();
        for f in fields {
            if !names.insert(f.name.as_str()) {
                return Err(Error::InvalidArgument {
                    reason: format!("field {:?} given twice", f.name),
                });
            }
        }
        let n_fields = u32::try_from(fields.len()).map_err(|_| Error::InvalidArgument {
            reason: "too many fields for a tensor file".into(),
        })?;
        let header_len: usize = 18
            + fields
                .iter()
                .map(|f| 2 + f.name.len() + 2 + 1 + 8 + 8 * f.shape.len())
                .sum::<usize>();
        let align = |x: usize| x.div_ceil(8) * 8;
        let mut offsets = Vec::with_capacity(fields.len());
        let mut pos = align(header_len);
        let mut end = pos;
        for f in fields {
            offsets.push(pos);
            end = pos + f.bytes.len();
            pos = align(end);
        }
        let mut out = Vec::with_capacity(end);
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&[1, 0]);
        out.extend_from_slice(&n_fields.to_le_bytes());
        for (f, &off) in fields.iter().zip(&offsets) {
            out.extend_from_slice(&(f.name.len() as u16).to_le_bytes());
            out.extend_from_slice(f.name.as_bytes());
            out.extend_from_slice(&(f.shape.len() as u16).to_le_bytes());
            out.push(f.dtype.code());
            out.extend_from_slice(&(off as u64).to_le_bytes());
            for &n in &f.shape {
                out.extend_from_slice(&(n as u64).to_le_bytes());
            }
        }
        for (f, &off) in fields.iter().zip(&offsets) {
            out.resize(off, 0);
            out.extend_from_slice(&f.bytes);
        }
        out.resize(end, 0);
        Ok(out)
    }

    /// The tensor file that `fields` make, as if read from `path` (no bytes involved).
    pub(crate) fn from_fields(fields: Vec<Field>, path: impl AsRef<Path>) -> Self {
        Self {
            path: path.as_ref().to_path_buf(),
            fields,
        }
    }

    /// The fields, taken out of the file.
    pub(crate) fn into_fields(self) -> Vec<Field> {
        self.fields
    }

    /// Writes `fields` as a tensor file at `path` through [`crate::output::write_file_atomic`]
    /// (temporary file and rename; special files such as `/dev/stdout` written in place).
    pub fn write(path: impl AsRef<Path>, fields: &[Field]) -> Result<()> {
        let bytes = Self::to_bytes(fields)?;
        crate::output::write_file_atomic(path, &bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tensor file written to a FIFO arrives whole and the FIFO survives; a file gets mode
    /// 0666 & !umask (the temporary file's 0600 used to stick).
    #[cfg(target_os = "linux")]
    #[test]
    fn writes_into_a_fifo_and_files_get_the_umask_mode() {
        use crate::output::test_util::{fifo, is_fifo, mode, umask};
        use std::io::Read;
        let dir = tempfile::tempdir().unwrap();
        let fields = sample_fields();
        let want = TensorFile::to_bytes(&fields).unwrap();
        let file = dir.path().join("t.bsdf");
        TensorFile::write(&file, &fields).unwrap();
        assert_eq!(mode(&file), 0o666 & !umask());
        assert_eq!(std::fs::read(&file).unwrap(), want);
        let (p, mut reader) = fifo(dir.path(), "pipe");
        TensorFile::write(&p, &fields).unwrap();
        assert!(is_fifo(&p));
        let mut got = vec![0u8; want.len()];
        reader.read_exact(&mut got).unwrap();
        assert_eq!(got, want);
    }

    fn sample_fields() -> Vec<Field> {
        vec![
            Field::from_u8("description", vec![5], b"hello").unwrap(),
            Field::from_f32("a", vec![2, 3], &[1.0, 2.0, 3.0, 4.0, 5.0, 6.5]).unwrap(),
            Field::from_f64("b", vec![1], &[-0.25]).unwrap(),
            Field::from_raw("c", DType::I16, vec![2], vec![0xff, 0xff, 2, 0]).unwrap(),
            Field::from_raw(
                "h",
                DType::F16,
                vec![1],
                half::f16::from_f64(1.5).to_le_bytes().to_vec(),
            )
            .unwrap(),
        ]
    }

    #[test]
    fn round_trip_in_memory() {
        let fields = sample_fields();
        let bytes = TensorFile::to_bytes(&fields).unwrap();
        let tf = TensorFile::from_bytes(&bytes, "mem.bsdf").unwrap();
        assert_eq!(tf.fields(), &fields[..]);
        let p = Path::new("mem.bsdf");
        assert_eq!(tf.field("a").unwrap().to_f64(p).unwrap()[5], 6.5);
        assert_eq!(tf.field("c").unwrap().to_f64(p).unwrap(), vec![-1.0, 2.0]);
        assert_eq!(tf.field("h").unwrap().to_f64(p).unwrap(), vec![1.5]);
        assert_eq!(tf.field("description").unwrap().to_text().unwrap(), "hello");
        let err = tf.field("zzz").unwrap_err().to_string();
        assert!(err.contains("mem.bsdf") && err.contains("zzz"), "{err}");
    }

    #[test]
    fn rejects_bad_headers() {
        let good = TensorFile::to_bytes(&sample_fields()).unwrap();
        let mut bad_magic = good.clone();
        bad_magic[0] = b'T';
        let e = TensorFile::from_bytes(&bad_magic, "x.bsdf")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("x.bsdf") && e.contains("not a tensor file"),
            "{e}"
        );
        // A file of another known format is named as such.
        let mut store = crate::store::MAGIC.to_vec();
        store.extend_from_slice(&[0; 32]);
        let e = TensorFile::from_bytes(&store, "s.bsdf")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("not a tensor file (it is a specgp dataset store, .sbrdf)"),
            "{e}"
        );
        let e = TensorFile::from_bytes(b"tens", "short.bsdf")
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a tensor file:"), "{e}");
        let mut bad_version = good.clone();
        bad_version[12] = 2;
        let e = TensorFile::from_bytes(&bad_version, "x.bsdf")
            .unwrap_err()
            .to_string();
        assert!(e.contains("version 2.0"), "{e}");
        // dtype of the first field sits after magic, version, count, name length, name, rank.
        let mut bad_dtype = good.clone();
        bad_dtype[18 + 2 + 11 + 2] = 42;
        let e = TensorFile::from_bytes(&bad_dtype, "x.bsdf")
            .unwrap_err()
            .to_string();
        assert!(e.contains("dtype code 42"), "{e}");
        let e = TensorFile::from_bytes(&good[..good.len() - 3], "x.bsdf")
            .unwrap_err()
            .to_string();
        assert!(e.contains("past the end"), "{e}");
    }

    #[test]
    fn non_finite_values_are_errors() {
        let f = Field::from_f32("x", vec![3], &[1.0, f32::NAN, 2.0]).unwrap();
        let e = f.to_f64(Path::new("n.bsdf")).unwrap_err().to_string();
        assert!(e.contains("n.bsdf") && e.contains("element 1"), "{e}");
        let f = Field::from_f64("y", vec![1], &[1e300]).unwrap();
        assert!(f.to_f32(Path::new("n.bsdf")).is_err());
    }

    /// Every dtype code 1..=11 maps to its dtype and back (codes 0 and 12 are refused), the
    /// sizes and the float flag are right, and a field of each dtype survives a round trip
    /// through the file bytes with its values (negative ones for the signed types).
    #[test]
    fn every_dtype_round_trips_through_a_file() {
        use DType::*;
        let all = [U8, I8, U16, I16, U32, I32, U64, I64, F16, F32, F64];
        for (k, &d) in all.iter().enumerate() {
            assert_eq!(d.code() as usize, k + 1);
            assert_eq!(DType::from_code(d.code()), Some(d));
            assert_eq!(d.is_float(), matches!(d, F16 | F32 | F64), "{d:?}");
        }
        assert_eq!(DType::from_code(0), None);
        assert_eq!(DType::from_code(12), None);
        let sizes = all.map(DType::size);
        assert_eq!(sizes, [1, 1, 2, 2, 4, 4, 8, 8, 2, 4, 8]);
        // Two elements per field: 3 and -2 (the bytes of -2 read as 2^bits - 2 when unsigned).
        let fields: Vec<Field> = all
            .iter()
            .map(|&d| {
                let bytes = match d {
                    U8 | I8 => vec![3, 0xfe],
                    U16 | I16 => [3i16, -2].iter().flat_map(|v| v.to_le_bytes()).collect(),
                    U32 | I32 => [3i32, -2].iter().flat_map(|v| v.to_le_bytes()).collect(),
                    U64 | I64 => [3i64, -2].iter().flat_map(|v| v.to_le_bytes()).collect(),
                    F16 => [3.0, -2.0]
                        .iter()
                        .flat_map(|&v| half::f16::from_f64(v).to_le_bytes())
                        .collect(),
                    F32 => [3.0f32, -2.0]
                        .iter()
                        .flat_map(|v| v.to_le_bytes())
                        .collect(),
                    F64 => [3.0f64, -2.0]
                        .iter()
                        .flat_map(|v| v.to_le_bytes())
                        .collect(),
                };
                Field::from_raw(format!("{d:?}"), d, vec![2], bytes).unwrap()
            })
            .collect();
        let bytes = TensorFile::to_bytes(&fields).unwrap();
        let tf = TensorFile::from_bytes(&bytes, "all.bsdf").unwrap();
        assert_eq!(tf.fields(), &fields[..]);
        let p = Path::new("all.bsdf");
        let want = |d: DType| match d {
            U8 => 254.0,
            U16 => 65534.0,
            U32 => 4_294_967_294.0,
            U64 => (u64::MAX - 1) as f64,
            _ => -2.0,
        };
        for (f, &d) in tf.fields().iter().zip(&all) {
            assert_eq!(f.dtype(), d);
            assert_eq!(f.to_f64(p).unwrap(), vec![3.0, want(d)], "{d:?}");
        }
    }

    /// The accessors: a field's raw bytes are the bytes it was made from, its length counts
    /// elements (not bytes), and only a field of no element is empty.
    #[test]
    fn field_accessors_report_bytes_length_and_emptiness() {
        let f = Field::from_f32("a", vec![2], &[1.0, -0.5]).unwrap();
        let mut want = 1.0f32.to_le_bytes().to_vec();
        want.extend_from_slice(&(-0.5f32).to_le_bytes());
        assert_eq!(f.bytes(), &want[..]);
        assert_eq!((f.len(), f.is_empty()), (2, false));
        let e = Field::from_f64("e", vec![3, 0], &[]).unwrap();
        assert_eq!((e.len(), e.is_empty(), e.bytes()), (0, true, &[][..]));
    }

    /// Names and ranks must fit the file's u16 length fields: 65535 bytes or axes are
    /// accepted and round-trip, 65536 are refused (either one alone).
    #[test]
    fn field_names_and_ranks_up_to_u16_max() {
        let max = u16::MAX as usize;
        let long = Field::from_u8("n".repeat(max), vec![1], &[7]).unwrap();
        let deep = Field::from_u8("d", vec![1; max], &[9]).unwrap();
        let bytes = TensorFile::to_bytes(&[long.clone(), deep.clone()]).unwrap();
        let tf = TensorFile::from_bytes(&bytes, "big.bsdf").unwrap();
        assert_eq!(tf.fields(), &[long, deep][..]);
        for (name, shape) in [
            ("n".repeat(max + 1), vec![1]),
            ("d".into(), vec![1; max + 1]),
        ] {
            let e = Field::from_u8(name, shape, &[1]).unwrap_err().to_string();
            assert!(e.contains("name or rank too long"), "{e}");
        }
    }

    /// A field count that cannot fit in the file (each field header takes at least 13 bytes)
    /// is refused up front, before anything is allocated for it; a count that could fit but
    /// whose headers are missing is a truncated file.
    #[test]
    fn field_counts_beyond_the_file_size_are_refused_up_front() {
        let header = |count: u32, len: usize| {
            let mut b = MAGIC.to_vec();
            b.extend_from_slice(&[1, 0]);
            b.extend_from_slice(&count.to_le_bytes());
            b.resize(len, 0);
            b
        };
        let e = TensorFile::from_bytes(&header(1000, 100), "c.bsdf")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("c.bsdf") && e.contains("field count 1000 cannot fit in a file of 100"),
            "{e}"
        );
        // 26 bytes: room for 26 / 13 = 2 field headers by the bound, but no field in them.
        let e = TensorFile::from_bytes(&header(2, 26), "c.bsdf")
            .unwrap_err()
            .to_string();
        assert!(e.contains("truncated tensor file"), "{e}");
        let e = TensorFile::from_bytes(&header(3, 26), "c.bsdf")
            .unwrap_err()
            .to_string();
        assert!(e.contains("field count 3 cannot fit"), "{e}");
    }

    #[test]
    fn writer_checks_lengths() {
        assert!(Field::from_f32("x", vec![2, 2], &[1.0; 3]).is_err());
        assert!(
            TensorFile::to_bytes(&[
                Field::from_u8("x", vec![1], &[1]).unwrap(),
                Field::from_u8("x", vec![1], &[2]).unwrap()
            ])
            .is_err()
        );
    }
}
