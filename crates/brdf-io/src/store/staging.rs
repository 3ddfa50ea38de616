//! Staged reads: the runs of a store's file that a [`super::Store::will_need`] hint names, read
//! at once into memory with direct I/O (no page cache), for stores read with positioned reads.
//!
//! Under [`super::Paging::OnDemand`] a cell is a positioned read of ~40 KB through the page
//! cache: the kernel copies every byte into the reader's buffer, and on a store larger than
//! memory it reclaims a page of its cache for every page it reads. A `.bsdf` export of a
//! prediction on the paper's grid (35 GB of cells) spent most of its time there (BENCHMARKS.md
//! "dataset store", session 52). A hint names the cells ahead; their merged runs (up to
//! [`super::WILL_NEED_MAX_RUN`] bytes) are read now, each in one `O_DIRECT` request straight
//! into an aligned buffer, and lookups inside a staged run read from it. A run is dropped once
//! as many reads as it had hinted spans have read from it, or, past [`STAGING_BUDGET`] bytes
//! of runs not read yet, when it is the oldest: a lookup whose run was dropped (or never
//! hinted) reads the file as before. Values are the same bytes either way.

use std::collections::{BTreeMap, VecDeque};
use std::fs::File;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

/// At most this many bytes of staged runs are kept (the oldest dropped first); one hint stages
/// at most half of it. Two windows of the RGL writer's cell cache (4096 cells hinted one
/// window ahead; ~270 MB each on the paper's grid) fit; a render's tasks (256 cells each) hold
/// a few MB, read as soon as they are staged.
pub(crate) const STAGING_BUDGET: usize = 1 << 30;

/// Direct reads in flight at once for one hint (see [`Staging::read_runs`]).
const READ_THREADS: usize = 16;

/// Alignment of direct reads: offsets, lengths and buffer addresses (the page size, a multiple
/// of every disk's logical block size).
const DIRECT_ALIGN: usize = 4096;

/// One run of the file held in memory.
#[derive(Debug)]
pub(crate) struct StagedRun {
    /// File offset of `buf[at]`.
    start: usize,
    /// The bytes read, from `at` on (a direct read's buffer starts at an aligned address).
    buf: Vec<u8>,
    at: usize,
    /// How many bytes from `start` were read.
    len: usize,
    /// Hinted spans not read yet: the run is dropped when the last one is.
    pending: AtomicUsize,
}

impl StagedRun {
    /// The bytes at file offsets `offset..offset + len` (inside the run).
    pub(crate) fn bytes(&self, offset: usize, len: usize) -> &[u8] {
        let i = self.at + offset - self.start;
        &self.buf[i..i + len]
    }

    fn covers(&self, offset: usize, len: usize) -> bool {
        offset >= self.start && offset + len <= self.start + self.len
    }
}

#[derive(Debug, Default)]
struct StagedRuns {
    by_start: BTreeMap<usize, Arc<StagedRun>>,
    /// Starts in the order the runs were staged (the oldest first).
    order: VecDeque<usize>,
    /// Bytes held by the runs' buffers.
    bytes: usize,
}

impl StagedRuns {
    /// The staged run holding `offset..offset + len`, if any. Runs never overlap: a run is
    /// staged only where none lies.
    fn find(&self, offset: usize, len: usize) -> Option<&Arc<StagedRun>> {
        let (_, run) = self.by_start.range(..=offset).next_back()?;
        run.covers(offset, len).then_some(run)
    }

    /// Whether any staged run overlaps `start..end`.
    fn overlaps(&self, start: usize, end: usize) -> bool {
        let before = self.by_start.range(..end).next_back();
        before.is_some_and(|(_, r)| r.start + r.len > start)
    }

    /// Removes the run starting at `start`, if it is there.
    fn remove(&mut self, start: usize) -> Option<Arc<StagedRun>> {
        let run = self.by_start.remove(&start)?;
        self.bytes -= run.buf.len();
        Some(run)
    }

    /// Keeps `run` (unless another hint staged an overlapping one meanwhile) and drops the
    /// oldest runs past `budget` bytes; returns the runs dropped (or `run` itself).
    fn insert(&mut self, run: StagedRun, budget: usize) -> Vec<Arc<StagedRun>> {
        if self.overlaps(run.start, run.start + run.len) {
            return vec![Arc::new(run)];
        }
        self.bytes += run.buf.len();
        self.order.push_back(run.start);
        self.by_start.insert(run.start, Arc::new(run));
        let mut dropped = Vec::new();
        while self.bytes > budget {
            let Some(oldest) = self.order.pop_front() else {
                break;
            };
            dropped.extend(self.remove(oldest));
        }
        dropped
    }
}

