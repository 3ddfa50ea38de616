//! Checks on the command line's file arguments.

use std::path::{Path, PathBuf};

use anyhow::bail;

/// The file a SOURCE argument reads (`FILE`, `DATA.sbrdf:MATERIAL` or `MODEL.toml@X,Y`): the
/// whole string when it names an existing file, else the part before the last `@` or `:`.
pub fn source_file(source: &str) -> PathBuf {
    if Path::new(source).exists() {
        return source.into();
    }
    let cut = source.rfind('@').or_else(|| source.rfind(':'));
    cut.map_or_else(|| source.into(), |i| source[..i].into())
}

/// An output argument: `-` means standard output (`/dev/stdout`, written in place, see
/// [`brdf_io::output`]); anything else is the path itself.
pub fn output(path: &Path) -> PathBuf {
    if path == Path::new("-") {
        PathBuf::from("/dev/stdout")
    } else {
        path.to_owned()
    }
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
/// points at itself). Paths are compared after resolving symbolic links; inputs that do not
/// exist are ignored (their own error comes later).
pub fn ensure_output_is_not_an_input(out: &Path, inputs: &[&Path]) -> anyhow::Result<()> {
    let Some(o) = resolved(out) else {
        return Ok(());
    };
    for input in inputs {
        if std::fs::canonicalize(input).is_ok_and(|i| i == o) {
            bail!(
                "{}: the output is the input {}; writing it would replace the input (choose \
                 another --out)",
                out.display(),
                input.display()
            );
        }
    }
    Ok(())
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
    }

    #[test]
    fn source_arguments_name_their_file() {
        assert_eq!(source_file("d.sbrdf:felt"), PathBuf::from("d.sbrdf"));
        assert_eq!(source_file("m.toml@0.5,-1"), PathBuf::from("m.toml"));
        assert_eq!(source_file("a.bsdf"), PathBuf::from("a.bsdf"));
        assert_eq!(output(Path::new("-")), PathBuf::from("/dev/stdout"));
        assert_eq!(output(Path::new("x.csv")), PathBuf::from("x.csv"));
    }
}
