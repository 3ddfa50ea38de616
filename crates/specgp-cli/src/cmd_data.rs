//! `specgp import`, `specgp info` and `specgp export`: data into and out of dataset stores.

use std::fs::File;
use std::io::{Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use crate::console::quantity;
use anyhow::{Context, bail};
use brdf_io::store::{Compression, Dtype};
use brdf_io::{AngularGrid, Channels, ImportReport, Store, StoreInfo, StoreOptions, StoreWriter};
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
    /// Stored value type: f32 (exact) or f16 (half precision, half the size; values up to 65504,
    /// a larger one is refused: keep f32 for sharp peaks).
    #[arg(long, default_value = "f32")]
    pub dtype: Dtype,
    /// Compress chunks with zstd at this level (1..=22); uncompressed when absent.
    #[arg(long, value_name = "LEVEL", value_parser = clap::value_parser!(i32).range(1..=22))]
    pub zstd: Option<i32>,
    /// With `--zstd`: byte-shuffle each chunk first (smaller files for float data).
    #[arg(long, requires = "zstd")]
    pub shuffle: bool,
    /// Indices d (angular cell x channel, in `info`'s order) per chunk; a chunk holds their
    /// values for every material (default: about 1 MiB per chunk, 256 KiB with zstd).
    #[arg(long)]
    pub chunk_len: Option<usize>,
}

