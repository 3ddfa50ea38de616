//! The dataset store (`.sbrdf`): N materials x D values on one grid, laid out for the two hot
//! paths of specgp.
//!
//! # Dimension order
//! A material row has `D = grid.len() * channels.len()` values; flat index
//! `d = angular_index * n_channels + channel` (channel fastest), with the angular index of
//! [`AngularGrid::index`] (MERL order, phi_d fastest). Cells whose bin centre lies below the
//! horizon ([`AngularGrid::validity_mask`]) are part of D but hold 0 (the writer zeroes them and
//! counts non-zero inputs it dropped); they never enter the statistics.
//!
//! # Layout (version 1)
//! The D indices are cut into chunks of `chunk_len` consecutive indices; a chunk is stored
//! **index-major**: for each d of the chunk, the N material values are contiguous. So
//! - a lookup of all N materials at one index d ([`Store::values_at`], lazy prediction) is one
//!   contiguous read of N values (uncompressed) or one slice of a cached decompressed chunk;
//! - a streaming Gram pass reads the chunks in file order, each an `N x chunk_len` column-major
//!   block ([`Store::for_each_chunk`], [`Store::par_fold_chunks`], [`Store::gram`]).
//!
//! File: a 64-byte prefix (magic `\x89SBRDF\n\x1a`, version u32, reserved u32, payload offset,
//! payload length, table offset, header offset, header length, xxh3-64 of the prefix and header,
//! all little-endian), the chunks from offset 4096 (f32 or f16, little-endian, optionally one
//! zstd frame per chunk), an offset table of `n_chunks + 1` u64 (chunk starts relative to the
//! payload), and the JSON [`StoreHeader`] (grid, channels, names, sources, layout, statistics and
//! the xxh3-64 checksum of chunks + table).

mod gram;
mod reader;
mod sample;
mod staging;
mod writer;

pub use gram::{F64_BLOCK, GramTransform, Identity};
pub use reader::{
    ON_DEMAND_MAX_BYTES, OpenOptions, PAGING_ENV, Paging, ReadMode, Store, WILL_NEED_GAP,
    WILL_NEED_MAX_RUN,
};
pub use sample::{StoreMaterial, parse_store_spec};
pub use writer::{MaterialWriter, StoreWriter, check_material_name};

use serde::{Deserialize, Serialize};

use crate::grid::{AngularGrid, Channels};

/// Asks the CPU to fetch the cache lines of `bytes` into L2 (x86-64 `prefetcht1`; elsewhere
/// nothing). A hint: it never faults and changes no value. Both users read the data after the
/// work at hand (the Gram pass's next block; a lazy lookup's next cell), which keeps L1 for
/// itself: prefetching a lookup's next cell into L1 instead made fast-table renders 1.4x and
/// default-table renders 1.6x slower (BENCHMARKS.md "render", session 11).
pub(crate) fn prefetch_lines(bytes: &[u8]) {
    #[cfg(target_arch = "x86_64")]
    for line in bytes.chunks(64) {
        use std::arch::x86_64::{_MM_HINT_T1, _mm_prefetch};
        // SAFETY: prefetching is a hint that never faults, the pointer is in bounds anyway,
        // and SSE is part of x86-64.
        unsafe { _mm_prefetch::<_MM_HINT_T1>(line.as_ptr().cast()) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = bytes;
}

/// Magic bytes at the start of every `.sbrdf` file.
pub const MAGIC: [u8; 8] = *b"\x89SBRDF\n\x1a";
/// The format version this build writes and reads.
pub const FORMAT_VERSION: u32 = 1;
/// Byte length of the fixed prefix.
pub(crate) const PREFIX_LEN: usize = 64;
/// Offset of the first chunk (page-aligned so memory-mapped f32 values are aligned).
pub(crate) const PAYLOAD_OFFSET: u64 = 4096;
/// The dimension order, spelled out in every header.
pub const DIMENSION_ORDER: &str = "d = angular_index * n_channels + channel (channel fastest); \
angular_index = (i_theta_h * n_theta_d + i_theta_d) * n_phi_d + i_phi_d (MERL order, phi_d fastest)";
/// The validity convention, spelled out in every header.
pub const VALIDITY: &str = "cells whose bin centre has wi or wo below the horizon \
(AngularGrid::validity_mask) hold 0 and are excluded from statistics";

/// Storage type of the values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub enum Dtype {
    /// IEEE 754 single precision (bit-exact round trip).
    F32,
    /// IEEE 754 half precision via the `half` crate (relative error <= 2^-11 in the normal range).
    F16,
}

impl Dtype {
    /// Bytes per stored value.
    pub fn size(self) -> usize {
        match self {
            Self::F32 => 4,
            Self::F16 => 2,
        }
    }

    /// `v` as this type stores it (f16: rounded to nearest, magnitudes below 2^-25 become 0).
    #[inline]
    pub fn round(self, v: f32) -> f32 {
        match self {
            Self::F32 => v,
            Self::F16 => half::f16::from_f32(v).to_f32(),
        }
    }

    /// The name used in headers and on the command line (`f32`, `f16`).
    pub fn name(self) -> &'static str {
        match self {
            Self::F32 => "f32",
            Self::F16 => "f16",
        }
    }
}

