//! Dataset store: round trips, layouts, lookups, Gram pass, and every kind of bad input.

use std::path::{Path, PathBuf};

use brdf_io::store::{
    Compression, Dtype, OpenOptions, Paging, ReadMode, StoreHeader, StoreMaterial,
};
use brdf_io::{AngularGrid, Channels, Error, Store, StoreInfo, StoreOptions, StoreWriter};
use proptest::prelude::*;

fn info(th: usize, td: usize, pd: usize, channels: Channels) -> StoreInfo {
    StoreInfo {
        grid: AngularGrid::new(th, td, pd).unwrap(),
        channels,
    }
}

/// Deterministic pseudo-random values, 0 below the horizon (the store's convention).
fn material(info: &StoreInfo, seed: u64) -> Vec<f32> {
    let mask = info.grid.validity_mask();
    let nc = info.channels.len();
    let mut s = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    (0..info.d())
        .map(|d| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            if mask[d / nc] {
                ((s >> 40) as f32) / (1u64 << 24) as f32 * 3.0 - 0.5
            } else {
                0.0
            }
        })
        .collect()
}

fn write_materials(
    path: &Path,
    info: &StoreInfo,
    rows: &[Vec<f32>],
    options: StoreOptions,
    slice: usize,
) -> brdf_io::Result<brdf_io::store::StoreHeader> {
    let mut w = StoreWriter::create(path, info.clone(), options)?;
    for (i, row) in rows.iter().enumerate() {
        let mut m = w.begin_material(&format!("mat{i}"), &format!("test:{i}"))?;
        let mut written = 0;
        for part in row.chunks(slice.max(1)) {
            m.write(part)?;
            written += part.len();
            assert_eq!(m.written(), written);
        }
        m.finish()?;
        assert_eq!(w.n_materials(), i + 1);
    }
    w.finish()
}

/// The ways a store can be read: a memory map paged as the kernel likes or on demand, and
/// positioned reads. Every read gives the same values whichever is used.
const READS: [(ReadMode, Paging); 3] = [
    (ReadMode::Mmap, Paging::ReadAround),
    (ReadMode::Mmap, Paging::OnDemand),
    (ReadMode::Buffered, Paging::Auto),
];

fn read_all(store: &Store) -> Vec<Vec<f32>> {
    let n = store.n_materials();
    (0..n)
        .map(|m| {
            let mut row = vec![0f32; store.d()];
            store.material_row(m, 0..store.d(), &mut row).unwrap();
            row
        })
        .collect()
}

fn dir() -> tempfile::TempDir {
    tempfile::tempdir().unwrap()
}

fn only_file(dir: &Path) -> Vec<PathBuf> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect()
}

#[test]
fn round_trip_material_mode_all_read_paths() {
    let info = info(4, 5, 6, Channels::Rgb);
    let rows: Vec<_> = (0..5).map(|i| material(&info, i)).collect();
    let t = dir();
    for compression in [
        Compression::None,
        Compression::Zstd { level: 3 },
        Compression::ZstdShuffle { level: 3 },
    ] {
        let path = t.path().join(format!("{compression:?}.sbrdf"));
        let options = StoreOptions {
            chunk_len: Some(7),
            compression,
            memory_budget: 5 * 4 * 20, // forces several transpose super-blocks
            ..Default::default()
        };
        let header = write_materials(&path, &info, &rows, options, 11).unwrap();
        assert_eq!(header.layout.n_chunks, info.d().div_ceil(7));
        for (mode, paging) in READS {
            let store = Store::open_with(
                &path,
                OpenOptions {
                    mode,
                    cache_chunks: 2,
                    paging,
                },
            )
            .unwrap();
            assert_eq!(store.paged_on_demand(), paging == Paging::OnDemand);
            // Hints reach the kernel for positioned reads of stored bytes only.
            let positioned = paging == Paging::OnDemand || mode == ReadMode::Buffered;
            assert_eq!(
                store.takes_will_need(),
                cfg!(target_os = "linux") && positioned && compression == Compression::None,
                "{mode:?} {paging:?} {compression:?}"
            );
            store.verify_checksum().unwrap();
            assert_eq!(store.n_materials(), 5);
            assert_eq!(store.d(), 4 * 5 * 6 * 3);
            assert_eq!(store.names(), ["mat0", "mat1", "mat2", "mat3", "mat4"]);
            assert_eq!(store.header().materials[3].source, "test:3");
            let back = read_all(&store);
            for (a, b) in back.iter().zip(&rows) {
                assert!(a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()));
            }
            // values_at: all N at one index, in every chunk position.
            let mut out = [0f32; 5];
            for d in [0, 1, 6, 7, 100, info.d() - 1] {
                store.values_at(d, &mut out).unwrap();
                for m in 0..5 {
                    assert_eq!(out[m].to_bits(), rows[m][d].to_bits(), "d = {d} m = {m}");
                }
            }
            // values_in: ranges inside one chunk (the first, a whole later one, part of one),
            // across chunk boundaries (chunks of 7), empty.
            for r in [
                0..3,
                5..16,
                6..8,
                7..14,
                15..20,
                13..29,
                40..40,
                info.d() - 9..info.d(),
            ] {
                let mut block = vec![0f32; r.len() * 5];
                store.values_in(r.clone(), &mut block).unwrap();
                // prefetch is a hint: any range, even outside the store, changes nothing.
                store.prefetch(r.clone());
                store.prefetch(info.d() - 2..info.d() + 5);
                // values_in_ref: borrowed inside a chunk (mmap), read into the buffer otherwise.
                let mut buf = Vec::new();
                let borrowed = store.values_in_ref(r.clone(), &mut buf).unwrap();
                assert_eq!(borrowed, &block[..], "{r:?}");
                for (k, d) in r.clone().enumerate() {
                    for m in 0..5 {
                        assert_eq!(block[k * 5 + m].to_bits(), rows[m][d].to_bits(), "{r:?}");
                    }
                }
            }
            // streaming pass sees every index once, index-major.
            let mut seen = 0;
            store
                .for_each_chunk(|range, block| {
                    assert_eq!(block.len(), range.len() * 5);
                    for (k, d) in range.clone().enumerate() {
                        for m in 0..5 {
                            assert_eq!(block[k * 5 + m], rows[m][d]);
                        }
                    }
                    seen += range.len();
                })
                .unwrap();
            assert_eq!(seen, info.d());
            // Gram matrix against a direct f64 computation.
            let g = store.gram().unwrap();
            for i in 0..5 {
                for j in 0..5 {
                    let want: f64 = rows[i]
                        .iter()
                        .zip(&rows[j])
                        .map(|(a, b)| f64::from(*a) * f64::from(*b))
                        .sum();
                    assert!((g[i * 5 + j] - want).abs() <= 1e-9 * want.abs().max(1.0));
                }
                assert!((g[i * 5 + i] - store.header().materials[i].stats.sum_sq).abs() < 1e-6);
            }
        }
    }
    // nothing but the three stores in the directory: no temporary or scratch file left.
    assert_eq!(only_file(t.path()).len(), 3);
}

#[test]
fn block_mode_equals_material_mode() {
    let info = info(
        3,
        4,
        8,
        Channels::spectral(vec![400.0, 500.0, 600.0, 700.0]).unwrap(),
    );
    let n = 3;
    let mut rows: Vec<_> = (0..n).map(|i| material(&info, 10 + i as u64)).collect();
    // Values f16 flushes to zero (cell 0 is above the horizon) and a big one.
    rows[1][0] = 1e-9;
    rows[2][1] = -3e-9;
    rows[0][2] = 6.0e4;
    for dtype in [Dtype::F32, Dtype::F16] {
        let t = dir();
        let a = t.path().join("a.sbrdf");
        let b = t.path().join("b.sbrdf");
        let opts = StoreOptions {
            chunk_len: Some(13),
            compression: Compression::Zstd { level: 1 },
            dtype,
            ..Default::default()
        };
        write_materials(&a, &info, &rows, opts.clone(), 1000).unwrap();
        let mut w = StoreWriter::create(&b, info.clone(), opts).unwrap();
        let names: Vec<(String, String)> = (0..n)
            .map(|i| (format!("mat{i}"), format!("test:{i}")))
            .collect();
        w.declare_materials(&names).unwrap();
        let mut d0 = 0;
        for len in [1usize, 5, 40, 17].iter().cycle() {
            let d1 = (d0 + len).min(info.d());
            let block: Vec<f32> = (d0..d1)
                .flat_map(|d| rows.iter().map(move |r| r[d]))
                .collect();
            w.write_block(d0..d1, &block).unwrap();
            d0 = d1;
            if d0 == info.d() {
                break;
            }
        }
        let hb = w.finish().unwrap();
        let (sa, sb) = (Store::open(&a).unwrap(), Store::open(&b).unwrap());
        assert_eq!(read_all(&sa), read_all(&sb));
        // Same statistics up to summation order.
        for (x, y) in sa.header().materials.iter().zip(&hb.materials) {
            assert_eq!((&x.name, &x.source), (&y.name, &y.source));
            let (p, q) = (&x.stats, &y.stats);
            assert_eq!(
                (p.count, p.min, p.max, p.negatives, p.flushed_to_zero),
                (q.count, q.min, q.max, q.negatives, q.flushed_to_zero)
            );
            assert_eq!(p.zeroed_below_horizon, q.zeroed_below_horizon);
            assert!((p.sum_sq - q.sum_sq).abs() < 1e-9 * p.sum_sq);
            assert!((p.mean - q.mean).abs() < 1e-12 * p.mean.abs().max(1.0));
        }
        let flushed: Vec<u64> = hb
            .materials
            .iter()
            .map(|m| m.stats.flushed_to_zero)
            .collect();
        let expected = if dtype == Dtype::F16 {
            [0, 1, 1]
        } else {
            [0; 3]
        };
        assert_eq!(flushed, expected, "{dtype:?}");
        // 6e4 = 1875 * 32 is exact in f16 too.
        assert_eq!(hb.materials[0].stats.max, 6.0e4);
        assert_eq!(sa.header().checksum, sb.header().checksum);
    }
}

