//! Render plans: what a picture looks up, independent of the material.
//!
//! For a grid source ([`BrdfSource::grid`]) under the pre-integrated environment, everything a
//! render does per pixel before reading BRDF values (the pixel's geometry, its local frame,
//! the half/difference angles of the light's lookup and their interpolation stencil, the view
//! angle of the environment term) and every lookup of the environment table's quadrature depend
//! only on the scene (shape, image size, light direction, grid, table resolution), not on the
//! material. A plan records them once, with the cells they touch renumbered compactly; a render
//! then evaluates exactly those cells once ([`BrdfSource::eval_cell`], in index order, in
//! parallel), projects them to linear sRGB and combines them: a few multiply-adds per pixel.
//! A source whose [`BrdfSource::lookup`] is not multilinear keeps each cell's needed channels
//! and their logarithms instead; its lookups combine them channel by channel with the
//! per-pixel shader's kernel (`log_look_up`: the source's own lookup to rounding, exponentials
//! by `exp_lanes` with relative error below 1e-15), then project.
//!
//! Only images up to [`MAX_CACHED_PIXELS`] pixels are rendered through plans (larger ones are
//! shaded directly, faster and in a fraction of the memory), and the plans of recent scenes (up
//! to [`CACHED_PLANS`]) are kept for the process, so rendering another material of the same scene (latent-map
//! thumbnails, comparison sheets, moving through the latent space) skips the geometry. A plan
//! holds no BRDF value: every render evaluates its material's cells afresh. The arithmetic is
//! the per-pixel shader's, in the same order: planned and unplanned renders are identical
//! (under multilinear lookups; to rounding under others, see above).

use std::convert::Infallible;
use std::sync::{Arc, Mutex, PoisonError};

use brdf_io::lookup::cell_logs;
use brdf_io::source::eval_cells_in_order_by;
use brdf_io::{AngularGrid, BrdfSource, Channels, HalfDiff, Lookup, Vec3};
use predict::PredictedMaterial;
use rayon::prelude::*;

use super::{
    ENV_TABLE_MAX_DEGREES, EnvTable, EnvTableSpec, Sight, SphereOptions, basis, cell_place,
    check_finite, colour_weights, dot, log_look_up, project,
};
use crate::error::{Error, Result};
use crate::image::Image;

/// Scenes kept by the plan cache (least recently built first out).
pub const CACHED_PLANS: usize = 4;
/// Largest image (pixels) whose plan is cached (a 256 x 256 sphere's pixels take ~10 MB of it:
/// 184 B per covered pixel).
pub const MAX_CACHED_PIXELS: usize = 256 * 256;
/// Most environment-table directions (nodes x rings x azimuths) a plan records, 144 B each
/// (~150 MB; the default table has 2^15, the fast one 2^11): so the cache holds at most
/// ~0.6 GB. Larger tables are shaded without a plan, to the same values.
pub const MAX_PLANNED_TABLE_DIRECTIONS: usize = 1 << 20;

/// The shape a scene renders (with the parameters that change its geometry, as bits).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scene {
    /// [`super::render_sphere`].
    Sphere,
    /// [`super::render_plane`] with these `PlaneOptions` (view angle, distance).
    Plane {
        /// `PlaneOptions::view`, bits.
        view: u64,
        /// `PlaneOptions::distance`, bits.
        distance: u64,
    },
}

/// Everything a plan depends on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Key {
    scene: Scene,
    size: usize,
    /// `SphereOptions::light` (theta, phi), bits.
    light: [u64; 2],
    grid: AngularGrid,
    spec: EnvTableSpec,
    /// Whether the light is on (non-zero irradiance: its lookups touch cells).
    light_on: bool,
    /// Whether the environment term is on (its lookups touch cells).
    env: bool,
}

/// Eight (compact cell index, weight) pairs: an interpolation stencil.
type Stencil = [(u32, f64); 8];

/// One covered pixel's lookups.
struct PixelLookup {
    /// Column of the pixel in its row.
    x: u32,
    coverage: f64,
    /// cos theta_o in the local frame; <= 0: the point faces away and renders black.
    wo_z: f64,
    /// The view angle's place in the environment table (node below, fraction to the next).
    env_at: (u32, f64),
    /// cos theta_i of the light and the stencil of its lookup; `None` when the light is below
    /// the horizon or the pair has no half/difference angles (it adds nothing).
    light: Option<(f64, Stencil)>,
}

