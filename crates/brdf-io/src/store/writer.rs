//! Streaming writer of `.sbrdf` stores.

use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::ops::Range;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use xxhash_rust::xxh3::Xxh3;

use super::{
    Checksum, Compression, DIMENSION_ORDER, Dtype, FORMAT_VERSION, Layout, MAGIC, MaterialEntry,
    PAYLOAD_OFFSET, PREFIX_LEN, StoreHeader, StoreInfo, StoreOptions, VALIDITY, ValueStats,
    encode_values, hex64,
};
use crate::error::{Error, Result};
use crate::grid::Channels;
use crate::output::AtomicOutput;

/// Writes a dataset store without holding the dataset in memory.
///
/// Two ways to feed it (not mixed in one store):
/// - **material mode**: [`StoreWriter::begin_material`] once per material, then its row in D order
///   in slices of any length ([`MaterialWriter::write`]); the rows go to an anonymous scratch file
///   (deleted by the OS whatever happens) and [`StoreWriter::finish`] transposes them into the
///   chunked index-major layout, `memory_budget` bytes at a time, with large sequential reads;
/// - **block mode**: [`StoreWriter::declare_materials`] once, then [`StoreWriter::write_block`]
///   with all N values of consecutive index ranges (index-major), written straight into chunks.
///
/// The output is an [`AtomicOutput`]: a temporary file in the target directory, renamed into
/// place by `finish` (if the writer is dropped or fails, nothing is left behind); an existing
/// seekable special file (`/dev/null`) is written in place, a pipe or terminal is refused. NaN and infinite values are errors;
/// below-horizon cells are stored as 0.
pub struct StoreWriter {
    path: PathBuf,
    info: StoreInfo,
    d: usize,
    n_channels: usize,
    mask: Vec<bool>,
    options: StoreOptions,
    out: AtomicOutput,
    /// Directory of the material-mode scratch file.
    scratch_dir: PathBuf,
    materials: Vec<MaterialEntry>,
    mode: Mode,
    failed: Option<String>,
}

enum Mode {
    Empty,
    Materials {
        scratch: BufWriter<File>,
        /// Values written of the material being written (`d` when it is complete).
        current: usize,
    },
    Blocks {
        sink: Box<ChunkSink>,
        chunk_len: usize,
        next_d: usize,
        /// Index-major values of the chunk(s) being filled: the indices before `next_d` that
        /// are not yet written (a whole number of chunks are written at a time).
        pending: Vec<f32>,
    },
}

/// Receives the values of one material, in D order, from [`StoreWriter::begin_material`].
pub struct MaterialWriter<'a> {
    w: &'a mut StoreWriter,
    index: usize,
    written: usize,
    stats: ValueStats,
    buf: Vec<u8>,
}

struct ChunkSink {
    file: BufWriter<File>,
    pos: u64,
    offsets: Vec<u64>,
    hasher: Xxh3,
    dtype: Dtype,
    compression: Compression,
}

fn encode_chunk(
    values: &[f32],
    dtype: Dtype,
    compression: Compression,
    path: &Path,
) -> Result<Vec<u8>> {
    let mut bytes = Vec::new();
    encode_values(values, dtype, &mut bytes);
    // Every zstd frame carries its content checksum, so a damaged chunk is an error when it is
    // read, not wrong numbers (a damaged frame could still decompress).
    let compress = |data: &[u8], level: i32| -> Result<Vec<u8>> {
        let io = |e| Error::io(path, e);
        let mut c = zstd::bulk::Compressor::new(level).map_err(io)?;
        c.set_parameter(zstd::stream::raw::CParameter::ChecksumFlag(true))
            .map_err(io)?;
        c.compress(data).map_err(io)
    };
    match compression {
        Compression::None => Ok(bytes),
        Compression::Zstd { level } => compress(&bytes, level),
        Compression::ZstdShuffle { level } => {
            compress(&super::shuffle(&bytes, dtype.size()), level)
        }
    }
}

impl ChunkSink {
    fn new(file: File, dtype: Dtype, compression: Compression, path: &Path) -> Result<Self> {
        let mut file = BufWriter::with_capacity(4 << 20, file);
        file.write_all(&[0u8; PAYLOAD_OFFSET as usize])
            .map_err(|e| Error::io(path, e))?;
        Ok(Self {
            file,
            pos: 0,
            offsets: vec![0],
            hasher: Xxh3::new(),
            dtype,
            compression,
        })
    }

