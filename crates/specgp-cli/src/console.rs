//! Printing to standard output and standard error without panics, and without a failed print
//! stopping the work.
//!
//! `println!` and `eprintln!` panic when their stream cannot be written (a reader that closed
//! the pipe, `specgp grid | head -0`; a full disk, `> /dev/full`), and an error returned from
//! a print in the middle of a command skips the outputs written after it. So the CLI prints
//! only through `outln!`, `errln!` (macros of this module, in scope in the modules declared
//! after it), [`table_output`] and [`finish_stdout`]:
//!
//! - standard output: once a print fails, later prints are skipped but the command goes on and
//!   writes its files. A closed pipe then ends the command quietly (exit 0: the reader wanted
//!   no more); any other error (ENOSPC, EIO) fails the command after its files are written
//!   ([`finish_stdout`], exit 1).
//! - standard error (reports, progress, warnings): write errors are ignored; a line that
//!   cannot be written never stops the work.

use std::io::Write as _;
use std::sync::Mutex;

pub use brdf_io::error::quantity;

/// What happened to standard output so far.
enum StdoutState {
    /// Every print so far succeeded.
    Open,
    /// Its reader closed the pipe: nothing more is printed, not an error.
    Closed,
    /// A print failed otherwise (the first such error): nothing more is printed.
    Failed(std::io::Error),
}

static STDOUT: Mutex<StdoutState> = Mutex::new(StdoutState::Open);

/// Runs `write` on locked standard output unless an earlier print failed, and records a
/// failure.
fn with_stdout(write: impl FnOnce(&mut std::io::StdoutLock<'static>) -> std::io::Result<()>) {
    let mut state = STDOUT.lock().unwrap_or_else(|p| p.into_inner());
    if !matches!(*state, StdoutState::Open) {
        return;
    }
    if let Err(e) = write(&mut std::io::stdout().lock()) {
        *state = if e.kind() == std::io::ErrorKind::BrokenPipe {
            StdoutState::Closed
        } else {
            StdoutState::Failed(e)
        };
    }
}

/// Prints `args` and a newline on standard output, flushed (see the module docs for errors).
pub fn stdout_line(args: std::fmt::Arguments<'_>) {
    with_stdout(|out| {
        out.write_fmt(args)?;
        out.write_all(b"\n")?;
        out.flush()
    });
}

/// Prints `args` and a newline on standard error, ignoring errors.
pub fn stderr_line(args: std::fmt::Arguments<'_>) {
    let mut err = std::io::stderr().lock();
    let _ = err.write_fmt(args).and_then(|()| err.write_all(b"\n"));
}

/// Flushes standard output and returns the first error of a print to it other than a closed
/// pipe, as the command's error: call once, after the command wrote its files.
pub fn finish_stdout() -> anyhow::Result<()> {
    with_stdout(|out| out.flush());
    let mut state = STDOUT.lock().unwrap_or_else(|p| p.into_inner());
    match std::mem::replace(&mut *state, StdoutState::Closed) {
        StdoutState::Failed(e) => Err(anyhow::Error::from(e).context("writing to standard output")),
        StdoutState::Open | StdoutState::Closed => Ok(()),
    }
}

/// A table's writer on standard output: writes never fail (see the module docs).
struct StdoutTable;

impl std::io::Write for StdoutTable {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        with_stdout(|out| out.write_all(buf));
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        with_stdout(|out| out.flush());
        Ok(())
    }
}

/// A table's writer on standard error: write errors are ignored.
struct StderrTable;

impl std::io::Write for StderrTable {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let _ = std::io::stderr().write_all(buf);
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        let _ = std::io::stderr().flush();
        Ok(())
    }
}

/// Where a command's table goes: standard output, or standard error when its JSON (`json`)
/// goes to standard output. Writes to it never fail (see the module docs).
pub fn table_output(json: Option<&std::path::Path>) -> Box<dyn std::io::Write> {
    if json.is_some_and(|p| p == std::path::Path::new(brdf_io::output::STDOUT)) {
        Box::new(StderrTable)
    } else {
        Box::new(StdoutTable)
    }
}

/// `println!` that neither panics nor stops the command when standard output cannot be
/// written (see the module docs).
macro_rules! outln {
    ($($t:tt)*) => {
        $crate::console::stdout_line(format_args!($($t)*))
    };
}

/// `eprintln!` that ignores write errors: a report, progress or warning line that cannot be
/// written never stops the work or panics.
macro_rules! errln {
    ($($t:tt)*) => {
        $crate::console::stderr_line(format_args!($($t)*))
    };
}