/// A scene's lookups; see the module docs.
struct Plan {
    key: Key,
    /// Flat grid index of each compact cell, ascending.
    cells: Vec<u32>,
    /// Per image row, its covered pixels left to right (built and used row by row, in
    /// parallel, never concatenated).
    rows: Vec<Vec<PixelLookup>>,
    /// Per environment-table node: each quadrature direction's weight and stencil.
    env: Vec<Vec<(f64, Option<Stencil>)>>,
}

static CACHE: Mutex<Vec<Arc<Plan>>> = Mutex::new(Vec::new());

/// The cached plan of `key`, or a new one from `build`, cached (the renderer plans only images
/// up to [`MAX_CACHED_PIXELS`]).
fn plan_for(key: Key, build: impl FnOnce() -> Plan) -> Arc<Plan> {
    let cached = |cache: &Vec<Arc<Plan>>| cache.iter().find(|p| p.key == key).cloned();
    if let Some(p) = cached(&CACHE.lock().unwrap_or_else(PoisonError::into_inner)) {
        return p;
    }
    let plan = Arc::new(build());
    let mut cache = CACHE.lock().unwrap_or_else(PoisonError::into_inner);
    if cached(&cache).is_none() {
        if cache.len() == CACHED_PLANS {
            cache.remove(0);
        }
        cache.push(plan.clone());
    }
    plan
}

/// The stencil (flat grid indices) of the lookup f(wi, wo), if both are above the horizon.
fn stencil(grid: &AngularGrid, wi: Vec3, wo: Vec3) -> Option<Stencil> {
    match HalfDiff::from_dirs(wi, wo) {
        Some(hd) if wi[2] > 0.0 && wo[2] > 0.0 => {
            Some(grid.interpolation_stencil(&hd).map(|(a, w)| (a as u32, w)))
        }
        _ => None,
    }
}

impl Plan {
    fn build(
        key: Key,
        light: Vec3,
        sight: &(dyn Fn(usize, usize) -> Option<Sight> + Sync),
    ) -> Self {
        let (grid, size) = (key.grid, key.size);
        let theta_max = ENV_TABLE_MAX_DEGREES.to_radians();
        let mut rows: Vec<Vec<PixelLookup>> = (0..size)
            .into_par_iter()
            .map(|py| {
                (0..size)
                    .filter_map(|px| {
                        let (n, view, coverage) = sight(px, py)?;
                        let (t, b) = basis(n);
                        let local = |v: Vec3| [dot(v, t), dot(v, b), dot(v, n)];
                        let wo = local(view);
                        let wi = local(light);
                        let light = (key.light_on && wo[2] > 0.0 && wi[2] > 0.0)
                            .then(|| stencil(&grid, wi, wo).map(|s| (wi[2], s)))
                            .flatten();
                        let env_at = if key.env && wo[2] > 0.0 {
                            let (i, t) = EnvTable::position(wo[2], key.spec.nodes, theta_max);
                            (i as u32, t)
                        } else {
                            (0, 0.0)
                        };
                        Some(PixelLookup {
                            x: px as u32,
                            coverage,
                            wo_z: wo[2],
                            env_at,
                            light,
                        })
                    })
                    .collect()
            })
            .collect();
        let mut env: Vec<Vec<(f64, Option<Stencil>)>> = Vec::new();
        if key.env {
            let q = key.spec.quadrature();
            env = (0..key.spec.nodes)
                .into_par_iter()
                .map(|k| {
                    let wo = EnvTable::node_view(k, key.spec.nodes, theta_max);
                    let mut dirs = Vec::new();
                    q.for_each(wo, |wi, w| dirs.push((w, stencil(&grid, wi, wo))));
                    dirs
                })
                .collect();
        }
        // Renumber the cells with a non-zero weight compactly, in index order (zero-weight
        // entries are skipped when shading, like the shader's, and point at cell 0).
        let stencils = || {
            let px = rows
                .iter()
                .flatten()
                .filter_map(|p| p.light.as_ref().map(|l| &l.1));
            px.chain(env.iter().flatten().filter_map(|(_, s)| s.as_ref()))
        };
        let mut compact = vec![u32::MAX; grid.len()];
        for s in stencils() {
            for &(a, w) in s {
                if w != 0.0 {
                    compact[a as usize] = 0;
                }
            }
        }
        let mut cells = Vec::new();
        for (a, c) in compact.iter_mut().enumerate() {
            if *c == 0 {
                *c = cells.len() as u32;
                cells.push(a as u32);
            }
        }
        let renumber = |s: &mut Stencil| {
            for (a, w) in s.iter_mut() {
                *a = if *w != 0.0 { compact[*a as usize] } else { 0 };
            }
        };
        rows.iter_mut()
            .flatten()
            .filter_map(|p| p.light.as_mut())
            .for_each(|l| renumber(&mut l.1));
        env.iter_mut()
            .flatten()
            .filter_map(|(_, s)| s.as_mut())
            .for_each(renumber);
        Self {
            key,
            cells,
            rows,
            env,
        }
    }
}