    fn write_encoded(&mut self, chunks: Vec<Vec<u8>>, path: &Path) -> Result<()> {
        for bytes in chunks {
            self.file
                .write_all(&bytes)
                .map_err(|e| Error::io(path, e))?;
            self.hasher.update(&bytes);
            self.pos += bytes.len() as u64;
            self.offsets.push(self.pos);
        }
        Ok(())
    }

    /// Encodes index-major chunks in parallel and appends them in order.
    fn write_chunks(&mut self, chunks: &[&[f32]], path: &Path) -> Result<()> {
        let (dtype, compression) = (self.dtype, self.compression);
        let encoded = chunks
            .par_iter()
            .map(|c| encode_chunk(c, dtype, compression, path))
            .collect::<Result<Vec<_>>>()?;
        self.write_encoded(encoded, path)
    }

    /// Writes the offset table, the header and the prefix; returns the file and the header as
    /// written.
    fn finish(mut self, mut header: StoreHeader, path: &Path) -> Result<(File, StoreHeader)> {
        let io = |e| Error::io(path, e);
        let table_offset = PAYLOAD_OFFSET + self.pos;
        let mut table = Vec::with_capacity(self.offsets.len() * 8);
        for o in &self.offsets {
            table.extend_from_slice(&o.to_le_bytes());
        }
        self.hasher.update(&table);
        self.file.write_all(&table).map_err(io)?;
        header.checksum = Checksum {
            algorithm: "xxh3-64".into(),
            value: hex64(self.hasher.digest()),
        };
        header.payload_bytes = self.pos + table.len() as u64;
        let json = serde_json::to_vec_pretty(&header).map_err(|e| Error::StoreUsage {
            path: path.to_owned(),
            reason: format!("cannot serialise header: {e}"),
        })?;
        let header_offset = table_offset + table.len() as u64;
        self.file.write_all(&json).map_err(io)?;
        let mut prefix = [0u8; PREFIX_LEN];
        prefix[0..8].copy_from_slice(&MAGIC);
        prefix[8..12].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
        let fields = [
            PAYLOAD_OFFSET,
            header.payload_bytes,
            table_offset,
            header_offset,
            json.len() as u64,
        ];
        for (i, f) in fields.iter().enumerate() {
            prefix[16 + 8 * i..24 + 8 * i].copy_from_slice(&f.to_le_bytes());
        }
        let mut h = Xxh3::new();
        h.update(&prefix[..56]);
        h.update(&json);
        prefix[56..64].copy_from_slice(&h.digest().to_le_bytes());
        let mut file = self.file.into_inner().map_err(|e| io(e.into_error()))?;
        file.seek(SeekFrom::Start(0)).map_err(io)?;
        file.write_all(&prefix).map_err(io)?;
        Ok((file, header))
    }
}

/// Reads `buf.len()` bytes at `offset`.
pub(crate) fn read_exact_at(file: &File, buf: &mut [u8], offset: u64) -> std::io::Result<()> {
    #[cfg(unix)]
    {
        std::os::unix::fs::FileExt::read_exact_at(file, buf, offset)
    }
    #[cfg(windows)]
    {
        let mut done = 0;
        while done < buf.len() {
            let n = std::os::windows::fs::FileExt::seek_read(
                file,
                &mut buf[done..],
                offset + done as u64,
            )?;
            if n == 0 {
                return Err(std::io::ErrorKind::UnexpectedEof.into());
            }
            done += n;
        }
        Ok(())
    }
}

