//! `specgp import`, `specgp info` and `specgp export`: data into and out of dataset stores.

use std::fs::File;
use std::io::{Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use brdf_io::store::{Compression, Dtype};
use brdf_io::{AngularGrid, Channels, Store, StoreInfo, StoreOptions, StoreWriter};
use indicatif::{ProgressBar, ProgressStyle};

/// Options shared by every `import` format: where and how the store is written.
#[derive(Debug, clap::Args)]
pub struct StoreOut {
    /// Output dataset store (`.sbrdf`).
    #[arg(long)]
    pub out: PathBuf,
    /// Angular resolution TH,TD,PD.
    #[arg(long, default_value = "90,90,180")]
    pub grid: AngularGrid,
    /// Stored value type: f32 (exact) or f16 (half precision, half the size).
    #[arg(long, default_value = "f32")]
    pub dtype: Dtype,
    /// Compress chunks with zstd at this level (1..=22); uncompressed when absent.
    #[arg(long, value_name = "LEVEL")]
    pub zstd: Option<i32>,
    /// Grid indices per chunk (default: about 1 MiB per chunk, 256 KiB with zstd).
    #[arg(long)]
    pub chunk_len: Option<usize>,
}

impl StoreOut {
    fn options(&self) -> StoreOptions {
        StoreOptions {
            chunk_len: self.chunk_len,
            dtype: self.dtype,
            compression: self
                .zstd
                .map_or(Compression::None, |level| Compression::Zstd { level }),
            ..StoreOptions::default()
        }
    }
}

/// Arguments of `specgp import`.
#[derive(Debug, clap::Args)]
pub struct ImportArgs {
    #[command(subcommand)]
    format: ImportFormat,
}

#[derive(Debug, clap::Subcommand)]
enum ImportFormat {
    /// RGL tensor files (`*_spec.bsdf`: spectral; `*_rgb.bsdf`: R,G,B), resampled onto the grid.
    Rgl(RglArgs),
}

/// Arguments of `specgp import rgl`.
#[derive(Debug, clap::Args)]
struct RglArgs {
    /// RGL `.bsdf` files, one material each (named by the file stem).
    #[arg(required = true)]
    files: Vec<PathBuf>,
    /// Wavelengths START:END:STEP or a comma list in nm (inside the files' range); default: the
    /// first file's own channels.
    #[arg(long)]
    wavelengths: Option<String>,
    #[command(flatten)]
    store: StoreOut,
}

fn bar(len: u64, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(len);
    pb.set_style(
        ProgressStyle::with_template(&format!(
            "{what} [{{elapsed_precise}}] {{bar:40}} {{pos}}/{{len}} {{msg}}"
        ))
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    pb
}

fn stem(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| path.display().to_string())
}

/// Runs `specgp import`.
pub fn import(args: &ImportArgs) -> anyhow::Result<()> {
    match &args.format {
        ImportFormat::Rgl(a) => import_rgl(a),
    }
}

fn import_rgl(args: &RglArgs) -> anyhow::Result<()> {
    use brdf_io::rgl::RglBsdf;
    let first = RglBsdf::open(&args.files[0])?;
    let channels = match &args.wavelengths {
        Some(spec) => Channels::parse_wavelengths(spec)?,
        None => first.native_channels().clone(),
    };
    drop(first);
    let info = StoreInfo {
        grid: args.store.grid,
        channels: channels.clone(),
    };
    let mut writer = StoreWriter::create(&args.store.out, info, args.store.options())?;
    let pb = bar(args.files.len() as u64, "import rgl");
    for file in &args.files {
        pb.set_message(stem(file));
        let bsdf = RglBsdf::open(file)?;
        let (values, report) = bsdf
            .resample(&args.store.grid, &channels)
            .with_context(|| format!("resampling {}", file.display()))?;
        let name = stem(file);
        writer.add_material(&name, &file.display().to_string(), &values)?;
        pb.suspend(|| println!("{name}: {report}"));
        pb.inc(1);
    }
    pb.finish_and_clear();
    let header = writer.finish()?;
    println!(
        "wrote {}: {} materials, grid {}, {} channels, D = {}",
        args.store.out.display(),
        header.n_materials(),
        header.grid,
        header.channels.len(),
        header.d
    );
    Ok(())
}

/// Arguments of `specgp info`.
#[derive(Debug, clap::Args)]
pub struct InfoArgs {
    /// A dataset store (`.sbrdf`).
    path: PathBuf,
    /// Print the header as JSON (with the file size and the checksum verdict).
    #[arg(long)]
    json: bool,
}

/// Runs `specgp info`.
pub fn info(args: &InfoArgs) -> anyhow::Result<()> {
    let store = Store::open(&args.path)?;
    let verified = store.verify_checksum();
    let h = store.header();
    if args.json {
        let mut v = serde_json::to_value(h)?;
        if let Some(o) = v.as_object_mut() {
            o.insert("path".into(), args.path.display().to_string().into());
            o.insert("file_bytes".into(), store.file_bytes().into());
            o.insert("checksum_verified".into(), verified.is_ok().into());
        }
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        let comp = match h.layout.compression {
            Compression::None => "none".to_owned(),
            Compression::Zstd { level } => format!("zstd level {level}"),
        };
        println!("file           {}", args.path.display());
        println!("materials      {}", h.n_materials());
        for m in &h.materials {
            println!(
                "  {:<24} mean {:.4e}  min {:.4e}  max {:.4e}  negatives {}  from {}",
                m.name, m.stats.mean, m.stats.min, m.stats.max, m.stats.negatives, m.source
            );
        }
        println!("grid           {}", h.grid);
        println!(
            "channels       {} ({})",
            h.channels.len(),
            match &h.channels {
                Channels::Rgb => "R,G,B".to_owned(),
                Channels::Spectral(w) => format!(
                    "{} .. {} nm",
                    w.first().copied().unwrap_or(0.0),
                    w.last().copied().unwrap_or(0.0)
                ),
            }
        );
        println!("D              {}", h.d);
        println!("order          {}", h.dimension_order);
        println!("bytes          {}", store.file_bytes());
        println!(
            "layout         {}, {} indices x {} chunks, {}, {comp}",
            h.layout.order,
            h.layout.chunk_len,
            h.layout.n_chunks,
            h.layout.dtype.name()
        );
        println!(
            "checksum       {} {} ({})",
            h.checksum.algorithm,
            h.checksum.value,
            if verified.is_ok() {
                "verified"
            } else {
                "MISMATCH"
            }
        );
    }
    verified?;
    Ok(())
}

/// Arguments of `specgp export`.
#[derive(Debug, clap::Args)]
pub struct ExportArgs {
    /// A dataset store (`.sbrdf`).
    path: PathBuf,
    /// Output `.npy`: an N x D matrix, rows in store order (or `--materials` order), columns in
    /// the store's dimension order.
    #[arg(long)]
    out: PathBuf,
    /// Comma-separated material names to export (default: all).
    #[arg(long, value_delimiter = ',')]
    materials: Option<Vec<String>>,
    /// Element type of the `.npy`.
    #[arg(long, default_value = "f32", value_parser = ["f32", "f64"])]
    dtype: String,
}

/// An `.npy` (version 1.0) header for a C-order 2-D little-endian float array.
fn npy_header(descr: &str, rows: usize, cols: usize) -> Vec<u8> {
    let dict =
        format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': ({rows}, {cols}), }}");
    let unpadded = 10 + dict.len() + 1;
    let total = unpadded.div_ceil(64) * 64;
    let mut h = Vec::with_capacity(total);
    h.extend_from_slice(b"\x93NUMPY\x01\x00");
    h.extend_from_slice(&((total - 10) as u16).to_le_bytes());
    h.extend_from_slice(dict.as_bytes());
    h.resize(total - 1, b' ');
    h.push(b'\n');
    h
}

/// Runs `specgp export`: streams the chosen rows out chunk by chunk (bounded memory).
pub fn export(args: &ExportArgs) -> anyhow::Result<()> {
    let store = Store::open(&args.path)?;
    let rows: Vec<usize> = match &args.materials {
        Some(names) => names
            .iter()
            .map(|n| store.material_index(n.trim()))
            .collect::<Result<_, _>>()?,
        None => (0..store.n_materials()).collect(),
    };
    if rows.is_empty() {
        bail!("--materials selects no material");
    }
    let (d, n) = (store.d(), store.n_materials());
    let f64_out = args.dtype == "f64";
    let size = if f64_out { 8 } else { 4 };
    let header = npy_header(if f64_out { "<f8" } else { "<f4" }, rows.len(), d);
    let dir = match args.out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_owned(),
        _ => PathBuf::from("."),
    };
    let mut builder = tempfile::Builder::new();
    #[cfg(unix)]
    builder
        .permissions(<std::fs::Permissions as std::os::unix::fs::PermissionsExt>::from_mode(0o644));
    let tmp = builder
        .tempfile_in(&dir)
        .with_context(|| format!("{}: cannot create a temporary file", args.out.display()))?;
    let io = |e: std::io::Error| anyhow::anyhow!("{}: {e}", args.out.display());
    let mut file: File = tmp.as_file().try_clone().map_err(io)?;
    file.write_all(&header).map_err(io)?;
    file.set_len((header.len() + rows.len() * d * size) as u64)
        .map_err(io)?;
    // Gather a window of indices for every selected row, then write each row's segment.
    let window = ((256usize << 20) / (rows.len() * size)).max(1);
    let mut bufs: Vec<Vec<u8>> = vec![Vec::with_capacity(window * size); rows.len()];
    let mut win_start = 0usize;
    let pb = bar(store.n_chunks() as u64, "export");
    let mut flush = |bufs: &mut Vec<Vec<u8>>, start: usize| -> anyhow::Result<()> {
        for (r, b) in bufs.iter_mut().enumerate() {
            let off = header.len() + (r * d + start) * size;
            file.seek(SeekFrom::Start(off as u64)).map_err(io)?;
            file.write_all(b).map_err(io)?;
            b.clear();
        }
        Ok(())
    };
    let mut err = None;
    store.for_each_chunk(|range, block| {
        if err.is_some() {
            return;
        }
        for (r, &m) in rows.iter().enumerate() {
            let b = &mut bufs[r];
            for k in 0..range.len() {
                let v = block[k * n + m];
                if f64_out {
                    b.extend_from_slice(&f64::from(v).to_le_bytes());
                } else {
                    b.extend_from_slice(&v.to_le_bytes());
                }
            }
        }
        if range.end - win_start >= window || range.end == d {
            if let Err(e) = flush(&mut bufs, win_start) {
                err = Some(e);
            }
            win_start = range.end;
        }
        pb.inc(1);
    })?;
    pb.finish_and_clear();
    if let Some(e) = err {
        return Err(e);
    }
    file.sync_all().map_err(io)?;
    tmp.persist(&args.out)
        .map_err(|e| anyhow::anyhow!("{}: {}", args.out.display(), e.error))?;
    println!(
        "wrote {}: {} x {d} {} ({})",
        args.out.display(),
        rows.len(),
        args.dtype,
        store.header().dimension_order
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn npy_header_is_aligned_and_parsable() {
        let h = npy_header("<f4", 3, 1_458_000);
        assert_eq!(h.len() % 64, 0);
        assert_eq!(&h[..8], b"\x93NUMPY\x01\x00");
        let len = u16::from_le_bytes([h[8], h[9]]) as usize;
        assert_eq!(len + 10, h.len());
        let text = std::str::from_utf8(&h[10..]).unwrap();
        assert!(text.contains("'shape': (3, 1458000)"));
        assert!(text.ends_with('\n'));
    }

    fn read_npy_f64(path: &Path) -> (Vec<usize>, Vec<f64>) {
        let b = std::fs::read(path).unwrap();
        let hl = u16::from_le_bytes([b[8], b[9]]) as usize;
        let text = std::str::from_utf8(&b[10..10 + hl]).unwrap();
        let shape = text
            .split("'shape': (")
            .nth(1)
            .unwrap()
            .split(')')
            .next()
            .unwrap();
        let shape: Vec<usize> = shape
            .split(',')
            .filter(|s| !s.trim().is_empty())
            .map(|s| s.trim().parse().unwrap())
            .collect();
        let data = &b[10 + hl..];
        let vals = if text.contains("<f8") {
            data.chunks_exact(8)
                .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
                .collect()
        } else {
            data.chunks_exact(4)
                .map(|c| f64::from(f32::from_le_bytes(c.try_into().unwrap())))
                .collect()
        };
        (shape, vals)
    }

    #[test]
    fn export_streams_selected_rows_in_dimension_order() {
        let dir = tempfile::tempdir().unwrap();
        let info = StoreInfo {
            grid: AngularGrid::new(3, 3, 4).unwrap(),
            channels: Channels::Rgb,
        };
        let mask = info.grid.validity_mask();
        let row = |m: usize| -> Vec<f32> {
            (0..info.d())
                .map(|d| {
                    if mask[d / 3] {
                        (m * 1000 + d) as f32
                    } else {
                        0.0
                    }
                })
                .collect()
        };
        let path = dir.path().join("s.sbrdf");
        let mut w = StoreWriter::create(
            &path,
            info.clone(),
            StoreOptions {
                chunk_len: Some(7),
                compression: Compression::Zstd { level: 1 },
                ..Default::default()
            },
        )
        .unwrap();
        for m in 0..3 {
            w.add_material(&format!("m{m}"), "test", &row(m)).unwrap();
        }
        w.finish().unwrap();
        for dtype in ["f32", "f64"] {
            let out = dir.path().join(format!("y_{dtype}.npy"));
            export(&ExportArgs {
                path: path.clone(),
                out: out.clone(),
                materials: Some(vec!["m2".into(), "m0".into()]),
                dtype: dtype.into(),
            })
            .unwrap();
            let (shape, vals) = read_npy_f64(&out);
            assert_eq!(shape, [2, info.d()]);
            let want: Vec<f64> = [row(2), row(0)]
                .concat()
                .into_iter()
                .map(f64::from)
                .collect();
            assert_eq!(vals, want);
        }
        let bad = ExportArgs {
            path: path.clone(),
            out: dir.path().join("z.npy"),
            materials: Some(vec!["nope".into()]),
            dtype: "f32".into(),
        };
        assert!(export(&bad).unwrap_err().to_string().contains("nope"));
        info_ok(&path);
    }

    fn info_ok(path: &Path) {
        info(&InfoArgs {
            path: path.to_owned(),
            json: true,
        })
        .unwrap();
        // A damaged payload makes `info` fail after printing the header.
        let mut b = std::fs::read(path).unwrap();
        b[4096 + 3] ^= 0xff;
        std::fs::write(path, &b).unwrap();
        let e = info(&InfoArgs {
            path: path.to_owned(),
            json: false,
        })
        .unwrap_err();
        assert!(e.to_string().contains("checksum mismatch"), "{e}");
    }
}