/// Staged runs of one store's file; see the module docs.
#[derive(Debug)]
pub(crate) struct Staging {
    /// The store's file, opened for direct reads (or, in tests, plainly).
    file: File,
    /// The file's length: the last run may end short of an aligned length.
    file_len: usize,
    budget: usize,
    runs: Mutex<StagedRuns>,
    /// Buffers of dropped runs, for the next runs of their size (a new buffer is zeroed first:
    /// a memset of every byte read, a fifth of a staged export's time); at most a quarter of
    /// the budget.
    free: Mutex<Vec<Vec<u8>>>,
}

impl Staging {
    /// Staging through `file` (any handle of the store's file) with `budget` bytes.
    pub(crate) fn new(file: File, file_len: usize, budget: usize) -> Self {
        Self {
            file,
            file_len,
            budget,
            runs: Mutex::new(StagedRuns::default()),
            free: Mutex::new(Vec::new()),
        }
    }

    /// Staging through a second handle of `file` opened with `O_DIRECT` (Linux), or `None`
    /// where direct I/O is not available (other systems; file systems that refuse it, such as
    /// older tmpfs): hints then stay hints to the page cache.
    pub(crate) fn direct(file: &File, file_len: u64) -> Option<Self> {
        #[cfg(target_os = "linux")]
        {
            use std::os::fd::AsRawFd;
            use std::os::unix::fs::OpenOptionsExt;
            let direct = std::fs::OpenOptions::new()
                .read(true)
                .custom_flags(rustix::fs::OFlags::DIRECT.bits() as i32)
                .open(format!("/proc/self/fd/{}", file.as_raw_fd()))
                .ok()?;
            Some(Self::new(
                direct,
                usize::try_from(file_len).ok()?,
                STAGING_BUDGET,
            ))
        }
        #[cfg(not(target_os = "linux"))]
        {
            let _ = (file, file_len);
            None
        }
    }

    /// The staged run holding file bytes `offset..offset + len`, if one does, for a read of
    /// them: the run counts the read, and is dropped after its last hinted span's (give it
    /// back with [`Staging::done`]).
    pub(crate) fn read(&self, offset: usize, len: usize) -> Option<Arc<StagedRun>> {
        let mut runs = self.lock();
        let run = runs.find(offset, len)?;
        if run.pending.fetch_sub(1, Ordering::Relaxed) > 1 {
            return Some(Arc::clone(run));
        }
        let start = run.start;
        runs.remove(start)
    }

    /// Whether a staged run holds file bytes `offset..offset + len` (not a read).
    pub(crate) fn holds(&self, offset: usize, len: usize) -> bool {
        self.lock().find(offset, len).is_some()
    }

    /// Takes back a run that a read is done with: its buffer is reused when the run was
    /// dropped meanwhile (this was its last holder).
    pub(crate) fn done(&self, run: Arc<StagedRun>) {
        if let Ok(run) = Arc::try_unwrap(run) {
            self.recycle(run.buf);
        }
    }

    /// Keeps `buf` for a later run of its size, while the kept buffers stay within a quarter
    /// of the budget.
    fn recycle(&self, buf: Vec<u8>) {
        let mut free = self.free.lock().unwrap_or_else(|e| e.into_inner());
        if free.iter().map(Vec::len).sum::<usize>() + buf.len() <= self.budget / 4 {
            free.push(buf);
        }
    }

    /// Bytes held by staged runs.
    #[cfg(test)]
    pub(crate) fn held_bytes(&self) -> usize {
        self.lock().bytes
    }

    /// Number of buffers kept for reuse.
    #[cfg(test)]
    pub(crate) fn kept_buffers(&self) -> usize {
        self.free.lock().unwrap_or_else(|e| e.into_inner()).len()
    }