impl TryFrom<String> for Dtype {
    type Error = String;
    fn try_from(s: String) -> Result<Self, String> {
        match s.as_str() {
            "f32" => Ok(Self::F32),
            "f16" => Ok(Self::F16),
            _ => Err(format!("unsupported dtype {s:?} (supported: f32, f16)")),
        }
    }
}

impl From<Dtype> for String {
    fn from(d: Dtype) -> String {
        d.name().to_owned()
    }
}

impl std::str::FromStr for Dtype {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::try_from(s.to_owned())
    }
}

/// Compression of the chunks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum Compression {
    /// Raw little-endian values.
    None,
    /// One zstd frame per chunk at this level (1..=22; 3 is zstd's default).
    Zstd {
        /// zstd compression level.
        level: i32,
    },
    /// Byte-shuffled, then zstd: the chunk's bytes are regrouped by significance (all first
    /// bytes of the values, then all second bytes, ...), which lets zstd find the redundancy
    /// of similar exponents in float data.
    #[serde(rename = "zstd-shuffle")]
    ZstdShuffle {
        /// zstd compression level.
        level: i32,
    },
}

impl Compression {
    /// The zstd level, if compressed.
    pub fn zstd_level(self) -> Option<i32> {
        match self {
            Self::None => None,
            Self::Zstd { level } | Self::ZstdShuffle { level } => Some(level),
        }
    }
}

/// Regroups `bytes` of `size`-byte values by byte significance.
pub(crate) fn shuffle(bytes: &[u8], size: usize) -> Vec<u8> {
    let count = bytes.len() / size;
    let mut out = vec![0u8; bytes.len()];
    for (i, v) in bytes.chunks_exact(size).enumerate() {
        for (b, x) in v.iter().enumerate() {
            out[b * count + i] = *x;
        }
    }
    out
}

/// Inverse of [`shuffle`].
pub(crate) fn unshuffle(bytes: &[u8], size: usize) -> Vec<u8> {
    let count = bytes.len() / size;
    let mut out = vec![0u8; bytes.len()];
    for (i, v) in out.chunks_exact_mut(size).enumerate() {
        for (b, x) in v.iter_mut().enumerate() {
            *x = bytes[b * count + i];
        }
    }
    out
}

/// Options of [`StoreWriter`].
#[derive(Debug, Clone, PartialEq)]
pub struct StoreOptions {
    /// Indices per chunk; `None` picks about 1 MiB (uncompressed) or 256 KiB (zstd) per chunk.
    pub chunk_len: Option<usize>,
    /// Storage type of the values.
    pub dtype: Dtype,
    /// Chunk compression.
    pub compression: Compression,
    /// Memory the material-mode transpose may use, in bytes (default 256 MiB).
    pub memory_budget: usize,
}

impl Default for StoreOptions {
    fn default() -> Self {
        Self {
            chunk_len: None,
            dtype: Dtype::F32,
            compression: Compression::None,
            memory_budget: 256 << 20,
        }
    }
}

impl StoreOptions {
    /// The size of a store of `n_materials` x `d` values written with these options, when it
    /// is known before writing (uncompressed: values, header and chunk table); `None` with
    /// compression.
    pub fn uncompressed_bytes(&self, n_materials: usize, d: usize) -> Option<u64> {
        if self.compression != Compression::None {
            return None;
        }
        let values = (n_materials as u64)
            .saturating_mul(d as u64)
            .saturating_mul(self.dtype.size() as u64);
        let chunks = d.div_ceil(self.effective_chunk_len(n_materials, d).max(1)) as u64;
        Some(values.saturating_add(PAYLOAD_OFFSET + 8 * (chunks + 1)))
    }

    /// The chunk length used for `n` materials.
    pub fn effective_chunk_len(&self, n_materials: usize, d: usize) -> usize {
        let len = self.chunk_len.unwrap_or_else(|| {
            let target = match self.compression {
                Compression::None => 1 << 20,
                Compression::Zstd { .. } | Compression::ZstdShuffle { .. } => 256 << 10,
            };
            (target / (n_materials.max(1) * self.dtype.size())).max(1)
        });
        len.clamp(1, d.max(1))
    }
}