#[test]
fn block_mode_reports_the_first_offence_in_material_order() {
    let info = info(2, 2, 4, Channels::Rgb);
    let t = dir();
    let path = t.path().join("b.sbrdf");
    let opts16 = StoreOptions {
        dtype: Dtype::F16,
        ..Default::default()
    };
    // At index 4 (above the horizon) material "b" is too big for f16 and "c" is not finite:
    // the error names "b"; with the two swapped it names "b" as not finite.
    for (b, c, non_finite) in [(7.0e4, f32::NAN, false), (f32::INFINITY, -7.0e4, true)] {
        let mut w = StoreWriter::create(&path, info.clone(), opts16.clone()).unwrap();
        w.declare_materials(&[("a", "s"), ("b", "s"), ("c", "s")])
            .unwrap();
        let mut block = vec![0.25f32; 6 * 3];
        block[4 * 3 + 1] = b;
        block[4 * 3 + 2] = c;
        let e = w.write_block(0..6, &block).unwrap_err();
        match &e {
            Error::NonFiniteValue {
                material, index, ..
            } => {
                assert!(non_finite, "{e}");
                assert_eq!((material.as_str(), *index), ("b", 4));
            }
            e => {
                assert!(!non_finite, "{e}");
                let text = e.to_string();
                assert!(
                    text.contains("material \"b\": value 70000 at index 4"),
                    "{text}"
                );
                assert!(text.contains("exceeds the f16 range"), "{text}");
            }
        }
        names_file(&e, &path);
        assert!(w.finish().is_err());
        assert!(only_file(t.path()).is_empty());
    }
}

#[test]
fn statistics_and_horizon_zeroing() {
    let info = info(4, 4, 4, Channels::Rgb);
    let mask = info.grid.validity_mask();
    let t = dir();
    let path = t.path().join("s.sbrdf");
    let mut row = vec![2.0f32; info.d()];
    row[0] = -1.0; // cell 0 is valid (normal incidence)
    let invalid = mask.iter().filter(|v| !**v).count();
    assert!(invalid > 0);
    let h = {
        let mut w = StoreWriter::create(&path, info.clone(), StoreOptions::default()).unwrap();
        w.add_material("x", "here", &row).unwrap();
        w.finish().unwrap()
    };
    let s = &h.materials[0].stats;
    let valid = (mask.len() - invalid) * 3;
    assert_eq!(s.count as usize, valid);
    assert_eq!(s.zeroed_below_horizon as usize, invalid * 3);
    assert_eq!(s.negatives, 1);
    assert_eq!((s.min, s.max), (-1.0, 2.0));
    let mean = ((valid - 1) as f64 * 2.0 - 1.0) / valid as f64;
    assert!((s.mean - mean).abs() < 1e-12);
    let store = Store::open(&path).unwrap();
    let back = &read_all(&store)[0];
    for (d, v) in back.iter().enumerate() {
        let want = if !mask[d / 3] {
            0.0
        } else if d == 0 {
            -1.0
        } else {
            2.0
        };
        assert_eq!(*v, want, "d = {d}");
    }
}

#[test]
fn f16_store_within_half_precision() {
    let info = info(3, 3, 6, Channels::Rgb);
    let rows: Vec<_> = (0..4).map(|i| material(&info, 40 + i)).collect();
    let t = dir();
    let path = t.path().join("h.sbrdf");
    let opts = StoreOptions {
        dtype: Dtype::F16,
        chunk_len: Some(10),
        ..Default::default()
    };
    write_materials(&path, &info, &rows, opts, 50).unwrap();
    let store = Store::open(&path).unwrap();
    assert_eq!(store.header().layout.dtype, Dtype::F16);
    for (a, b) in read_all(&store).iter().zip(&rows) {
        for (x, y) in a.iter().zip(b) {
            assert!(
                (x - y).abs() <= y.abs() * 2f32.powi(-11) + 6e-8,
                "{x} vs {y}"
            );
        }
    }
}

/// An f16 store keeps values up to f16's largest, 65504, exactly, and refuses the next f32
/// above it (alone in its block: no other value makes the writer look closer) above the
/// horizon, in both write modes; below the horizon any finite value is zeroed. The first
/// offence in writing order is named (65504 before it is none), also where every value at an
/// index is out of range. Non-zero values below the horizon are counted in both modes. After a
/// refusal the writer stays unusable, naming the first error.
#[test]
fn f16_range_is_checked_at_its_edge_in_both_write_modes() {
    let info = info(2, 2, 4, Channels::Rgb);
    let mask = info.grid.validity_mask();
    let (valid, invalid) = (
        mask.iter().position(|&v| v).unwrap() * 3,
        mask.iter().position(|&v| !v).unwrap() * 3,
    );
    let max = f32::from(half::f16::MAX);
    let t = dir();
    let path = t.path().join("edge.sbrdf");
    let opts = StoreOptions {
        dtype: Dtype::F16,
        ..Default::default()
    };
    // Two materials' rows with the values `set` (material, index, value); block mode writes
    // them index-major.
    let rows = |set: &[(usize, usize, f32)]| {
        let mut rows = [vec![0.5f32; info.d()], vec![0.25f32; info.d()]];
        for &(m, at, v) in set {
            rows[m][at] = v;
        }
        rows
    };
    let write = |rows: &[Vec<f32>; 2], blocks: bool| -> brdf_io::Result<StoreHeader> {
        let mut w = StoreWriter::create(&path, info.clone(), opts.clone())?;
        let result = if blocks {
            w.declare_materials(&[("a", "s"), ("b", "s")])?;
            let block: Vec<f32> = (0..info.d())
                .flat_map(|d| [rows[0][d], rows[1][d]])
                .collect();
            w.write_block(0..info.d(), &block)
        } else {
            rows.iter().enumerate().try_for_each(|(i, row)| {
                let mut m = w.begin_material(["a", "b"][i], "s")?;
                m.write(row)?;
                m.finish()
            })
        };
        if let Err(e) = result {
            let again = w.finish().unwrap_err().to_string();
            assert!(
                again.contains("writer unusable after an earlier error")
                    && again.contains("exceeds the f16 range"),
                "{again}"
            );
            return Err(e);
        }
        w.finish()
    };
    // Every value below the horizon is non-zero, and counted as zeroed.
    let below = 3 * mask.iter().filter(|&&v| !v).count() as u64;
    let above = max.next_up();
    for blocks in [false, true] {
        for (at, v) in [(valid, max), (valid, -max), (invalid, 1e30)] {
            let header = write(&rows(&[(0, at, v)]), blocks).unwrap();
            for m in &header.materials {
                assert_eq!(m.stats.zeroed_below_horizon, below, "blocks {blocks}");
            }
            let store = Store::open(&path).unwrap();
            let mut row = vec![0f32; info.d()];
            store.material_row(0, 0..info.d(), &mut row).unwrap();
            let want = if at == valid { v } else { 0.0 };
            assert_eq!(row[at], want, "blocks {blocks}: {v} at {at}");
        }
        // The first offence in writing order is named; 65504 before it is none.
        let first = if blocks {
            ("b", valid)
        } else {
            ("a", valid + 1)
        };
        for (set, (name, index), v) in [
            (vec![(0, valid, above)], ("a", valid), above),
            (vec![(0, valid, -above)], ("a", valid), -above),
            (vec![(0, valid, 7e4)], ("a", valid), 7e4),
            (
                vec![(0, valid, max), (1, valid, above), (0, valid + 1, above)],
                first,
                above,
            ),
            // Every material out of range at one index (no value in range beside them).
            (
                vec![(0, valid, above), (1, valid, above)],
                ("a", valid),
                above,
            ),
        ] {
            let e = write(&rows(&set), blocks).unwrap_err();
            let text = e.to_string();
            assert!(
                text.contains(&format!("material \"{name}\": value {v} at index {index}"))
                    && text.contains("exceeds the f16 range"),
                "blocks {blocks}: {text}"
            );
            names_file(&e, &path);
        }
    }
    std::fs::remove_file(&path).unwrap();
    assert!(only_file(t.path()).is_empty());
}

/// Blocks must follow each other: a reversed range or one past D is refused (never a panic),
/// naming the expected start; an empty block where the next one starts is no change.
#[test]
fn block_ranges_out_of_order_or_past_the_end_are_refused() {
    let info = info(2, 2, 4, Channels::Rgb);
    let d = info.d();
    let t = dir();
    let path = t.path().join("blocks.sbrdf");
    let values = |r: std::ops::Range<usize>| vec![0.5f32; r.len() * 2];
    // Each writer has written the block 0..6.
    let writer = || {
        let mut w = StoreWriter::create(&path, info.clone(), StoreOptions::default()).unwrap();
        w.declare_materials(&[("a", "s"), ("b", "s")]).unwrap();
        w.write_block(0..6, &values(0..6)).unwrap();
        w
    };
    #[allow(clippy::reversed_empty_ranges)]
    for bad in [6..4, 6..d + 1, 7..9, 0..6] {
        let mut w = writer();
        let e = w
            .write_block(bad.clone(), &values(bad.clone()))
            .unwrap_err();
        let text = e.to_string();
        let expected =
            format!("block {bad:?} out of order: expected a range starting at 6 and ending <= {d}");
        assert!(text.contains(&expected), "{text}");
        names_file(&e, &path);
    }
    let mut w = writer();
    w.write_block(6..6, &[]).unwrap();
    w.write_block(6..d, &values(6..d)).unwrap();
    w.finish().unwrap();
    let store = Store::open(&path).unwrap();
    let mut row = vec![0f32; d];
    store.material_row(1, 0..d, &mut row).unwrap();
    let mask = info.grid.validity_mask();
    for (i, v) in row.iter().enumerate() {
        assert_eq!(*v, if mask[i / 3] { 0.5 } else { 0.0 }, "{i}");
    }
}

