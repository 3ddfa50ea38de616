//! Checks on the command line's file arguments.

use std::path::{Path, PathBuf};

use anyhow::bail;

/// The file a SOURCE argument reads (`FILE`, `DATA.sbrdf:MATERIAL` or `MODEL.toml@X,Y`): the
/// whole string when it names an existing file, else the part before the last `@` or `:`.
pub fn source_file(source: &str) -> PathBuf {
    if Path::new(source).exists() {
        return source.into();
    }
    if let Some((store, _)) = brdf_io::store::parse_store_spec(source) {
        return store;
    }
    let cut = source.rfind('@').or_else(|| source.rfind(':'));
    cut.map_or_else(|| source.into(), |i| source[..i].into())
}

/// Refuses an output name whose extension says another format than the one written (`render
/// --out x.jpg` would write PNG data under a JPEG name): `out` must end in `.ext` (any case),
/// be `-` (standard output) or an existing special file (`/dev/null`, a FIFO: written into as
/// it is, see `brdf_io::output`). `what` names the format in the message.
pub fn ensure_extension(out: &Path, ext: &str, what: &str) -> anyhow::Result<()> {
    let matches = brdf_io::has_extension(out, ext);
    let special = std::fs::metadata(out).is_ok_and(|m| !m.is_file() && !m.is_dir());
    if !matches && !special && out != Path::new(brdf_io::output::STDOUT) {
        bail!(
            "{}: the output is {what}; its name must end in .{ext} (or be - for standard output)",
            out.display()
        );
    }
    Ok(())
}

/// Refuses `-` (standard output) for binary data (`what`: a PNG image, an .npy array, ...)
/// when standard output is a terminal: the bytes would garble it. Redirected or piped, it
/// passes.
pub fn refuse_binary_on_terminal(out: &Path, what: &str) -> anyhow::Result<()> {
    let terminal = std::io::IsTerminal::is_terminal(&std::io::stdout());
    refuse_binary_if_terminal(out, what, terminal)
}

fn refuse_binary_if_terminal(out: &Path, what: &str, terminal: bool) -> anyhow::Result<()> {
    if terminal && out == Path::new(brdf_io::output::STDOUT) {
        bail!(
            "--out -: refusing to write {what} (binary data) to the terminal; redirect standard \
             output (> FILE) or name a file"
        );
    }
    Ok(())
}

/// Refuses, before any work is done, an output that is a directory or whose directory does
/// not exist or cannot be written (the atomic write would otherwise fail at the end, after the
/// rendering or fitting, naming its temporary file). `-` (standard output) always passes.
pub fn ensure_output_directory(out: &Path) -> anyhow::Result<()> {
    if out == Path::new(brdf_io::output::STDOUT) {
        return Ok(());
    }
    if out.is_dir() {
        bail!(
            "{}: cannot write the output: it is a directory",
            out.display()
        );
    }
    let dir = match out.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    if !dir.is_dir() {
        let why = if dir.exists() {
            "is not a directory"
        } else {
            "does not exist (create it first)"
        };
        bail!(
            "{}: cannot write the output: its directory {} {why}",
            out.display(),
            dir.display()
        );
    }
    if let Err(e) = brdf_io::output::check_writable_dir(dir) {
        bail!("{}: cannot write the output: {e}", out.display());
    }
    Ok(())
}

/// `path` made absolute with symbolic links resolved as far as it exists (the output may not
/// exist yet: its directory is resolved and the file name appended).
fn resolved(path: &Path) -> Option<PathBuf> {
    if let Ok(p) = std::fs::canonicalize(path) {
        return Some(p);
    }
    let name = path.file_name()?;
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    Some(std::fs::canonicalize(dir).ok()?.join(name))
}

/// Refuses an output path that is one of the command's inputs: writing it would replace the
/// input (e.g. `fit data.sbrdf --out data.sbrdf` would turn the dataset into a model file that
/// points at itself). A model file (`.toml`) brings the files it reads along: its dataset store
/// and that store's forward-transformed sidecar ([`model_data_files`]). Paths are compared
/// after resolving symbolic links; inputs given that do not exist are ignored (their own error
/// comes later). `-` (standard output) is never an input. Checks
/// [`ensure_output_directory`] first.
pub fn ensure_output_is_not_an_input(out: &Path, inputs: &[&Path]) -> anyhow::Result<()> {
    if out == Path::new(brdf_io::output::STDOUT) {
        return Ok(());
    }
    ensure_output_directory(out)?;
    let Some(o) = resolved(out) else {
        return Ok(());
    };
    // Inputs as given must exist (else their own error comes later); a model's data files
    // count even before they exist (`predict --sidecar` writes the sidecar it then reads).
    let mut all: Vec<(PathBuf, Option<PathBuf>)> = inputs
        .iter()
        .map(|p| (p.to_path_buf(), std::fs::canonicalize(p).ok()))
        .collect();
    for input in inputs {
        all.extend(model_data_files(input).into_iter().map(|p| {
            let r = resolved(&p);
            (p, r)
        }));
    }
    for (input, r) in &all {
        if r.as_ref().is_some_and(|i| *i == o) {
            bail!(
                "{}: the output is the input {}; writing it would replace the input (choose \
                 another output file)",
                out.display(),
                input.display()
            );
        }
    }
    Ok(())
}