impl StoreOut {
    fn options(&self) -> StoreOptions {
        StoreOptions {
            chunk_len: self.chunk_len,
            dtype: self.dtype,
            compression: self.zstd.map_or(Compression::None, |level| {
                if self.shuffle {
                    Compression::ZstdShuffle { level }
                } else {
                    Compression::Zstd { level }
                }
            }),
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
    /// MERL `.binary` files (R,G,B), resampled onto the grid.
    Merl(MerlArgs),
    /// Neural-BRDF networks (one weights row per material) evaluated on the grid.
    Nbrdf(NbrdfArgs),
}

/// Arguments of `specgp import merl`.
#[derive(Debug, clap::Args)]
struct MerlArgs {
    /// MERL `.binary` files, one material each (named by the file stem).
    #[arg(required = true)]
    files: Vec<PathBuf>,
    /// How MERL cells map onto a different grid: `average` (mean of the valid MERL cells in each
    /// target bin) or `nearest`.
    #[arg(long, default_value = "average", value_parser = ["average", "nearest"])]
    resampling: String,
    #[command(flatten)]
    store: StoreOut,
}

/// Arguments of `specgp import nbrdf`.
#[derive(Debug, clap::Args)]
struct NbrdfArgs {
    /// The `(N, 675)` weights `.npy`.
    weights: PathBuf,
    /// Material names, one line per weights row.
    #[arg(long)]
    names: PathBuf,
    /// Only these materials (comma-separated names; default: all).
    #[arg(long, value_delimiter = ',')]
    only: Option<Vec<String>>,
    /// Values above this (1/sr) are counted as outliers in the report.
    #[arg(long, default_value_t = brdf_io::nbrdf::DEFAULT_OUTLIER_THRESHOLD)]
    outlier_threshold: f64,
    /// Clamp outliers to `--outlier-threshold` (otherwise they are stored as computed).
    #[arg(long)]
    clamp: bool,
    /// Store f(wi, wo) of each bin centre's own direction pair instead of the reciprocal mean
    /// of both orders ((f(wi, wo) + f(wo, wi)) / 2; for RGL files weighted by the square of
    /// the cosine each order divides by) (half the evaluations; the source's non-reciprocal
    /// part then shows as a seam along the plane of incidence in renders).
    #[arg(long)]
    no_reciprocal: bool,
    #[command(flatten)]
    store: StoreOut,
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
    /// Store f(wi, wo) of each bin centre's own direction pair instead of the reciprocal mean
    /// of both orders ((f(wi, wo) + f(wo, wi)) / 2; for RGL files weighted by the square of
    /// the cosine each order divides by) (half the evaluations; the source's non-reciprocal
    /// part then shows as a seam along the plane of incidence in renders).
    #[arg(long)]
    no_reciprocal: bool,
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
    let (out, inputs): (&Path, Vec<&Path>) = match &args.format {
        ImportFormat::Rgl(a) => (&a.store.out, a.files.iter().map(PathBuf::as_path).collect()),
        ImportFormat::Merl(a) => (&a.store.out, a.files.iter().map(PathBuf::as_path).collect()),
        ImportFormat::Nbrdf(a) => (&a.store.out, vec![&a.weights, &a.names]),
    };
    crate::paths::ensure_output_is_not_an_input(out, &inputs)?;
    crate::paths::ensure_extension(out, "sbrdf", "a dataset store")?;
    match &args.format {
        ImportFormat::Rgl(a) => import_rgl(a),
        ImportFormat::Merl(a) => import_merl(a),
        ImportFormat::Nbrdf(a) => import_nbrdf(a),
    }
}

/// Writes materials produced one at a time by `load(i) -> (name, source, values, report)`,
/// with a progress bar, a report line per material and a total.
fn import_each(
    store: &StoreOut,
    channels: Channels,
    what: &str,
    count: usize,
    mut load: impl FnMut(usize) -> anyhow::Result<(String, String, Vec<f32>, ImportReport)>,
) -> anyhow::Result<()> {
    if let Some(bytes) = store
        .options()
        .uncompressed_bytes(count, store.grid.len() * channels.len())
    {
        brdf_io::output::ensure_space(&store.out, bytes, "the dataset store")?;
    }
    let info = StoreInfo {
        grid: store.grid,
        channels,
    };
    let mut writer = StoreWriter::create(&store.out, info, store.options())?;
    let pb = bar(count as u64, what);
    let mut total = ImportReport::new();
    // Material i is written while material i + 1 is resampled.
    writer.add_materials_overlapped(
        count,
        |i| {
            let (name, source, values, report) = load(i)?;
            report.ensure_finite(&format!("{name} ({source})"))?;
            pb.set_message(name.clone());
            pb.suspend(|| {
                errln!("{name}: {report}");
                // (A MERL file whose samples are all negative, i.e. all "not measured".)
                if report.values > 0 && report.max <= 0.0 {
                    errln!(
                        "warning: {name} ({source}): every stored value is 0 (a black material: \
                         nothing in the source was measured or positive)"
                    );
                }
            });
            total = total.merge(&report);
            pb.inc(1);
            Ok((name, source, values))
        },
        anyhow::Error::from,
    )?;
    pb.finish_and_clear();
    let header = writer.finish()?;
    // Status goes to stderr like every command's (stdout is for machine-readable output).
    errln!("total: {total}");
    errln!(
        "wrote {}: {}, grid {}, {}, D = {}",
        store.out.display(),
        quantity(header.n_materials(), "material"),
        header.grid,
        quantity(header.channels.len(), "channel"),
        header.d
    );
    Ok(())
}

/// Refuses repeated or invalid material names before anything is read or written (a store's
/// names are unique and free of control characters; the store writer would only find out
/// after resampling the earlier sources). `names` pairs each name with the source it comes
/// from.
fn ensure_unique_names(names: &[(String, String)]) -> anyhow::Result<()> {
    let mut seen: std::collections::HashMap<&str, &str> = std::collections::HashMap::new();
    for (name, source) in names {
        if let Err(why) = brdf_io::store::check_material_name(name) {
            bail!("{source}: {why}");
        }
        if let Some(first) = seen.insert(name, source) {
            bail!(
                "{source}: the material name {name:?} is already taken by {first} (names in a \
                 store must be unique)"
            );
        }
    }
    Ok(())
}

/// Names (file stems) and sources of material files.
fn file_names(files: &[PathBuf]) -> Vec<(String, String)> {
    files
        .iter()
        .map(|f| (stem(f), f.display().to_string()))
        .collect()
}

fn import_merl(args: &MerlArgs) -> anyhow::Result<()> {
    use brdf_io::merl::{Resampling, read_merl};
    let method = if args.resampling == "nearest" {
        Resampling::Nearest
    } else {
        Resampling::Average
    };
    ensure_unique_names(&file_names(&args.files))?;
    import_each(
        &args.store,
        Channels::Rgb,
        "import merl",
        args.files.len(),
        |i| {
            let file = &args.files[i];
            let brdf = read_merl(file)?;
            let (values, report) = brdf.resample(&args.store.grid, method);
            Ok((stem(file), file.display().to_string(), values, report))
        },
    )
}

fn import_nbrdf(args: &NbrdfArgs) -> anyhow::Result<()> {
    use brdf_io::nbrdf::{NbrdfOptions, NbrdfSet};
    // A name given twice in --only is the command line's mistake, not names.txt's.
    let mut seen = std::collections::HashSet::new();
    if let Some(repeated) = args.only.iter().flatten().find(|n| !seen.insert(n.trim())) {
        bail!(
            "--only names {:?} twice (names in a store must be unique)",
            repeated.trim()
        );
    }
    let set = NbrdfSet::open(&args.weights, &args.names)?;
    let rows: Vec<usize> = match &args.only {
        Some(names) => names
            .iter()
            .map(|n| {
                set.find(n.trim()).with_context(|| {
                    let names: Vec<&str> = set.names().iter().map(String::as_str).collect();
                    let hint = brdf_io::error::closest_name(n.trim(), &names)
                        .map_or(String::new(), |c| format!("; did you mean {c:?}?"));
                    format!(
                        "{}: no material named {:?}{hint}",
                        args.names.display(),
                        n.trim()
                    )
                })
            })
            .collect::<anyhow::Result<_>>()?,
        None => (0..set.len()).collect(),
    };
    ensure_unique_names(
        &rows
            .iter()
            .map(|&r| {
                let source = format!("{} line {}", args.names.display(), r + 1);
                (set.names()[r].clone(), source)
            })
            .collect::<Vec<_>>(),
    )?;
    let options = NbrdfOptions {
        outlier_threshold: args.outlier_threshold,
        clamp_outliers: args.clamp,
        reciprocal: !args.no_reciprocal,
    };
    // The networks' inputs are the same for every network: made once.
    let inputs = brdf_io::nbrdf::GridInputs::new(&args.store.grid);
    import_each(
        &args.store,
        Channels::Rgb,
        "import nbrdf",
        rows.len(),
        |i| {
            let net = set.material(rows[i])?;
            let (values, report) = net.resample_on(&inputs, options)?;
            let source = format!("{} row {}", args.weights.display(), rows[i]);
            Ok((net.name().to_owned(), source, values, report))
        },
    )
}

/// Whether the RGL file `path` is spectral (a `wavelengths` field) or RGB (an `rgb` field),
/// from the field list of its header alone (a few hundred bytes; the tables stay unread).
/// `None` when the header cannot be read that far: the file's own error comes when it is
/// opened.
fn rgl_is_spectral(path: &Path) -> Option<bool> {
    use std::io::Read;
    let mut r = std::io::BufReader::new(File::open(path).ok()?);
    let mut take = |n: usize| -> Option<Vec<u8>> {
        let mut b = vec![0; n];
        r.read_exact(&mut b).ok()?;
        Some(b)
    };
    let u16_le = |b: Vec<u8>| Some(u16::from_le_bytes(b.try_into().ok()?));
    // Magic, version, field count (tensor_file, as `brdf_io::tensor::TensorFile` reads it).
    if take(12)? != b"tensor_file\0" {
        return None;
    }
    take(2)?;
    let fields = u32::from_le_bytes(take(4)?.try_into().ok()?);
    let mut rgb = false;
    for _ in 0..fields.min(1024) {
        let len = usize::from(u16_le(take(2)?)?);
        let name = take(len)?;
        let rank = usize::from(u16_le(take(2)?)?);
        take(1 + 8 + 8 * rank)?; // dtype code, offset, shape
        match name.as_slice() {
            b"wavelengths" => return Some(true),
            b"rgb" => rgb = true,
            _ => {}
        }
    }
    rgb.then_some(false)
}

/// Refuses, before any file is resampled, RGL files that mix spectral and RGB data (a store
/// holds one kind) and `--wavelengths` for RGB files; each message names the files.
fn ensure_one_kind_of_rgl(args: &RglArgs) -> anyhow::Result<()> {
    let kinds: Vec<(&PathBuf, bool)> = args
        .files
        .iter()
        .filter_map(|f| rgl_is_spectral(f).map(|s| (f, s)))
        .collect();
    let spectral = kinds.iter().find(|(_, s)| *s).map(|(f, _)| f.display());
    let rgb = kinds.iter().find(|(_, s)| !*s).map(|(f, _)| f.display());
    match (spectral, rgb) {
        (Some(s), Some(r)) => bail!(
            "the files mix spectral and RGB data: {s} is spectral, {r} is RGB; a store holds \
             one kind, so import them into separate stores"
        ),
        (None, Some(r)) if args.wavelengths.is_some() => bail!(
            "{r}: RGB data has no wavelengths; leave out --wavelengths (its R, G, B channels \
             are read as they are)"
        ),
        _ => Ok(()),
    }
}

fn import_rgl(args: &RglArgs) -> anyhow::Result<()> {
    use brdf_io::rgl::RglBsdf;
    ensure_unique_names(&file_names(&args.files))?;
    ensure_one_kind_of_rgl(args)?;
    let options = brdf_io::source::ResampleOptions {
        reciprocal: !args.no_reciprocal,
        ..Default::default()
    };
    // Every file is read and checked against the channels before any is resampled (which
    // takes far longer than reading): a damaged file or a spectral file whose range misses a
    // wavelength is refused up front, not after the files before it were resampled.
    let first = RglBsdf::open(&args.files[0])?;
    let channels = match &args.wavelengths {
        Some(spec) => Channels::parse_wavelengths(spec)?,
        None => first.native_channels().clone(),
    };
    first.with_channels(&channels)?;
    let pb = bar(args.files.len() as u64 - 1, "check rgl");
    for file in &args.files[1..] {
        pb.set_message(stem(file));
        RglBsdf::open(file)?.with_channels(&channels)?;
        pb.inc(1);
    }
    pb.finish_and_clear();
    import_each(
        &args.store,
        channels.clone(),
        "import rgl",
        args.files.len(),
        |i| {
            let file = &args.files[i];
            let (values, report) = RglBsdf::open(file)?
                .resample_with(&args.store.grid, &channels, options)
                .with_context(|| format!("resampling {}", file.display()))?;
            Ok((stem(file), file.display().to_string(), values, report))
        },
    )
}

/// Arguments of `specgp info`.
#[derive(Debug, clap::Args)]
pub struct InfoArgs {
    /// A dataset store (`.sbrdf`), a model file (`.toml`, written by `specgp fit`) or an RGL
    /// file (`.bsdf`).
    path: PathBuf,
    /// Print the header (store) or the model without its Gram matrix as JSON, with the file
    /// size and the checksum verdict (store) or whether the model's dataset is present and
    /// matches (model: `dataset_checksum_verified`, true when the dataset is intact and the
    /// one the model was fitted on; `dataset_intact`, null when it does not open); for an RGL
    /// file its description, channels and table sizes.
    #[arg(long)]
    json: bool,
}

/// `specgp info FILE.bsdf`: an RGL file's description, channels and table sizes.
fn bsdf_info(args: &InfoArgs) -> anyhow::Result<()> {
    let bsdf = brdf_io::rgl::RglBsdf::open(&args.path)?;
    let degrees: Vec<f64> = bsdf.theta_i().iter().map(|t| t.to_degrees()).collect();
    let (tw, th) = bsdf.table_size();
    let (ww, wh) = bsdf.warp_size();
    let channels = bsdf.native_channels();
    let bytes = std::fs::metadata(&args.path)
        .with_context(|| format!("reading {}", args.path.display()))?
        .len();
    if args.json {
        let v = serde_json::json!({
            "path": args.path.display().to_string(),
            "format": "rgl-bsdf",
            "description": bsdf.description(),
            "channels": channels,
            "theta_i_degrees": degrees,
            "table": [tw, th],
            "warp": [ww, wh],
            "jacobian": bsdf.jacobian(),
            "file_bytes": bytes,
        });
        outln!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        let list = |v: &[f64]| {
            v.iter()
                .map(|d| format!("{d:.1}"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        outln!(
            "file           {} (RGL tensor file, isotropic)",
            args.path.display()
        );
        outln!("description    {}", bsdf.description());
        outln!(
            "channels       {} ({})",
            channels.len(),
            channels.labels().join(",")
        );
        outln!(
            "theta_i        {} (degrees: {})",
            degrees.len(),
            list(&degrees)
        );
        outln!("value tables   {tw} x {th} per incident elevation");
        outln!("warp tables    {ww} x {wh}");
        outln!("jacobian       {}", bsdf.jacobian());
        outln!("bytes          {bytes}");
    }
    Ok(())
}

/// Runs `specgp info`: a model file (`.toml`), an RGL file (`.bsdf`) or a dataset store
/// (anything else).
pub fn info(args: &InfoArgs) -> anyhow::Result<()> {
    if brdf_io::has_extension(&args.path, "toml") {
        return model_info(args);
    }
    if brdf_io::has_extension(&args.path, "bsdf") {
        return bsdf_info(args);
    }
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
        outln!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        let comp = match h.layout.compression {
            Compression::None => "none".to_owned(),
            Compression::Zstd { level } => format!("zstd level {level}"),
            Compression::ZstdShuffle { level } => format!("byte shuffle + zstd level {level}"),
        };
        outln!("file           {}", args.path.display());
        outln!("materials      {}", h.n_materials());
        let width = name_width(h.materials.iter().map(|m| m.name.as_str()));
        for m in &h.materials {
            let flushed = match m.stats.flushed_to_zero {
                0 => String::new(),
                n => format!("  flushed to 0 by {} {n}", h.layout.dtype.name()),
            };
            outln!(
                "  {:<width$} mean {:<10.4e}  min {:<10.4e}  max {:<10.4e}  negatives {}{flushed}  from {}",
                m.name,
                m.stats.mean,
                m.stats.min,
                m.stats.max,
                m.stats.negatives,
                m.source
            );
        }
        outln!("grid           {}", h.grid);
        outln!(
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
        outln!("D              {}", h.d);
        outln!("order          {}", h.dimension_order);
        outln!("bytes          {}", store.file_bytes());
        outln!(
            "layout         {}, {} indices x {} chunks, {}, {comp}",
            h.layout.order,
            h.layout.chunk_len,
            h.layout.n_chunks,
            h.layout.dtype.name()
        );
        outln!(
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

/// `specgp info MODEL.toml`: the fit's summary and whether its dataset is where the model says,
/// with the checksum it was fitted on and an intact payload (re-hashed as `specgp info
/// DATA.sbrdf` does; a damaged payload is reported, then fails the command like there).
fn model_info(args: &InfoArgs) -> anyhow::Result<()> {
    let model = gplvm::Model::load(&args.path)?;
    let ds = &model.dataset;
    let ds_path = model.dataset_path(&args.path);
    let mut recorded = false;
    let (dataset, verified) = match Store::open(&ds_path) {
        Ok(store) => {
            let verified = store.verify_checksum();
            recorded = store.header().checksum.to_string() == ds.checksum;
            let status = match (&verified, recorded) {
                (Err(brdf_io::Error::StoreChecksum { .. }), _) => {
                    "present, checksum MISMATCH: its payload is damaged".to_owned()
                }
                (Err(e), _) => format!("present, its payload cannot be verified: {e}"),
                (Ok(()), true) => "present, checksum verified".to_owned(),
                (Ok(()), false) => "present, DIFFERENT checksum (refitted or replaced?)".to_owned(),
            };
            (status, Some(verified))
        }
        Err(e) => (format!("not usable: {e}"), None),
    };
    // After the summary: a damaged dataset fails the command, as `info DATA.sbrdf` does.
    let intact = verified.as_ref().map(Result::is_ok);
    let verdict = match verified {
        Some(Err(e)) => {
            let model = args.path.display();
            Err(anyhow::Error::from(e).context(format!("the dataset of model {model}")))
        }
        _ => Ok(()),
    };
    let f = &model.fit;
    let h = &model.hyperparameters;
    if args.json {
        let mut v = serde_json::to_value(&model)?;
        if let Some(o) = v.as_object_mut() {
            o.remove("gram");
            o.insert("path".into(), args.path.display().to_string().into());
            o.insert("dataset_status".into(), dataset.into());
            // Usable by the model: intact, and the data it was fitted on.
            let usable = intact == Some(true) && recorded;
            o.insert("dataset_checksum_verified".into(), usable.into());
            o.insert("dataset_intact".into(), intact.into());
        }
        outln!("{}", serde_json::to_string_pretty(&v)?);
        return verdict;
    }
    outln!("file           {} (model)", args.path.display());
    outln!("dataset        {} ({dataset})", ds_path.display());
    outln!("checksum       {}", ds.checksum);
    outln!(
        "data           {}, grid {}, {}, D {} ({} with data)",
        quantity(ds.n_materials, "material"),
        ds.grid,
        quantity(ds.channels.len(), "channel"),
        ds.d,
        ds.d_effective
    );
    outln!(
        "model          q = {}, transform {}, data scale {:.6e}, prior {}",
        model.latent_dim,
        model.transform,
        model.data_scale,
        if model.prior { "on" } else { "off" }
    );
    outln!(
        "kernel         signal variance {:.6e}, length-scale {:?}, noise {:.3e}",
        h.signal_variance,
        h.length_scale,
        h.noise
    );
    outln!(
        "fit            {}: log-likelihood {:.10e} (PCA start {:.6e}), |grad| {:.3e}",
        f.optimizer,
        f.log_likelihood,
        f.initial_log_likelihood,
        f.gradient_norm
    );
    outln!(
        "               {} iterations, {} evaluations, stopped: {}",
        f.iterations,
        f.evaluations,
        f.stop_reason
    );
    outln!(
        "               jitter {:.3e}, condition number {:.3e}, PCA explained {:.4}",
        f.jitter,
        f.condition_number,
        f.pca_explained
    );
    outln!(
        "               Gram pass {:.3} s, optimiser {:.3} s",
        f.gram_seconds,
        f.optimize_seconds
    );
    outln!("materials      (see `specgp latent`)");
    let width = name_width(model.materials.iter().map(|m| m.name.as_str()));
    for m in &model.materials {
        let coords: Vec<String> = m.coords.iter().map(|c| format!("{c:+.4}")).collect();
        outln!("  {:<width$} {}", m.name, coords.join(" "));
    }
    verdict
}

/// Arguments of `specgp export`.
#[derive(Debug, clap::Args)]
pub struct ExportArgs {
    /// A dataset store (`.sbrdf`).
    path: PathBuf,
    /// Output `.npy`: an N x D matrix, rows in store order (or `--materials` order), columns in
    /// the store's dimension order (`-`: standard output, redirected to a file with `>`).
    #[arg(long)]
    out: PathBuf,
    /// Comma-separated material names to export (default: all); names that contain commas
    /// (e.g. `gp-exact@0.1,0.2` from `specgp predict`) are recognised whole, and a list that
    /// the store's names read in more than one way is refused as ambiguous.
    #[arg(long)]
    materials: Option<String>,
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

/// The store rows that the comma-separated `list` names. Names may contain commas, so the
/// list is split at the commas that leave every piece a material name (as given, else
/// trimmed): a list that reads in no way is an error naming the piece where the furthest
/// reading stops, one that reads in several ways is ambiguous.
fn select_materials(store: &Store, list: &str) -> anyhow::Result<Vec<usize>> {
    let pieces: Vec<&str> = list.split(',').collect();
    let k = pieces.len();
    let all = store.names();
    let longest = all.iter().map(|n| n.len()).max().unwrap_or(0);
    let index: std::collections::HashMap<&str, usize> =
        all.iter().enumerate().map(|(r, n)| (&**n, r)).collect();
    // names[i]: (row, j) for each name made of pieces i..=j (no longer than the longest name).
    let names: Vec<Vec<(usize, usize)>> = (0..k)
        .map(|i| {
            let mut name = String::new();
            let mut found = Vec::new();
            for (j, piece) in pieces.iter().enumerate().skip(i) {
                if j > i {
                    name.push(',');
                }
                name.push_str(piece);
                if name.trim().len() > longest {
                    break;
                }
                if let Some(&r) = index.get(name.as_str()).or_else(|| index.get(name.trim())) {
                    found.push((r, j));
                }
            }
            found
        })
        .collect();
    // readings[i]: in how many ways pieces i.. read as names (saturating at 2).
    let mut readings = vec![0u8; k + 1];
    readings[k] = 1;
    for i in (0..k).rev() {
        readings[i] = names[i]
            .iter()
            .fold(0u8, |n, &(_, j)| n.saturating_add(readings[j + 1]).min(2));
    }
    // A reading: at each name, the first (or last) choice that still reads to the end.
    let walk = |last: bool| {
        let (mut i, mut rows) = (0, Vec::new());
        while i < k {
            let mut viable = names[i].iter().filter(|&&(_, j)| readings[j + 1] > 0);
            let &(row, j) = if last {
                viable.next_back()
            } else {
                viable.next()
            }
            .expect("a position with readings has a viable name");
            rows.push(row);
            i = j + 1;
        }
        rows
    };
    match readings[0] {
        0 => {
            // The last piece, among those a reading can reach, that no name starts with (the
            // one the furthest reading stops at; its error names the store and suggests a near
            // name); there is one, since no reading reaches the end.
            let mut reachable = vec![false; k + 1];
            reachable[0] = true;
            let mut stuck = None;
            for i in 0..k {
                if reachable[i] {
                    names[i].iter().for_each(|&(_, j)| reachable[j + 1] = true);
                    if names[i].is_empty() {
                        stuck = Some(i);
                    }
                }
            }
            let piece = stuck.map_or(list, |i| pieces[i]);
            match store.material_index(piece.trim()) {
                Err(e) => Err(e.into()),
                Ok(_) => bail!("--materials {list:?} does not read as material names"),
            }
        }
        1 => Ok(walk(false)),
        _ => {
            let show = |rows: Vec<usize>| {
                format!("{:?}", rows.iter().map(|&r| all[r]).collect::<Vec<_>>())
            };
            bail!(
                "--materials {list:?} is ambiguous: the store's material names (which may \
                 contain commas) read it as {} or as {}",
                show(walk(false)),
                show(walk(true))
            )
        }
    }
}

/// Bytes of the rows [`export`] gathers before writing them out (the window of indices d is
/// this over the selected rows' bytes per index, at least 1).
const EXPORT_WINDOW_BYTES: usize = 256 << 20;

/// Runs `specgp export`: streams the chosen rows out chunk by chunk (bounded memory).
pub fn export(args: &ExportArgs) -> anyhow::Result<()> {
    export_in_windows(args, EXPORT_WINDOW_BYTES)
}

/// [`export`] gathering about `window_bytes` of the rows at a time (a parameter for tests:
/// exports of test-sized stores fit in one window of the default).
fn export_in_windows(args: &ExportArgs, window_bytes: usize) -> anyhow::Result<()> {
    crate::paths::ensure_output_is_not_an_input(&args.out, &[&args.path])?;
    crate::paths::ensure_extension(&args.out, "npy", "an .npy array")?;
    crate::paths::refuse_binary_on_terminal(&args.out, "an .npy array")?;
    let store = Store::open(&args.path)?;
    // Export reads every value anyway: damaged data must not leave as numbers.
    store.verify_checksum()?;
    let rows: Vec<usize> = match &args.materials {
        Some(list) => select_materials(&store, list)?,
        None => (0..store.n_materials()).collect(),
    };
    if rows.is_empty() {
        bail!("--materials selects no material");
    }
    let (d, n) = (store.d(), store.n_materials());
    let f64_out = args.dtype == "f64";
    let size = if f64_out { 8 } else { 4 };
    let header = npy_header(if f64_out { "<f8" } else { "<f4" }, rows.len(), d);
    // Rows are written window by window at their offsets, so the output must be seekable.
    let out = brdf_io::output::AtomicOutput::create_seekable(&args.out, "an .npy export")?;
    let io = |e: std::io::Error| anyhow::anyhow!("{}: {e}", args.out.display());
    let mut file: File = out.file().try_clone().map_err(io)?;
    file.write_all(&header).map_err(io)?;
    out.set_len((header.len() + rows.len() * d * size) as u64)?;
    // Gather a window of indices for every selected row, then write each row's segment.
    let window = (window_bytes / (rows.len() * size)).max(1);
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
    drop(file);
    out.commit()?;
    errln!(
        "wrote {}: {} x {d} {} ({})",
        args.out.display(),
        rows.len(),
        args.dtype,
        store.header().dimension_order
    );
    Ok(())
}

/// The column width that lines up material names: the longest name's (in characters), at
/// least 24.
fn name_width<'a>(names: impl Iterator<Item = &'a str>) -> usize {
    names.map(|n| n.chars().count()).fold(24, usize::max)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Names longer than 24 characters widen the column (counted in characters, not bytes).
    #[test]
    fn name_columns_fit_the_longest_name() {
        assert_eq!(name_width(["paper", "satin"].into_iter()), 24);
        let long = ["paper", "laika_ceiling_paint_18_gray"];
        assert_eq!(name_width(long.into_iter()), 27);
        assert_eq!(name_width(["é".repeat(30).as_str()].into_iter()), 30);
    }

    #[test]
    fn repeated_material_names_are_refused_up_front() {
        let files = [
            PathBuf::from("a/gold.bsdf"),
            PathBuf::from("b/felt.bsdf"),
            PathBuf::from("c/gold.bsdf"),
        ];
        let e = ensure_unique_names(&file_names(&files))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("c/gold.bsdf") && e.contains("\"gold\"") && e.contains("a/gold.bsdf"),
            "{e}"
        );
        assert!(ensure_unique_names(&file_names(&files[..2])).is_ok());
    }

    /// `--materials` reads names that hold commas whole, in the one way the store's names
    /// allow; a list that reads in two ways is refused as ambiguous (the shortest name was
    /// taken first: "a,b" failed on "b" although "a,b" is a material).
    #[test]
    fn material_lists_split_where_the_names_allow() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.sbrdf");
        let info = brdf_io::StoreInfo {
            grid: brdf_io::AngularGrid::new(2, 2, 4).unwrap(),
            channels: brdf_io::Channels::Rgb,
        };
        let mut w = brdf_io::StoreWriter::create(&path, info, Default::default()).unwrap();
        let d = w.d();
        for name in ["a", "a,b", "b,c", "c", " x "] {
            w.add_material(name, "test", &vec![0.0; d]).unwrap();
        }
        w.finish().unwrap();
        let store = Store::open(&path).unwrap();
        let rows = |list: &str| select_materials(&store, list).map_err(|e| e.to_string());
        assert_eq!(rows("a,b"), Ok(vec![1]));
        assert_eq!(rows("c,a,b"), Ok(vec![3, 1]));
        assert_eq!(rows("a, x ,c"), Ok(vec![0, 4, 3]));
        assert_eq!(rows("a , c"), Ok(vec![0, 3]));
        assert!(rows("a,b,c,a").unwrap_err().contains("is ambiguous"));
        let e = rows("a,b,c").unwrap_err();
        assert!(
            e.contains("is ambiguous")
                && e.contains(r#"["a,b", "c"]"#)
                && e.contains(r#"["a", "b,c"]"#),
            "{e}"
        );
        let e = rows("a,b,d").unwrap_err();
        assert!(e.contains("\"d\"") && e.contains("s.sbrdf"), "{e}");
        let e = rows("q,a").unwrap_err();
        assert!(e.contains("\"q\""), "{e}");
    }

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
                compression: Compression::ZstdShuffle { level: 1 },
                ..Default::default()
            },
        )
        .unwrap();
        for m in 0..3 {
            w.add_material(&format!("m{m}"), "test", &row(m)).unwrap();
        }
        w.finish().unwrap();
        // One window, or rows gathered for 10 indices in f64 and 20 in f32 (written every
        // second or third chunk of 7, the last window partial) or for 1 (every chunk).
        let windows = [EXPORT_WINDOW_BYTES, 2 * 8 * 10, 1];
        for (dtype, window) in ["f32", "f64"]
            .into_iter()
            .flat_map(|t| windows.map(|w| (t, w)))
        {
            let out = dir.path().join(format!("y_{dtype}_{window}.npy"));
            let args = ExportArgs {
                path: path.clone(),
                out: out.clone(),
                materials: Some("m2,m0".into()),
                dtype: dtype.into(),
            };
            export_in_windows(&args, window).unwrap();
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
            materials: Some("nope".into()),
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
