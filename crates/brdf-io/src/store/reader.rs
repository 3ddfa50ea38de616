//! Reading `.sbrdf` stores: memory-mapped (default) or with positioned reads.

use std::fs::File;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};

use rayon::prelude::*;
use xxhash_rust::xxh3::Xxh3;

use super::gram::{GramAccumulator, GramTransform, Identity};
use super::staging::{StagedRun, Staging};
use super::writer::read_exact_at;
use super::{
    Compression, Dtype, FORMAT_VERSION, MAGIC, PAYLOAD_OFFSET, PREFIX_LEN, StoreHeader,
    decode_values, hex64,
};
use crate::error::{Error, Result};
use crate::grid::{AngularGrid, Channels};

/// How a [`Store`] reads its file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ReadMode {
    /// Memory-map the file (default): zero-copy chunks and lookups from the page cache.
    ///
    /// Contract (the one `unsafe` block of the store): the file must not be modified or
    /// truncated by anyone while a [`Store`] maps it. specgp never does (stores are written to a
    /// temporary file and renamed into place, so replacing a store is safe); if another process
    /// rewrites the file in place, reads may return changed values, and truncating it makes
    /// reads past the new end fault with SIGBUS. Use [`ReadMode::Buffered`] when that can happen.
    #[default]
    Mmap,
    /// Positioned reads (`pread`) into buffers: for file systems where mapping is unwise
    /// (network mounts, files that other processes may truncate).
    Buffered,
}

/// How a memory-mapped store's pages come in from the disk when they are not in the page cache.
///
/// A page fault in a mapping normally makes the kernel read a window around the page
/// (`read_ahead_kb`, 8 MB on this project's VMs): right for a store that fits in memory, where
/// the whole file soon sits in the page cache anyway, but a store larger than memory then reads
/// almost all of itself for a few thousand scattered lookups (a 256 px sphere of a predicted
/// material on the paper's 58 GB grid read ~55 GB in 25 s; BENCHMARKS.md "dataset store").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Paging {
    /// [`Paging::OnDemand`] for a file larger than half the physical memory, else
    /// [`Paging::ReadAround`]; the environment variable `SPECGP_PAGING` (`auto`, `on-demand`,
    /// `read-around`) overrides the choice.
    #[default]
    Auto,
    /// The kernel's default: a fault reads a window around its page.
    ReadAround,
    /// Small reads (a lookup's cell, one index's N values: under [`ON_DEMAND_MAX_BYTES`]) are
    /// positioned reads of exactly their bytes (one request to the disk for a cell, through a
    /// handle of their own advised `POSIX_FADV_RANDOM` on Linux, so that the kernel reads no
    /// more even for reads that follow one another) instead of faults in the map. Larger
    /// reads (chunks, the streaming passes, the checksum) keep the map and the kernel's
    /// read-around, whose read-ahead keeps a sequential pass at the disk's speed. Values are
    /// the same as under [`Paging::ReadAround`]; only the disk traffic differs.
    OnDemand,
}

/// [`Store::will_need`] reads ranges of the file at most this many bytes apart as one (the
/// bytes between cost less than another request to the disk).
pub const WILL_NEED_GAP: usize = 64 << 10;

/// [`Store::will_need`] merges ranges into runs of at most this many bytes.
pub const WILL_NEED_MAX_RUN: usize = 8 << 20;

/// The environment variable that overrides [`Paging::Auto`].
pub const PAGING_ENV: &str = "SPECGP_PAGING";

/// Reads shorter than this are positioned reads under [`Paging::OnDemand`] (a cell of the
/// paper's grid, 195 channels x 51 materials in f32, is 40 KB).
pub const ON_DEMAND_MAX_BYTES: usize = 1 << 20;

impl Paging {
    /// Parses `auto`, `on-demand` or `read-around` (the values of [`PAGING_ENV`]).
    pub fn parse(s: &str) -> Option<Self> {
        match s.trim() {
            "auto" => Some(Self::Auto),
            "on-demand" => Some(Self::OnDemand),
            "read-around" => Some(Self::ReadAround),
            _ => None,
        }
    }

    /// Whether a mapped file of `file_len` bytes is paged on demand: the variant's own answer,
    /// or for [`Paging::Auto`] the environment's (an error for a value that is not one of the
    /// three) or else the file's size against the physical memory.
    fn on_demand(self, file_len: u64, path: &Path) -> Result<bool> {
        match self {
            Self::ReadAround => Ok(false),
            Self::OnDemand => Ok(true),
            Self::Auto => match std::env::var(PAGING_ENV) {
                Ok(v) => match Self::parse(&v) {
                    Some(Self::Auto) => Ok(larger_than_half_the_memory(file_len)),
                    Some(p) => p.on_demand(file_len, path),
                    None => Err(Error::StoreUsage {
                        path: path.to_owned(),
                        reason: format!(
                            "{PAGING_ENV}={v:?}: expected auto, on-demand or read-around"
                        ),
                    }),
                },
                Err(_) => Ok(larger_than_half_the_memory(file_len)),
            },
        }
    }
}

/// Merges file spans `(offset, len)`, in the order given, into runs `emit(start, end, spans)`
/// (`spans`: how many spans the run holds; the hints of [`Store::will_need`]): a span
/// joins the run before it when it starts in it or at most `gap` bytes after its end and the
/// run stays within `max_run` bytes; otherwise (also when it starts before the run) it starts
/// a new run. Empty spans are skipped.
fn merge_spans(
    spans: impl IntoIterator<Item = (usize, usize)>,
    gap: usize,
    max_run: usize,
    mut emit: impl FnMut(usize, usize, usize),
) {
    let mut run: Option<(usize, usize, usize)> = None;
    for (offset, len) in spans.into_iter().filter(|&(_, len)| len > 0) {
        let end = offset + len;
        run = match run {
            Some((s, e, n)) if offset >= s && offset <= e + gap && end.max(e) - s <= max_run => {
                Some((s, end.max(e), n + 1))
            }
            Some((s, e, n)) => {
                emit(s, e, n);
                Some((offset, end, 1))
            }
            None => Some((offset, end, 1)),
        };
    }
    if let Some((s, e, n)) = run {
        emit(s, e, n);
    }
}

/// The handle for [`Paging::OnDemand`]'s positioned reads of a store opened as `file`: on
/// Linux a second open file description of the same file (`/proc/self/fd/N`, so it cannot be
/// another file) advised `POSIX_FADV_RANDOM`, so that the kernel reads what each read asks
/// instead of a read-ahead window that grows whenever reads happen to follow one another (the
/// RGL writer's cell reads then read 100 GB of a 58 GB store), while the map, made from
/// `file`, keeps its read-ahead for streaming passes; elsewhere, or when that fails, `file`.
fn random_read_handle(file: File) -> File {
    #[cfg(target_os = "linux")]
    {
        use std::os::fd::AsRawFd;
        let reopened = File::open(format!("/proc/self/fd/{}", file.as_raw_fd()));
        if let Ok(second) = reopened
            && rustix::fs::fadvise(&second, 0, None, rustix::fs::Advice::Random).is_ok()
        {
            return second;
        }
    }
    file
}

/// Asks the kernel to start reading bytes `start..end` of `file` into the page cache
/// (`posix_fadvise(WILLNEED)`, Linux; nothing elsewhere). A hint: a kernel that refuses it
/// reads the bytes when they are read.
fn advise_will_need(file: &File, start: usize, end: usize) {
    #[cfg(target_os = "linux")]
    let _ = rustix::fs::fadvise(
        file,
        start as u64,
        std::num::NonZeroU64::new((end - start) as u64),
        rustix::fs::Advice::WillNeed,
    );
    #[cfg(not(target_os = "linux"))]
    let _ = (file, start, end);
}

/// Whether `bytes` exceed half the physical memory (`MemTotal` of `/proc/meminfo`; false where
/// that cannot be read).
fn larger_than_half_the_memory(bytes: u64) -> bool {
    let total = std::fs::read_to_string("/proc/meminfo").ok().and_then(|m| {
        let line = m.lines().find(|l| l.starts_with("MemTotal:"))?;
        let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
        kib.checked_mul(1024)
    });
    total.is_some_and(|t| bytes > t / 2)
}

