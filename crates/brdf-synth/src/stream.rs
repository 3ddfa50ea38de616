//! Streaming a synthetic dataset into a `.sbrdf` store: any grid size, never more than one
//! block of cells (about 16 MB of f32 values for all materials) in memory, plus each thread's
//! [`FresnelCache`]s (up to 1 MiB per material).

use std::path::Path;

use brdf_io::store::StoreHeader;
use brdf_io::{AngularGrid, Channels, StoreInfo, StoreOptions, StoreWriter};
use rayon::prelude::*;

use crate::dataset::prepare_all;
use crate::error::{Error, Result};
use crate::material::{FresnelCache, Material};

/// Values held in memory per block while streaming to a store (f32 values).
const BLOCK_VALUES: usize = 4 << 20;

/// Streams `materials` evaluated on `grid` x `channels` into a new store at `path` (written
/// to a temporary file and renamed into place). `progress` is called with the number of angular
/// cells completed so far (out of `grid.len()`). Only one block of cells (about 16 MB) of all
/// materials is in memory at a time.
pub fn write_store(
    path: &Path,
    materials: &[Material],
    grid: AngularGrid,
    channels: &Channels,
    options: StoreOptions,
    seed: u64,
    progress: impl FnMut(usize),
) -> Result<StoreHeader> {
    write_store_in_blocks(
        path,
        materials,
        grid,
        channels,
        options,
        seed,
        BLOCK_VALUES,
        progress,
    )
}

/// [`write_store`] holding about `block_values` values in memory per block (tests use small
/// blocks to cover several).
#[allow(clippy::too_many_arguments)]
fn write_store_in_blocks(
    path: &Path,
    materials: &[Material],
    grid: AngularGrid,
    channels: &Channels,
    options: StoreOptions,
    seed: u64,
    block_values: usize,
    mut progress: impl FnMut(usize),
) -> Result<StoreHeader> {
    let store_err = |source| Error::Store {
        path: path.to_owned(),
        source,
    };
    if materials.is_empty() {
        return Err(Error::InvalidRequest {
            reason: "no materials to write".into(),
        });
    }
    let prepared = prepare_all(materials, channels)?;
    let n = materials.len();
    let nc = channels.len();
    let info = StoreInfo {
        grid,
        channels: channels.clone(),
    };
    let mut writer = StoreWriter::create(path, info, options).map_err(store_err)?;
    let sources: Vec<(String, String)> = materials
        .iter()
        .map(|m| {
            (
                m.name.clone(),
                format!("brdf-synth preset seed {seed} ({:?})", m.family),
            )
        })
        .collect();
    writer.declare_materials(&sources).map_err(store_err)?;
    let cells_per_block = (block_values / (n * nc)).max(1);
    // Each block is cut into one part per thread; part p of every block remembers its
    // materials' Fresnel reflectances in caches[p] (the grid's few distinct cos(theta_d)).
    let parts = rayon::current_num_threads().max(1);
    let mut caches: Vec<Vec<FresnelCache>> = (0..parts)
        .map(|_| (0..n).map(|_| FresnelCache::new()).collect())
        .collect();
    let mut block = Vec::new();
    let mut start = 0;
    while start < grid.len() {
        let end = (start + cells_per_block).min(grid.len());
        block.clear();
        block.resize((end - start) * nc * n, 0.0f32);
        let cells_per_part = (end - start).div_ceil(parts);
        // Index-major: for cell c and channel l, the N materials are contiguous.
        block
            .par_chunks_mut(cells_per_part * nc * n)
            .zip(caches.par_iter_mut())
            .enumerate()
            .for_each(|(p, (part, caches))| {
                let mut scratch = vec![0.0f64; nc];
                for (k, out) in part.chunks_mut(nc * n).enumerate() {
                    let hd = grid.bin_centre_flat(start + p * cells_per_part + k);
                    if !hd.is_above_horizon() {
                        continue;
                    }
                    // The cell's directions, for every material.
                    let (wi, wo) = hd.to_dirs();
                    for (mi, (m, cache)) in prepared.iter().zip(caches.iter_mut()).enumerate() {
                        m.eval_cached(wi, wo, &mut scratch, cache);
                        for (l, v) in scratch.iter().enumerate() {
                            out[l * n + mi] = *v as f32;
                        }
                    }
                }
            });
        writer
            .write_block(start * nc..end * nc, &block)
            .map_err(store_err)?;
        start = end;
        progress(start);
    }
    writer.finish().map_err(store_err)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::generate;
    use crate::preset::preset;
    use brdf_io::Store;

    #[test]
    fn store_round_trip_matches_in_memory_generation() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("synth.sbrdf");
        let grid = AngularGrid::new(6, 5, 8).unwrap();
        let channels = Channels::parse_wavelengths("400:700:100").unwrap();
        let mats = preset(2);
        // Small chunks so several chunks are exercised (blocks: below).
        let options = StoreOptions {
            chunk_len: Some(50),
            ..StoreOptions::default()
        };
        let mut calls = Vec::new();
        let header = write_store(
            &path,
            &mats[..7],
            grid,
            &channels,
            options.clone(),
            2,
            |done| calls.push(done),
        )
        .unwrap();
        assert_eq!(header.n_materials(), 7);
        // 7 x 4 x 240 values: one block of about 4 Mi values.
        assert_eq!(calls, [grid.len()]);
        let expect = generate(&mats[..7], grid, &channels).unwrap();
        let store = Store::open(&path).unwrap();
        assert_eq!(store.n_materials(), 7);
        assert_eq!(store.d(), expect.d());
        assert_eq!(
            store.names(),
            expect.names.iter().map(|s| s.as_str()).collect::<Vec<_>>()
        );
        let mut row = vec![0.0f32; store.d()];
        for m in 0..7 {
            store.material_row(m, 0..store.d(), &mut row).unwrap();
            for (a, b) in row.iter().zip(expect.row(m)) {
                assert_eq!(*a, *b as f32);
            }
        }
        // Nothing but the store is left in the directory.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);

        // Blocks of 17 cells (7 materials x 4 wavelengths x 17), the last one partial: the
        // same values, reported block by block.
        let small = dir.path().join("blocks.sbrdf");
        let mut calls = Vec::new();
        let block_values = 7 * 4 * 17 + 5;
        write_store_in_blocks(
            &small,
            &mats[..7],
            grid,
            &channels,
            options,
            2,
            block_values,
            |done| calls.push(done),
        )
        .unwrap();
        let want: Vec<usize> = (1..=14).map(|b| 17 * b).chain([240]).collect();
        assert_eq!(calls, want);
        let blocks = Store::open(&small).unwrap();
        let mut block_row = vec![0.0f32; store.d()];
        for m in 0..7 {
            store.material_row(m, 0..store.d(), &mut row).unwrap();
            blocks
                .material_row(m, 0..store.d(), &mut block_row)
                .unwrap();
            assert!(row == block_row, "material {m}");
        }
    }

    #[test]
    fn rgb_channels_are_refused_without_leaving_a_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.sbrdf");
        let grid = AngularGrid::new(2, 2, 2).unwrap();
        let err = write_store(
            &path,
            &preset(0),
            grid,
            &Channels::Rgb,
            StoreOptions::default(),
            0,
            |_| {},
        )
        .unwrap_err();
        assert!(err.to_string().contains("spectral"), "{err}");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }
}