impl StoreWriter {
    /// Starts a store at `path` (written to a temporary file beside it until [`Self::finish`]).
    pub fn create(path: impl AsRef<Path>, info: StoreInfo, options: StoreOptions) -> Result<Self> {
        let path = path.as_ref().to_owned();
        if let Some(level) = options.compression.zstd_level()
            && !zstd::compression_level_range().contains(&level)
        {
            return Err(Error::StoreUsage {
                path,
                reason: format!(
                    "zstd level {level} outside {:?}",
                    zstd::compression_level_range()
                ),
            });
        }
        if options.chunk_len == Some(0) {
            return Err(Error::StoreUsage {
                path,
                reason: "chunk length must be at least 1".into(),
            });
        }
        if let Channels::Spectral(w) = &info.channels
            && let Err(e) = Channels::spectral(w.clone())
        {
            return Err(Error::StoreUsage {
                path,
                reason: e.to_string(),
            });
        }
        let out = AtomicOutput::create_seekable(&path, "a dataset store")?;
        let scratch_dir = match path.parent() {
            _ if out.is_direct() => std::env::temp_dir(),
            Some(p) if !p.as_os_str().is_empty() => p.to_owned(),
            _ => PathBuf::from("."),
        };
        let mask = info.grid.validity_mask();
        Ok(Self {
            d: info.d(),
            n_channels: info.channels.len(),
            info,
            mask,
            options,
            out,
            scratch_dir,
            path,
            materials: Vec::new(),
            mode: Mode::Empty,
            failed: None,
        })
    }

    /// The grid and channels the store is written on.
    pub fn info(&self) -> &StoreInfo {
        &self.info
    }

    /// Values per material.
    pub fn d(&self) -> usize {
        self.d
    }

    /// Number of materials begun or declared so far.
    pub fn n_materials(&self) -> usize {
        self.materials.len()
    }

    /// Checks that data sampled on `other` fits this store (same grid and channels).
    pub fn check_info(&self, other: &StoreInfo) -> Result<()> {
        if other != &self.info {
            return Err(self.usage(format!(
                "data on grid {} with {} channels ({:?}) does not match the store's grid {} with {} channels ({:?})",
                other.grid,
                other.channels.len(),
                other.channels.labels(),
                self.info.grid,
                self.info.channels.len(),
                self.info.channels.labels()
            )));
        }
        Ok(())
    }

    fn usage(&self, reason: String) -> Error {
        Error::StoreUsage {
            path: self.path.clone(),
            reason,
        }
    }

    fn check_ok(&self) -> Result<()> {
        match &self.failed {
            Some(why) => Err(self.usage(format!("writer unusable after an earlier error: {why}"))),
            None => Ok(()),
        }
    }

    fn fail<T>(&mut self, e: Error) -> Result<T> {
        self.failed = Some(e.to_string());
        Err(e)
    }

    /// The error of value `v` of material `m` at `index` (`valid`: above the horizon, so
    /// kept), if any: not finite, or kept and beyond the storage type's range.
    fn check_value(&self, m: usize, index: usize, v: f32, valid: bool) -> Option<Error> {
        if !v.is_finite() {
            return Some(Error::NonFiniteValue {
                path: self.path.clone(),
                material: self.materials[m].name.clone(),
                index,
                value: v,
            });
        }
        let max = f32::from(half::f16::MAX);
        (valid && self.options.dtype == Dtype::F16 && v.abs() > max)
            .then(|| self.beyond_f16(m, index, v))
    }

    /// The error of value `v` of material `m` at `index`, beyond the f16 range.
    #[cold]
    fn beyond_f16(&self, m: usize, index: usize, v: f32) -> Error {
        let max = f32::from(half::f16::MAX);
        Error::StoreUsage {
            path: self.path.clone(),
            reason: format!(
                "material {:?}: value {v} at index {index} exceeds the f16 range (|v| <= {max}); \
                 store as f32 or clamp outliers",
                self.materials[m].name
            ),
        }
    }

    fn add_entry(&mut self, name: &str, source: &str) -> Result<()> {
        if let Err(why) = check_material_name(name) {
            return Err(self.usage(why));
        }
        if self.materials.iter().any(|m| m.name == name) {
            return Err(self.usage(format!("duplicate material name {name:?}")));
        }
        self.materials.push(MaterialEntry {
            name: name.to_owned(),
            source: source.to_owned(),
            stats: ValueStats::default(),
        });
        Ok(())
    }