/// The plan's cells of k materials, as their lookups read them: cell after cell, each with the
/// k materials' entries one after the other ([`Member`] reads one material's).
enum Cells {
    /// Multilinear lookups: each cell's linear sRGB (the projection is linear, so
    /// interpolating projected cells is projecting the interpolated values).
    Colours(Vec<[f64; 3]>),
    /// Logarithmic lookups ([`Lookup::LogMultilinear`]), which are not linear in the cells:
    /// each cell's needed channels and their logarithms ([`cell_logs`]), apart (a lookup reads
    /// the logarithms, the values only where one is NaN: fewer bytes and cache lines per
    /// lookup); a lookup combines them channel by channel ([`log_look_up`]) and projects the
    /// result.
    Logs {
        /// Needed channels per cell.
        m: usize,
        /// m values per cell and material.
        values: Vec<f64>,
        /// m logarithms per cell and material (NaN where the value is not positive).
        logs: Vec<f64>,
    },
}

/// A lookup's working space for [`Cells::Logs`] (one per parallel task).
struct Scratch {
    f: Vec<f64>,
}

/// Material `j` of the `k` whose cells a [`Cells`] holds (cell `a`'s entry of it at `a * k +
/// j`).
struct Member<'t> {
    cells: &'t Cells,
    k: usize,
    j: usize,
}

impl Member<'_> {
    fn scratch(&self) -> Scratch {
        match self.cells {
            Cells::Colours(_) => Scratch { f: Vec::new() },
            Cells::Logs { m, .. } => Scratch { f: vec![0.0; *m] },
        }
    }

    /// Linear sRGB interpolated from the material's cells (`columns`: the linear-sRGB weights
    /// of each needed channel, for [`Cells::Logs`]).
    fn interpolate(&self, s: &Stencil, columns: &[[f64; 3]], scratch: &mut Scratch) -> [f64; 3] {
        let (k, j) = (self.k, self.j);
        match self.cells {
            Cells::Colours(colours) => {
                let mut rgb = [0.0; 3];
                for &(a, w) in s {
                    if w == 0.0 {
                        continue;
                    }
                    let cell = colours[a as usize * k + j];
                    (0..3).for_each(|c| rgb[c] += w * cell[c]);
                }
                rgb
            }
            Cells::Logs { m, values, logs } => {
                let stencil = s.iter().map(|&(a, w)| (a as usize, w));
                let cell = |a: usize| {
                    let e = a * k + j;
                    let at = e * m..(e + 1) * m;
                    Ok::<_, Infallible>((&values[at.clone()], &logs[at]))
                };
                let Ok(()) = log_look_up(stencil, cell, &mut scratch.f);
                // `project`'s sums, the three rows in one pass (each row's terms in the same
                // order); negative values count as 0.
                let mut rgb = [0.0; 3];
                for (c, f) in columns.iter().zip(&scratch.f) {
                    let f = f.max(0.0);
                    (0..3).for_each(|r| rgb[r] += c[r] * f);
                }
                rgb
            }
        }
    }
}

/// The materials a planned render evaluates: one source, or predictions of one model whose
/// cells are evaluated together ([`PredictedMaterial::eval_cell_each`]: each cell's stored
/// values read once for all of them).
pub(super) enum Materials<'a> {
    /// One source.
    One(&'a dyn BrdfSource),
    /// Predictions that share their cells ([`PredictedMaterial::shares_cells`]).
    Predicted {
        /// The first of them as a source: its hints serve all (they read the same cells).
        first: &'a dyn BrdfSource,
        /// All of them, in order.
        members: Vec<&'a PredictedMaterial>,
    },
}