/// Options of [`Store::open_with`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OpenOptions {
    /// Memory map or positioned reads.
    pub mode: ReadMode,
    /// Decompressed chunks kept for [`Store::values_at`] on zstd stores (default 64).
    pub cache_chunks: usize,
    /// How a memory map's pages are read from the disk (no effect on positioned reads).
    pub paging: Paging,
}

impl Default for OpenOptions {
    fn default() -> Self {
        Self {
            mode: ReadMode::Mmap,
            cache_chunks: 64,
            paging: Paging::Auto,
        }
    }
}

enum Backing {
    /// The map, and under [`Paging::OnDemand`] the file for small positioned reads.
    Mmap(memmap2::Mmap, Option<File>),
    File(File),
}

const CACHE_SHARDS: usize = 16;

/// (chunk index, last-use stamp, decoded values).
type CacheEntry = (usize, u64, Arc<Vec<f32>>);

struct ChunkCache {
    shards: Vec<Mutex<Vec<CacheEntry>>>,
    per_shard: usize,
    clock: AtomicU64,
}

/// Number of contiguous chunk segments [`Store::par_fold_chunks`] folds in parallel; fixed so
/// that results do not depend on the thread count.
const PAR_FOLD_SEGMENTS: usize = 32;

/// Memory the Gram pass's accumulators may hold at once (bytes): beyond it, the segments are
/// folded in waves of [`FOLD_WAVE_PER_THREAD`] per thread. Waves cost time (the threads wait
/// for each other at their ends: +7-10 % on the default synthetic store's pass, session 19),
/// so they are kept for stores of thousands of materials.
const FOLD_MEMORY_BUDGET: u64 = 1 << 30;

/// Segments per worker thread in a wave of a fold that would otherwise exceed its memory.
const FOLD_WAVE_PER_THREAD: usize = 2;

/// An open dataset store. `Send + Sync`: share one `Store` (or `Arc<Store>`) between threads.
pub struct Store {
    path: PathBuf,
    header: StoreHeader,
    backing: Backing,
    /// Chunk start offsets relative to the payload, `n_chunks + 1` entries.
    offsets: Vec<u64>,
    table_offset: u64,
    file_len: u64,
    cache: ChunkCache,
    mask: OnceLock<Vec<bool>>,
    /// Runs read ahead with direct I/O for [`Store::will_need`] hints (a store read with
    /// positioned reads, where direct I/O is available; see `staging.rs`), set up by the
    /// first hint.
    staging: OnceLock<Option<Staging>>,
}

/// The largest ratio of decompressed to compressed size a zstd frame can have: a block holds
/// at most 128 KiB and takes at least 4 bytes (a 3-byte header and one RLE byte).
const ZSTD_MAX_RATIO: usize = 32_768;

/// Why the zstd frame `raw` cannot decompress to `want` bytes, if it cannot: more than zstd
/// can encode in `raw.len()` bytes, or a frame header that records another size.
fn check_zstd_claim(raw: &[u8], want: usize) -> std::result::Result<(), String> {
    if want / ZSTD_MAX_RATIO > raw.len() {
        return Err(format!(
            "{} compressed bytes cannot hold it (zstd encodes at most {ZSTD_MAX_RATIO} bytes \
             per byte)",
            raw.len()
        ));
    }
    match zstd::zstd_safe::get_frame_content_size(raw) {
        Ok(Some(size)) if size != want as u64 => {
            Err(format!("its zstd frame records {size} bytes"))
        }
        Ok(_) => Ok(()),
        Err(_) => Err("not a zstd frame".into()),
    }
}

fn corrupt(path: &Path, reason: impl Into<String>) -> Error {
    Error::StoreCorrupt {
        path: path.to_owned(),
        reason: reason.into(),
    }
}