    /// Starts the next material (material mode); write its D values, then call
    /// [`MaterialWriter::finish`]. Names must be non-empty, unique and free of control
    /// characters (newlines).
    pub fn begin_material(&mut self, name: &str, source: &str) -> Result<MaterialWriter<'_>> {
        self.check_ok()?;
        match &self.mode {
            Mode::Empty => {
                let scratch = tempfile::tempfile_in(&self.scratch_dir)
                    .map_err(|e| Error::io(&self.path, e))?;
                self.mode = Mode::Materials {
                    scratch: BufWriter::with_capacity(4 << 20, scratch),
                    current: self.d,
                };
            }
            Mode::Materials { current, .. } => {
                if *current != self.d {
                    let last = self.materials.last().map(|m| m.name.clone());
                    return Err(self.usage(format!(
                        "material {last:?} was not finished ({current} of {} values)",
                        self.d
                    )));
                }
            }
            Mode::Blocks { .. } => {
                return Err(self.usage(
                    "begin_material after declare_materials: use one mode per store".into(),
                ));
            }
        }
        self.add_entry(name, source)?;
        if let Mode::Materials { current, .. } = &mut self.mode {
            *current = 0;
        }
        Ok(MaterialWriter {
            index: self.materials.len() - 1,
            w: self,
            written: 0,
            stats: ValueStats::default(),
            buf: Vec::new(),
        })
    }

    /// Writes one whole material (material mode): `values` is its row of D values.
    pub fn add_material(&mut self, name: &str, source: &str, values: &[f32]) -> Result<()> {
        let mut m = self.begin_material(name, source)?;
        m.write(values)?;
        m.finish()
    }

    /// Adds `count` whole materials in order (material mode), `load(i)` giving material `i`'s
    /// `(name, source, values)`: material `i` is written on a second thread while `load(i + 1)`
    /// runs, so that an import's resampling and its writes overlap. The first error stops
    /// both: `load`'s as it is, the writer's through `write_error`.
    pub fn add_materials_overlapped<E>(
        &mut self,
        count: usize,
        mut load: impl FnMut(usize) -> std::result::Result<(String, String, Vec<f32>), E>,
        write_error: impl FnOnce(Error) -> E,
    ) -> std::result::Result<(), E> {
        let (send, receive) = std::sync::mpsc::sync_channel::<(String, String, Vec<f32>)>(1);
        std::thread::scope(|scope| {
            let writer = scope.spawn(move || -> Result<()> {
                for (name, source, values) in receive {
                    self.add_material(&name, &source, &values)?;
                }
                Ok(())
            });
            let mut loaded = Ok(());
            for i in 0..count {
                match load(i) {
                    // A closed channel means the writer stopped on an error: it is returned below.
                    Ok(material) => {
                        if send.send(material).is_err() {
                            break;
                        }
                    }
                    Err(e) => {
                        loaded = Err(e);
                        break;
                    }
                }
            }
            drop(send);
            let written = writer
                .join()
                .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
            loaded?;
            written.map_err(write_error)
        })
    }

    /// Switches to block mode with these (name, source) materials, in row order (names as for
    /// [`StoreWriter::begin_material`]).
    pub fn declare_materials<S: AsRef<str>, T: AsRef<str>>(
        &mut self,
        materials: &[(S, T)],
    ) -> Result<()> {
        self.check_ok()?;
        if !matches!(self.mode, Mode::Empty) {
            return Err(self.usage("declare_materials must come first and only once".into()));
        }
        if materials.is_empty() {
            return Err(self.usage("a store needs at least one material".into()));
        }
        for (name, source) in materials {
            self.add_entry(name.as_ref(), source.as_ref())?;
        }
        let n = self.materials.len();
        let chunk_len = self.options.effective_chunk_len(n, self.d);
        let file = self
            .out
            .file()
            .try_clone()
            .map_err(|e| Error::io(&self.path, e))?;
        let sink = ChunkSink::new(
            file,
            self.options.dtype,
            self.options.compression,
            &self.path,
        )?;
        self.mode = Mode::Blocks {
            sink: Box::new(sink),
            chunk_len,
            next_d: 0,
            pending: Vec::new(),
        };
        Ok(())
    }

    /// Writes all N values of the indices `range` (block mode), index-major:
    /// `values[(d - range.start) * N + n]`. Ranges must follow each other from 0 to D.
    pub fn write_block(&mut self, range: Range<usize>, values: &[f32]) -> Result<()> {
        self.check_ok()?;
        let n = self.materials.len();
        let (d, nc) = (self.d, self.n_channels);
        let Mode::Blocks { next_d, .. } = &self.mode else {
            return Err(self.usage("write_block needs declare_materials first".into()));
        };
        if range.start != *next_d || range.end > d || range.end < range.start {
            return Err(self.usage(format!(
                "block {range:?} out of order: expected a range starting at {next_d} and ending <= {d}"
            )));
        }
        if values.len() != range.len() * n {
            return Err(self.usage(format!(
                "block {range:?} has {} values, expected {} ({} indices x {n} materials)",
                values.len(),
                range.len() * n,
                range.len()
            )));
        }
        // Validate and gather statistics before touching any state.
        let mut block = BlockStats::new(n);
        let f16 = self.options.dtype == Dtype::F16;
        for (i, row) in values.chunks_exact(n.max(1)).enumerate() {
            let di = range.start + i;
            let valid = self.mask[di / nc];
            if may_offend(row, f16 && valid) {
                // The first offence in material order, as reported value by value.
                for (m, &v) in row.iter().enumerate() {
                    if let Some(e) = self.check_value(m, di, v, valid) {
                        return self.fail(e);
                    }
                }
            }
            block.add_row(row, valid, self.options.dtype);
        }
        let (stats, sums) = block.into_stats();
        for (m, (s, sum)) in stats.into_iter().zip(sums).enumerate() {
            let s = close_stats(s, sum);
            self.materials[m].stats.merge(&s);
        }
        let path = self.path.clone();
        let mask = &self.mask;
        let Mode::Blocks {
            sink,
            chunk_len,
            next_d,
            pending,
        } = &mut self.mode
        else {
            unreachable!("checked above")
        };
        let start_len = pending.len();
        pending.extend_from_slice(values);
        for (i, row) in pending[start_len..].chunks_exact_mut(n).enumerate() {
            if !mask[(range.start + i) / nc] {
                row.iter_mut().for_each(|v| *v = 0.0);
            }
        }
        *next_d = range.end;
        // Flush whole chunks in batches large enough to compress in parallel.
        let pending_len = pending.len() / n;
        let batch = (*chunk_len * 4 * rayon::current_num_threads()).max(*chunk_len);
        let complete = if range.end == d {
            pending_len
        } else if pending_len >= batch {
            pending_len / *chunk_len * *chunk_len
        } else {
            0
        };
        if complete > 0 {
            let chunks: Vec<&[f32]> = pending[..complete * n].chunks(*chunk_len * n).collect();
            let res = sink.write_chunks(&chunks, &path);
            pending.drain(..complete * n);
            if let Err(e) = res {
                return self.fail(e);
            }
        }
        Ok(())
    }

    /// Completes the store: transposes (material mode), writes table and header, renames the
    /// temporary file into place. Returns the header written.
    pub fn finish(self) -> Result<StoreHeader> {
        self.check_ok()?;
        let mut this = self;
        let mode = std::mem::replace(&mut this.mode, Mode::Empty);
        let n = this.materials.len();
        if n == 0 {
            return Err(this.usage("a store needs at least one material".into()));
        }
        let (sink, chunk_len) = match mode {
            Mode::Empty => unreachable!("materials exist, so a mode was chosen"),
            Mode::Blocks {
                sink,
                chunk_len,
                next_d,
                ..
            } => {
                if next_d != this.d {
                    return Err(this.usage(format!(
                        "blocks cover 0..{next_d} of 0..{}: the store is incomplete",
                        this.d
                    )));
                }
                (*sink, chunk_len)
            }
            Mode::Materials { scratch, current } => {
                if current != this.d {
                    return Err(this.usage(format!(
                        "material {:?} was not finished ({current} of {} values)",
                        this.materials[n - 1].name,
                        this.d
                    )));
                }
                let scratch = scratch
                    .into_inner()
                    .map_err(|e| Error::io(&this.path, e.into_error()))?;
                this.transpose(&scratch)?
            }
        };
        let mut stats = ValueStats::default();
        for m in &mut this.materials {
            m.stats = m.stats.clone().finalize();
            stats.merge(&m.stats);
            if m.stats.flushed_to_zero > 0 {
                tracing::warn!(
                    store = %this.path.display(),
                    material = %m.name,
                    "{} of {} values are below the {} range and were stored as 0",
                    m.stats.flushed_to_zero,
                    m.stats.count,
                    this.options.dtype.name()
                );
            }
        }
        let header = StoreHeader {
            format: "specgp-sbrdf".into(),
            version: FORMAT_VERSION,
            grid: this.info.grid,
            channels: this.info.channels.clone(),
            d: this.d,
            dimension_order: DIMENSION_ORDER.into(),
            validity: VALIDITY.into(),
            materials: this.materials.clone(),
            layout: Layout {
                order: "chunked-index-major".into(),
                chunk_len,
                n_chunks: this.d.div_ceil(chunk_len),
                dtype: this.options.dtype,
                compression: this.options.compression,
            },
            stats: stats.finalize(),
            checksum: Checksum {
                algorithm: "xxh3-64".into(),
                value: String::new(),
            },
            payload_bytes: 0,
            created_by: format!("brdf-io {}", env!("CARGO_PKG_VERSION")),
        };
        let path = this.path.clone();
        let (_, header) = sink.finish(header, &path)?;
        let direct = this.out.is_direct();
        this.out.commit()?;
        tracing::info!(path = %path.display(), n, d = this.d, "dataset store written");
        if direct {
            // A special file (e.g. /dev/null) may not read back what was written.
            return Ok(header);
        }
        // Re-read the header as written (checksum and sizes filled in).
        let store = super::Store::open_with(
            &path,
            super::OpenOptions {
                mode: super::ReadMode::Buffered,
                ..Default::default()
            },
        )?;
        Ok(store.header().clone())
    }

    /// Material mode: scratch rows (material-major f32) -> chunked index-major output.
    fn transpose(&self, scratch: &File) -> Result<(ChunkSink, usize)> {
        let n = self.materials.len();
        let d = self.d;
        let chunk_len = self.options.effective_chunk_len(n, d);
        let file = self
            .out
            .file()
            .try_clone()
            .map_err(|e| Error::io(&self.path, e))?;
        let mut sink = ChunkSink::new(
            file,
            self.options.dtype,
            self.options.compression,
            &self.path,
        )?;
        let per_block = (self.options.memory_budget / (n * 4) / chunk_len).max(1) * chunk_len;
        let super_len = per_block.min(d);
        let mut buf = vec![0f32; n * super_len];
        let mut start = 0;
        while start < d {
            let len = super_len.min(d - start);
            for m in 0..n {
                let dst: &mut [u8] = bytemuck::cast_slice_mut(&mut buf[m * len..(m + 1) * len]);
                read_exact_at(scratch, dst, ((m * d + start) * 4) as u64)
                    .map_err(|e| Error::io(&self.path, e))?;
            }
            #[cfg(target_endian = "big")]
            for v in &mut buf[..n * len] {
                *v = f32::from_bits(u32::from_le(v.to_bits()));
            }
            let block = &buf[..n * len];
            let (dtype, compression, path) =
                (self.options.dtype, self.options.compression, &self.path);
            let encoded = (0..len.div_ceil(chunk_len))
                .into_par_iter()
                .map(|c| {
                    let lo = c * chunk_len;
                    let hi = (lo + chunk_len).min(len);
                    let mut t = vec![0f32; (hi - lo) * n];
                    for m in 0..n {
                        let row = &block[m * len + lo..m * len + hi];
                        for (j, v) in row.iter().enumerate() {
                            t[j * n + m] = *v;
                        }
                    }
                    encode_chunk(&t, dtype, compression, path)
                })
                .collect::<Result<Vec<_>>>()?;
            sink.write_encoded(encoded, &self.path)?;
            tracing::debug!(start, len, d, "transposed super-block");
            start += len;
        }
        Ok((sink, chunk_len))
    }
}

