//! What a closure logs through `tracing` at WARN level and above, as plain text, for tests that
//! check a warning is given (or not). The subscriber is the thread's default only while the
//! closure runs, so tests running in parallel do not see each other's warnings.

use std::io::Write;
use std::sync::{Arc, Mutex, PoisonError};

/// A shared byte buffer that the subscriber writes into.
#[derive(Clone, Default)]
struct Buffer(Arc<Mutex<Vec<u8>>>);

impl Write for Buffer {
    fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        let mut held = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        held.extend_from_slice(bytes);
        Ok(bytes.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// Runs `f` and returns its result with what it logged at WARN level and above (plain text,
/// no colours; lossy UTF-8).
pub fn warnings_of<T>(f: impl FnOnce() -> T) -> (T, String) {
    let buffer = Buffer::default();
    let writer = buffer.clone();
    let subscriber = tracing_subscriber::fmt()
        .with_writer(move || writer.clone())
        .with_max_level(tracing::Level::WARN)
        .with_ansi(false)
        .finish();
    let out = tracing::subscriber::with_default(subscriber, f);
    let bytes = buffer.0.lock().unwrap_or_else(PoisonError::into_inner);
    (out, String::from_utf8_lossy(&bytes).into_owned())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Warnings and errors are captured, in order; info and debug are not; nothing logged is
    /// an empty string; the closure's result comes back.
    #[test]
    fn captures_warnings_and_errors_only() {
        let (n, said) = warnings_of(|| {
            tracing::info!("not this");
            tracing::warn!("first: {}", 1);
            tracing::debug!("nor this");
            tracing::error!("second");
            7
        });
        assert_eq!(n, 7);
        let lines: Vec<&str> = said.lines().collect();
        assert_eq!(lines.len(), 2, "{said}");
        assert!(
            lines[0].contains("WARN") && lines[0].ends_with("first: 1"),
            "{said}"
        );
        assert!(
            lines[1].contains("ERROR") && lines[1].ends_with("second"),
            "{said}"
        );
        assert_eq!(warnings_of(|| tracing::info!("quiet")).1, "");
    }
}