/// f16 statistics describe the stored values, and inputs too small for f16 are counted (they
/// used to vanish silently, the header describing the f32 input) and warned of, in both write
/// modes.
#[test]
fn f16_statistics_describe_stored_values_and_count_flushed_inputs() {
    let info = info(3, 3, 6, Channels::Rgb);
    let mask = info.grid.validity_mask();
    // Valid values cycle through 1e-9 (below f16's smallest subnormal, 6e-8: stored as 0),
    // 0.1 (rounded to 0.0999755859375) and 1.0.
    let cycle = [1e-9f32, 0.1, 1.0];
    let row: Vec<f32> = (0..info.d())
        .map(|d| if mask[d / 3] { cycle[d % 3] } else { 0.0 })
        .collect();
    let valid = (0..info.d()).filter(|d| mask[d / 3]).count() as u64;
    let tiny = (0..info.d()).filter(|&d| mask[d / 3] && d % 3 == 0).count() as u64;
    let t = dir();
    for dtype in [Dtype::F16, Dtype::F32] {
        let opts = StoreOptions {
            dtype,
            ..Default::default()
        };
        let a = t.path().join(format!("{}-materials.sbrdf", dtype.name()));
        let (ha, said_a) = test_warnings::warnings_of(|| {
            write_materials(&a, &info, std::slice::from_ref(&row), opts.clone(), 7).unwrap()
        });
        let b = t.path().join(format!("{}-blocks.sbrdf", dtype.name()));
        let mut w = StoreWriter::create(&b, info.clone(), opts).unwrap();
        w.declare_materials(&[("mat0", "test:0")]).unwrap();
        w.write_block(0..info.d(), &row).unwrap();
        let (hb, said_b) = test_warnings::warnings_of(|| w.finish().unwrap());
        // The values stored as 0 are a warning naming the material; none, no warning.
        for said in [&said_a, &said_b] {
            if dtype == Dtype::F16 {
                let what = format!(
                    "{tiny} of {valid} values are below the f16 range and were stored as 0"
                );
                assert!(said.contains(&what) && said.contains("mat0"), "{said}");
            } else {
                assert_eq!(said, "", "{dtype:?}");
            }
        }
        for h in [&ha, &hb] {
            let s = &h.materials[0].stats;
            assert_eq!(s.count, valid);
            let (flushed, min) = match dtype {
                Dtype::F16 => (tiny, 0.0),
                Dtype::F32 => (0, f64::from(1e-9f32)),
            };
            assert_eq!((s.flushed_to_zero, s.min, s.max), (flushed, min, 1.0));
            assert_eq!(h.stats.flushed_to_zero, flushed);
            // The sum of squares is that of the stored values (the rounded 0.1 in f16).
            let tenth = f64::from(dtype.round(0.1));
            let n = (valid - tiny) as f64 / 2.0;
            let tiny_sq = if dtype == Dtype::F32 {
                1e-18 * tiny as f64
            } else {
                0.0
            };
            let want = n * (tenth * tenth + 1.0) + tiny_sq;
            assert!((s.sum_sq - want).abs() < 1e-9 * want, "{} {want}", s.sum_sq);
        }
        let stored = read_all(&Store::open(&a).unwrap());
        let zeros = stored[0].iter().filter(|v| **v == 0.0).count() as u64;
        let invalid = info.d() as u64 - valid;
        assert_eq!(zeros - invalid, if dtype == Dtype::F16 { tiny } else { 0 });
    }
}