/// Whether `name` may name a material in a store (non-empty, no newline or other control
/// character: names are listed one per line); the reason when not. Importers check their
/// names with it before reading any data.
pub fn check_material_name(name: &str) -> std::result::Result<(), String> {
    if name.is_empty() {
        return Err("material names must not be empty".into());
    }
    if name.chars().any(char::is_control) {
        return Err(format!(
            "material name {name:?} contains a newline or another control character (names \
             are listed one per line)"
        ));
    }
    Ok(())
}

/// Whether `values` may hold an offence for [`StoreWriter::check_value`]: a non-finite value,
/// or (`f16_range`: an f16 store, above the horizon) one beyond f16's range. A vectorised look:
/// only then are the values checked one by one, for the first offence in order.
#[inline]
fn may_offend(values: &[f32], f16_range: bool) -> bool {
    let f16_max = f32::from(half::f16::MAX);
    values.iter().any(|v| !v.is_finite()) || (f16_range && values.iter().any(|v| v.abs() > f16_max))
}

/// Adds input `v` to the statistics of the values as `dtype` stores them.
#[inline(always)]
fn accumulate(s: &mut ValueStats, sum: &mut f64, v: f32, valid: bool, dtype: Dtype) {
    if !valid {
        if v != 0.0 {
            s.zeroed_below_horizon += 1;
        }
        return;
    }
    let stored = dtype.round(v);
    if stored == 0.0 && v != 0.0 {
        s.flushed_to_zero += 1;
    }
    let x = f64::from(stored);
    s.count += 1;
    s.min = s.min.min(x);
    s.max = s.max.max(x);
    *sum += x;
    s.sum_sq += x * x;
    if x < 0.0 {
        s.negatives += 1;
    }
}

