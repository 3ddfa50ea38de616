//! The team's shared reference data for tests: `../shared/data` beside the project root, or the
//! folder [`ROOT_VARIABLE`] names (real RGL files, Neural-BRDF networks, CIE tables, measured
//! spectra; see its `SOURCES.md`).
//!
//! Tests that check against real data must not pass without it: a missing file **fails** the
//! test with a message naming it. To run the tests on a machine without the folder on purpose,
//! set [`SKIP_VARIABLE`] (any value): the helpers then return `None` and say on standard error
//! that the test is skipped. CI runs with the folder present and the variable unset.

use std::path::{Path, PathBuf};

/// Environment variable that turns a missing shared file into a skipped test.
pub const SKIP_VARIABLE: &str = "SPECGP_SKIP_SHARED_DATA";

/// Environment variable naming the shared data folder, for a checkout that does not sit beside
/// `shared/` (default: `../shared/data` beside the project root).
pub const ROOT_VARIABLE: &str = "SPECGP_SHARED_DATA";

/// The shared data folder (it may not exist): [`ROOT_VARIABLE`] when set and not empty, else
/// `../shared/data` beside the project root.
pub fn root() -> PathBuf {
    root_from(std::env::var_os(ROOT_VARIABLE))
}

/// [`root`] for the value `variable` of [`ROOT_VARIABLE`].
fn root_from(variable: Option<std::ffi::OsString>) -> PathBuf {
    match variable {
        Some(v) if !v.is_empty() => PathBuf::from(v),
        _ => Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"),
    }
}

/// The file or folder `relative` under the shared data folder. Missing: `None` when
/// [`SKIP_VARIABLE`] is set, else a panic naming it.
pub fn path(relative: &str) -> Option<PathBuf> {
    let p = root().join(relative);
    if p.exists() {
        return Some(p);
    }
    if std::env::var_os(SKIP_VARIABLE).is_some() {
        eprintln!(
            "skipping ({SKIP_VARIABLE} is set): {} is absent",
            p.display()
        );
        return None;
    }
    panic!(
        "{} is absent: this test needs the shared reference data (../shared/data beside the \
         project root, or where {ROOT_VARIABLE} says); set {SKIP_VARIABLE}=1 to skip such tests",
        p.display()
    );
}

/// The text of the shared file `relative` (missing: as [`path`]).
pub fn read_to_string(relative: &str) -> Option<String> {
    let p = path(relative)?;
    match std::fs::read_to_string(&p) {
        Ok(t) => Some(t),
        Err(e) => panic!("{}: {e}", p.display()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn present_files_are_found() {
        // SOURCES.md describes the folder; it is the one file every copy has.
        let t = read_to_string("SOURCES.md").unwrap();
        assert!(!t.is_empty());
        assert_eq!(
            t,
            std::fs::read_to_string(root().join("SOURCES.md")).unwrap()
        );
        assert!(path("rgl-rgb").unwrap().is_dir());
    }

    #[test]
    fn the_root_variable_moves_the_folder() {
        let default = root_from(None);
        assert!(default.ends_with("shared/data"), "{}", default.display());
        assert_eq!(root_from(Some("".into())), default);
        assert_eq!(root_from(Some("/data/x".into())), PathBuf::from("/data/x"));
    }

    #[test]
    #[should_panic(expected = "needs the shared reference data")]
    fn a_missing_file_fails_unless_skipping_is_asked_for() {
        if std::env::var_os(SKIP_VARIABLE).is_some() {
            panic!("needs the shared reference data (skipping is asked for: nothing to check)");
        }
        path("no/such/file.csv");
    }
}