/// What a store is sampled on: the grid and the channel axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StoreInfo {
    /// Angular grid.
    pub grid: AngularGrid,
    /// Channel axis.
    pub channels: Channels,
}

impl StoreInfo {
    /// Values per material, `grid.len() * channels.len()`.
    pub fn d(&self) -> usize {
        self.grid.len() * self.channels.len()
    }
}

/// Statistics of stored values over the valid (above-horizon) cells.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ValueStats {
    /// Number of valid values.
    pub count: u64,
    /// Smallest valid value (0 when `count` is 0).
    pub min: f64,
    /// Largest valid value (0 when `count` is 0).
    pub max: f64,
    /// Mean of the valid values.
    pub mean: f64,
    /// Sum of squares of all stored values (the diagonal of the uncentred Gram matrix).
    pub sum_sq: f64,
    /// Number of negative valid values.
    pub negatives: u64,
    /// Number of non-zero below-horizon inputs the writer replaced by 0.
    pub zeroed_below_horizon: u64,
    /// Number of non-zero valid inputs the storage type rounded to 0 (f16: magnitudes below
    /// 2^-25 ~ 3e-8). The other statistics describe the values as stored.
    #[serde(default)]
    pub flushed_to_zero: u64,
}

impl Default for ValueStats {
    fn default() -> Self {
        Self {
            count: 0,
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
            mean: 0.0,
            sum_sq: 0.0,
            negatives: 0,
            zeroed_below_horizon: 0,
            flushed_to_zero: 0,
        }
    }
}

impl ValueStats {
    /// Merges another set of statistics into this one.
    pub fn merge(&mut self, o: &ValueStats) {
        let total = self.count + o.count;
        if total > 0 {
            self.mean = (self.mean * self.count as f64 + o.mean * o.count as f64) / total as f64;
        }
        self.count = total;
        self.min = self.min.min(o.min);
        self.max = self.max.max(o.max);
        self.sum_sq += o.sum_sq;
        self.negatives += o.negatives;
        self.zeroed_below_horizon += o.zeroed_below_horizon;
        self.flushed_to_zero += o.flushed_to_zero;
    }

    pub(crate) fn finalize(mut self) -> Self {
        if self.count == 0 {
            self.min = 0.0;
            self.max = 0.0;
        }
        self
    }
}

/// One material of a store.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MaterialEntry {
    /// Unique name.
    pub name: String,
    /// Where it came from (file path, generator and seed, ...).
    pub source: String,
    /// Statistics of its values.
    pub stats: ValueStats,
}

/// Chunk layout of the payload.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Layout {
    /// Always `chunked-index-major`.
    pub order: String,
    /// Consecutive d indices per chunk (the last chunk may be shorter).
    pub chunk_len: usize,
    /// Number of chunks, `ceil(D / chunk_len)`.
    pub n_chunks: usize,
    /// Storage type.
    pub dtype: Dtype,
    /// Chunk compression.
    pub compression: Compression,
}

/// Payload checksum.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Checksum {
    /// Always `xxh3-64`, over the chunk bytes and the offset table as stored.
    pub algorithm: String,
    /// The hash as 16 hex digits.
    pub value: String,
}

impl std::fmt::Display for Checksum {
    /// `algorithm:value`, e.g. `xxh3-64:a5d06b176ea1a16a` (how model files record a dataset).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}:{}", self.algorithm, self.value)
    }
}

/// The JSON header of a store.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StoreHeader {
    /// Always `specgp-sbrdf`.
    pub format: String,
    /// Format version ([`FORMAT_VERSION`]).
    pub version: u32,
    /// Angular grid.
    pub grid: AngularGrid,
    /// Channel axis.
    pub channels: Channels,
    /// Values per material.
    pub d: usize,
    /// The dimension order ([`DIMENSION_ORDER`]).
    pub dimension_order: String,
    /// The validity convention ([`VALIDITY`]).
    pub validity: String,
    /// The materials, in row order.
    pub materials: Vec<MaterialEntry>,
    /// Chunk layout.
    pub layout: Layout,
    /// Statistics over all materials.
    pub stats: ValueStats,
    /// Payload checksum.
    pub checksum: Checksum,
    /// Payload bytes (chunks + offset table).
    pub payload_bytes: u64,
    /// Writer that produced the file.
    pub created_by: String,
}

impl StoreHeader {
    /// Number of materials.
    pub fn n_materials(&self) -> usize {
        self.materials.len()
    }

    /// The d range of chunk `c`.
    pub fn chunk_range(&self, c: usize) -> std::ops::Range<usize> {
        let start = c * self.layout.chunk_len;
        start..(start + self.layout.chunk_len).min(self.d)
    }
}