/// The statistics of a block of index-major rows (all N materials' values at one index), one
/// lane per material: each row's loop over the materials vectorises, and each material's
/// statistics take its values in index order, as [`accumulate`] does one value at a time.
struct BlockStats {
    min: Vec<f64>,
    max: Vec<f64>,
    sum: Vec<f64>,
    sum_sq: Vec<f64>,
    negatives: Vec<u64>,
    flushed_to_zero: Vec<u64>,
    zeroed_below_horizon: Vec<u64>,
    valid_rows: u64,
}

impl BlockStats {
    fn new(n: usize) -> Self {
        let empty = ValueStats::default();
        Self {
            min: vec![empty.min; n],
            max: vec![empty.max; n],
            sum: vec![0.0; n],
            sum_sq: vec![0.0; n],
            negatives: vec![0; n],
            flushed_to_zero: vec![0; n],
            zeroed_below_horizon: vec![0; n],
            valid_rows: 0,
        }
    }

    /// Adds one row of finite inputs (in range for `dtype`), stored as `dtype` stores them.
    #[inline]
    fn add_row(&mut self, row: &[f32], valid: bool, dtype: Dtype) {
        if !valid {
            for (z, &v) in self.zeroed_below_horizon.iter_mut().zip(row) {
                *z += u64::from(v != 0.0);
            }
            return;
        }
        self.valid_rows += 1;
        match dtype {
            Dtype::F32 => self.add_valid(row, |v| v),
            Dtype::F16 => self.add_valid(row, |v| Dtype::F16.round(v)),
        }
    }