impl Materials<'_> {
    fn len(&self) -> usize {
        match self {
            Materials::One(_) => 1,
            Materials::Predicted { members, .. } => members.len(),
        }
    }

    /// The source that takes the hints (its channels and lookup are all materials').
    fn hints(&self) -> &dyn BrdfSource {
        match self {
            Materials::One(source) => *source,
            Materials::Predicted { first, .. } => *first,
        }
    }

    /// Values of cell `a` for every material, one after the other, into `f`.
    fn eval(&self, a: usize, f: &mut [f64]) -> Result<()> {
        match self {
            Materials::One(source) => Ok(source.eval_cell(a, f)?),
            Materials::Predicted { members, .. } => {
                PredictedMaterial::eval_cell_each(members, a, f).map_err(|e| {
                    Error::InvalidArgument {
                        reason: e.to_string(),
                    }
                })
            }
        }
    }
}

/// Most bytes of evaluated cells ([`Cells`]) a batch of materials keeps at once: more
/// materials than that takes are evaluated in several passes over the plan's cells (a
/// multilinear lookup keeps 24 bytes a cell, a logarithmic one 16 per needed channel).
const MAX_BATCH_CELL_BYTES: usize = 256 << 20;

/// Renders the scene `sight` of grid sources with the pre-integrated environment of `spec`
/// through its plan (see the module docs), one image per material of `materials` (all with the
/// channels and lookup of the source that takes the hints), each the image a render of it
/// alone gives. `opts` must be checked.
pub(super) fn render(
    materials: &Materials<'_>,
    opts: &SphereOptions,
    grid: AngularGrid,
    spec: EnvTableSpec,
    scene: Scene,
    sight: &(dyn Fn(usize, usize) -> Option<Sight> + Sync),
) -> Result<Vec<Image>> {
    let (channels, lookup) = (&materials.hints().channels(), materials.hints().lookup());
    let (weights, needed) = colour_weights(channels, opts.illuminant)?;
    let key = Key {
        scene,
        size: opts.size,
        light: [opts.light.0.to_bits(), opts.light.1.to_bits()],
        grid,
        spec,
        light_on: opts.light_irradiance != 0.0,
        env: opts.env_radiance > 0.0,
    };
    let plan = plan_for(key, || Plan::build(key, opts.light_dir(), sight));
    let m = needed.len();
    let columns: Vec<[f64; 3]> = (0..m)
        .map(|c| [weights[0][c], weights[1][c], weights[2][c]])
        .collect();
    // The materials' cells, as many at a time as fit `MAX_BATCH_CELL_BYTES`, each pass's
    // spheres shaded before the next pass.
    let mut images = Vec::with_capacity(materials.len());
    let mut pass = |part: &Materials<'_>| -> Result<()> {
        #[cfg(test)]
        PASSES.with(|p| p.set(p.get() + 1));
        let cells = evaluate(&plan, part, channels, lookup, &weights, &needed)?;
        let k = part.len();
        for j in 0..k {
            let member = Member {
                cells: &cells,
                k,
                j,
            };
            images.push(shade(&plan, &member, &columns, opts));
        }
        Ok(())
    };
    let group = batch_size(lookup, plan.cells.len(), m, max_batch_cell_bytes());
    match materials {
        Materials::Predicted { first, members } if members.len() > group => {
            for members in members.chunks(group) {
                pass(&Materials::Predicted {
                    first: *first,
                    members: members.to_vec(),
                })?;
            }
        }
        _ => pass(materials)?,
    }
    Ok(images)
}