/// The inputs of a command that reads the model file `model` and, when given, its dataset
/// from `dataset` (`--dataset`), for [`ensure_output_is_not_an_input`].
pub fn model_inputs<'a>(model: &'a Path, dataset: Option<&'a Path>) -> Vec<&'a Path> {
    std::iter::once(model).chain(dataset).collect()
}

/// The files a model file reads besides itself: its dataset store (resolved as
/// `predict::Predictor::open` does) and the store's sidecar of forward-transformed values.
/// Empty when `path` is not a readable model file.
pub fn model_data_files(path: &Path) -> Vec<PathBuf> {
    if !brdf_io::has_extension(path, "toml") {
        return Vec::new();
    }
    match gplvm::Model::load(path) {
        Ok(model) => {
            let data = model.dataset_path(path);
            let side = predict::transformed_store_path(&data, model.transform);
            vec![data, side]
        }
        Err(_) => Vec::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outputs_equal_to_inputs_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let data = dir.path().join("data.sbrdf");
        std::fs::write(&data, b"x").unwrap();
        let err = ensure_output_is_not_an_input(&data, &[&data])
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("data.sbrdf") && err.contains("replace the input"),
            "{err}"
        );
        // The same file through another spelling of its path.
        let other = dir.path().join(".").join("data.sbrdf");
        assert!(ensure_output_is_not_an_input(&other, &[&data]).is_err());
        // A new file next to it, and a missing input, are fine.
        let new = dir.path().join("model.toml");
        assert!(ensure_output_is_not_an_input(&new, &[&data]).is_ok());
        assert!(ensure_output_is_not_an_input(&new, &[&dir.path().join("nope")]).is_ok());
        assert!(ensure_output_is_not_an_input(Path::new("-"), &[&data]).is_ok());
    }

    /// An output inside a directory whose mode bits say read-only is refused before any work,
    /// even for root (who may write there), naming the directory.
    #[cfg(unix)]
    #[test]
    fn outputs_in_read_only_directories_are_refused() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let ro = dir.path().join("ro");
        std::fs::create_dir(&ro).unwrap();
        std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o555)).unwrap();
        let err = ensure_output_directory(&ro.join("x.png"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains(&format!("{}: the directory is read-only", ro.display())),
            "{err}"
        );
        assert_eq!(std::fs::read_dir(&ro).unwrap().count(), 0);
        std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o755)).unwrap();
        ensure_output_directory(&ro.join("x.png")).unwrap();
    }

    #[test]
    fn output_extensions_must_name_the_format() {
        assert!(ensure_extension(Path::new("a/b.png"), "png", "a PNG image").is_ok());
        assert!(ensure_extension(Path::new("B.PNG"), "png", "a PNG image").is_ok());
        assert!(ensure_extension(Path::new("-"), "png", "a PNG image").is_ok());
        #[cfg(unix)]
        assert!(ensure_extension(Path::new("/dev/null"), "png", "a PNG image").is_ok());
        // An existing file or directory is no special file.
        let dir = tempfile::tempdir().unwrap();
        let jpg = dir.path().join("x.jpg");
        std::fs::write(&jpg, b"x").unwrap();
        for existing in [&jpg, &dir.path().to_path_buf()] {
            assert!(ensure_extension(existing, "png", "a PNG image").is_err());
        }
        for bad in ["x.jpg", "x", "png"] {
            let e = ensure_extension(Path::new(bad), "png", "a PNG image")
                .unwrap_err()
                .to_string();
            assert!(e.starts_with(bad) && e.contains("must end in .png"), "{e}");
        }
    }

    #[test]
    fn binary_data_is_not_written_to_a_terminal() {
        let e = refuse_binary_if_terminal(Path::new("-"), "a PNG image", true)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("refusing to write a PNG image (binary data) to the terminal"),
            "{e}"
        );
        assert!(refuse_binary_if_terminal(Path::new("-"), "a PNG image", false).is_ok());
        assert!(refuse_binary_if_terminal(Path::new("x.png"), "a PNG image", true).is_ok());
    }

    /// A path that does not exist yet resolves to its resolved directory joined with its name;
    /// a bare name to the current directory's.
    #[test]
    fn new_paths_resolve_through_their_directory() {
        let dir = tempfile::tempdir().unwrap();
        let real = std::fs::canonicalize(dir.path()).unwrap();
        let new = dir.path().join(".").join("new.png");
        assert_eq!(resolved(&new), Some(real.join("new.png")));
        let cwd = std::fs::canonicalize(".").unwrap();
        assert_eq!(resolved(Path::new("new.png")), Some(cwd.join("new.png")));
        assert_eq!(resolved(&dir.path().join("no/new.png")), None);
    }

    #[test]
    fn source_arguments_name_their_file() {
        assert_eq!(source_file("d.sbrdf:felt"), PathBuf::from("d.sbrdf"));
        assert_eq!(source_file("d.sbrdf:gp@0.5,1:x"), PathBuf::from("d.sbrdf"));
        assert_eq!(source_file("m.toml@0.5,-1"), PathBuf::from("m.toml"));
        assert_eq!(source_file("a.bsdf"), PathBuf::from("a.bsdf"));
    }
}