    #[inline(always)]
    fn add_valid(&mut self, row: &[f32], round: impl Fn(f32) -> f32) {
        let n = row.len();
        let (min, max) = (&mut self.min[..n], &mut self.max[..n]);
        let (sum, sum_sq) = (&mut self.sum[..n], &mut self.sum_sq[..n]);
        let (negatives, flushed) = (&mut self.negatives[..n], &mut self.flushed_to_zero[..n]);
        for m in 0..n {
            let v = row[m];
            let stored = round(v);
            flushed[m] += u64::from(stored == 0.0 && v != 0.0);
            let x = f64::from(stored);
            min[m] = min[m].min(x);
            max[m] = max[m].max(x);
            sum[m] += x;
            sum_sq[m] += x * x;
            negatives[m] += u64::from(x < 0.0);
        }
    }

    /// Per material: its statistics (without the mean) and the sum of its valid values.
    fn into_stats(self) -> (Vec<ValueStats>, Vec<f64>) {
        let stats = (0..self.min.len())
            .map(|m| ValueStats {
                count: self.valid_rows,
                min: self.min[m],
                max: self.max[m],
                mean: 0.0,
                sum_sq: self.sum_sq[m],
                negatives: self.negatives[m],
                zeroed_below_horizon: self.zeroed_below_horizon[m],
                flushed_to_zero: self.flushed_to_zero[m],
            })
            .collect();
        (stats, self.sum)
    }
}