/// The cells of `plan` evaluated for all of `materials` (one pass over the plan's cells) as
/// their lookups read them (`weights`, `needed`: the colour projection of `channels`).
fn evaluate(
    plan: &Plan,
    materials: &Materials<'_>,
    channels: &Channels,
    lookup: Lookup,
    weights: &[Vec<f64>; 3],
    needed: &[usize],
) -> Result<Cells> {
    let (k, m, nc) = (materials.len(), needed.len(), channels.len());
    let grid = plan.key.grid;
    // Each planned cell evaluated once for all materials, in parallel (chunks of `CHUNK`
    // cells), into what their lookups read: `keep(i, f)` keeps the i-th cell of the chunk
    // from the materials' channels `f` (k x nc values).
    const CHUNK: usize = 256;
    let eval_chunk = |chunk: &[u32], keep: &mut dyn FnMut(usize, &[f64])| -> Result<()> {
        eval_cells_in_order_by(
            materials.hints(),
            k * nc,
            |a, f| materials.eval(a, f),
            chunk,
            |&a| a as usize,
            |i, &a, f| {
                for f in f.chunks_exact(nc.max(1)) {
                    check_finite(f, needed, channels, || cell_place(&grid, a as usize))?;
                }
                keep(i, f);
                Ok(())
            },
        )
    };
    let n_cells = plan.cells.len();
    Ok(match lookup {
        Lookup::Multilinear => {
            // Cell after cell, each the k materials' colours.
            let mut colours = vec![[0.0; 3]; n_cells * k];
            plan.cells
                .par_chunks(CHUNK)
                .zip(colours.par_chunks_mut(CHUNK * k))
                .try_for_each(|(chunk, colours)| {
                    eval_chunk(chunk, &mut |i, f| {
                        for (j, f) in f.chunks_exact(nc.max(1)).enumerate() {
                            colours[i * k + j] = project(weights, needed, f, 1.0);
                        }
                    })
                })?;
            Cells::Colours(colours)
        }
        Lookup::LogMultilinear => {
            // Cell after cell, each the k materials' m needed values (and their logarithms).
            let per_cell = k * m;
            let mut values = vec![0.0; n_cells * per_cell];
            let mut logs = vec![0.0; n_cells * per_cell];
            plan.cells
                .par_chunks(CHUNK)
                .zip(values.par_chunks_mut(CHUNK * per_cell.max(1)))
                .zip(logs.par_chunks_mut(CHUNK * per_cell.max(1)))
                .try_for_each(|((chunk, values), logs)| {
                    eval_chunk(chunk, &mut |i, f| {
                        for (j, f) in f.chunks_exact(nc.max(1)).enumerate() {
                            let at = (i * k + j) * m..(i * k + j + 1) * m;
                            let v = &mut values[at.clone()];
                            v.iter_mut().zip(needed).for_each(|(v, &c)| *v = f[c]);
                            cell_logs(v, &mut logs[at]);
                        }
                    })
                })?;
            Cells::Logs { m, values, logs }
        }
    })
}

/// How many materials' cells (of a plan of `cells` cells, `m` needed channels) one pass of
/// [`render`] keeps under `lookup`: as many as fit `max_bytes`, at least one.
fn batch_size(lookup: Lookup, cells: usize, m: usize, max_bytes: usize) -> usize {
    let per_material = match lookup {
        Lookup::Multilinear => 24 * cells,
        Lookup::LogMultilinear => 16 * m * cells,
    };
    (max_bytes / per_material.max(1)).max(1)
}

/// [`MAX_BATCH_CELL_BYTES`], or in tests [`BATCH_BYTES_IN_TESTS`] when that is set.
fn max_batch_cell_bytes() -> usize {
    #[cfg(test)]
    if let bytes @ 1.. = BATCH_BYTES_IN_TESTS.load(std::sync::atomic::Ordering::Relaxed) {
        return bytes;
    }
    MAX_BATCH_CELL_BYTES
}

/// In tests, a [`MAX_BATCH_CELL_BYTES`] small enough to split a few thumbnails into passes (0:
/// the constant). The images do not depend on it, so tests running meanwhile are unaffected.
#[cfg(test)]
pub(super) static BATCH_BYTES_IN_TESTS: std::sync::atomic::AtomicUsize =
    std::sync::atomic::AtomicUsize::new(0);

#[cfg(test)]
thread_local! {
    /// In tests, the passes [`render`] has made on this thread (each evaluates the plan's
    /// cells for one group of materials).
    pub(super) static PASSES: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
}