impl Store {
    /// Opens a store with the default options (memory-mapped; see [`ReadMode::Mmap`] for the
    /// contract on the file).
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        Self::open_with(path, OpenOptions::default())
    }

    /// Opens a store: reads and checks the prefix, header and offset table (not the payload
    /// checksum; see [`Store::verify_checksum`]).
    pub fn open_with(path: impl AsRef<Path>, options: OpenOptions) -> Result<Self> {
        let path = path.as_ref().to_owned();
        // Checked before opening: opening a FIFO blocks until something writes to it, and a
        // pipe (`<(...)`) has length 0, which read as "the file is empty".
        let meta = std::fs::metadata(&path).map_err(|e| Error::io(&path, e))?;
        if !meta.is_file() {
            let what = if meta.is_dir() {
                "a directory"
            } else {
                "not a regular file (a pipe, socket or device)"
            };
            return Err(Error::StoreUsage {
                path,
                reason: format!(
                    "{what}: a dataset store is read at offsets (memory-mapped), so it must be \
                     a regular file"
                ),
            });
        }
        let file = File::open(&path).map_err(|e| Error::io(&path, e))?;
        let file_len = file.metadata().map_err(|e| Error::io(&path, e))?.len();
        let mut prefix = [0u8; PREFIX_LEN];
        let have = (file_len as usize).min(PREFIX_LEN);
        read_exact_at(&file, &mut prefix[..have], 0).map_err(|e| Error::io(&path, e))?;
        if have < MAGIC.len() || prefix[..8] != MAGIC {
            return Err(Error::NotAStore {
                path,
                reason: describe_foreign_file(&prefix[..have], file_len),
            });
        }
        if have < PREFIX_LEN {
            return Err(corrupt(
                &path,
                format!("truncated: {file_len} bytes, shorter than the {PREFIX_LEN}-byte prefix"),
            ));
        }
        let u64_at = |i: usize| u64::from_le_bytes(prefix[i..i + 8].try_into().unwrap());
        let version = u32::from_le_bytes(prefix[8..12].try_into().unwrap());
        if version != FORMAT_VERSION {
            return Err(Error::StoreVersion {
                path,
                found: version,
                supported: FORMAT_VERSION,
            });
        }
        let (payload_offset, payload_len, table_offset, header_offset, header_len) =
            (u64_at(16), u64_at(24), u64_at(32), u64_at(40), u64_at(48));
        let expected_len = header_offset.checked_add(header_len);
        if expected_len != Some(file_len) {
            return Err(corrupt(
                &path,
                format!(
                    "truncated or extended: {file_len} bytes, the prefix says {}",
                    expected_len.map_or("an overflowing length".into(), |l| l.to_string())
                ),
            ));
        }
        if payload_offset != PAYLOAD_OFFSET
            || table_offset < payload_offset
            || payload_offset.checked_add(payload_len) != Some(header_offset)
            || table_offset > header_offset
            || header_len > 64 << 20
        {
            return Err(corrupt(&path, "inconsistent offsets in the prefix"));
        }
        let mut json = vec![0u8; header_len as usize];
        read_exact_at(&file, &mut json, header_offset).map_err(|e| Error::io(&path, e))?;
        let mut h = Xxh3::new();
        h.update(&prefix[..56]);
        h.update(&json);
        if h.digest() != u64_at(56) {
            return Err(corrupt(
                &path,
                "prefix/header hash mismatch (header damaged)",
            ));
        }
        let header: StoreHeader =
            serde_json::from_slice(&json).map_err(|e| corrupt(&path, format!("header: {e}")))?;
        validate_header(&header, &path)?;
        if header.payload_bytes != payload_len {
            return Err(corrupt(
                &path,
                format!(
                    "the header's payload_bytes = {} disagrees with the prefix's payload length {payload_len}",
                    header.payload_bytes
                ),
            ));
        }
        let n_chunks = header.layout.n_chunks;
        let table_len = (n_chunks as u64 + 1) * 8;
        if table_offset + table_len != header_offset {
            return Err(corrupt(
                &path,
                "offset table size does not match the chunk count",
            ));
        }
        let mut table = vec![0u8; table_len as usize];
        read_exact_at(&file, &mut table, table_offset).map_err(|e| Error::io(&path, e))?;
        let offsets: Vec<u64> = table
            .chunks_exact(8)
            .map(|b| u64::from_le_bytes(b.try_into().unwrap()))
            .collect();
        let n = header.n_materials();
        let size = header.layout.dtype.size() as u64;
        let monotone = offsets.windows(2).all(|w| w[0] <= w[1]);
        if offsets[0] != 0 || !monotone || offsets[n_chunks] != table_offset - payload_offset {
            return Err(corrupt(
                &path,
                "offset table is not a partition of the payload",
            ));
        }
        if header.layout.compression == Compression::None {
            for c in 0..n_chunks {
                let want = header.chunk_range(c).len() as u64 * n as u64 * size;
                if offsets[c + 1] - offsets[c] != want {
                    return Err(corrupt(&path, format!("chunk {c} has the wrong size")));
                }
            }
        }
        let backing = match options.mode {
            ReadMode::Buffered => Backing::File(file),
            ReadMode::Mmap => {
                // SAFETY: memmap2 requires that the mapped file is not modified or truncated
                // while the map lives. Contract of `Store` (documented on `ReadMode::Mmap`,
                // `Store::open`): `.sbrdf` files are written once into a temporary file and
                // renamed into place, never modified in place by specgp; a user who truncates
                // or rewrites a mapped file from another process breaks the contract, and the
                // process may then read changed values or receive SIGBUS on access to pages
                // past the new end of file. Use `ReadMode::Buffered` where that can happen.
                let map = unsafe { memmap2::Mmap::map(&file) }.map_err(|e| Error::io(&path, e))?;
                let small_reads = options
                    .paging
                    .on_demand(file_len, &path)?
                    .then(|| random_read_handle(file));
                Backing::Mmap(map, small_reads)
            }
        };
        let per_shard = options.cache_chunks.div_ceil(CACHE_SHARDS).max(1);
        Ok(Self {
            path,
            header,
            backing,
            offsets,
            table_offset,
            file_len,
            cache: ChunkCache {
                shards: (0..CACHE_SHARDS).map(|_| Mutex::new(Vec::new())).collect(),
                per_shard,
                clock: AtomicU64::new(0),
            },
            mask: OnceLock::new(),
            staging: OnceLock::new(),
        })
    }

    /// The file this store was opened from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The header (grid, channels, materials, layout, statistics, checksum).
    pub fn header(&self) -> &StoreHeader {
        &self.header
    }

    /// Number of materials N.
    pub fn n_materials(&self) -> usize {
        self.header.materials.len()
    }

    /// Values per material D.
    pub fn d(&self) -> usize {
        self.header.d
    }

    /// The angular grid.
    pub fn grid(&self) -> &AngularGrid {
        &self.header.grid
    }

    /// The channel axis.
    pub fn channels(&self) -> &Channels {
        &self.header.channels
    }

    /// Material names in row order.
    pub fn names(&self) -> Vec<&str> {
        self.header
            .materials
            .iter()
            .map(|m| m.name.as_str())
            .collect()
    }

    /// Row index of the material called `name`.
    pub fn material_index(&self, name: &str) -> Result<usize> {
        self.header
            .materials
            .iter()
            .position(|m| m.name == name)
            .ok_or_else(|| {
                let names = self.names();
                Error::UnknownMaterial {
                    path: self.path.clone(),
                    name: name.to_owned(),
                    closest: crate::error::closest_name(name, &names).map(str::to_owned),
                    available: names.join(", "),
                }
            })
    }

    /// Number of chunks.
    pub fn n_chunks(&self) -> usize {
        self.header.layout.n_chunks
    }

    /// The d range of chunk `c`.
    pub fn chunk_range(&self, c: usize) -> Range<usize> {
        self.header.chunk_range(c)
    }

    /// Size of the file in bytes.
    pub fn file_bytes(&self) -> u64 {
        self.file_len
    }

    /// Validity mask over angular indices (cached).
    pub fn validity_mask(&self) -> &[bool] {
        self.mask.get_or_init(|| self.header.grid.validity_mask())
    }

    /// Whether the store is memory-mapped and paged on demand ([`Paging::OnDemand`]).
    pub fn paged_on_demand(&self) -> bool {
        matches!(self.backing, Backing::Mmap(_, Some(_)))
    }

    /// Whether [`Store::will_need`] hints reach the kernel: an uncompressed store whose values
    /// are read from the file as they are needed (positioned reads under
    /// [`Paging::OnDemand`], or [`ReadMode::Buffered`]), on Linux. A consumer may skip working
    /// out what it will read when they do not.
    pub fn takes_will_need(&self) -> bool {
        self.will_need_file().is_some()
    }

    /// The file that [`Store::will_need`] hints go to ([`Store::takes_will_need`]).
    fn will_need_file(&self) -> Option<&File> {
        let uncompressed = self.header.layout.compression == Compression::None;
        match &self.backing {
            Backing::Mmap(_, Some(file)) | Backing::File(file)
                if cfg!(target_os = "linux") && uncompressed =>
            {
                Some(file)
            }
            _ => None,
        }
    }

    /// The file for a positioned read of `len` bytes instead of the map: the store's file
    /// under [`Paging::OnDemand`] for a read shorter than [`ON_DEMAND_MAX_BYTES`], else `None`.
    fn read_on_demand(&self, len: usize) -> Option<&File> {
        match &self.backing {
            Backing::Mmap(_, Some(file)) if len < ON_DEMAND_MAX_BYTES => Some(file),
            _ => None,
        }
    }

    /// Raw bytes at `offset..offset + len` of the file.
    fn bytes(&self, offset: u64, len: usize) -> Result<FileBytes<'_>> {
        match (&self.backing, self.read_on_demand(len)) {
            (Backing::Mmap(m, _), None) => {
                let s = offset as usize;
                m.get(s..s + len).map(FileBytes::Mapped).ok_or_else(|| {
                    corrupt(&self.path, format!("read past the end at byte {offset}"))
                })
            }
            (Backing::File(f), _) | (_, Some(f)) => {
                if let Some(staging) = self.staging()
                    && let Some(run) = staging.read(offset as usize, len)
                {
                    return Ok(FileBytes::Staged {
                        run: Some(run),
                        offset: offset as usize,
                        len,
                        staging,
                    });
                }
                let mut buf = vec![0u8; len];
                read_exact_at(f, &mut buf, offset).map_err(|e| Error::io(&self.path, e))?;
                Ok(FileBytes::Read(buf))
            }
        }
    }

    /// The staged runs, once a hint has set them up.
    fn staging(&self) -> Option<&Staging> {
        self.staging.get()?.as_ref()
    }

    fn chunk_bytes(&self, c: usize) -> Result<FileBytes<'_>> {
        let (a, b) = (self.offsets[c], self.offsets[c + 1]);
        self.bytes(PAYLOAD_OFFSET + a, (b - a) as usize)
    }

    /// Decodes chunk `c` into `out` (index-major, `len * N` values); returns its d range.
    pub fn read_chunk(&self, c: usize, out: &mut Vec<f32>) -> Result<Range<usize>> {
        if c >= self.n_chunks() {
            return Err(Error::StoreUsage {
                path: self.path.clone(),
                reason: format!("chunk {c} out of range (the store has {})", self.n_chunks()),
            });
        }
        let range = self.chunk_range(c);
        let count = range.len() * self.n_materials();
        let raw = self.chunk_bytes(c)?;
        let dtype = self.header.layout.dtype;
        match self.header.layout.compression {
            Compression::None => {
                out.clear();
                out.resize(count, 0.0);
                decode_values(&raw, dtype, out)
            }
            compression => {
                let want = count * dtype.size();
                // Checked before allocating: a damaged or crafted header can claim a chunk of
                // terabytes behind a few compressed bytes.
                check_zstd_claim(&raw, want).map_err(|reason| {
                    corrupt(&self.path, format!("chunk {c} ({want} bytes): {reason}"))
                })?;
                let no_memory = |_| Error::OutOfMemory {
                    path: self.path.clone(),
                    what: format!("decompressing chunk {c}"),
                    needed: want as u64,
                };
                let mut bytes = Vec::new();
                bytes.try_reserve_exact(want).map_err(no_memory)?;
                bytes.resize(want, 0);
                let got = zstd::bulk::decompress_to_buffer(&raw, &mut bytes)
                    .map_err(|e| corrupt(&self.path, format!("chunk {c}: zstd: {e}")))?;
                if got != want {
                    return Err(corrupt(
                        &self.path,
                        format!("chunk {c}: {got} bytes decompressed, expected {want}"),
                    ));
                }
                out.clear();
                out.try_reserve_exact(count).map_err(no_memory)?;
                out.resize(count, 0.0);
                if let Compression::ZstdShuffle { .. } = compression {
                    decode_values(&super::unshuffle(&bytes, dtype.size()), dtype, out);
                } else {
                    decode_values(&bytes, dtype, out);
                }
            }
        }
        Ok(range)
    }

    /// Chunk `c` (index-major, as [`Store::read_chunk`]) and its d range, borrowed from the
    /// memory map when possible (uncompressed f32, mmap, little-endian host: no copy), else
    /// decoded into `buf`.
    pub fn chunk<'a>(
        &'a self,
        c: usize,
        buf: &'a mut Vec<f32>,
    ) -> Result<(Range<usize>, &'a [f32])> {
        if c >= self.n_chunks() {
            return Err(Error::StoreUsage {
                path: self.path.clone(),
                reason: format!("chunk {c} out of range (the store has {})", self.n_chunks()),
            });
        }
        let values = self.chunk_values(c, buf)?;
        Ok((self.chunk_range(c), values))
    }

    /// Chunk `c` as f32 values, borrowed from the map when possible (uncompressed f32, mmap,
    /// little-endian host), else decoded into `buf`.
    fn chunk_values<'a>(&'a self, c: usize, buf: &'a mut Vec<f32>) -> Result<&'a [f32]> {
        if cfg!(target_endian = "little")
            && self.header.layout.compression == Compression::None
            && self.header.layout.dtype == Dtype::F32
            && let Backing::Mmap(m, _) = &self.backing
        {
            let (a, b) = (self.offsets[c] as usize, self.offsets[c + 1] as usize);
            let s = PAYLOAD_OFFSET as usize;
            if let Ok(v) = bytemuck::try_cast_slice::<u8, f32>(&m[s + a..s + b]) {
                return Ok(v);
            }
        }
        self.read_chunk(c, buf)?;
        Ok(buf)
    }

    /// Streams every chunk in order: `f(d_range, block)` with `block[(d - d_range.start) * N + n]`
    /// (index-major; as a matrix: N x len, column-major).
    pub fn for_each_chunk(&self, mut f: impl FnMut(Range<usize>, &[f32])) -> Result<()> {
        let mut buf = Vec::new();
        for c in 0..self.n_chunks() {
            let v = self.chunk_values(c, &mut buf)?;
            f(self.chunk_range(c), v);
        }
        Ok(())
    }

    /// Parallel fold over the chunks (rayon): each worker starts from `init()`, folds chunks in
    /// with `fold(acc, d_range, block)` (block as in [`Store::for_each_chunk`]), and the partial
    /// results are combined with `reduce`. The grouping of chunks and the order of reduction are
    /// fixed, so the result is bit-identical from run to run and on any number of threads.
    /// Up to 33 accumulators are alive at once.
    pub fn par_fold_chunks<T: Send>(
        &self,
        init: impl Fn() -> T + Sync + Send,
        fold: impl Fn(&mut T, Range<usize>, &[f32]) + Sync + Send,
        reduce: impl Fn(T, T) -> T + Sync + Send,
    ) -> Result<T> {
        self.par_try_fold_chunks(PAR_FOLD_SEGMENTS, || Ok(init()), fold, reduce)
    }

    /// [`Store::par_fold_chunks`] with accumulators that may fail to be made (too large to
    /// allocate: the first such error is returned), and at most `wave` segments folded at once
    /// (`wave` + 1 accumulators alive); the result does not depend on `wave`.
    fn par_try_fold_chunks<T: Send>(
        &self,
        wave: usize,
        init: impl Fn() -> Result<T> + Sync + Send,
        fold: impl Fn(&mut T, Range<usize>, &[f32]) + Sync + Send,
        reduce: impl Fn(T, T) -> T + Sync + Send,
    ) -> Result<T> {
        // Deterministic whatever the thread count and scheduling: the chunks are split into at
        // most PAR_FOLD_SEGMENTS contiguous segments, each folded in chunk order, and the segment
        // results are reduced left to right. Floating-point sums (the Gram matrix) are then
        // bit-identical from run to run, which makes fits reproducible. Waves of segments are
        // reduced into the total before the next wave starts, in the same order.
        let n_chunks = self.n_chunks();
        let per_segment = n_chunks.div_ceil(PAR_FOLD_SEGMENTS).max(1);
        let n_segments = n_chunks.div_ceil(per_segment);
        let wave = wave.max(1);
        let mut total = init()?;
        for first in (0..n_segments).step_by(wave) {
            let partials = (first..(first + wave).min(n_segments))
                .into_par_iter()
                .map(|s| {
                    let mut acc = init()?;
                    let mut buf = Vec::new();
                    for c in s * per_segment..((s + 1) * per_segment).min(n_chunks) {
                        let v = self.chunk_values(c, &mut buf)?;
                        fold(&mut acc, self.chunk_range(c), v);
                    }
                    Ok::<_, Error>(acc)
                })
                .collect::<Result<Vec<T>>>()?;
            total = partials.into_iter().fold(total, &reduce);
        }
        Ok(total)
    }

    /// The uncentred N x N Gram matrix `G[n][m] = sum_d y_n[d] y_m[d]` (row-major), f64
    /// arithmetic, in one parallel streaming pass.
    pub fn gram(&self) -> Result<Vec<f64>> {
        self.gram_with(&Identity)
    }

    /// The Gram matrix of transformed values `t(y)` over the valid cells (below-horizon cells
    /// are skipped whatever `t` gives, so `t = ln` is safe there), f64 arithmetic.
    /// Deterministic: bit-identical from run to run and on any number of threads.
    pub fn gram_with<T: GramTransform + ?Sized>(&self, t: &T) -> Result<Vec<f64>> {
        let n = self.n_materials();
        let nc = self.channels().len();
        let mask = self.validity_mask();
        // All segments at once unless their accumulators would exceed the memory budget (a
        // store of thousands of materials: 32 x 200 MB for N = 5000).
        let bytes = GramAccumulator::<T>::bytes(n);
        let wave = (FOLD_MEMORY_BUDGET / bytes.max(1)) as usize;
        let wave = wave.max(FOLD_WAVE_PER_THREAD * rayon::current_num_threads());
        let acc = self.par_try_fold_chunks(
            wave,
            || {
                GramAccumulator::new(n, t).ok_or_else(|| {
                    let count = wave.min(PAR_FOLD_SEGMENTS) + 1;
                    Error::OutOfMemory {
                        path: self.path.clone(),
                        what: format!(
                            "the Gram pass over {n} materials ({count} accumulators of \
                             {n} x {n} values)"
                        ),
                        needed: bytes.saturating_mul(count as u64),
                    }
                })
            },
            |acc, range, block| acc.push_chunk(range, block, mask, nc),
            GramAccumulator::merge,
        )?;
        Ok(acc.finish())
    }

    fn cached_chunk(&self, c: usize) -> Result<Arc<Vec<f32>>> {
        let shard = &self.cache.shards[c % CACHE_SHARDS];
        let stamp = self.cache.clock.fetch_add(1, Ordering::Relaxed);
        {
            let mut s = shard.lock().unwrap_or_else(|p| p.into_inner());
            if let Some(e) = s.iter_mut().find(|e| e.0 == c) {
                e.1 = stamp;
                return Ok(e.2.clone());
            }
        }
        let mut v = Vec::new();
        self.read_chunk(c, &mut v)?;
        let v = Arc::new(v);
        let mut s = shard.lock().unwrap_or_else(|p| p.into_inner());
        if !s.iter().any(|e| e.0 == c) {
            if s.len() >= self.cache.per_shard
                && let Some(oldest) = s.iter().enumerate().min_by_key(|(_, e)| e.1).map(|x| x.0)
            {
                s.swap_remove(oldest);
            }
            s.push((c, stamp, v.clone()));
        }
        Ok(v)
    }

    fn check_d(&self, d: usize) -> Result<()> {
        if d >= self.d() {
            return Err(Error::StoreUsage {
                path: self.path.clone(),
                reason: format!("index {d} out of range (D = {})", self.d()),
            });
        }
        Ok(())
    }

    /// All N values at index `d` (`out.len()` must be N). Uncompressed stores read N contiguous
    /// values; zstd stores go through a small thread-safe cache of decompressed chunks.
    pub fn values_at(&self, d: usize, out: &mut [f32]) -> Result<()> {
        self.check_d(d)?;
        let n = self.n_materials();
        if out.len() != n {
            return Err(Error::StoreUsage {
                path: self.path.clone(),
                reason: format!(
                    "values_at: output has {} slots for {n} materials",
                    out.len()
                ),
            });
        }
        let chunk_len = self.header.layout.chunk_len;
        let c = d / chunk_len;
        let j = d - c * chunk_len;
        let dtype = self.header.layout.dtype;
        match self.header.layout.compression {
            Compression::None => {
                let size = dtype.size();
                let off = PAYLOAD_OFFSET + self.offsets[c] + (j * n * size) as u64;
                let raw = self.bytes(off, n * size)?;
                decode_values(&raw, dtype, out);
            }
            _ => {
                let chunk = self.cached_chunk(c)?;
                out.copy_from_slice(&chunk[j * n..(j + 1) * n]);
            }
        }
        Ok(())
    }

    /// All N values at every index of `d_range` into `out`, index-major
    /// (`out[(d - d_range.start) * N + m]`, `out.len() == d_range.len() * N`): one contiguous
    /// read on an uncompressed store (the N x channels block of one angular cell is one read,
    /// whatever chunks it spans), else a slice of each decompressed chunk the range touches.
    pub fn values_in(&self, d_range: Range<usize>, out: &mut [f32]) -> Result<()> {
        let n = self.n_materials();
        if d_range.end > self.d() || d_range.start > d_range.end || out.len() != d_range.len() * n {
            return Err(Error::StoreUsage {
                path: self.path.clone(),
                reason: format!(
                    "values_in({d_range:?}): D = {}, output has {} slots for {} values",
                    self.d(),
                    out.len(),
                    d_range.len() * n
                ),
            });
        }
        let dtype = self.header.layout.dtype;
        if let Some((offset, len)) = self.span(d_range.clone()) {
            // Uncompressed: one read, whatever chunks the range spans.
            let raw = self.bytes(offset as u64, len)?;
            decode_values(&raw, dtype, out);
            return Ok(());
        }
        let chunk_len = self.header.layout.chunk_len;
        let mut d = d_range.start;
        while d < d_range.end {
            let c = d / chunk_len;
            let j = d - c * chunk_len;
            let end = d_range.end.min((c + 1) * chunk_len);
            let dst = &mut out[(d - d_range.start) * n..(end - d_range.start) * n];
            let chunk = self.cached_chunk(c)?;
            dst.copy_from_slice(&chunk[j * n..(j + end - d) * n]);
            d = end;
        }
        Ok(())
    }

    /// [`Store::values_in`] without a copy when possible: borrowed from the map when the range
    /// is non-empty and the store an uncompressed f32 store opened with a memory map
    /// (little-endian host; under [`Paging::OnDemand`] only from [`ON_DEMAND_MAX_BYTES`] on),
    /// else read into `buf`.
    pub fn values_in_ref<'a>(
        &'a self,
        d_range: Range<usize>,
        buf: &'a mut Vec<f32>,
    ) -> Result<&'a [f32]> {
        if cfg!(target_endian = "little")
            && self.header.layout.dtype == Dtype::F32
            && let Some(bytes) = self.mapped_bytes(d_range.clone())
            && let Ok(v) = bytemuck::try_cast_slice::<u8, f32>(bytes)
        {
            return Ok(v);
        }
        buf.resize(d_range.len() * self.n_materials(), 0.0);
        self.values_in(d_range, buf)?;
        Ok(buf)
    }

    /// A hint that the values of `d_range` (all materials) are read soon: on an uncompressed
    /// store opened with a memory map, asks the CPU to fetch their cache lines into L2
    /// (x86-64), or where [`Paging::OnDemand`] reads them with a positioned read, the kernel to
    /// start reading them from the disk (Linux); no effect otherwise, or for a range outside
    /// the store.
    pub fn prefetch(&self, d_range: Range<usize>) {
        let Some((offset, len)) = self.span(d_range) else {
            return;
        };
        match (&self.backing, self.read_on_demand(len)) {
            (_, Some(_)) if self.staging().is_some_and(|s| s.holds(offset, len)) => {}
            (_, Some(file)) => advise_will_need(file, offset, offset + len),
            (Backing::Mmap(m, _), None) => {
                if let Some(bytes) = m.get(offset..offset + len) {
                    super::prefetch_lines(bytes);
                }
            }
            (Backing::File(_), None) => {}
        }
    }

    /// A hint that the values of `d_ranges` (all materials; in the order they are read) are
    /// read soon, far enough ahead for the disk: on a store read with positioned reads
    /// ([`Paging::OnDemand`], [`ReadMode::Buffered`]), ranges closer than
    /// [`WILL_NEED_GAP`] bytes to the one before are merged into runs, which are read at once
    /// with direct I/O and kept for the reads that follow (up to a budget; the oldest runs
    /// are dropped first), or where direct I/O is not available, which the kernel is asked to
    /// start reading (Linux). So on such a store this call returns once the runs are in
    /// memory. No effect otherwise (a store in memory needs no hint that far ahead:
    /// [`Store::prefetch`] fetches cache lines just in time).
    pub fn will_need(&self, d_ranges: impl IntoIterator<Item = Range<usize>>) {
        let Some(file) = self.will_need_file() else {
            return;
        };
        let spans = d_ranges.into_iter().filter_map(|r| self.span(r));
        let mut runs = Vec::new();
        merge_spans(spans, WILL_NEED_GAP, WILL_NEED_MAX_RUN, |start, end, n| {
            runs.push((start, end, n));
        });
        let staging = self
            .staging
            .get_or_init(|| Staging::direct(file, self.file_len));
        // What is not staged (no direct I/O, over the budget) is left to the kernel.
        let unstaged = match staging {
            Some(staging) => staging.stage(&runs),
            None => runs
                .into_iter()
                .map(|(start, end, _)| (start, end))
                .collect(),
        };
        for (start, end) in unstaged {
            advise_will_need(file, start, end);
        }
    }

    /// Where the stored bytes of `d_range` (all materials) lie in the file (offset, length),
    /// when the range is non-empty and the store is uncompressed. Its chunks then follow one
    /// another with no gap (each exactly its values' size, checked on opening), so index d
    /// lies at `d * N * value size` from the payload whatever chunk holds it, and any range is
    /// one span, even across chunks.
    fn span(&self, d_range: Range<usize>) -> Option<(usize, usize)> {
        let layout = &self.header.layout;
        let chunk_len = layout.chunk_len;
        if layout.compression != Compression::None
            || d_range.start >= d_range.end
            || d_range.end > self.d()
        {
            return None;
        }
        let c = d_range.start / chunk_len;
        let j = d_range.start - c * chunk_len;
        let row = self.n_materials() * layout.dtype.size();
        let s = (PAYLOAD_OFFSET + self.offsets[c]) as usize + j * row;
        Some((s, d_range.len() * row))
    }

    /// The stored bytes of `d_range` (all materials) in the memory map, when the range is
    /// non-empty, the store is uncompressed and opened with a map, and the range is not read
    /// with positioned reads ([`Paging::OnDemand`]).
    fn mapped_bytes(&self, d_range: Range<usize>) -> Option<&[u8]> {
        let Backing::Mmap(m, _) = &self.backing else {
            return None;
        };
        let (s, len) = self.span(d_range)?;
        if self.read_on_demand(len).is_some() {
            return None;
        }
        m.get(s..s + len)
    }

    /// Values of material `m` over `d_range` into `out` (`out.len() == d_range.len()`).
    pub fn material_row(&self, m: usize, d_range: Range<usize>, out: &mut [f32]) -> Result<()> {
        let n = self.n_materials();
        if m >= n || d_range.end > self.d() || d_range.start > d_range.end {
            return Err(Error::StoreUsage {
                path: self.path.clone(),
                reason: format!(
                    "material_row({m}, {d_range:?}) out of range ({n} materials, D = {})",
                    self.d()
                ),
            });
        }
        if out.len() != d_range.len() {
            return Err(Error::StoreUsage {
                path: self.path.clone(),
                reason: format!(
                    "material_row: output has {} slots for {} values",
                    out.len(),
                    d_range.len()
                ),
            });
        }
        if d_range.is_empty() {
            return Ok(());
        }
        let chunk_len = self.header.layout.chunk_len;
        let (c0, c1) = (d_range.start / chunk_len, (d_range.end - 1) / chunk_len);
        let dtype = self.header.layout.dtype;
        let size = dtype.size();
        let mut buf = Vec::new();
        for c in c0..=c1 {
            let cr = self.chunk_range(c);
            let lo = cr.start.max(d_range.start);
            let hi = cr.end.min(d_range.end);
            let dst = &mut out[lo - d_range.start..hi - d_range.start];
            match self.header.layout.compression {
                Compression::None => {
                    // Strided gather straight from the file: one span covering the rows.
                    let first = self.offsets[c] + (((lo - cr.start) * n + m) * size) as u64;
                    let span = ((hi - lo - 1) * n + 1) * size;
                    let raw = self.bytes(PAYLOAD_OFFSET + first, span)?;
                    for (k, o) in dst.iter_mut().enumerate() {
                        let b = &raw[k * n * size..k * n * size + size];
                        decode_values(b, dtype, std::slice::from_mut(o));
                    }
                }
                _ => {
                    let single = c0 == c1;
                    let chunk: Arc<Vec<f32>>;
                    let vals: &[f32] = if single {
                        chunk = self.cached_chunk(c)?;
                        &chunk
                    } else {
                        self.read_chunk(c, &mut buf)?;
                        &buf
                    };
                    for (k, o) in dst.iter_mut().enumerate() {
                        *o = vals[(lo - cr.start + k) * n + m];
                    }
                }
            }
        }
        Ok(())
    }

    /// Recomputes the payload checksum (chunks + offset table) and compares it with the header.
    pub fn verify_checksum(&self) -> Result<()> {
        let mut h = Xxh3::new();
        let end = self.table_offset + self.offsets.len() as u64 * 8;
        let mut pos = PAYLOAD_OFFSET;
        const STEP: u64 = 8 << 20;
        while pos < end {
            let len = STEP.min(end - pos) as usize;
            h.update(&self.bytes(pos, len)?);
            pos += len as u64;
        }
        let actual = hex64(h.digest());
        if actual != self.header.checksum.value {
            return Err(Error::StoreChecksum {
                path: self.path.clone(),
                expected: self.header.checksum.value.clone(),
                actual,
            });
        }
        Ok(())
    }
}