#[test]
fn material_sampling_interpolates_on_the_grid() {
    // A material linear in the continuous theta_d coordinate is reproduced exactly between
    // bin centres; phi_d wraps.
    let info = info(2, 6, 4, Channels::Rgb);
    let g = info.grid;
    let mut row = vec![0f32; info.d()];
    for a in 0..g.len() {
        let (_, j, k) = g.unindex(a);
        for c in 0..3 {
            row[a * 3 + c] = (j as f32 + 1.0) * (c as f32 + 1.0) + 10.0 * k as f32;
        }
    }
    // Keep everything: no cell of this grid is checked against the mask here, so build on cells
    // above the horizon only.
    let mask = g.validity_mask();
    let t = dir();
    let path = t.path().join("m.sbrdf");
    let mut w = StoreWriter::create(&path, info.clone(), StoreOptions::default()).unwrap();
    w.add_material("lin", "test", &row).unwrap();
    w.finish().unwrap();
    let store = std::sync::Arc::new(Store::open(&path).unwrap());
    let m = StoreMaterial::new(store.clone(), "lin").unwrap();
    let mut out = [0f64; 3];
    // Bin centre (0, 1, 2): exact stored value.
    assert!(mask[g.index(0, 1, 2)] && mask[g.index(0, 2, 2)]);
    m.eval_half_diff(&g.bin_centre(0, 1, 2), &mut out).unwrap();
    assert_eq!(out, [2.0 + 20.0, 4.0 + 20.0, 6.0 + 20.0]);
    // Halfway between theta_d bins 1 and 2 at phi_d bin 2, theta_h centre 0.
    let mut hd = g.bin_centre(0, 1, 2);
    hd.theta_d = 2.0 / 6.0 * std::f64::consts::FRAC_PI_2;
    m.eval_half_diff(&hd, &mut out).unwrap();
    for (c, o) in out.iter().enumerate() {
        let want = 2.5 * (c as f64 + 1.0) + 20.0;
        assert!((o - want).abs() < 1e-9, "{o} vs {want}");
    }
    // phi_d = 0 lies halfway between bin 3 (wrapped) and bin 0.
    let mut hd = g.bin_centre(0, 1, 0);
    hd.phi_d = 0.0;
    m.eval_half_diff(&hd, &mut out).unwrap();
    assert!((out[0] - (2.0 + 15.0)).abs() < 1e-9, "{out:?}");
    assert!(StoreMaterial::new(store.clone(), "nope").is_err());
    assert!(StoreMaterial::by_index(store.clone(), 1).is_err());
    // Through the BrdfSource trait, as `specgp sample DATA.sbrdf:lin` uses it.
    let spec = format!("{}:lin", path.display());
    let (p, name) = brdf_io::store::parse_store_spec(&spec).unwrap();
    let src: Box<dyn brdf_io::BrdfSource> = Box::new(StoreMaterial::open(&p, &name).unwrap());
    assert_eq!(src.channels(), Channels::Rgb);
    let (wi, wo) = g.bin_centre(0, 1, 2).to_dirs();
    src.eval(wi, wo, &mut out).unwrap();
    assert!((out[2] - 26.0).abs() < 1e-9, "{out:?}");
    // Cell hints: taken when the store reads on demand, and they change no value (cells
    // outside the grid included).
    use brdf_io::BrdfSource;
    assert!(!src.takes_cell_hints());
    let options = OpenOptions {
        paging: Paging::OnDemand,
        ..OpenOptions::default()
    };
    let on_demand = std::sync::Arc::new(Store::open_with(&path, options).unwrap());
    let hinted = StoreMaterial::new(on_demand.clone(), "lin").unwrap();
    assert_eq!(hinted.takes_cell_hints(), on_demand.takes_will_need());
    assert_eq!(hinted.takes_cell_hints(), cfg!(target_os = "linux"));
    hinted.will_need_cells(&mut (0..g.len() + 3).rev());
    let (mut got, mut want) = ([0f64; 3], [0f64; 3]);
    for a in (0..g.len()).filter(|&a| mask[a]) {
        hinted.eval_cell(a, &mut got).unwrap();
        m.eval_cell(a, &mut want).unwrap();
        assert_eq!(got.map(f64::to_bits), want.map(f64::to_bits), "cell {a}");
    }
    assert!(brdf_io::store::parse_store_spec("x.bsdf").is_none());
    // Both parts are needed: a `.sbrdf` path and a non-empty name.
    assert!(brdf_io::store::parse_store_spec("x.bsdf:lin").is_none());
    assert!(brdf_io::store::parse_store_spec("x.sbrdf:").is_none());
    // Directions exactly on the horizon (either one) read 0, not the grazing cells' values.
    for (wi, wo) in [
        ([1.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
        ([0.0, 0.0, 1.0], [0.0, 1.0, 0.0]),
    ] {
        out = [9.0; 3];
        src.eval(wi, wo, &mut out).unwrap();
        assert_eq!(out, [0.0; 3], "{wi:?} {wo:?}");
    }
    // Names may contain `:` (the store path ends at the first `.sbrdf:`).
    assert_eq!(
        brdf_io::store::parse_store_spec("d/x.sbrdf:a:b@0.5,1"),
        Some((
            std::path::PathBuf::from("d/x.sbrdf"),
            "a:b@0.5,1".to_owned()
        ))
    );
    // A grid source: its cells are the stored values, and interpolating them with the stencil
    // is `eval` (what renderers use to evaluate each touched cell once).
    assert_eq!(src.grid(), Some(g));
    src.eval_cell(g.index(0, 1, 2), &mut out).unwrap();
    assert_eq!(out, [22.0, 24.0, 26.0]);
    assert!(src.eval_cell(g.len(), &mut out).is_err());
    assert!(src.eval_cell(0, &mut [0.0; 2]).is_err());
    let (wi, wo) = hd.to_dirs();
    src.eval(wi, wo, &mut out).unwrap();
    let mut via_cells = [0.0; 3];
    let mut cell = [0.0; 3];
    for (a, w) in g.interpolation_stencil(&brdf_io::HalfDiff::from_dirs(wi, wo).unwrap()) {
        src.eval_cell(a, &mut cell).unwrap();
        (0..3).for_each(|c| via_cells[c] += w * cell[c]);
    }
    for c in 0..3 {
        assert!(
            (out[c] - via_cells[c]).abs() < 1e-12,
            "{out:?} vs {via_cells:?}"
        );
    }
    // Below the horizon: 0.
    m.eval([0.0, 0.0, 1.0], [1.0, 0.0, -0.1], &mut out).unwrap();
    assert_eq!(out, [0.0; 3]);
}

/// A material that is 1/pi (a white Lambertian) in every valid cell samples as 1/pi right
/// down to the horizon: the lookup does not interpolate towards the 0 stored in the cells below
/// it (it read up to ~70 % low within a degree of the horizon before), and a pair none of whose
/// stencil cells is valid reads the nearest valid one (it read 0).
#[test]
fn grazing_lookups_read_valid_cells_only() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("white.sbrdf");
    let info = info(16, 16, 32, Channels::Rgb);
    let mask = info.grid.validity_mask();
    let value = std::f32::consts::FRAC_1_PI;
    let row: Vec<f32> = (0..info.d())
        .map(|d| if mask[d / 3] { value } else { 0.0 })
        .collect();
    write_materials(&path, &info, &[row], StoreOptions::default(), 4096).unwrap();
    let m = StoreMaterial::open(&path, "mat0").unwrap();
    let mut out = [0f64; 3];
    let mut checked = 0;
    for i in 0..=40 {
        // Light from 80..89.9 degrees, viewer at 0..89.9 degrees, several azimuths.
        let ti = (80.0 + i as f64 * 0.2475f64).to_radians();
        for j in 0..=30 {
            let to = (j as f64 * 2.997f64).to_radians();
            for phi in [0.0f64, 0.7, 1.6, 2.5, 3.1] {
                let wi = [ti.sin(), 0.0, ti.cos()];
                let wo = [to.sin() * phi.cos(), to.sin() * phi.sin(), to.cos()];
                m.eval(wi, wo, &mut out).unwrap();
                // Every pair above the horizon reads the constant, even where no corner of
                // its stencil holds a value (the nearest valid cell stands in).
                checked += 1;
                for o in out {
                    assert!((o - f64::from(value)).abs() < 1e-6, "{ti} {to} {phi}: {o}");
                }
            }
        }
    }
    assert!(checked > 5000, "{checked}");
}

#[test]
fn stored_material_at_chosen_wavelengths_interpolates_between_stored_ones() {
    // Stored channels 400, 500, 600 nm holding 1, 3, 7 (+ cell index): 450 nm is 2, 525 nm is
    // 3 + 0.25 * 4 = 4 (linear in wavelength, in BRDF values), 600 nm is 7.
    let info = info(
        2,
        2,
        4,
        Channels::spectral(vec![400.0, 500.0, 600.0]).unwrap(),
    );
    let g = info.grid;
    let mask = g.validity_mask();
    let row: Vec<f32> = (0..info.d())
        .map(|d| {
            let (a, c) = (d / 3, d % 3);
            if mask[a] {
                [1.0, 3.0, 7.0][c] + a as f32
            } else {
                0.0
            }
        })
        .collect();
    let t = dir();
    let path = t.path().join("s.sbrdf");
    let mut w = StoreWriter::create(&path, info.clone(), StoreOptions::default()).unwrap();
    w.add_material("m", "test", &row).unwrap();
    w.finish().unwrap();
    let m = StoreMaterial::open(&path, "m").unwrap();
    let at = m
        .with_wavelengths(&Channels::parse_wavelengths("450,525,600").unwrap())
        .unwrap();
    assert_eq!(at.n_channels(), 3);
    assert_eq!(
        brdf_io::BrdfSource::channels(&at),
        Channels::parse_wavelengths("450,525,600").unwrap()
    );
    let a = (0..g.len()).find(|&a| mask[a]).unwrap();
    let mut out = [0.0; 3];
    brdf_io::BrdfSource::eval_cell(&at, a, &mut out).unwrap();
    let base = a as f64;
    assert_eq!(out, [2.0 + base, 4.0 + base, 7.0 + base]);
    // Between cells too: `eval` at a bin centre is that cell, at the chosen wavelengths.
    at.eval_half_diff(&g.bin_centre_flat(a), &mut out).unwrap();
    assert!((out[1] - (4.0 + base)).abs() < 1e-12, "{out:?}");
    // The material itself still has all stored channels.
    assert_eq!(m.n_channels(), 3);
    brdf_io::BrdfSource::eval_cell(&m, a, &mut out).unwrap();
    assert_eq!(out, [1.0 + base, 3.0 + base, 7.0 + base]);
    // Outside the stored range, or wavelengths of an RGB store: errors naming the store.
    let e = m
        .with_wavelengths(&Channels::parse_wavelengths("380,500").unwrap())
        .unwrap_err();
    assert!(matches!(e, Error::WavelengthOutOfRange { .. }), "{e}");
    assert!(
        e.to_string().contains("s.sbrdf") && e.to_string().contains("380 nm"),
        "{e}"
    );
    let e = m.with_wavelengths(&Channels::Rgb).unwrap_err().to_string();
    assert!(
        e.contains("s.sbrdf") && e.contains("no RGB channels"),
        "{e}"
    );
    // A selection that starts past the first stored channel (525 nm reads 500 and 600 only).
    let late = m
        .with_wavelengths(&Channels::parse_wavelengths("525,600").unwrap())
        .unwrap();
    let mut two = [0.0; 2];
    brdf_io::BrdfSource::eval_cell(&late, a, &mut two).unwrap();
    assert_eq!(two, [4.0 + base, 7.0 + base]);
    // A damaged payload value (lookups do not re-hash the payload) is an error naming the
    // store, the material and its flat index, here cell a's 600 nm value. One uncompressed
    // material: index d is stored at the payload offset (4096) + 4 d.
    let d = a * 3 + 2;
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[4096 + 4 * d..4096 + 4 * d + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    let bad = t.path().join("bad.sbrdf");
    std::fs::write(&bad, bytes).unwrap();
    let late = StoreMaterial::open(&bad, "m")
        .unwrap()
        .with_wavelengths(&Channels::parse_wavelengths("525,600").unwrap())
        .unwrap();
    match brdf_io::BrdfSource::eval_cell(&late, a, &mut two) {
        Err(Error::DamagedValue {
            path,
            material,
            index,
            value,
        }) => {
            assert!(
                path.ends_with("bad.sbrdf") && material == "m" && index == d && value.is_nan(),
                "{} {material} {index} {value}",
                path.display()
            );
        }
        other => panic!("{other:?}"),
    }
}

// ---------------------------------------------------------------- bad input

fn small_store(dir: &Path, compression: Compression) -> PathBuf {
    let info = info(3, 3, 4, Channels::Rgb);
    let rows: Vec<_> = (0..3).map(|i| material(&info, 70 + i)).collect();
    let path = dir.join("bad.sbrdf");
    let opts = StoreOptions {
        chunk_len: Some(16),
        compression,
        ..Default::default()
    };
    write_materials(&path, &info, &rows, opts, 1000).unwrap();
    path
}

fn names_file(e: &Error, path: &Path) {
    let msg = e.to_string();
    assert!(
        msg.contains(&path.display().to_string()),
        "error does not name {}: {msg}",
        path.display()
    );
}

#[test]
fn missing_file_and_wrong_magic() {
    let t = dir();
    let missing = t.path().join("nope.sbrdf");
    let e = Store::open(&missing).unwrap_err();
    assert!(matches!(e, Error::Io { .. }), "{e}");
    names_file(&e, &missing);
    let other = t.path().join("other.sbrdf");
    std::fs::write(
        &other,
        b"tensor_file\0 and more bytes, well past sixty-four of them........",
    )
    .unwrap();
    let e = Store::open(&other).unwrap_err();
    assert!(matches!(e, Error::NotAStore { .. }), "{e}");
    names_file(&e, &other);
    assert!(e.to_string().contains("an RGL .bsdf tensor file"), "{e}");
    // Other files a user may hand over by mistake are named for what they are.
    let mut merl: Vec<u8> = [2i32, 1, 3].iter().flat_map(|d| d.to_le_bytes()).collect();
    merl.extend((0..18).flat_map(|_| 0.5f64.to_le_bytes()));
    let mut npy = b"\x93NUMPY\x01\x00".to_vec();
    npy.extend([b' '; 80]);
    for (name, bytes, says) in [
        ("empty.sbrdf", Vec::new(), "the file is empty"),
        (
            "png.sbrdf",
            b"\x89PNG\r\n\x1a\n0000".to_vec(),
            "a PNG image",
        ),
        ("npy.sbrdf", npy, "a NumPy .npy array"),
        ("merl.sbrdf", merl, "a MERL .binary BRDF (2 x 1 x 3"),
        (
            "model.sbrdf",
            b"format = \"specgp-model\"\nversion = 1\n".to_vec(),
            "the file is text (starts \"format = ",
        ),
        (
            "odd.sbrdf",
            vec![0u8, 1, 2, 3, 250, 251, 252, 253, 7],
            "file starts with [00, 01",
        ),
        // A MERL-like header with a zero dimension holds no BRDF, though its 12 bytes are the
        // size such dimensions imply.
        (
            "zero.sbrdf",
            [0i32, 90, 180]
                .iter()
                .flat_map(|d| d.to_le_bytes())
                .collect(),
            "file starts with [00, 00, 00, 00, 5a",
        ),
    ] {
        let path = t.path().join(name);
        std::fs::write(&path, bytes).unwrap();
        let e = Store::open(&path).unwrap_err();
        assert!(matches!(e, Error::NotAStore { .. }), "{name}: {e}");
        names_file(&e, &path);
        assert!(e.to_string().contains(says), "{name}: {e}");
    }
}

#[test]
fn truncated_files_are_rejected_at_every_length() {
    let t = dir();
    let path = small_store(t.path(), Compression::None);
    let bytes = std::fs::read(&path).unwrap();
    let cut = t.path().join("cut.sbrdf");
    for len in [
        8,
        40,
        64,
        100,
        4096,
        4200,
        bytes.len() - 300,
        bytes.len() - 1,
    ] {
        std::fs::write(&cut, &bytes[..len]).unwrap();
        let e = Store::open(&cut).unwrap_err();
        assert!(matches!(e, Error::StoreCorrupt { .. }), "len {len}: {e}");
        names_file(&e, &cut);
    }
}

#[test]
fn unsupported_version_and_dtype() {
    let t = dir();
    let path = small_store(t.path(), Compression::None);
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[8] = 7;
    std::fs::write(&path, &bytes).unwrap();
    match Store::open(&path).unwrap_err() {
        Error::StoreVersion { found, .. } => assert_eq!(found, 7),
        e => panic!("expected a version error, got {e}"),
    }
    bytes[8] = 1;
    // Rewrite the header's dtype and fix up the header hash so only the dtype is wrong.
    let key = b"\"dtype\": \"f32\"";
    let pos = bytes
        .windows(key.len())
        .position(|w| w == key)
        .expect("dtype in header");
    bytes[pos + 10..pos + 13].copy_from_slice(b"f64");
    let hoff = u64::from_le_bytes(bytes[40..48].try_into().unwrap()) as usize;
    let h = xxhash_rust_digest(&bytes[..56], &bytes[hoff..]);
    bytes[56..64].copy_from_slice(&h.to_le_bytes());
    std::fs::write(&path, &bytes).unwrap();
    let e = Store::open(&path).unwrap_err();
    assert!(e.to_string().contains("unsupported dtype \"f64\""), "{e}");
    names_file(&e, &path);
}

/// Replaces the JSON header of the store at `path` by `edit` of it, fixing up the header length
/// and hash so that only the edited content is wrong.
fn rewrite_header(path: &Path, edit: impl FnOnce(&mut serde_json::Value)) {
    let mut bytes = std::fs::read(path).unwrap();
    let hoff = u64::from_le_bytes(bytes[40..48].try_into().unwrap()) as usize;
    let mut header: serde_json::Value = serde_json::from_slice(&bytes[hoff..]).unwrap();
    edit(&mut header);
    let json = serde_json::to_vec_pretty(&header).unwrap();
    bytes.truncate(hoff);
    bytes.extend_from_slice(&json);
    bytes[48..56].copy_from_slice(&(json.len() as u64).to_le_bytes());
    let h = xxhash_rust_digest(&bytes[..56], &json);
    bytes[56..64].copy_from_slice(&h.to_le_bytes());
    std::fs::write(path, &bytes).unwrap();
}

/// A header claiming a grid beyond the supported bounds is refused on open (before anything is
/// allocated for it), naming the file and the bound.
#[test]
fn header_with_a_huge_grid_is_refused() {
    let t = dir();
    let path = small_store(t.path(), Compression::None);
    rewrite_header(&path, |h| {
        h["grid"] =
            serde_json::json!({"n_theta_h": 100000, "n_theta_d": 100000, "n_phi_d": 100000});
        h["d"] = serde_json::json!(3_000_000_000_000_000u64);
    });
    let e = Store::open(&path).unwrap_err();
    assert!(matches!(e, Error::StoreCorrupt { .. }), "{e}");
    assert!(e.to_string().contains("longer than 4096 bins"), "{e}");
    names_file(&e, &path);
    rewrite_header(&path, |h| {
        h["grid"] = serde_json::json!({"n_theta_h": 1000, "n_theta_d": 1000, "n_phi_d": 2000});
        h["d"] = serde_json::json!(6_000_000_000u64);
    });
    let e = Store::open(&path).unwrap_err();
    assert!(
        e.to_string().contains("more than the supported 134217728"),
        "{e}"
    );
    names_file(&e, &path);
}

/// A header whose N x D x value size overflows 64 bits (1.2 10^6 wavelengths on a 512^3 grid,
/// 10^5 materials, one chunk as before) is refused on open, naming the file; the chunk
/// size check multiplied these unchecked (an overflow: a panic in debug builds).
#[test]
fn header_whose_payload_size_overflows_is_refused() {
    let t = dir();
    // One chunk: the chunk size check multiplies N by D itself.
    let info = info(3, 3, 4, Channels::Rgb);
    let rows: Vec<_> = (0..3).map(|i| material(&info, 70 + i)).collect();
    let path = t.path().join("one_chunk.sbrdf");
    let opts = StoreOptions {
        chunk_len: Some(1000),
        ..Default::default()
    };
    write_materials(&path, &info, &rows, opts, 1000).unwrap();
    let cells: u64 = 512 * 512 * 512;
    let channels: u64 = 1_200_000;
    rewrite_header(&path, |h| {
        let first = h["materials"][0].clone();
        let materials: Vec<serde_json::Value> = (0..100_000)
            .map(|i| {
                let mut m = first.clone();
                m["name"] = serde_json::json!(format!("m{i}"));
                m
            })
            .collect();
        h["materials"] = serde_json::Value::Array(materials);
        h["grid"] = serde_json::json!({"n_theta_h": 512, "n_theta_d": 512, "n_phi_d": 512});
        let wavelengths: Vec<f64> = (1..=channels).map(|w| w as f64).collect();
        h["channels"] = serde_json::json!({"kind": "spectral", "wavelengths_nm": wavelengths});
        // The chunk count (and so the offset table) stays: only the sizes are wrong.
        let d = cells * channels;
        let n_chunks = h["layout"]["n_chunks"].as_u64().unwrap();
        let chunk_len = d.div_ceil(n_chunks);
        assert_eq!(d.div_ceil(chunk_len), n_chunks);
        h["d"] = serde_json::json!(d);
        h["layout"]["chunk_len"] = serde_json::json!(chunk_len);
    });
    let e = Store::open(&path).unwrap_err();
    assert!(matches!(e, Error::StoreCorrupt { .. }), "{e}");
    assert!(
        e.to_string().contains(
            "100000 materials x D = 161061273600000 values x 4 bytes do not fit in 64 bits"
        ),
        "{e}"
    );
    names_file(&e, &path);
}

/// A zstd store whose header claims chunks larger than their compressed bytes can hold (a
/// bigger grid, or more materials, than written) is refused when a chunk is read, naming the
/// file and the chunk, before the claimed size is allocated (the reader allocated it first).
#[test]
fn zstd_chunk_claiming_more_than_its_frame_is_refused() {
    let t = dir();
    let info = info(3, 3, 4, Channels::Rgb);
    let rows: Vec<_> = (0..3).map(|i| material(&info, 70 + i)).collect();
    let path = t.path().join("zstd_one_chunk.sbrdf");
    let opts = StoreOptions {
        chunk_len: Some(1000),
        compression: Compression::Zstd { level: 3 },
        ..Default::default()
    };
    write_materials(&path, &info, &rows, opts.clone(), 1000).unwrap();
    let mut v = Vec::new();
    Store::open(&path).unwrap().read_chunk(0, &mut v).unwrap();
    assert_eq!(v.len(), 3 * 108);
    // 128 x 128 x 256 cells x 3 channels x 3 materials x 4 bytes: 151 MB claimed by one chunk
    // of a few hundred compressed bytes (zstd encodes at most 32768 bytes per byte).
    rewrite_header(&path, |h| {
        h["grid"] = serde_json::json!({"n_theta_h": 128, "n_theta_d": 128, "n_phi_d": 256});
        let d = 128u64 * 128 * 256 * 3;
        h["d"] = serde_json::json!(d);
        h["layout"]["chunk_len"] = serde_json::json!(d);
    });
    let e = Store::open(&path)
        .unwrap()
        .read_chunk(0, &mut v)
        .unwrap_err();
    assert!(matches!(e, Error::StoreCorrupt { .. }), "{e}");
    assert!(
        e.to_string().contains("chunk 0 (150994944 bytes): ")
            && e.to_string().contains("compressed bytes cannot hold it"),
        "{e}"
    );
    names_file(&e, &path);
    // Within the ratio bound, the frame's own record of its size is checked: 2 x 2 x 4 cells.
    write_materials(&path, &info, &rows, opts, 1000).unwrap();
    rewrite_header(&path, |h| {
        h["grid"] = serde_json::json!({"n_theta_h": 4, "n_theta_d": 4, "n_phi_d": 8});
        h["d"] = serde_json::json!(384);
        h["layout"]["chunk_len"] = serde_json::json!(384);
    });
    let e = Store::open(&path)
        .unwrap()
        .read_chunk(0, &mut v)
        .unwrap_err();
    assert!(
        e.to_string()
            .contains("chunk 0 (4608 bytes): its zstd frame records 1296 bytes"),
        "{e}"
    );
    names_file(&e, &path);
}

/// Headers with bad wavelengths or material names are refused on open, naming the store file
/// (they used to open and fail later with messages naming no file).
#[test]
fn header_with_bad_wavelengths_or_names_is_refused() {
    let t = dir();
    let info = info(
        3,
        3,
        4,
        Channels::spectral(vec![400.0, 500.0, 600.0]).unwrap(),
    );
    let rows: Vec<_> = (0..2).map(|i| material(&info, 90 + i)).collect();
    let path = t.path().join("spec.sbrdf");
    write_materials(&path, &info, &rows, StoreOptions::default(), 1000).unwrap();
    let good = std::fs::read(&path).unwrap();
    let cases: [(&str, serde_json::Value, &str); 5] = [
        (
            "channels",
            serde_json::json!({"kind": "spectral", "wavelengths_nm": [500.0, 400.0, 600.0]}),
            "strictly increasing",
        ),
        (
            "channels",
            serde_json::json!({"kind": "spectral", "wavelengths_nm": [400.0, 400.0, 600.0]}),
            "strictly increasing",
        ),
        (
            "channels",
            serde_json::json!({"kind": "spectral", "wavelengths_nm": [-400.0, 500.0, 600.0]}),
            "finite and positive",
        ),
        (
            "materials.0.name",
            serde_json::json!(""),
            "material 0 has an empty name",
        ),
        (
            "materials.1.name",
            serde_json::json!("mat0"),
            "duplicate material name \"mat0\"",
        ),
    ];
    for (key, value, want) in cases {
        std::fs::write(&path, &good).unwrap();
        rewrite_header(&path, |h| {
            let mut slot = &mut *h;
            for k in key.split('.') {
                slot = match k.parse::<usize>() {
                    Ok(i) => &mut slot[i],
                    Err(_) => &mut slot[k],
                };
            }
            *slot = value.clone();
        });
        let e = Store::open(&path).unwrap_err();
        assert!(matches!(e, Error::StoreCorrupt { .. }), "{key}: {e}");
        assert!(e.to_string().contains(want), "{key}: {e}");
        names_file(&e, &path);
    }
    // A NaN wavelength cannot even be written in JSON (it becomes null): refused as well.
    std::fs::write(&path, &good).unwrap();
    rewrite_header(&path, |h| {
        h["channels"]["wavelengths_nm"][1] = serde_json::Value::Null
    });
    let e = Store::open(&path).unwrap_err();
    names_file(&e, &path);
}

/// The writer refuses names with a newline (or other control character) and bad wavelengths,
/// naming the output file and the name.
#[test]
fn writer_refuses_control_characters_in_names_and_bad_wavelengths() {
    let t = dir();
    let path = t.path().join("out.sbrdf");
    let info = info(2, 2, 4, Channels::Rgb);
    let mut w = StoreWriter::create(&path, info.clone(), StoreOptions::default()).unwrap();
    let e = w
        .declare_materials(&[("ok", "s"), ("two\nlines", "s")])
        .unwrap_err();
    let msg = e.to_string();
    assert!(msg.contains("\"two\\nlines\" contains a newline"), "{msg}");
    names_file(&e, &path);
    drop(w);
    let mut w = StoreWriter::create(&path, info.clone(), StoreOptions::default()).unwrap();
    let e = w
        .add_material("tab\there", "s", &vec![0.0; info.d()])
        .unwrap_err();
    assert!(e.to_string().contains("\"tab\\there\" contains"), "{e}");
    drop(w);
    let bad = StoreInfo {
        grid: info.grid,
        channels: Channels::Spectral(vec![500.0, 400.0]),
    };
    let e = StoreWriter::create(&path, bad, StoreOptions::default())
        .err()
        .unwrap();
    assert!(e.to_string().contains("strictly increasing"), "{e}");
    names_file(&e, &path);
    assert!(only_file(t.path()).is_empty());
}

/// xxh3-64 of the prefix fields followed by the header (as the format defines it).
fn xxhash_rust_digest(prefix: &[u8], header: &[u8]) -> u64 {
    let mut v = prefix.to_vec();
    v.extend_from_slice(header);
    xxhash_rust::xxh3::xxh3_64(&v)
}

#[test]
fn corrupt_payload_fails_checksum_and_damaged_header_fails_open() {
    let t = dir();
    for compression in [
        Compression::None,
        Compression::Zstd { level: 3 },
        Compression::ZstdShuffle { level: 3 },
    ] {
        let path = small_store(t.path(), compression);
        let mut bytes = std::fs::read(&path).unwrap();
        bytes[4096 + 5] ^= 0x40;
        std::fs::write(&path, &bytes).unwrap();
        let store = Store::open(&path).unwrap();
        let e = store.verify_checksum().unwrap_err();
        assert!(matches!(e, Error::StoreChecksum { .. }), "{e}");
        names_file(&e, &path);
        if compression != Compression::None {
            // A damaged zstd frame is an error on read (every frame carries its content
            // checksum), never wrong numbers or a panic.
            let mut out = vec![0f32; 3];
            let e = store.values_at(0, &mut out).unwrap_err();
            assert!(matches!(e, Error::StoreCorrupt { .. }), "{e}");
        }
        // A damaged header byte is caught by the header hash.
        let n = bytes.len();
        bytes[n - 10] ^= 0x01;
        std::fs::write(&path, &bytes).unwrap();
        let e = Store::open(&path).unwrap_err();
        assert!(matches!(e, Error::StoreCorrupt { .. }), "{e}");
    }
}

/// The payload checksum covers all of a payload larger than the 8 MiB the check hashes at a
/// time: damage in the last chunk is found. An intact store passes, and its `Debug` names the
/// file and its shape.
#[test]
fn checksum_covers_a_payload_of_several_steps() {
    let t = dir();
    let path = t.path().join("big.sbrdf");
    let info = info(32, 32, 64, Channels::Rgb);
    let rows: Vec<Vec<f32>> = (0..16).map(|s| material(&info, s)).collect();
    write_materials(&path, &info, &rows, StoreOptions::default(), 1 << 20).unwrap();
    let store = Store::open(&path).unwrap();
    store.verify_checksum().unwrap();
    let debug = format!("{store:?}");
    for part in [
        format!("{:?}", path),
        "n_materials: 16".into(),
        format!("d: {}", info.d()),
    ] {
        assert!(debug.contains(&part), "{debug} lacks {part}");
    }
    drop(store);
    let mut bytes = std::fs::read(&path).unwrap();
    let table = u64::from_le_bytes(bytes[32..40].try_into().unwrap()) as usize;
    assert!(table > 4096 + (8 << 20) + 1024, "{table}");
    bytes[table - 7] ^= 0x10;
    std::fs::write(&path, &bytes).unwrap();
    let e = Store::open(&path).unwrap().verify_checksum().unwrap_err();
    assert!(matches!(e, Error::StoreChecksum { .. }), "{e}");
}

#[test]
fn writer_rejects_non_finite_and_bad_lengths_and_leaves_nothing() {
    let t = dir();
    let info = info(2, 2, 4, Channels::Rgb);
    let path = t.path().join("w.sbrdf");
    for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        let mut w = StoreWriter::create(&path, info.clone(), StoreOptions::default()).unwrap();
        let mut row = vec![0.5f32; info.d()];
        row[5] = bad;
        let e = w.add_material("m", "s", &row).unwrap_err();
        match &e {
            Error::NonFiniteValue {
                material, index, ..
            } => assert_eq!((material.as_str(), *index), ("m", 5)),
            e => panic!("expected NonFiniteValue, got {e}"),
        }
        names_file(&e, &path);
        // The writer is poisoned; finishing fails, and nothing is left behind.
        assert!(w.finish().is_err());
        assert!(only_file(t.path()).is_empty());
    }
    // Values beyond the f16 range are an error in an f16 store, not a silent infinity.
    let opts16 = StoreOptions {
        dtype: Dtype::F16,
        ..Default::default()
    };
    let mut w = StoreWriter::create(&path, info.clone(), opts16.clone()).unwrap();
    let mut row = vec![0.5f32; info.d()];
    row[0] = 7.0e4; // cell 0 is above the horizon
    let e = w.add_material("big", "s", &row).unwrap_err();
    assert!(e.to_string().contains("exceeds the f16 range"), "{e}");
    drop(w);
    // The first offence in index order is the one reported, whichever its kind, and a big
    // value below the horizon (stored as 0) is none.
    let below = info.grid.validity_mask().iter().position(|v| !v).unwrap() * 3;
    for (big, nan, first_is_nan) in [(5, 7, false), (7, 5, true), (below, 5, true)] {
        let mut w = StoreWriter::create(&path, info.clone(), opts16.clone()).unwrap();
        let mut row = vec![0.5f32; info.d()];
        row[big] = -7.0e4;
        row[nan] = f32::NAN;
        let mut m = w.begin_material("m", "s").unwrap();
        let e = m
            .write(&row[..2])
            .and_then(|_| m.write(&row[2..]))
            .unwrap_err();
        match &e {
            Error::NonFiniteValue { index, .. } => {
                assert!(first_is_nan, "{e}");
                assert_eq!(*index, nan);
            }
            e => {
                assert!(!first_is_nan, "{e}");
                assert!(
                    e.to_string().contains(&format!("at index {big} exceeds")),
                    "{e}"
                );
            }
        }
    }
    let mut w = StoreWriter::create(&path, info.clone(), opts16.clone()).unwrap();
    let mut row = vec![0.0f32; info.d()];
    row[below] = 7.0e4;
    let h = {
        w.add_material("m", "s", &row).unwrap();
        w.finish().unwrap()
    };
    assert_eq!(h.materials[0].stats.zeroed_below_horizon, 1);
    assert_eq!(
        Store::open(&path).unwrap().header().materials[0].stats.max,
        0.0
    );
    std::fs::remove_file(&path).unwrap();
    // Too many values, too few values, duplicate names, empty store, grid mismatch.
    let mut w = StoreWriter::create(&path, info.clone(), StoreOptions::default()).unwrap();
    assert!(w.add_material("m", "s", &vec![0.0; info.d() + 1]).is_err());
    drop(w);
    let mut w = StoreWriter::create(&path, info.clone(), StoreOptions::default()).unwrap();
    {
        let mut m = w.begin_material("a", "s").unwrap();
        m.write(&[1.0; 4]).unwrap();
        let e = m.finish().unwrap_err();
        assert!(e.to_string().contains("expected D = 48"), "{e}");
    }
    drop(w);
    let mut w = StoreWriter::create(&path, info.clone(), StoreOptions::default()).unwrap();
    w.add_material("a", "s", &vec![0.0; info.d()]).unwrap();
    assert!(w.add_material("a", "s", &vec![0.0; info.d()]).is_err());
    drop(w);
    let w = StoreWriter::create(&path, info.clone(), StoreOptions::default()).unwrap();
    let other = StoreInfo {
        grid: AngularGrid::new(2, 2, 5).unwrap(),
        channels: Channels::Rgb,
    };
    let e = w.check_info(&other).unwrap_err();
    assert!(e.to_string().contains("does not match"), "{e}");
    w.check_info(&info).unwrap();
    assert!(w.finish().is_err(), "a store without materials is an error");
    // Block mode: out of order, wrong length, incomplete.
    let mut w = StoreWriter::create(&path, info.clone(), StoreOptions::default()).unwrap();
    w.declare_materials(&[("a", "s"), ("b", "s")]).unwrap();
    assert!(w.write_block(1..3, &[0.0; 4]).is_err());
    assert!(w.write_block(0..3, &[0.0; 5]).is_err());
    w.write_block(0..3, &[0.0; 6]).unwrap();
    assert!(w.begin_material("c", "s").is_err());
    let e = w.finish().unwrap_err();
    assert!(e.to_string().contains("incomplete"), "{e}");
    // Writing into a directory that does not exist names the path.
    let nowhere = t.path().join("no/such/dir/x.sbrdf");
    let e = StoreWriter::create(&nowhere, info, StoreOptions::default())
        .err()
        .unwrap();
    names_file(&e, &nowhere);
    assert!(only_file(t.path()).is_empty(), "{:?}", only_file(t.path()));
}

/// Lookups outside the store are errors, compressed or not (an uncompressed store's file
/// holds its offset table and header after the values: a range past the end must not borrow
/// them).
#[test]
fn lookups_out_of_range_are_errors() {
    let t = dir();
    for compression in [Compression::None, Compression::Zstd { level: 1 }] {
        let path = small_store(t.path(), compression);
        let store = Store::open(&path).unwrap();
        let mut out = vec![0f32; 3];
        assert!(store.values_at(store.d(), &mut out).is_err());
        assert!(store.values_at(0, &mut out[..2]).is_err());
        assert!(store.values_in(0..1, &mut out[..2]).is_err());
        let past_end = store.d() - 1..store.d() + 1;
        let mut two = vec![0f32; 6];
        assert!(store.values_in(past_end.clone(), &mut two).is_err());
        assert!(
            store.values_in_ref(past_end, &mut Vec::new()).is_err(),
            "{compression:?}"
        );
        let mut row = vec![0f32; 4];
        assert!(store.material_row(3, 0..4, &mut row).is_err());
        assert!(store.material_row(0, 0..5, &mut row).is_err());
        assert!(store.material_index("zzz").is_err());
    }
    fn send_sync<T: Send + Sync>() {}
    send_sync::<Store>();
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    #[test]
    fn random_stores_round_trip(
        n in 1usize..5,
        th in 1usize..4, td in 1usize..4, pd in 1usize..5,
        nc in 1usize..4,
        chunk in 1usize..40,
        zstd in 0u8..3,
        half in any::<bool>(),
        slice in 1usize..50,
        seed in any::<u64>(),
    ) {
        let channels = Channels::spectral((0..nc).map(|i| 400.0 + 10.0 * i as f64).collect()).unwrap();
        let info = info(th, td, pd, channels);
        let rows: Vec<_> = (0..n).map(|i| material(&info, seed ^ i as u64)).collect();
        let t = dir();
        let path = t.path().join("p.sbrdf");
        let opts = StoreOptions {
            chunk_len: Some(chunk),
            dtype: if half { Dtype::F16 } else { Dtype::F32 },
            compression: match zstd {
                0 => Compression::None,
                1 => Compression::Zstd { level: 2 },
                _ => Compression::ZstdShuffle { level: 2 },
            },
            memory_budget: 64,
        };
        write_materials(&path, &info, &rows, opts, slice).unwrap();
        let store = Store::open(&path).unwrap();
        store.verify_checksum().unwrap();
        let back = read_all(&store);
        for (a, b) in back.iter().zip(&rows) {
            for (x, y) in a.iter().zip(b) {
                if half {
                    prop_assert!((x - y).abs() <= y.abs() * 2f32.powi(-11) + 6e-8);
                } else {
                    prop_assert_eq!(x.to_bits(), y.to_bits());
                }
            }
        }
        let mut out = vec![0f32; n];
        for d in (0..store.d()).step_by(3) {
            store.values_at(d, &mut out).unwrap();
            for m in 0..n {
                prop_assert_eq!(out[m].to_bits(), back[m][d].to_bits());
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    /// Every read of a sub-range agrees with the full rows, bit for bit, for each compression
    /// and value type (all six in every case), in both read modes and with a one-chunk cache
    /// (so that chunks are evicted and read again): `material_row` of each material,
    /// `values_in` and `values_in_ref` (index-major; borrowed from the map exactly for ranges
    /// of an uncompressed f32 store), `values_at` at the ends, over ranges inside a chunk,
    /// across chunk boundaries, empty, and up to the end of the store.
    #[test]
    fn sub_range_reads_agree_with_the_rows(
        n in 1usize..5,
        pd in 1usize..5,
        nc in 1usize..4,
        chunk in 1usize..20,
        cuts in proptest::collection::vec((0.0f64..=1.0, 0.0f64..=1.0), 1..6),
        seed in any::<u64>(),
    ) {
        let channels = Channels::spectral((0..nc).map(|i| 400.0 + 10.0 * i as f64).collect()).unwrap();
        let info = info(2, 3, pd, channels);
        let rows: Vec<_> = (0..n).map(|i| material(&info, seed ^ i as u64)).collect();
        let d = info.d();
        let mut ranges: Vec<std::ops::Range<usize>> = cuts
            .iter()
            .map(|&(a, b)| {
                let (a, b) = ((a * d as f64) as usize, (b * d as f64) as usize);
                a.min(b)..a.max(b)
            })
            .collect();
        ranges.extend([0..0, d..d, 0..1, d - 1..d, 0..d, chunk.min(d) - 1..(chunk + 1).min(d)]);
        let t = dir();
        let compressions = [
            Compression::None,
            Compression::Zstd { level: 1 },
            Compression::ZstdShuffle { level: 1 },
        ];
        for (compression, dtype) in compressions.into_iter().flat_map(|c| [(c, Dtype::F32), (c, Dtype::F16)]) {
            let path = t.path().join(format!("{compression:?}-{dtype:?}.sbrdf"));
            let opts = StoreOptions {
                chunk_len: Some(chunk),
                dtype,
                compression,
                memory_budget: 64,
            };
            write_materials(&path, &info, &rows, opts, 7).unwrap();
            let full = read_all(&Store::open(&path).unwrap());
            for (mode, paging) in READS {
                let options = OpenOptions { mode, cache_chunks: 1, paging };
                let store = Store::open_with(&path, options).unwrap();
                let how = format!("{compression:?} {dtype:?} {mode:?}");
                // Hints change no value, whatever the ranges (across chunks, empty, reversed,
                // past the end).
                store.will_need(ranges.iter().cloned().chain([d - 1..d + 3, d / 2 + 1..d / 2, d..d]));
                for r in &ranges {
                    store.prefetch(r.clone());
                    for (m, row) in full.iter().enumerate() {
                        let mut out = vec![f32::NAN; r.len()];
                        store.material_row(m, r.clone(), &mut out).unwrap();
                        prop_assert!(
                            out.iter().zip(&row[r.clone()]).all(|(a, b)| a.to_bits() == b.to_bits()),
                            "material_row({}, {:?}), {}", m, r, how
                        );
                    }
                    let mut block = vec![f32::NAN; r.len() * n];
                    store.values_in(r.clone(), &mut block).unwrap();
                    let mut buf = Vec::new();
                    let borrowed = store.values_in_ref(r.clone(), &mut buf).unwrap();
                    prop_assert_eq!(borrowed.len(), r.len() * n);
                    for (k, d) in r.clone().enumerate() {
                        for m in 0..n {
                            let want = full[m][d].to_bits();
                            prop_assert_eq!(block[k * n + m].to_bits(), want, "{:?} {}", r, &how);
                            prop_assert_eq!(borrowed[k * n + m].to_bits(), want, "{:?} {}", r, &how);
                        }
                    }
                    // Borrowed (the buffer untouched) exactly where documented: a non-empty
                    // range (within a chunk or across chunks: they follow one another) of an
                    // uncompressed f32 store read through a map (on-demand paging reads ranges
                    // this small with positioned reads).
                    let maps = (compression, dtype, mode) == (Compression::None, Dtype::F32, ReadMode::Mmap)
                        && paging != Paging::OnDemand;
                    if !r.is_empty() {
                        prop_assert_eq!(buf.is_empty(), maps, "{:?} {}", r, &how);
                    }
                }
                let mut at = vec![f32::NAN; n];
                for d in [0, d / 2, d - 1] {
                    store.values_at(d, &mut at).unwrap();
                    for m in 0..n {
                        prop_assert_eq!(at[m].to_bits(), full[m][d].to_bits(), "{} {}", d, &how);
                    }
                }
            }
        }
    }
}

/// A zstd level outside zstd's range is refused before anything is written, for both
/// compressed modes, with the level in the message; the range's own ends are accepted.
#[test]
fn zstd_level_outside_the_range_is_refused() {
    assert_eq!(Compression::None.zstd_level(), None);
    assert_eq!(Compression::Zstd { level: 5 }.zstd_level(), Some(5));
    assert_eq!(Compression::ZstdShuffle { level: 7 }.zstd_level(), Some(7));
    let d = dir();
    let info = info(4, 4, 8, Channels::Rgb);
    let range = zstd::compression_level_range();
    let path = d.path().join("z.sbrdf");
    for level in [*range.end() + 1, *range.start() - 1] {
        for compression in [
            Compression::Zstd { level },
            Compression::ZstdShuffle { level },
        ] {
            let options = StoreOptions {
                compression,
                ..StoreOptions::default()
            };
            let e = StoreWriter::create(&path, info.clone(), options)
                .err()
                .unwrap_or_else(|| panic!("{compression:?} accepted"));
            let msg = e.to_string();
            assert!(
                matches!(e, Error::StoreUsage { .. })
                    && msg.contains(&format!("zstd level {level} outside"))
                    && msg.contains("z.sbrdf"),
                "{compression:?}: {msg}"
            );
            assert!(only_file(d.path()).is_empty(), "{compression:?}");
        }
    }
    for level in [*range.start(), *range.end()] {
        let options = StoreOptions {
            compression: Compression::Zstd { level },
            ..StoreOptions::default()
        };
        let rows: Vec<Vec<f32>> = (0..2).map(|s| material(&info, s)).collect();
        write_materials(&path, &info, &rows, options, 1000).unwrap();
        assert_eq!(
            Store::open(&path).unwrap().n_materials(),
            2,
            "level {level}"
        );
    }
}

/// The size announced before writing an uncompressed store (what `synth` and `import` check
/// against the free space) is the file's size, up to its JSON header's padding; compressed
/// stores have no size before writing; an output its file system cannot hold is refused. An
/// opened store reports the file's size.
#[test]
fn uncompressed_size_is_known_before_writing() {
    let d = dir();
    let info = info(8, 8, 16, Channels::Rgb);
    let rows: Vec<Vec<f32>> = (0..5).map(|s| material(&info, s)).collect();
    for dtype in [Dtype::F32, Dtype::F16] {
        for chunk_len in [None, Some(100)] {
            let options = StoreOptions {
                dtype,
                chunk_len,
                ..StoreOptions::default()
            };
            let path = d.path().join("s.sbrdf");
            write_materials(&path, &info, &rows, options.clone(), 1000).unwrap();
            let actual = std::fs::metadata(&path).unwrap().len();
            let announced = options.uncompressed_bytes(5, info.d()).unwrap();
            let values = (5 * info.d() * dtype.size()) as u64;
            assert!(
                announced >= values && announced.abs_diff(actual) <= 4096 + actual / 100,
                "{dtype:?} {chunk_len:?}: announced {announced}, wrote {actual}"
            );
            // Exactly: the file is the announced payload offset, values and chunk table, then
            // the JSON header, whose length the fixed prefix records (its 5th u64 field, after
            // magic and version: payload offset, payload bytes, table offset, header offset,
            // header length).
            let bytes = std::fs::read(&path).unwrap();
            let field =
                |i: usize| u64::from_le_bytes(bytes[16 + 8 * i..24 + 8 * i].try_into().unwrap());
            assert_eq!(
                announced + field(4),
                actual,
                "{dtype:?} {chunk_len:?}: announced {announced} + header {}",
                field(4)
            );
            assert_eq!(announced, field(0) + field(1), "{dtype:?} {chunk_len:?}");
            assert_eq!(Store::open(&path).unwrap().file_bytes(), actual);
        }
    }
    let zstd = StoreOptions {
        compression: Compression::Zstd { level: 3 },
        ..StoreOptions::default()
    };
    assert_eq!(zstd.uncompressed_bytes(5, info.d()), None);
    let out = d.path().join("huge.sbrdf");
    let e = brdf_io::output::ensure_space(&out, u64::MAX, "the store").unwrap_err();
    assert!(
        matches!(e, Error::NoSpace { .. }) && e.to_string().contains("huge.sbrdf"),
        "{e}"
    );
    brdf_io::output::ensure_space(&out, 1, "the store").unwrap();
    brdf_io::output::ensure_space(Path::new("-"), u64::MAX, "the store").unwrap();
}

/// `add_materials_overlapped` writes what `add_material` writes, byte for byte, and stops at
/// the first error, its loader's or its writer's, leaving no file.
#[test]
fn overlapped_material_writes_match_and_stop_at_the_first_error() {
    let tmp = dir();
    let info = info(4, 5, 6, Channels::Spectral(vec![450.0, 550.0, 650.0]));
    let rows: Vec<_> = (0..6).map(|i| material(&info, i)).collect();
    let plain = tmp.path().join("plain.sbrdf");
    write_materials(&plain, &info, &rows, StoreOptions::default(), usize::MAX).unwrap();
    let overlapped = tmp.path().join("overlapped.sbrdf");
    let mut w = StoreWriter::create(&overlapped, info.clone(), StoreOptions::default()).unwrap();
    let mut asked = Vec::new();
    w.add_materials_overlapped(
        rows.len(),
        |i| -> Result<_, String> {
            asked.push(i);
            Ok((format!("mat{i}"), format!("test:{i}"), rows[i].clone()))
        },
        |e| e.to_string(),
    )
    .unwrap();
    w.finish().unwrap();
    assert_eq!(asked, [0, 1, 2, 3, 4, 5]);
    assert_eq!(
        std::fs::read(&plain).unwrap(),
        std::fs::read(&overlapped).unwrap()
    );

    // The loader fails at material 2: nothing after it is asked for, and nothing is left.
    let sub = tempfile::tempdir().unwrap();
    let out = sub.path().join("loader.sbrdf");
    let mut w = StoreWriter::create(&out, info.clone(), StoreOptions::default()).unwrap();
    let mut asked = Vec::new();
    let e = w
        .add_materials_overlapped(
            rows.len(),
            |i| {
                asked.push(i);
                if i == 2 {
                    return Err(format!("cannot load {i}"));
                }
                Ok((format!("mat{i}"), String::new(), rows[i].clone()))
            },
            |e| e.to_string(),
        )
        .unwrap_err();
    assert_eq!(e, "cannot load 2");
    assert_eq!(asked, [0, 1, 2]);
    drop(w);
    assert!(only_file(sub.path()).is_empty());

    // The writer fails on material 1 (a non-finite value): its error comes back through
    // `write_error`, the loader stops soon after (at most two materials ahead), and the writer
    // stays failed.
    let out = sub.path().join("writer.sbrdf");
    let mut w = StoreWriter::create(&out, info.clone(), StoreOptions::default()).unwrap();
    let mut asked = Vec::new();
    let e = w
        .add_materials_overlapped(
            rows.len(),
            |i| -> Result<_, String> {
                asked.push(i);
                let mut row = rows[i].clone();
                if i == 1 {
                    row[0] = f32::NAN;
                }
                Ok((format!("mat{i}"), String::new(), row))
            },
            |e| format!("writer: {e}"),
        )
        .unwrap_err();
    assert!(e.starts_with("writer: ") && e.contains("mat1"), "{e}");
    assert!(asked.len() <= 4, "{asked:?}");
    assert!(w.finish().is_err());
    assert!(only_file(sub.path()).is_empty());
}

/// Merging statistics weights the means by their counts, and merging two empty ones keeps
/// the empty mean (0, not the NaN of 0 / 0).
#[test]
fn value_stats_merge_weights_means_and_keeps_empty_ones_finite() {
    use brdf_io::store::ValueStats;
    let mut empty = ValueStats::default();
    empty.merge(&ValueStats::default());
    assert_eq!((empty.count, empty.mean), (0, 0.0));
    let a = ValueStats {
        count: 3,
        min: -1.0,
        max: 2.0,
        mean: 1.0,
        sum_sq: 6.0,
        negatives: 1,
        ..ValueStats::default()
    };
    let b = ValueStats {
        count: 1,
        min: 0.5,
        max: 5.0,
        mean: 5.0,
        sum_sq: 25.0,
        ..ValueStats::default()
    };
    let mut m = a.clone();
    m.merge(&b);
    assert_eq!(
        (m.count, m.mean, m.min, m.max, m.sum_sq, m.negatives),
        (4, 2.0, -1.0, 5.0, 31.0, 1)
    );
    // An empty side changes nothing.
    let mut same = a.clone();
    same.merge(&ValueStats::default());
    assert_eq!(same, a);
}

/// A checksum prints as `algorithm:value`, as model files record their dataset's.
#[test]
fn checksum_displays_as_algorithm_and_value() {
    let c = brdf_io::store::Checksum {
        algorithm: "xxh3-64".into(),
        value: "a5d06b176ea1a16a".into(),
    };
    assert_eq!(c.to_string(), "xxh3-64:a5d06b176ea1a16a");
}

/// Without a chunk length, a chunk holds about 1 MiB of values uncompressed and 256 KiB
/// under zstd (at most one index of N values under the target), at least one index and at
/// most the whole of d; an explicit length is kept (within 1..=d).
#[test]
fn default_chunk_length_targets_1_mib_or_256_kib() {
    for (compression, target) in [
        (Compression::None, 1usize << 20),
        (Compression::Zstd { level: 3 }, 256 << 10),
        (Compression::ZstdShuffle { level: 3 }, 256 << 10),
    ] {
        for dtype in [Dtype::F32, Dtype::F16] {
            for n in [1usize, 7, 51] {
                let o = StoreOptions {
                    compression,
                    dtype,
                    ..StoreOptions::default()
                };
                let len = o.effective_chunk_len(n, 1 << 30);
                let index_bytes = n * dtype.size();
                assert!(
                    len * index_bytes <= target && (len + 1) * index_bytes > target,
                    "{compression:?} {dtype:?} n {n}: {len}"
                );
                assert_eq!(o.effective_chunk_len(n, 10), 10, "capped at d");
                assert_eq!(o.effective_chunk_len(1 << 30, 10), 1, "at least one index");
            }
        }
    }
    let o = StoreOptions {
        chunk_len: Some(100),
        ..StoreOptions::default()
    };
    assert_eq!(o.effective_chunk_len(51, 1000), 100);
    assert_eq!(o.effective_chunk_len(51, 40), 40);
}

/// The benchmarks' read baseline returns the file's size in bytes and a positive, finite
/// time; a missing file is an error.
#[test]
fn sequential_read_reports_the_file_size_and_a_positive_time() {
    let d = dir();
    let path = d.path().join("r.bin");
    let len = (8 << 20) + 12345;
    std::fs::write(&path, vec![7u8; len]).unwrap();
    let (bytes, seconds) = brdf_io::store::sequential_read_seconds(&path, 2).unwrap();
    assert_eq!(bytes, len as u64);
    assert!(seconds > 0.0 && seconds < 60.0, "{seconds}");
    assert!(brdf_io::store::sequential_read_seconds(&d.path().join("none"), 1).is_err());
}

/// A stored material knows its row: by index and by name.
#[test]
fn store_material_index_is_its_row() {
    let d = dir();
    let info = info(2, 2, 4, Channels::Rgb);
    let rows: Vec<Vec<f32>> = (0..3).map(|s| material(&info, s)).collect();
    let path = d.path().join("i.sbrdf");
    write_materials(&path, &info, &rows, StoreOptions::default(), 1000).unwrap();
    let store = std::sync::Arc::new(Store::open(&path).unwrap());
    for (i, name) in store.names().iter().enumerate() {
        assert_eq!(
            StoreMaterial::by_index(store.clone(), i).unwrap().index(),
            i
        );
        assert_eq!(StoreMaterial::new(store.clone(), name).unwrap().index(), i);
    }
    assert_eq!(store.names().len(), 3);
}