/// Bytes of chunk index-major f32 values encoded as `dtype`.
pub(crate) fn encode_values(values: &[f32], dtype: Dtype, out: &mut Vec<u8>) {
    out.clear();
    match dtype {
        Dtype::F32 => {
            if cfg!(target_endian = "little") {
                // The values' own bytes are their little-endian encoding: one copy.
                out.extend_from_slice(bytemuck::cast_slice(values));
            } else {
                out.reserve(values.len() * 4);
                for v in values {
                    out.extend_from_slice(&v.to_le_bytes());
                }
            }
        }
        Dtype::F16 => {
            out.reserve(values.len() * 2);
            for v in values {
                out.extend_from_slice(&half::f16::from_f32(*v).to_le_bytes());
            }
        }
    }
}

/// Decodes little-endian `dtype` bytes into f32 values (`out.len()` values).
pub(crate) fn decode_values(bytes: &[u8], dtype: Dtype, out: &mut [f32]) {
    match dtype {
        Dtype::F32 => {
            for (o, b) in out.iter_mut().zip(bytes.chunks_exact(4)) {
                *o = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
            }
        }
        Dtype::F16 => {
            // Vectorised (F16C when the CPU has it) on aligned little-endian input.
            if cfg!(target_endian = "little")
                && let Ok(bits) = bytemuck::try_cast_slice::<u8, u16>(bytes)
                && bits.len() == out.len()
            {
                use half::slice::{HalfBitsSliceExt, HalfFloatSliceExt};
                bits.reinterpret_cast::<half::f16>()
                    .convert_to_f32_slice(out);
                return;
            }
            for (o, b) in out.iter_mut().zip(bytes.chunks_exact(2)) {
                *o = half::f16::from_le_bytes([b[0], b[1]]).to_f32();
            }
        }
    }
}

pub(crate) fn hex64(h: u64) -> String {
    format!("{h:016x}")
}

/// The baseline every throughput benchmark of specgp compares against: one plain sequential
/// read of the file at `path` from the page cache, single-threaded, 8 MiB `read` calls into one
/// buffer (each buffer touched so nothing is elided). Returns (bytes, seconds of the fastest of
/// `repeats` reads, after one untimed read that warms the cache). On a VM whose kernel tiers
/// memory (DAMON), the first reads of a file that has not been touched for a while can be several
/// times slower: benchmarks call this before and after the measured operation and keep the best.
pub fn sequential_read_seconds(
    path: &std::path::Path,
    repeats: usize,
) -> std::io::Result<(u64, f64)> {
    use std::io::Read;
    let mut buf = vec![0u8; 8 << 20];
    let mut best = f64::INFINITY;
    let mut bytes = 0;
    for round in 0..=repeats.max(1) {
        let start = std::time::Instant::now();
        let mut file = std::fs::File::open(path)?;
        let mut total = 0u64;
        let mut touch = 0u64;
        loop {
            let k = file.read(&mut buf)?;
            if k == 0 {
                break;
            }
            touch = touch.wrapping_add(u64::from(buf[k - 1]));
            total += k as u64;
        }
        std::hint::black_box(touch);
        bytes = total;
        if round > 0 {
            best = best.min(start.elapsed().as_secs_f64());
        }
    }
    Ok((bytes, best))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Values spanning half precision's range: normal, subnormal, rounded, out of range.
    const SAMPLES: [f32; 9] = [0.0, -1.5, 0.1, 3e-5, 6e-8, 65504.0, 1e5, 1.0 / 3.0, -2e-6];

    #[test]
    fn decode_values_reads_out_len_values_whatever_the_buffer_holds_beyond() {
        for dtype in [Dtype::F32, Dtype::F16] {
            let mut encoded = Vec::new();
            encode_values(&SAMPLES, dtype, &mut encoded);
            assert_eq!(encoded.len(), SAMPLES.len() * dtype.size());
            let expected: Vec<f32> = SAMPLES.iter().map(|&v| dtype.round(v)).collect();
            // In u32-aligned memory: at offset 0 the vectorised f16 path reads it, one byte in
            // (unaligned) the scalar path.
            for offset in [0, 1] {
                let mut words = vec![0u32; encoded.len() / 4 + 2];
                let memory: &mut [u8] = bytemuck::cast_slice_mut(&mut words);
                let bytes = &mut memory[offset..offset + encoded.len()];
                bytes.copy_from_slice(&encoded);
                let mut out = vec![f32::NAN; SAMPLES.len()];
                decode_values(bytes, dtype, &mut out);
                assert_eq!(out, expected, "{dtype:?} at {offset}");
                // Fewer values than the buffer holds: the first ones, on either path.
                let mut head = [f32::NAN; 4];
                decode_values(bytes, dtype, &mut head);
                assert_eq!(head, expected[..4], "{dtype:?} at {offset}");
            }
        }
    }
}