/// The image of one material's evaluated `cells` under `plan` (`columns`: the linear-sRGB
/// weights of each needed channel).
fn shade(plan: &Plan, cells: &Member<'_>, columns: &[[f64; 3]], opts: &SphereOptions) -> Image {
    let key = plan.key;
    let table = key.env.then(|| EnvTable {
        theta_max: ENV_TABLE_MAX_DEGREES.to_radians(),
        rgb: plan
            .env
            .par_iter()
            .map_init(
                || cells.scratch(),
                |scratch, dirs| {
                    let mut acc = [0.0; 3];
                    for (w, s) in dirs {
                        let rgb = s
                            .as_ref()
                            .map_or([0.0; 3], |s| cells.interpolate(s, columns, scratch));
                        (0..3).for_each(|c| acc[c] += w * rgb[c]);
                    }
                    acc.map(|v| opts.env_radiance * v)
                },
            )
            .collect(),
    });
    let (scale, e) = (2f64.powf(opts.exposure), opts.light_irradiance);
    let shade = |p: &PixelLookup, scratch: &mut Scratch| {
        let mut acc = [0.0; 3];
        if p.wo_z <= 0.0 {
            return acc;
        }
        if let Some((cos_i, s)) = &p.light
            && e != 0.0
        {
            let rgb = cells.interpolate(s, columns, scratch);
            let k = cos_i * e;
            (0..3).for_each(|c| acc[c] += k * rgb[c]);
        }
        match &table {
            Some(t) => {
                let env = t.lerp((p.env_at.0 as usize, p.env_at.1));
                [0, 1, 2].map(|c| scale * (acc[c] + env[c]))
            }
            None => acc.map(|v| scale * v),
        }
    };
    let size = opts.size;
    let mut img = Image::new(size, size, [0.0; 3]);
    img.alpha.fill(0.0);
    img.rgb
        .par_chunks_mut(size)
        .zip(img.alpha.par_chunks_mut(size))
        .zip(&plan.rows)
        .for_each_init(
            || cells.scratch(),
            |scratch, ((rgb, alpha), row)| {
                for p in row {
                    rgb[p.x as usize] = shade(p, scratch);
                    alpha[p.x as usize] = p.coverage;
                }
            },
        );
    img
}

/// Drops the cached render plans (the next render of every scene rebuilds its plan): frees
/// their memory; benchmarks use it to time renders of a new scene.
pub fn clear_plans() {
    CACHE.lock().unwrap_or_else(PoisonError::into_inner).clear();
}

#[cfg(test)]
pub(super) fn cached_plans() -> usize {
    CACHE.lock().unwrap_or_else(PoisonError::into_inner).len()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A pass keeps as many materials as fit the bytes (24 per cell multilinear, 16 per needed
    /// channel and cell logarithmic), at least one; the map's 36 thumbnails of a plan of
    /// 100,000 cells (a 64 px sphere on 45 x 45 x 90) go in one pass under the default lookup.
    #[test]
    fn a_pass_keeps_the_materials_that_fit_its_bytes() {
        use Lookup::{LogMultilinear, Multilinear};
        assert_eq!(batch_size(Multilinear, 1000, 5, 240_000), 10);
        assert_eq!(batch_size(Multilinear, 1000, 5, 239_999), 9);
        assert_eq!(batch_size(LogMultilinear, 1000, 5, 240_000), 3);
        assert_eq!(batch_size(LogMultilinear, 1000, 5, 79_999), 1);
        assert_eq!(batch_size(Multilinear, 1000, 5, 0), 1);
        assert_eq!(batch_size(Multilinear, 0, 5, 100), 100);
        assert!(batch_size(Multilinear, 100_000, 33, MAX_BATCH_CELL_BYTES) >= 36);
    }

    /// A lookup's stencil is the grid's interpolation stencil when both directions are above
    /// the horizon, and none when either lies on it or below (grid sources read 0 there).
    #[test]
    fn stencils_only_above_the_horizon() {
        let grid = AngularGrid::new(8, 8, 16).unwrap();
        let (wi, wo) = ([0.6, 0.0, 0.8], [-0.48, 0.36, 0.8]);
        let hd = HalfDiff::from_dirs(wi, wo).unwrap();
        let expected = grid.interpolation_stencil(&hd).map(|(a, w)| (a as u32, w));
        assert_eq!(stencil(&grid, wi, wo), Some(expected));
        for low in [[0.8, 0.6, 0.0], [0.8, 0.0, -1e-3]] {
            assert!(HalfDiff::from_dirs(low, wo).is_some());
            assert_eq!(stencil(&grid, low, wo), None, "wi {low:?}");
            assert_eq!(stencil(&grid, wi, low), None, "wo {low:?}");
        }
    }
}