fn validate_header(h: &StoreHeader, path: &Path) -> Result<()> {
    let bad = |r: String| Err(corrupt(path, r));
    if h.format != "specgp-sbrdf" {
        return bad(format!(
            "header format {:?}, expected \"specgp-sbrdf\"",
            h.format
        ));
    }
    if h.version != FORMAT_VERSION {
        return Err(Error::StoreVersion {
            path: path.to_owned(),
            found: h.version,
            supported: FORMAT_VERSION,
        });
    }
    let g = AngularGrid::new(h.grid.n_theta_h, h.grid.n_theta_d, h.grid.n_phi_d)
        .map_err(|e| corrupt(path, format!("header grid: {e}")))?;
    let d = g.len().checked_mul(h.channels.len());
    if d != Some(h.d) {
        return bad(format!(
            "header D = {} but grid {} x {} channels gives {}",
            h.d,
            g,
            h.channels.len(),
            d.map_or_else(|| "more than fits in memory".into(), |d| d.to_string())
        ));
    }
    if let Channels::Spectral(w) = &h.channels {
        Channels::spectral(w.clone())
            .map_err(|e| corrupt(path, format!("header channels: {e}")))?;
    }
    if h.materials.is_empty() {
        return bad("no materials".into());
    }
    let mut seen = std::collections::HashSet::new();
    for (i, m) in h.materials.iter().enumerate() {
        if m.name.is_empty() {
            return bad(format!("material {i} has an empty name"));
        }
        if !seen.insert(m.name.as_str()) {
            return bad(format!("duplicate material name {:?}", m.name));
        }
    }
    // Every size the reader computes (a chunk's bytes, the payload's) is at most N x D values:
    // a header whose N x D x value size does not fit in 64 bits is refused here, before any
    // of those products overflows.
    let payload = (h.materials.len() as u64)
        .checked_mul(h.d as u64)
        .and_then(|v| v.checked_mul(h.layout.dtype.size() as u64))
        .filter(|&b| usize::try_from(b).is_ok());
    if payload.is_none() {
        return bad(format!(
            "{} materials x D = {} values x {} bytes do not fit in 64 bits",
            h.materials.len(),
            h.d,
            h.layout.dtype.size()
        ));
    }
    let l = &h.layout;
    if l.order != "chunked-index-major" {
        return bad(format!("unsupported layout order {:?}", l.order));
    }
    if l.chunk_len == 0 || l.n_chunks != h.d.div_ceil(l.chunk_len) {
        return bad(format!(
            "chunk length {} and chunk count {} do not fit D = {}",
            l.chunk_len, l.n_chunks, h.d
        ));
    }
    if h.checksum.algorithm != "xxh3-64" {
        return bad(format!(
            "unsupported checksum algorithm {:?}",
            h.checksum.algorithm
        ));
    }
    Ok(())
}