    /// Number of staged runs.
    #[cfg(test)]
    pub(crate) fn run_count(&self) -> usize {
        self.lock().by_start.len()
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, StagedRuns> {
        // A panic while holding the lock leaves consistent maps (every update is complete
        // before the next starts), so a poisoned lock is used as it is.
        self.runs.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Reads the runs `(start, end, spans)` of file offsets (`spans`: how many hinted spans
    /// each holds) that no staged run overlaps yet, up to half the budget, and keeps them.
    /// Returns the runs not staged (over the budget, or whose read failed), for the caller to
    /// hint otherwise; a failed read is left for the lookup, whose own read reports the error.
    pub(crate) fn stage(&self, runs: &[(usize, usize, usize)]) -> Vec<(usize, usize)> {
        let (mut wanted, mut rest) = (Vec::new(), Vec::new());
        let mut total = 0;
        {
            let staged = self.lock();
            for &(s, e, spans) in runs {
                if staged.overlaps(s, e) {
                    continue;
                }
                if total + (e - s) <= self.budget / 2 {
                    total += e - s;
                    wanted.push((s, e, spans));
                } else {
                    rest.push((s, e));
                }
            }
        }
        let read = self.read_runs(&wanted);
        let mut dropped = Vec::new();
        {
            let mut staged = self.lock();
            for (s, e, run) in read {
                match run {
                    Some(run) => dropped.extend(staged.insert(run, self.budget)),
                    None => rest.push((s, e)),
                }
            }
        }
        for run in dropped {
            // A run still being read from goes back with its reader's `done`.
            self.done(run);
        }
        rest
    }

    /// Reads `runs` with up to [`READ_THREADS`] requests in flight (threads that wait for the
    /// disk, not compute: a hint's runs are often a cell or two each, so the disk's speed
    /// needs many of them queued at once).
    fn read_runs(&self, runs: &[(usize, usize, usize)]) -> Vec<(usize, usize, Option<StagedRun>)> {
        let threads = runs.len().min(READ_THREADS);
        if threads <= 1 {
            return runs
                .iter()
                .map(|&(s, e, n)| (s, e, self.read_run(s, e, n)))
                .collect();
        }
        let next = AtomicUsize::new(0);
        let read = Mutex::new(Vec::with_capacity(runs.len()));
        std::thread::scope(|scope| {
            for _ in 0..threads {
                scope.spawn(|| {
                    while let Some(&(s, e, n)) = runs.get(next.fetch_add(1, Ordering::Relaxed)) {
                        let run = self.read_run(s, e, n);
                        read.lock()
                            .unwrap_or_else(|e| e.into_inner())
                            .push((s, e, run));
                    }
                });
            }
        });
        read.into_inner().unwrap_or_else(|e| e.into_inner())
    }

    /// A buffer of `len` bytes for a run: one of a dropped run's of that size, or a new one.
    fn buffer(&self, len: usize) -> Vec<u8> {
        let mut free = self.free.lock().unwrap_or_else(|e| e.into_inner());
        match free.iter().position(|b| b.len() == len) {
            Some(i) => free.swap_remove(i),
            None => vec![0u8; len],
        }
    }

    /// Reads file bytes `start..end` (holding `spans` hinted spans) in aligned requests into
    /// an aligned buffer.
    fn read_run(&self, start: usize, end: usize, spans: usize) -> Option<StagedRun> {
        let end = end.min(self.file_len);
        let first = start - start % DIRECT_ALIGN;
        let last = end.div_ceil(DIRECT_ALIGN) * DIRECT_ALIGN;
        let mut buf = self.buffer(size_class(last - first + DIRECT_ALIGN));
        let at = buf.as_ptr().align_offset(DIRECT_ALIGN);
        if at >= DIRECT_ALIGN {
            return None;
        }
        let target = &mut buf[at..at + last - first];
        let want = end - first;
        let mut done = 0;
        while done < want {
            match read_at(&self.file, &mut target[done..], (first + done) as u64) {
                Ok(n) if n > 0 => done += n,
                _ => {
                    self.recycle(buf);
                    return None;
                }
            }
        }
        Some(StagedRun {
            start,
            buf,
            at: at + start - first,
            len: end - start,
            pending: AtomicUsize::new(spans.max(1)),
        })
    }
}

/// The buffer size for `len` bytes, from few enough sizes that dropped runs' buffers serve
/// later runs: a power of two up to 1 MiB, then whole MiB (a run of 8 MiB must not take 16:
/// two windows of the RGL writer's runs would then not fit in the budget).
fn size_class(len: usize) -> usize {
    const MIB: usize = 1 << 20;
    if len <= MIB {
        len.next_power_of_two()
    } else {
        len.div_ceil(MIB) * MIB
    }
}

#[cfg(unix)]
fn read_at(file: &File, buf: &mut [u8], offset: u64) -> std::io::Result<usize> {
    std::os::unix::fs::FileExt::read_at(file, buf, offset)
}

#[cfg(windows)]
fn read_at(file: &File, buf: &mut [u8], offset: u64) -> std::io::Result<usize> {
    std::os::windows::fs::FileExt::seek_read(file, buf, offset)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A file of `len` bytes whose byte i is a function of i, and a plain staging of it.
    fn staged_file(len: usize, budget: usize) -> (tempfile::TempDir, Vec<u8>, Staging) {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("bytes.bin");
        let bytes: Vec<u8> = (0..len).map(|i| (i * 131 % 251) as u8).collect();
        std::fs::write(&p, &bytes).unwrap();
        let staging = Staging::new(File::open(&p).unwrap(), len, budget);
        (dir, bytes, staging)
    }

    /// The bytes of a read of `offset..offset + len` from a staged run, which must hold them.
    fn read(staging: &Staging, offset: usize, len: usize) -> Vec<u8> {
        let run = staging.read(offset, len).expect("inside a staged run");
        let bytes = run.bytes(offset, len).to_vec();
        staging.done(run);
        bytes
    }

    /// Staged runs hold the file's bytes, wherever they start and end (unaligned, at the end
    /// of the file); spans inside a run are found, spans reaching out of every run are not.
    #[test]
    fn staged_runs_hold_the_files_bytes() {
        let (_dir, bytes, staging) = staged_file(50_000, 1 << 20);
        let rest = staging.stage(&[(100, 9000, 9), (12_288, 20_000, 9), (45_001, 50_000, 9)]);
        assert_eq!(rest, []);
        assert_eq!(staging.run_count(), 3);
        for (offset, len) in [(100, 8900), (5000, 17), (12_288, 7712), (45_001, 4999)] {
            assert!(staging.holds(offset, len));
            assert_eq!(read(&staging, offset, len), &bytes[offset..offset + len]);
        }
        for (offset, len) in [(99, 2), (8999, 2), (9000, 1), (20_000, 1), (30_000, 10)] {
            assert!(!staging.holds(offset, len), "{offset}+{len}");
            assert!(staging.read(offset, len).is_none(), "{offset}+{len}");
        }
    }

    /// A run is dropped when as many reads as it holds hinted spans have read from it; its
    /// buffer then serves the next run of its size.
    #[test]
    fn runs_are_dropped_once_their_spans_are_read() {
        let (_dir, bytes, staging) = staged_file(100_000, 1 << 20);
        assert_eq!(staging.stage(&[(1000, 3000, 2)]), []);
        let held = staging.held_bytes();
        assert_eq!(read(&staging, 1000, 1000), &bytes[1000..2000]);
        assert!(staging.holds(2000, 1000), "one hinted span is left");
        // A read that still holds the run when it is dropped gives its buffer back last.
        let last = staging.read(2000, 1000).expect("staged");
        assert_eq!(staging.run_count(), 0);
        assert_eq!(staging.held_bytes(), 0);
        assert!(staging.read(2000, 1000).is_none(), "dropped");
        assert_eq!(last.bytes(2000, 1000), &bytes[2000..3000]);
        staging.done(last);
        assert_eq!(staging.kept_buffers(), 1, "the buffer is kept");
        assert_eq!(staging.stage(&[(50_000, 52_000, 1)]), []);
        assert_eq!(staging.held_bytes(), held, "a run of the same size class");
        assert_eq!(staging.kept_buffers(), 0, "the kept buffer is reused");
        assert_eq!(read(&staging, 50_000, 2000), &bytes[50_000..52_000]);
    }

    /// Runs overlapping staged ones are not read again; a hint beyond half the budget returns
    /// the runs it did not stage; past the budget the oldest runs are dropped first.
    #[test]
    fn the_budget_drops_the_oldest_runs() {
        let (_dir, bytes, staging) = staged_file(200_000, 100_000);
        assert_eq!(staging.stage(&[(0, 10_000, 5)]), []);
        let held = staging.held_bytes();
        assert_eq!(
            held, 16_384,
            "10,000 bytes and the alignment, to a power of two"
        );
        assert_eq!(
            staging.stage(&[(5_000, 12_000, 5)]),
            [],
            "overlaps: skipped"
        );
        assert_eq!(staging.run_count(), 1);
        assert!(!staging.holds(10_000, 1));
        // Half the budget is 50,000 bytes: the second run does not fit after the first.
        assert_eq!(
            staging.stage(&[(20_000, 50_000, 5), (60_000, 85_000, 5)]),
            [(60_000, 85_000)]
        );
        assert_eq!(staging.run_count(), 2);
        assert_eq!(staging.held_bytes(), 16_384 + 65_536);
        // The budget is passed (by 32,768 bytes more): the oldest run (0..10,000) goes.
        assert_eq!(staging.stage(&[(60_000, 85_000, 5)]), []);
        assert_eq!(staging.held_bytes(), 65_536 + 32_768);
        assert!(!staging.holds(0, 10), "the oldest run was dropped");
        assert!(staging.holds(20_000, 30_000), "the next one is kept");
        assert_eq!(read(&staging, 60_000, 25_000), &bytes[60_000..85_000]);
    }

    /// A hint stages its runs while their lengths add up to at most half the budget, wherever
    /// in the file they lie; a run that starts where a staged one ends does not overlap it.
    #[test]
    fn a_hint_stages_runs_up_to_half_the_budget() {
        let (_dir, bytes, staging) = staged_file(200_000, 100_000);
        // 20,000 + 25,000 bytes: within half the budget (50,000), far into the file.
        assert_eq!(
            staging.stage(&[(10_000, 30_000, 1), (40_000, 65_000, 1)]),
            []
        );
        assert_eq!(staging.run_count(), 2);
        assert_eq!(read(&staging, 40_000, 25_000), &bytes[40_000..65_000]);
        // Adjacent to the run 10,000..30,000 on either side.
        assert_eq!(staging.stage(&[(30_000, 31_000, 1)]), []);
        assert_eq!(staging.stage(&[(9_000, 10_000, 1)]), []);
        assert_eq!(staging.run_count(), 3);
        assert!(
            !staging.holds(29_000, 2_000),
            "a span across two runs is in neither"
        );
        assert_eq!(read(&staging, 30_000, 1_000), &bytes[30_000..31_000]);
        assert_eq!(read(&staging, 9_000, 1_000), &bytes[9_000..10_000]);
        assert_eq!(read(&staging, 10_000, 20_000), &bytes[10_000..30_000]);
        assert_eq!(staging.run_count(), 0);
    }

    /// A run that overlaps one staged meanwhile (by another hint) is handed back and the
    /// staged one kept; runs adding up to exactly the budget are all kept, one byte more drops
    /// the oldest.
    #[test]
    fn runs_are_kept_up_to_exactly_the_budget() {
        let run = |start: usize, len: usize| StagedRun {
            start,
            buf: vec![0; len],
            at: 0,
            len,
            pending: AtomicUsize::new(1),
        };
        let starts = |runs: &[Arc<StagedRun>]| runs.iter().map(|r| r.start).collect::<Vec<_>>();
        let mut runs = StagedRuns::default();
        assert_eq!(starts(&runs.insert(run(1000, 4096), 8192)), [0usize; 0]);
        // 0..4096 overlaps 1000..5096 from before its start.
        assert_eq!(starts(&runs.insert(run(0, 4096), 8192)), [0]);
        assert_eq!((runs.bytes, runs.by_start.len()), (4096, 1));
        assert_eq!(runs.by_start[&1000].len, 4096, "the staged run is kept");
        // Adjacent, and exactly the budget.
        assert_eq!(starts(&runs.insert(run(5096, 4096), 8192)), [0usize; 0]);
        assert_eq!(runs.bytes, 8192);
        assert_eq!(starts(&runs.insert(run(9192, 1), 8192)), [1000]);
        assert_eq!((runs.bytes, runs.by_start.len()), (4097, 2));
    }

    /// Dropped runs' buffers are kept for later runs up to a quarter of the budget, no more.
    #[test]
    fn kept_buffers_stay_within_a_quarter_of_the_budget() {
        let (_dir, _bytes, staging) = staged_file(10, 32_768);
        let kept = || {
            let free = staging.free.lock().unwrap();
            free.iter().map(Vec::len).collect::<Vec<_>>()
        };
        staging.recycle(vec![0; 4096]);
        staging.recycle(vec![0; 4096]);
        assert_eq!(kept(), [4096, 4096], "exactly a quarter");
        staging.recycle(vec![0; 1]);
        assert_eq!(kept(), [4096, 4096], "one byte more is not kept");
        assert_eq!(staging.buffer(4096).len(), 4096);
        assert_eq!(kept(), [4096], "a kept buffer is taken");
    }

    /// Buffer sizes: powers of two up to 1 MiB, whole MiB above.
    #[test]
    fn buffer_sizes_come_in_few_classes() {
        const MIB: usize = 1 << 20;
        let classes: Vec<usize> = [1, 4097, 65_536, 65_537, MIB, MIB + 1, 8 * MIB + 8192]
            .map(size_class)
            .to_vec();
        assert_eq!(
            classes,
            [1, 8192, 65_536, 131_072, MIB, 2 * MIB, 9 * MIB],
            "{classes:?}"
        );
    }

    /// A run that cannot be read (past the end of the file) is returned, not staged.
    #[test]
    fn runs_that_cannot_be_read_are_returned() {
        let (_dir, _bytes, mut staging) = staged_file(10_000, 1 << 20);
        staging.file_len = 20_000; // the file is shorter than the staging believes
        assert_eq!(staging.stage(&[(12_000, 15_000, 1)]), [(12_000, 15_000)]);
        assert_eq!(staging.run_count(), 0);
    }
}