fn close_stats(mut s: ValueStats, sum: f64) -> ValueStats {
    if s.count > 0 {
        s.mean = sum / s.count as f64;
    }
    s
}

impl MaterialWriter<'_> {
    /// Appends the next values of the material's row (D order).
    pub fn write(&mut self, values: &[f32]) -> Result<()> {
        let w = &mut *self.w;
        w.check_ok()?;
        let (d, nc) = (w.d, w.n_channels);
        if self.written + values.len() > d {
            let e = w.usage(format!(
                "material {:?}: {} values written, more than D = {d}",
                w.materials[self.index].name,
                self.written + values.len()
            ));
            return w.fail(e);
        }
        // Checked value by value (for the first offence in index order) only when a
        // vectorised look finds a suspect.
        let suspect = may_offend(values, w.options.dtype == Dtype::F16);
        self.buf.clear();
        self.buf.resize(values.len() * 4, 0);
        let mut sum = 0.0;
        let mut stats = ValueStats::default();
        let (mut cell, mut channel) = (self.written / nc, self.written % nc);
        for (i, (&v, out)) in values.iter().zip(self.buf.chunks_exact_mut(4)).enumerate() {
            let valid = w.mask[cell];
            if suspect && let Some(e) = w.check_value(self.index, self.written + i, v, valid) {
                return w.fail(e);
            }
            accumulate(&mut stats, &mut sum, v, valid, w.options.dtype);
            let v = if valid { v } else { 0.0 };
            out.copy_from_slice(&v.to_le_bytes());
            channel += 1;
            if channel == nc {
                (cell, channel) = (cell + 1, 0);
            }
        }
        self.stats.merge(&close_stats(stats, sum));
        let Mode::Materials { scratch, current } = &mut w.mode else {
            unreachable!("a MaterialWriter exists only in material mode")
        };
        if let Err(e) = scratch.write_all(&self.buf) {
            let e = Error::io(&w.path, e);
            return w.fail(e);
        }
        self.written += values.len();
        *current = self.written;
        Ok(())
    }

    /// Values written so far.
    pub fn written(&self) -> usize {
        self.written
    }

    /// Completes the material; fails unless exactly D values were written.
    pub fn finish(self) -> Result<()> {
        let w = self.w;
        w.check_ok()?;
        if self.written != w.d {
            let e = w.usage(format!(
                "material {:?}: {} values written, expected D = {}",
                w.materials[self.index].name, self.written, w.d
            ));
            return w.fail(e);
        }
        w.materials[self.index].stats = self.stats;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{AngularGrid, Channels};

    fn info() -> StoreInfo {
        StoreInfo {
            grid: AngularGrid::new(2, 3, 4).unwrap(),
            channels: Channels::Rgb,
        }
    }

    /// A store aimed at a FIFO is refused up front with an error naming it (it used to be
    /// written to a temporary file and renamed over the FIFO); the FIFO stays.
    #[cfg(target_os = "linux")]
    #[test]
    fn refuses_a_fifo_and_leaves_it_alone() {
        use crate::output::test_util::{fifo, is_fifo};
        let dir = tempfile::tempdir().unwrap();
        let (p, _reader) = fifo(dir.path(), "out.sbrdf");
        let e = StoreWriter::create(&p, info(), StoreOptions::default())
            .err()
            .unwrap();
        assert!(matches!(e, Error::NotSeekable { .. }), "{e}");
        assert!(e.to_string().contains("out.sbrdf"), "{e}");
        assert!(is_fifo(&p));
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    /// A finished store has mode 0666 & !umask and replacing one keeps its mode.
    #[cfg(target_os = "linux")]
    #[test]
    fn store_file_modes() {
        use crate::output::test_util::{mode, umask};
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.sbrdf");
        let write = || {
            let mut w = StoreWriter::create(&p, info(), StoreOptions::default()).unwrap();
            w.add_material("m", "test", &vec![0.5; w.d()]).unwrap();
            w.finish().unwrap();
        };
        write();
        assert_eq!(mode(&p), 0o666 & !umask());
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o600)).unwrap();
        write();
        assert_eq!(mode(&p), 0o600);
    }
}