/// Bytes of a store's file: borrowed from the map, read into a buffer, or in a staged run.
enum FileBytes<'a> {
    Mapped(&'a [u8]),
    Read(Vec<u8>),
    /// File bytes `offset..offset + len` of a staged run (`Some` until dropped, when it goes
    /// back to `staging`).
    Staged {
        run: Option<Arc<StagedRun>>,
        offset: usize,
        len: usize,
        staging: &'a Staging,
    },
}

impl std::ops::Deref for FileBytes<'_> {
    type Target = [u8];

    fn deref(&self) -> &[u8] {
        match self {
            Self::Mapped(b) => b,
            Self::Read(v) => v,
            Self::Staged {
                run, offset, len, ..
            } => run.as_ref().map_or(&[], |r| r.bytes(*offset, *len)),
        }
    }
}

impl Drop for FileBytes<'_> {
    fn drop(&mut self) {
        if let Self::Staged { run, staging, .. } = self
            && let Some(run) = run.take()
        {
            staging.done(run);
        }
    }
}

impl std::fmt::Debug for Store {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Store")
            .field("path", &self.path)
            .field("n_materials", &self.n_materials())
            .field("d", &self.d())
            .field("layout", &self.header.layout)
            .finish()
    }
}

/// What a file that is not a store holds, from its first bytes: a format specgp meets
/// elsewhere when recognisable, else the bytes against the store's magic.
fn describe_foreign_file(head: &[u8], file_len: u64) -> String {
    let known: [(&[u8], &str); 6] = [
        (b"\x89PNG", "a PNG image"),
        (
            b"\x93NUMPY",
            "a NumPy .npy array (`specgp export` writes these)",
        ),
        (
            b"tensor_file\0",
            "an RGL .bsdf tensor file (import it: `specgp import rgl`)",
        ),
        (b"PK\x03\x04", "a zip archive"),
        (b"\x28\xb5\x2f\xfd", "a bare zstd frame"),
        (b"\x1f\x8b", "a gzip file"),
    ];
    if head.is_empty() {
        return "the file is empty".into();
    }
    if let Some((_, what)) = known.iter().find(|(m, _)| head.starts_with(m)) {
        return format!("the file is {what}");
    }
    // MERL's `.binary`: three positive i32 dimensions, then 3 x their product f64 values.
    if head.len() >= 12 {
        let dims = crate::merl::header_dims(head);
        if dims.iter().all(|&d| d > 0) {
            let bytes = dims
                .iter()
                .try_fold(24u64, |acc, &d| acc.checked_mul(d as u64))
                .and_then(|b| b.checked_add(12));
            if bytes == Some(file_len) {
                return format!(
                    "the file is a MERL .binary BRDF ({} x {} x {}; import it: `specgp import merl`)",
                    dims[0], dims[1], dims[2]
                );
            }
        }
    }
    let text = head
        .iter()
        .all(|b| b.is_ascii_graphic() || b.is_ascii_whitespace());
    if text {
        return format!(
            "the file is text (starts {:?}; a model .toml or a config?)",
            String::from_utf8_lossy(&head[..head.len().min(24)])
        );
    }
    format!(
        "file starts with {:02x?}, expected {:02x?}",
        &head[..head.len().min(8)],
        MAGIC
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::{StoreOptions, StoreWriter};
    use crate::{AngularGrid, Channels, StoreInfo};

    /// `merge_spans` joins a span to the run before it when it starts within `gap` bytes of
    /// the run's end (or inside it) and the run stays within `max_run`; anything else (a larger
    /// gap, a span before the run, a run that would grow too long) starts a new run.
    #[test]
    fn merge_spans_joins_near_spans_in_order() {
        let runs = |spans: &[(usize, usize)], gap, max_run| {
            let mut out = Vec::new();
            merge_spans(spans.iter().copied(), gap, max_run, |s, e, _| {
                out.push((s, e))
            });
            out
        };
        assert_eq!(runs(&[], 10, 100), []);
        assert_eq!(runs(&[(5, 0)], 10, 100), []);
        assert_eq!(
            runs(&[(5, 3)], 0, 1),
            [(5, 8)],
            "a long span alone is a run"
        );
        // Touching, within the gap, exactly at the gap, one past it.
        assert_eq!(runs(&[(0, 4), (4, 4)], 0, 100), [(0, 8)]);
        assert_eq!(runs(&[(0, 4), (9, 1)], 5, 100), [(0, 10)]);
        assert_eq!(runs(&[(0, 4), (10, 1)], 5, 100), [(0, 4), (10, 11)]);
        // Overlapping and contained spans extend nothing past their end.
        assert_eq!(runs(&[(0, 10), (2, 3), (8, 4)], 0, 100), [(0, 12)]);
        // A span before the run starts a new one (order is kept, not sorted).
        assert_eq!(runs(&[(20, 4), (0, 4), (6, 2)], 5, 100), [(20, 24), (0, 8)]);
        // The run's length: up to max_run joins, past it starts anew.
        assert_eq!(runs(&[(0, 4), (4, 6)], 0, 10), [(0, 10)]);
        assert_eq!(runs(&[(0, 4), (4, 7)], 0, 10), [(0, 4), (4, 11)]);
        assert_eq!(
            runs(&[(100, 4), (104, 6)], 0, 10),
            [(100, 110)],
            "the run's own length"
        );
        // Empty spans are skipped, even between two that join.
        assert_eq!(runs(&[(0, 4), (50, 0), (6, 2)], 5, 100), [(0, 8)]);
        // Each run counts the (non-empty) spans it holds.
        let mut counted = Vec::new();
        let spans = [(0, 4), (50, 0), (6, 2), (3, 1), (20, 4), (0, 1)];
        merge_spans(spans, 5, 100, |s, e, n| counted.push((s, e, n)));
        assert_eq!(counted, [(0, 8, 3), (20, 24, 1), (0, 1, 1)]);
    }

    /// The handle of on-demand positioned reads is the file that was opened (its inode, its
    /// bytes), even when its path names another file by then (on Linux it is a second open
    /// file description of the same file, not a second open of the path).
    #[cfg(unix)]
    #[test]
    fn random_read_handles_read_the_file_opened() {
        use std::os::unix::fs::MetadataExt;
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("bytes.bin");
        let bytes: Vec<u8> = (0..5000u32).map(|i| (i * 7 % 251) as u8).collect();
        std::fs::write(&p, &bytes).unwrap();
        let file = File::open(&p).unwrap();
        let id = |m: std::fs::Metadata| (m.dev(), m.ino());
        let opened = id(file.metadata().unwrap());
        // The path replaced by another file before the handle is made.
        std::fs::write(dir.path().join("other.bin"), [9u8; 5000]).unwrap();
        std::fs::rename(dir.path().join("other.bin"), &p).unwrap();
        assert_ne!(id(std::fs::metadata(&p).unwrap()), opened);
        let handle = random_read_handle(file);
        assert_eq!(id(handle.metadata().unwrap()), opened);
        let mut got = [0u8; 100];
        read_exact_at(&handle, &mut got, 4321).unwrap();
        assert_eq!(got[..], bytes[4321..4421]);
    }

    /// Writes a store of `n` materials on the RGB grid 4 x 4 x 8 at `path` in chunks of
    /// `chunk_len` indices, material m's value at index i being `value(m, i)`.
    fn rgb_store(
        path: &Path,
        chunk_len: usize,
        compression: Compression,
        n: u32,
        value: impl Fn(u32, u32) -> f32,
    ) {
        let info = StoreInfo {
            grid: AngularGrid::new(4, 4, 8).unwrap(),
            channels: Channels::Rgb,
        };
        let options = StoreOptions {
            chunk_len: Some(chunk_len),
            compression,
            ..StoreOptions::default()
        };
        let mut w = StoreWriter::create(path, info, options).unwrap();
        let d = w.d() as u32;
        for m in 0..n {
            let values: Vec<f32> = (0..d).map(|i| value(m, i)).collect();
            w.add_material(&format!("m{m}"), "test", &values).unwrap();
        }
        w.finish().unwrap();
    }

    /// Folds in waves give the same bits as one wave of all segments, whatever the wave size.
    #[test]
    fn folds_in_waves_give_the_same_bits() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("waves.sbrdf");
        rgb_store(&p, 5, Compression::None, 7, |m, i| {
            1.0 / (1.0 + ((i * 7919 + m * 104_729) % 1013) as f32)
        });
        let store = Store::open(&p).unwrap();
        assert!(
            store.n_chunks() > 2 * PAR_FOLD_SEGMENTS,
            "{}",
            store.n_chunks()
        );
        let n = store.n_materials();
        let mask = store.validity_mask();
        let gram = |wave| {
            store
                .par_try_fold_chunks(
                    wave,
                    || Ok(GramAccumulator::new(n, &crate::store::Identity).unwrap()),
                    |acc, range, block| acc.push_chunk(range, block, mask, 3),
                    GramAccumulator::merge,
                )
                .unwrap()
                .finish()
        };
        let all = gram(PAR_FOLD_SEGMENTS);
        assert_eq!(all, store.gram().unwrap());
        for wave in [0, 1, 2, 3, 5, 31, 1000] {
            let g = gram(wave);
            assert!(
                g.iter().zip(&all).all(|(a, b)| a.to_bits() == b.to_bits()),
                "wave {wave}"
            );
        }
    }

    /// A hint on a store read with positioned reads stages the hinted cells' merged runs; the
    /// reads that follow get the stored values from them (bit for bit), each run dropped after
    /// as many reads as it had hinted cells. Checked through a plain handle (any file system)
    /// and through direct I/O where the file system takes it.
    #[test]
    fn hinted_cells_are_read_from_staged_runs() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("staged.sbrdf");
        // Chunks of ten cells: hinted cells meet chunk boundaries.
        rgb_store(&p, 30, Compression::None, 5, |m, i| {
            (i * 5 + m) as f32 / 7.0
        });
        let mapped = Store::open(&p).unwrap();
        let buffered = OpenOptions {
            mode: ReadMode::Buffered,
            ..OpenOptions::default()
        };
        let cells = [0usize, 1, 2, 7, 8, 9, 10, 40, 41, 95, 127];
        let ranges = || cells.iter().map(|&a| a * 3..a * 3 + 3);
        let direct = Store::open_with(&p, buffered).unwrap();
        assert!(direct.staging.get().is_none(), "set up by the first hint");
        let mut plain = Store::open_with(&p, buffered).unwrap();
        let len = std::fs::metadata(&p).unwrap().len() as usize;
        plain.staging = OnceLock::from(Some(Staging::new(File::open(&p).unwrap(), len, 1 << 20)));
        for store in [&plain, &direct] {
            store.will_need(ranges());
            let Some(staging) = store.staging() else {
                // Only where the file system refuses direct I/O.
                assert!(
                    !takes_direct_io(&p),
                    "direct I/O is available: the hint staged nothing"
                );
                continue;
            };
            let runs = staging.run_count();
            // Cells 0-2, 7-10, 40-41 join (within WILL_NEED_GAP); the chunk of 10 cells
            // starts the runs anew at cells 10 and 40 no more than the file's order does.
            assert!((1..=cells.len()).contains(&runs), "{runs} runs");
            for r in ranges() {
                let (mut want, mut got) = (vec![0f32; 15], vec![0f32; 15]);
                mapped.values_in(r.clone(), &mut want).unwrap();
                store.values_in(r.clone(), &mut got).unwrap();
                assert_eq!(
                    got.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                    want.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                    "{r:?}"
                );
            }
            assert_eq!(staging.run_count(), 0, "every run read as often as hinted");
            assert_eq!(staging.held_bytes(), 0);
            assert!(
                staging.kept_buffers() > 0,
                "the reads gave the runs' buffers back"
            );
            // Unhinted reads go to the file as before.
            let mut got = vec![0f32; 15];
            store.values_in(60..63, &mut got).unwrap();
            assert_eq!(got[5], mapped_value(&mapped, 61, 0));
        }
    }

    /// Whether the file at `path` opens for direct I/O (Linux's `O_DIRECT`).
    fn takes_direct_io(path: &Path) -> bool {
        #[cfg(target_os = "linux")]
        {
            use std::os::unix::fs::OpenOptionsExt;
            std::fs::OpenOptions::new()
                .read(true)
                .custom_flags(rustix::fs::OFlags::DIRECT.bits() as i32)
                .open(path)
                .is_ok()
        }
        #[cfg(not(target_os = "linux"))]
        {
            let _ = path;
            false
        }
    }

    fn mapped_value(store: &Store, d: usize, m: usize) -> f32 {
        let mut out = vec![0f32; store.n_materials()];
        store.values_at(d, &mut out).unwrap();
        out[m]
    }

    /// A store of 3 materials in chunks of 1 index (D = 4 x 4 x 8 x 3 = 384 chunks) with
    /// `compression`, opened with a cache of `cache_chunks`.
    fn one_index_chunks(
        dir: &Path,
        compression: crate::store::Compression,
        cache_chunks: usize,
    ) -> Store {
        let p = dir.join(format!("{compression:?}.sbrdf"));
        rgb_store(&p, 1, compression, 3, |m, i| m as f32 + i as f32 / 1000.0);
        let options = OpenOptions {
            mode: ReadMode::Mmap,
            cache_chunks,
            ..OpenOptions::default()
        };
        Store::open_with(&p, options).unwrap()
    }

    /// `Paging::Auto` pages a file on demand when it is larger than half the physical memory;
    /// the environment's values parse, anything else does not.
    #[test]
    fn paging_auto_goes_by_the_file_size_and_parses_the_environment_values() {
        assert!(!larger_than_half_the_memory(1 << 20));
        #[cfg(target_os = "linux")]
        assert!(larger_than_half_the_memory(u64::MAX));
        assert_eq!(Paging::parse("on-demand"), Some(Paging::OnDemand));
        assert_eq!(Paging::parse(" read-around\n"), Some(Paging::ReadAround));
        assert_eq!(Paging::parse("auto"), Some(Paging::Auto));
        assert_eq!(Paging::parse("random"), None);
        let p = Path::new("x.sbrdf");
        assert!(Paging::OnDemand.on_demand(0, p).unwrap());
        assert!(!Paging::ReadAround.on_demand(u64::MAX, p).unwrap());
    }

    /// How many chunks the cache holds, over all shards.
    fn cached(store: &Store) -> usize {
        let shards = &store.cache.shards;
        shards.iter().map(|s| s.lock().unwrap().len()).sum()
    }

    /// The zstd chunk cache keeps a decoded chunk (the same allocation comes back) in shard
    /// `c % 16`, up to `cache_chunks / 16` chunks per shard, evicting the least recently used
    /// of a full shard and never holding a chunk twice; uncompressed stores read straight from
    /// the file and cache nothing (`values_at`, `values_in`, `material_row`).
    #[test]
    fn the_chunk_cache_keeps_evicts_and_shards_by_chunk_index() {
        use crate::store::Compression;
        let dir = tempfile::tempdir().unwrap();
        // One chunk per shard: chunks 0 and 1 live side by side, chunk 16 evicts chunk 0.
        let store = one_index_chunks(dir.path(), Compression::Zstd { level: 1 }, CACHE_SHARDS);
        assert_eq!(store.cache.per_shard, 1);
        let first = store.cached_chunk(0).unwrap();
        assert_eq!(&first[..], &[0.0, 1.0, 2.0]);
        assert!(Arc::ptr_eq(&first, &store.cached_chunk(0).unwrap()));
        let one = store.cached_chunk(1).unwrap();
        assert!(
            Arc::ptr_eq(&first, &store.cached_chunk(0).unwrap()),
            "chunk 1 evicted 0"
        );
        assert!(Arc::ptr_eq(&one, &store.cached_chunk(1).unwrap()));
        assert_eq!(cached(&store), 2);
        let sixteen = store.cached_chunk(16).unwrap();
        assert_eq!(&sixteen[..], &[0.016, 1.016, 2.016]);
        assert_eq!(store.cache.shards[0].lock().unwrap().len(), 1);
        assert!(
            !Arc::ptr_eq(&first, &store.cached_chunk(0).unwrap()),
            "0 not evicted"
        );
        assert!(
            Arc::ptr_eq(&one, &store.cached_chunk(1).unwrap()),
            "1 evicted"
        );
        assert_eq!(cached(&store), 2);

        // Two per shard: 0 and 16 share shard 0; reading 0 again makes 16 the older one, so
        // 32 evicts 16 and keeps 0.
        let store = one_index_chunks(dir.path(), Compression::Zstd { level: 1 }, 32);
        assert_eq!(store.cache.per_shard, 2);
        let zero = store.cached_chunk(0).unwrap();
        let sixteen = store.cached_chunk(16).unwrap();
        assert!(Arc::ptr_eq(&sixteen, &store.cached_chunk(16).unwrap()));
        assert!(Arc::ptr_eq(&zero, &store.cached_chunk(0).unwrap()));
        store.cached_chunk(32).unwrap();
        assert_eq!(store.cache.shards[0].lock().unwrap().len(), 2);
        assert!(
            Arc::ptr_eq(&zero, &store.cached_chunk(0).unwrap()),
            "0 evicted"
        );
        assert!(
            !Arc::ptr_eq(&sixteen, &store.cached_chunk(16).unwrap()),
            "16 kept"
        );
        assert_eq!(cached(&store), 2);

        // values_at and values_in read through the cache on zstd stores, around it otherwise.
        let (mut out, mut two) = ([0f32; 3], [0f32; 6]);
        let pair = [0.005, 1.005, 2.005, 0.006, 1.006, 2.006];
        let store = one_index_chunks(dir.path(), Compression::Zstd { level: 1 }, 64);
        store.values_at(5, &mut out).unwrap();
        assert_eq!((out, cached(&store)), ([0.005, 1.005, 2.005], 1));
        store.values_in(5..7, &mut two).unwrap();
        assert_eq!((two, cached(&store)), (pair, 2));
        let store = one_index_chunks(dir.path(), Compression::None, 64);
        store.values_at(5, &mut out).unwrap();
        assert_eq!((out, cached(&store)), ([0.005, 1.005, 2.005], 0));
        store.values_in(5..7, &mut two).unwrap();
        assert_eq!((two, cached(&store)), (pair, 0));
        // material_row likewise; on zstd stores a row over several chunks reads them into a
        // scratch buffer, one within a chunk through the cache.
        let mut row = [0f32; 2];
        store.material_row(1, 5..7, &mut row).unwrap();
        assert_eq!((row, cached(&store)), ([1.005, 1.006], 0));
        store.material_row(2, 9..10, &mut row[..1]).unwrap();
        assert_eq!((row[0], cached(&store)), (2.009, 0));
        let store = one_index_chunks(dir.path(), Compression::Zstd { level: 1 }, 64);
        store.material_row(1, 5..7, &mut row).unwrap();
        assert_eq!((row, cached(&store)), ([1.005, 1.006], 0));
        store.material_row(2, 9..10, &mut row[..1]).unwrap();
        assert_eq!((row[0], cached(&store)), (2.009, 1));
    }
}
