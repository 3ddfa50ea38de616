//! Directional albedo of any [`BrdfSource`]: the fraction of the light arriving from one
//! direction that the surface reflects, per channel,
//!
//! rho(wi) = integral over the hemisphere of f(wi, wo) cos theta_o dwo.
//!
//! A physically plausible BRDF has rho <= 1 at every incidence (a fluorescent material can
//! exceed 1 in a channel, shifting light from other wavelengths, which a BRDF cannot express);
//! above 1 it creates energy, and a path tracer's paths gain energy at every bounce (a white
//! furnace test glows). A white
//! Lambertian (f = 1/pi) has rho = 1. With [`BrdfSource`]'s argument order (`wi` = Mitsuba's
//! `si.wi`), rho is also the expected weight of a path tracer's BSDF sample, which is what
//! decides whether a material gains energy in a renderer; for reciprocal data (MERL, stored and
//! predicted materials) the two directions' roles do not matter.
//!
//! The integral runs over the half vector m (wo = wi reflected about m, dwo = 4 (wi . m) dm), on
//! a midpoint grid in the RGL format's coordinates (u = sqrt(2 theta_m / pi), phi_m) whose nodes
//! crowd towards the mirror direction, so a sharp specular peak is integrated as well as a
//! broad lobe ([`AlbedoNodes`]). The RGL writer checks its files with the same nodes.

use std::sync::OnceLock;

use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::grid::{AngularGrid, Channels, HalfDiff, Vec3};
use crate::lookup::{Lookup, cell_record, look_up};
use crate::source::{BrdfSource, eval_cells_in_order};

/// Nodes per axis of the half-vector grid by default ([`AlbedoNodes::new`]): 96 x 96.
pub const DEFAULT_RESOLUTION: usize = 96;

/// An albedo above 1 by more than this counts as energy gain ([`gains_energy`]): above the
/// quadrature's error (at most 0.4 % on the synthetic presets at 0-88 degrees, 1.5e-4 on a
/// Lambertian).
pub const ENERGY_MARGIN: f64 = 0.005;

/// Whether an albedo reflects more light than arrives, beyond the quadrature's error: strictly
/// above 1 + [`ENERGY_MARGIN`].
pub fn gains_energy(albedo: f64) -> bool {
    albedo > 1.0 + ENERGY_MARGIN
}

/// Quadrature nodes of the directional albedo at one incident direction: outgoing directions
/// `wo` above the horizon with weights `cos theta_o dwo`, so that `sum weight * f(wi, wo)`
/// estimates rho(wi).
#[derive(Debug, Clone, PartialEq)]
pub struct AlbedoNodes {
    wi: Vec3,
    nodes: Vec<(Vec3, f64)>,
}

impl AlbedoNodes {
    /// The nodes for incidence at elevation `theta_i` (radians, in the plane y = 0): half
    /// vectors on a `resolution` x `resolution` midpoint grid in (u = sqrt(2 theta_m / pi),
    /// phi_m), kept where wo, the reflection of wi about m, lies above the horizon. An isotropic
    /// source needs no other azimuth of wi.
    pub fn new(theta_i: f64, resolution: usize) -> Self {
        use std::f64::consts::{FRAC_PI_2, PI};
        let wi = direction(theta_i, 0.0);
        let n = resolution.max(1);
        let (du, dphi) = (1.0 / n as f64, 2.0 * PI / n as f64);
        let mut nodes = Vec::new();
        for i in 0..n {
            let u = (i as f64 + 0.5) * du;
            let tm = u * u * FRAC_PI_2;
            // dm = sin(theta_m) dtheta_m dphi, dtheta_m = pi u du.
            let dm = tm.sin() * PI * u * du * dphi;
            for j in 0..n {
                let m = direction(tm, (j as f64 + 0.5) * dphi);
                let dot = wi[0] * m[0] + wi[1] * m[1] + wi[2] * m[2];
                let wo = [0, 1, 2].map(|k| 2.0 * dot * m[k] - wi[k]);
                if !(dot > 0.0 && wo[2] > 0.0) {
                    continue;
                }
                nodes.push((wo, wo[2] * 4.0 * dot * dm));
            }
        }
        Self { wi, nodes }
    }

    /// The incident direction.
    pub fn wi(&self) -> Vec3 {
        self.wi
    }

    /// The outgoing directions and their weights (cos theta_o dwo), in a fixed order.
    pub fn nodes(&self) -> &[(Vec3, f64)] {
        &self.nodes
    }

    /// The nodes' lookups on `grid` gathered per cell: (flat cell index, weight), by cell, so
    /// that `sum weight * f(cell)` is the quadrature of the multilinear interpolant between the
    /// cells' values (what a grid source's `eval` returns, [`AngularGrid::interpolation_stencil`]).
    /// The integral is a linear functional over the few thousand cells the nodes touch: every
    /// material on the grid reuses it.
    pub fn cell_weights(&self, grid: &AngularGrid) -> Vec<(usize, f64)> {
        let mut dense = vec![0.0; grid.len()];
        for &(wo, w) in &self.nodes {
            let Some(hd) = HalfDiff::from_dirs(self.wi, wo) else {
                continue;
            };
            for (a, s) in grid.interpolation_stencil(&hd) {
                dense[a] += w * s;
            }
        }
        dense
            .into_iter()
            .enumerate()
            .filter(|(_, w)| *w != 0.0)
            .collect()
    }

    /// rho(wi) of `source` per channel into `out` (length: the source's channels), its values
    /// at the nodes summed in order ([`directional_albedo`] reads a grid source's cells once
    /// instead).
    pub fn integrate(&self, source: &dyn BrdfSource, out: &mut [f64]) -> Result<()> {
        crate::source::check_output_len(out, source.channels().len())?;
        let mut f = vec![0.0; out.len()];
        out.fill(0.0);
        for &(wo, w) in &self.nodes {
            source.eval(self.wi, wo, &mut f)?;
            for (a, v) in out.iter_mut().zip(&f) {
                *a += w * v;
            }
        }
        Ok(())
    }
}

/// The unit direction of elevation `theta` and azimuth `phi`.
pub(crate) fn direction(theta: f64, phi: f64) -> Vec3 {
    let (s, c) = theta.sin_cos();
    [s * phi.cos(), s * phi.sin(), c]
}

/// Directional albedo of a source at several incident elevations ([`directional_albedo`]).
#[derive(Debug, Clone, PartialEq)]
pub struct AlbedoTable {
    /// Incident elevations in degrees, as asked.
    pub angles_deg: Vec<f64>,
    /// The source's channels.
    pub channels: Channels,
    /// rho per elevation (rows) and channel (columns), row-major.
    pub values: Vec<f64>,
}

/// The largest albedo of an [`AlbedoTable`] and where it is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AlbedoPeak {
    /// The albedo.
    pub value: f64,
    /// Its elevation in degrees.
    pub angle_deg: f64,
    /// Its channel's index.
    pub channel: usize,
}

impl AlbedoTable {
    /// rho at elevation `k` (of [`AlbedoTable::angles_deg`]), one value per channel.
    pub fn row(&self, k: usize) -> &[f64] {
        let nc = self.channels.len();
        &self.values[k * nc..(k + 1) * nc]
    }

    /// The largest value over every elevation and channel (the first of equal ones); `None`
    /// for an empty table.
    pub fn peak(&self) -> Option<AlbedoPeak> {
        let nc = self.channels.len();
        let mut best: Option<AlbedoPeak> = None;
        for (i, &value) in self.values.iter().enumerate() {
            if best.is_none_or(|b| value > b.value) {
                best = Some(AlbedoPeak {
                    value,
                    angle_deg: self.angles_deg[i / nc],
                    channel: i % nc,
                });
            }
        }
        best
    }
}

/// rho of `source` at each incident elevation of `angles_deg` (degrees, in [0, 90): at 90
/// degrees the light grazes the surface and nothing is reflected), with
/// [`AlbedoNodes::new`]`(theta, resolution)`; the elevations in parallel. A grid source goes
/// through [`GridAlbedo`] (each touched cell evaluated once).
///
/// Accuracy of the default resolution (96), measured by the tests: a Lambertian within 1.5e-4
/// at every elevation up to 89 degrees; every synthetic preset (metals, clear coats, diffusers)
/// within 0.4 % of a twice finer quadrature at 0-88 degrees (brdf-synth's physics tests).
pub fn directional_albedo(
    source: &dyn BrdfSource,
    angles_deg: &[f64],
    resolution: usize,
) -> Result<AlbedoTable> {
    if let Some(grid) = source.grid() {
        return GridAlbedo::new(&grid, angles_deg, resolution)?.table(source);
    }
    check_quadrature(angles_deg, resolution)?;
    let channels = source.channels();
    let nc = channels.len();
    let mut values = vec![0.0; angles_deg.len() * nc];
    values
        .par_chunks_mut(nc.max(1))
        .zip(angles_deg.par_iter())
        .try_for_each(|(row, deg)| {
            AlbedoNodes::new(deg.to_radians(), resolution).integrate(source, row)
        })?;
    Ok(AlbedoTable {
        angles_deg: angles_deg.to_vec(),
        channels,
        values,
    })
}

/// Refuses elevations outside [0, 90) degrees and a resolution of 0.
fn check_quadrature(angles_deg: &[f64], resolution: usize) -> Result<()> {
    if let Some(bad) = angles_deg
        .iter()
        .find(|a| !(a.is_finite() && (0.0..90.0).contains(*a)))
    {
        return Err(Error::InvalidArgument {
            reason: format!(
                "directional albedo at an incident elevation of {bad} degrees: elevations must \
                 lie in [0, 90) degrees"
            ),
        });
    }
    if resolution == 0 {
        return Err(Error::InvalidArgument {
            reason: "directional albedo with a quadrature resolution of 0".into(),
        });
    }
    Ok(())
}

/// [`directional_albedo`] on one grid, built once ([`AlbedoNodes::cell_weights`] per
/// elevation, merged by cell) and applied to any number of grid sources on it: each then
/// costs one [`BrdfSource::eval_cell`] per cell any elevation touches (every stored material
/// of a dataset, say).
#[derive(Debug, Clone, PartialEq)]
pub struct GridAlbedo {
    grid: AngularGrid,
    angles_deg: Vec<f64>,
    resolution: usize,
    /// Every cell any elevation touches, once, by index: (cell, its (elevation, weight)s).
    cells: Vec<(usize, Vec<(usize, f64)>)>,
    /// Each elevation's nodes for lookups that are not multilinear, made by the first such
    /// table when there are at most [`MAX_CACHED_NODES`] nodes in all.
    node_stencils: NodeStencils,
}

/// A quadrature node of [`GridAlbedo`]'s tables by lookup: its weight and its stencil as
/// (position in [`GridAlbedo`]'s `cells`, weight) pairs (position 0 where the weight is 0).
type NodeStencil = (f64, [(u32, f64); 8]);

/// Most nodes (elevations x resolution^2) whose stencils a [`GridAlbedo`] keeps for the tables
/// of sources looked up logarithmically (136 B each: at most ~36 MB; the pipeline's 8 x 96 x 96
/// take 10 MB). Every such table then skips the nodes' directions, half/difference angles and
/// stencils (sin/cos, acos, atan2: ~15 % of a `lookup = "log"` pipeline's samples before); more
/// nodes (e.g. `specgp albedo --resolution 1024`, one source) are computed per table instead.
const MAX_CACHED_NODES: usize = 1 << 18;

// The bound holds the pipeline's 8 x 96 x 96 nodes, in the ~36 MB its documentation gives.
const _: () = assert!(
    MAX_CACHED_NODES >= 8 * 96 * 96
        && MAX_CACHED_NODES * std::mem::size_of::<NodeStencil>() <= 36_000_000
);

/// [`GridAlbedo`]'s cached [`NodeStencil`]s per elevation: derived from its other fields, so
/// they take no part in comparisons.
#[derive(Debug, Clone, Default)]
struct NodeStencils(OnceLock<Vec<Vec<NodeStencil>>>);

impl PartialEq for NodeStencils {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

/// Cells per parallel task of [`GridAlbedo::table`] (fixed, so the sums' order, hence their
/// bits, do not depend on the threads).
const CELLS_PER_TASK: usize = 512;

impl GridAlbedo {
    /// The cell weights of `grid` at `angles_deg` (as [`directional_albedo`]).
    pub fn new(grid: &AngularGrid, angles_deg: &[f64], resolution: usize) -> Result<Self> {
        check_quadrature(angles_deg, resolution)?;
        let per_angle: Vec<Vec<(usize, f64)>> = angles_deg
            .par_iter()
            .map(|deg| AlbedoNodes::new(deg.to_radians(), resolution).cell_weights(grid))
            .collect();
        // Each cell once (elevations touch 2.4x fewer distinct cells than in total on 16,16,32).
        let mut by_cell: std::collections::BTreeMap<usize, Vec<(usize, f64)>> =
            std::collections::BTreeMap::new();
        for (k, cells) in per_angle.into_iter().enumerate() {
            for (a, w) in cells {
                by_cell.entry(a).or_default().push((k, w));
            }
        }
        let cells = by_cell.into_iter().collect();
        Ok(Self {
            grid: *grid,
            angles_deg: angles_deg.to_vec(),
            resolution,
            cells,
            node_stencils: NodeStencils::default(),
        })
    }

    /// The albedo table of `source`, which must be a grid source on this grid. A source looked
    /// up multilinearly costs a weighted sum per touched cell; another [`Lookup`] is not linear
    /// in the cells, so its lookups are combined node by node from the touched cells, each
    /// still evaluated once (the same sums as [`AlbedoNodes::integrate`] of the source's own
    /// `eval`).
    pub fn table(&self, source: &dyn BrdfSource) -> Result<AlbedoTable> {
        if source.grid() != Some(self.grid) {
            return Err(Error::InvalidArgument {
                reason: format!(
                    "directional albedo weights of grid {} for a source {}",
                    self.grid,
                    source
                        .grid()
                        .map_or_else(|| "not on a grid".to_owned(), |g| format!("on grid {g}"))
                ),
            });
        }
        if source.lookup() != Lookup::Multilinear {
            return self.table_by_nodes(source, MAX_CACHED_NODES);
        }
        let channels = source.channels();
        let nc = channels.len();
        let len = self.angles_deg.len() * nc;
        let partials = self
            .cells
            .par_chunks(CELLS_PER_TASK)
            .map(|chunk| {
                let mut sums = vec![0.0; len];
                eval_cells_in_order(
                    source,
                    chunk,
                    |(a, _)| *a,
                    |_, (_, weights), f| {
                        for &(k, w) in weights {
                            for (s, v) in sums[k * nc..(k + 1) * nc].iter_mut().zip(f) {
                                *s += w * v;
                            }
                        }
                        Ok::<_, Error>(())
                    },
                )?;
                Ok(sums)
            })
            .collect::<Result<Vec<_>>>()?;
        let mut values = vec![0.0; len];
        for p in &partials {
            for (v, s) in values.iter_mut().zip(p) {
                *v += s;
            }
        }
        Ok(AlbedoTable {
            angles_deg: self.angles_deg.clone(),
            channels,
            values,
        })
    }

    /// [`GridAlbedo::table`] of a source whose lookup is not multilinear: every touched cell
    /// evaluated once, then each elevation's nodes looked up from them (their stencils kept
    /// for later tables when there are at most `max_cached_nodes`).
    fn table_by_nodes(
        &self,
        source: &dyn BrdfSource,
        max_cached_nodes: usize,
    ) -> Result<AlbedoTable> {
        let channels = source.channels();
        let nc = channels.len();
        let lookup = source.lookup();
        let records = self
            .cells
            .par_chunks(CELLS_PER_TASK)
            .map(|chunk| {
                let mut records = Vec::with_capacity(chunk.len());
                eval_cells_in_order(
                    source,
                    chunk,
                    |(a, _)| *a,
                    |_, _, f| {
                        records.push(cell_record(lookup, f));
                        Ok::<_, Error>(())
                    },
                )?;
                Ok(records)
            })
            .collect::<Result<Vec<_>>>()?
            .concat();
        // Each touched cell's position in `cells` (and so in `records`), by flat index.
        let positions = || {
            let mut position = vec![u32::MAX; self.grid.len()];
            for (i, (a, _)) in self.cells.iter().enumerate() {
                position[*a] = i as u32;
            }
            position
        };
        let n_nodes = self.angles_deg.len() * self.resolution.saturating_mul(self.resolution);
        let cached = (n_nodes <= max_cached_nodes).then(|| {
            self.node_stencils.0.get_or_init(|| {
                let position = positions();
                (0..self.angles_deg.len())
                    .into_par_iter()
                    .map(|k| self.node_stencils(k, &position))
                    .collect()
            })
        });
        let position = if cached.is_none() {
            positions()
        } else {
            Vec::new()
        };
        let mut rows = vec![0.0; self.angles_deg.len() * nc];
        rows.par_chunks_mut(nc.max(1))
            .enumerate()
            .for_each(|(k, row)| {
                let fresh;
                let nodes = match cached {
                    Some(cached) => &cached[k],
                    None => {
                        fresh = self.node_stencils(k, &position);
                        &fresh
                    }
                };
                let mut f = vec![0.0; nc];
                for (w, stencil) in nodes {
                    let stencil = stencil.iter().map(|&(i, s)| (i as usize, s));
                    let record = |i: usize| Ok::<_, std::convert::Infallible>(&records[i][..]);
                    let Ok(()) = look_up(lookup, stencil, record, &mut f);
                    for (r, v) in row.iter_mut().zip(&f) {
                        *r += w * v;
                    }
                }
            });
        Ok(AlbedoTable {
            angles_deg: self.angles_deg.clone(),
            channels,
            values: rows,
        })
    }

    /// The nodes of elevation `k` (those with half/difference angles) as [`NodeStencil`]s, in
    /// the order of [`AlbedoNodes::nodes`] (`position`: each touched cell's position in
    /// `cells`, by flat index).
    fn node_stencils(&self, k: usize, position: &[u32]) -> Vec<NodeStencil> {
        let nodes = AlbedoNodes::new(self.angles_deg[k].to_radians(), self.resolution);
        nodes
            .nodes()
            .iter()
            .filter_map(|&(wo, w)| {
                let hd = HalfDiff::from_dirs(nodes.wi(), wo)?;
                let stencil = self.grid.interpolation_stencil(&hd);
                Some((
                    w,
                    stencil.map(|(a, s)| (if s != 0.0 { position[a] } else { 0 }, s)),
                ))
            })
            .collect()
    }

    /// A [`GridAlbedo::table`] accumulated from values that stream past instead of evaluated
    /// cell by cell: see [`AlbedoStream`].
    pub fn stream(&self, channels: Channels) -> AlbedoStream<'_> {
        AlbedoStream {
            sums: vec![0.0; self.angles_deg.len() * channels.len()],
            albedo: self,
            channels,
            next_cell: 0,
            done: 0,
        }
    }
}

/// The albedo table of a grid source looked up multilinearly, summed from its values as they
/// stream past in flat order (`cell * channels + channel`, blocks from 0 to the end, as a
/// prediction is materialised), so that a check of the values costs no second read of them:
/// [`AlbedoStream::push`] every block in order, then [`AlbedoStream::finish`]. The table equals
/// [`GridAlbedo::table`] of a source with these values but for the sums' order (their last
/// bits).
#[derive(Debug)]
pub struct AlbedoStream<'a> {
    albedo: &'a GridAlbedo,
    channels: Channels,
    /// Per elevation (rows) and channel, the sums so far.
    sums: Vec<f64>,
    /// Position in the albedo's `cells` of the first touched cell not yet complete.
    next_cell: usize,
    /// Values pushed so far.
    done: usize,
}

impl AlbedoStream<'_> {
    /// Adds the block of values at flat indices `range` (`values.len() == range.len()`),
    /// which must start where the block before ended (0 for the first).
    pub fn push(&mut self, range: std::ops::Range<usize>, values: &[f32]) -> Result<()> {
        let nc = self.channels.len();
        let total = self.albedo.grid.len() * nc;
        if range.start != self.done || range.len() != values.len() || range.end > total {
            return Err(Error::InvalidArgument {
                reason: format!(
                    "albedo stream: block {range:?} of {} values after {} of {total}",
                    values.len(),
                    self.done
                ),
            });
        }
        let cells = &self.albedo.cells;
        while let Some((a, weights)) = cells.get(self.next_cell) {
            let (first, end) = (a * nc, (a + 1) * nc);
            if first >= range.end {
                break;
            }
            for d in first.max(range.start)..end.min(range.end) {
                let (c, v) = (d - first, f64::from(values[d - range.start]));
                for &(k, w) in weights {
                    self.sums[k * nc + c] += w * v;
                }
            }
            if end > range.end {
                break;
            }
            self.next_cell += 1;
        }
        self.done = range.end;
        Ok(())
    }

    /// The table, once every value has been pushed.
    pub fn finish(self) -> Result<AlbedoTable> {
        let total = self.albedo.grid.len() * self.channels.len();
        if self.done != total {
            return Err(Error::InvalidArgument {
                reason: format!("albedo stream ended after {} of {total} values", self.done),
            });
        }
        Ok(AlbedoTable {
            angles_deg: self.albedo.angles_deg.clone(),
            channels: self.channels,
            values: self.sums,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    /// f = albedo / pi in every channel above the horizon.
    struct Lambert(Vec<f64>);

    impl BrdfSource for Lambert {
        fn channels(&self) -> Channels {
            Channels::spectral((0..self.0.len()).map(|k| 400.0 + k as f64).collect()).unwrap()
        }
        fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> Result<()> {
            let up = wi[2] > 0.0 && wo[2] > 0.0;
            for (o, a) in out.iter_mut().zip(&self.0) {
                *o = if up { a / PI } else { 0.0 };
            }
            Ok(())
        }
    }

    #[test]
    fn a_lambertian_reflects_its_albedo() {
        let src = Lambert(vec![1.0, 0.5, 2.0]);
        let angles: Vec<f64> = (0..90).map(f64::from).collect();
        let t = directional_albedo(&src, &angles, DEFAULT_RESOLUTION).unwrap();
        for (k, a) in angles.iter().enumerate() {
            let row = t.row(k);
            // Measured: 1.5e-4 at worst.
            assert!((row[0] - 1.0).abs() < 2e-4, "{a}: {row:?}");
            assert!((row[1] - 0.5 * row[0]).abs() < 1e-15, "{a}: {row:?}");
            assert!((row[2] - 2.0 * row[0]).abs() < 1e-15, "{a}: {row:?}");
        }
        let peak = t.peak().unwrap();
        assert_eq!(peak.channel, 2);
        assert_eq!(peak.value, t.values.iter().copied().fold(0.0, f64::max));
        assert_eq!(
            t.row(angles.iter().position(|a| *a == peak.angle_deg).unwrap())[2],
            peak.value
        );
    }

    /// `inner` without its grid: evaluated pair by pair.
    struct NoGrid<'a>(&'a dyn BrdfSource);

    impl BrdfSource for NoGrid<'_> {
        fn channels(&self) -> Channels {
            self.0.channels()
        }
        fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> Result<()> {
            self.0.eval(wi, wo, out)
        }
    }

    /// Two stored materials on 8,8,16 at 3 wavelengths: a sharp peak at small theta_h growing
    /// towards grazing theta_d, and a Lambertian of albedo 0.6.
    fn store(dir: &std::path::Path) -> std::path::PathBuf {
        use crate::{StoreInfo, StoreOptions, StoreWriter};
        let grid = AngularGrid::new(8, 8, 16).unwrap();
        let info = StoreInfo {
            grid,
            channels: Channels::parse_wavelengths("450:650:100").unwrap(),
        };
        let path = dir.join("two.sbrdf");
        let mut w = StoreWriter::create(&path, info.clone(), StoreOptions::default()).unwrap();
        let glossy: Vec<f32> = (0..info.d())
            .map(|i| {
                let hd = grid.bin_centre_flat(i / 3);
                let peak = (-hd.theta_h / 0.05).exp() / hd.theta_d.cos();
                (0.1 + (i % 3) as f64 * 0.2 + 5.0 * peak) as f32
            })
            .collect();
        w.add_material("glossy", "test", &glossy).unwrap();
        w.add_material("white", "test", &vec![(0.6 / PI) as f32; info.d()])
            .unwrap();
        w.finish().unwrap();
        path
    }

    /// The albedo of grid source `source` from its cells, after checking that it equals the
    /// pair-by-pair quadrature of its own lookups up to rounding (`name` for messages).
    fn from_cells_as_pairs(source: &dyn BrdfSource, angles: &[f64], name: &str) -> AlbedoTable {
        let cells = directional_albedo(source, angles, DEFAULT_RESOLUTION).unwrap();
        let pairs = directional_albedo(&NoGrid(source), angles, DEFAULT_RESOLUTION).unwrap();
        assert_eq!(cells.channels, pairs.channels);
        for (a, b) in cells.values.iter().zip(&pairs.values) {
            assert!((a - b).abs() <= 1e-12 * b.abs(), "{name}: {a} vs {b}");
        }
        cells
    }

    /// A grid source's albedo from its cells (each evaluated once) equals the pair-by-pair
    /// quadrature of its interpolated values up to rounding; a Lambertian grid source reflects
    /// its albedo; the weights of one grid refuse a source on another or none.
    #[test]
    fn grid_sources_integrate_their_cells_once() {
        let dir = tempfile::tempdir().unwrap();
        let path = store(dir.path());
        let angles = [0.0, 35.0, 70.0, 86.0, 89.0];
        for name in ["glossy", "white"] {
            let m = crate::store::StoreMaterial::open(&path, name).unwrap();
            let cells = from_cells_as_pairs(&m, &angles, name);
            if name == "white" {
                assert!(
                    cells.values.iter().all(|v| (v - 0.6).abs() < 2e-4),
                    "{cells:?}"
                );
            } else {
                // The constant base reflects (0.1 + 0.2 c) pi in channel c; the peak adds to it.
                for k in 0..angles.len() {
                    for (c, v) in cells.row(k).iter().enumerate() {
                        assert!(*v > (0.1 + 0.2 * c as f64) * PI, "{cells:?}");
                    }
                }
                assert_eq!(cells.peak().unwrap().channel, 2);
            }
        }
        let m = crate::store::StoreMaterial::open(&path, "white").unwrap();
        let other = GridAlbedo::new(&AngularGrid::new(8, 8, 8).unwrap(), &angles, 16).unwrap();
        let e = other.table(&m).unwrap_err().to_string();
        assert!(
            e.contains("grid 8,8,8") && e.contains("on grid 8,8,16"),
            "{e}"
        );
        let same = GridAlbedo::new(&AngularGrid::new(8, 8, 16).unwrap(), &angles, 16).unwrap();
        let e = same.table(&NoGrid(&m)).unwrap_err().to_string();
        assert!(e.contains("not on a grid"), "{e}");
    }

    /// A logarithmic lookup's albedo from the touched cells equals the pair-by-pair quadrature
    /// of the source's own (logarithmic) lookups; a Lambertian reflects the same under both
    /// lookups; the glossy material reflects less than multilinearly at every elevation (the
    /// chords between bin centres overshoot its peak, convex in theta_h, and its growth
    /// towards grazing theta_d).
    #[test]
    fn log_lookups_integrate_from_the_cells() {
        use crate::lookup::{Lookup, WithLookup};
        let dir = tempfile::tempdir().unwrap();
        let path = store(dir.path());
        let angles = [0.0, 35.0, 70.0, 86.0, 89.0];
        for name in ["glossy", "white"] {
            let m = crate::store::StoreMaterial::open(&path, name).unwrap();
            let log = WithLookup::new(&m, Lookup::LogMultilinear).unwrap();
            let cells = from_cells_as_pairs(&log, &angles, name);
            let linear = directional_albedo(&m, &angles, DEFAULT_RESOLUTION).unwrap();
            for (k, deg) in angles.iter().enumerate() {
                for (a, b) in cells.row(k).iter().zip(linear.row(k)) {
                    if name == "white" {
                        assert!((a - b).abs() < 1e-12, "{deg}: {a} vs {b}");
                    } else {
                        // Measured: 0.904-0.995 of the multilinear albedo.
                        assert!(*a < 0.996 * b, "{deg}: {a} vs {b}");
                    }
                }
            }
        }
    }

    /// A logarithmic table through the cached node stencils (filled by the first table, read by
    /// the later ones) has the bits of one whose nodes are computed afresh; a filled cache
    /// changes no comparison.
    #[test]
    fn cached_node_stencils_give_the_same_tables() {
        use crate::lookup::{Lookup, WithLookup};
        let dir = tempfile::tempdir().unwrap();
        let path = store(dir.path());
        let angles = [0.0, 35.0, 70.0, 86.0, 89.0];
        let grid = AngularGrid::new(8, 8, 16).unwrap();
        let cached = GridAlbedo::new(&grid, &angles, 24).unwrap();
        let unfilled = cached.clone();
        let fresh = GridAlbedo::new(&grid, &angles, 24).unwrap();
        let bits = |t: &AlbedoTable| t.values.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        for name in ["glossy", "white", "glossy"] {
            let m = crate::store::StoreMaterial::open(&path, name).unwrap();
            let log = WithLookup::new(&m, Lookup::LogMultilinear).unwrap();
            let through_cache = cached.table_by_nodes(&log, usize::MAX).unwrap();
            let afresh = fresh.table_by_nodes(&log, 0).unwrap();
            assert_eq!(bits(&through_cache), bits(&afresh), "{name}");
            assert_eq!(bits(&through_cache), bits(&cached.table(&log).unwrap()));
        }
        assert!(cached.node_stencils.0.get().is_some() && fresh.node_stencils.0.get().is_none());
        assert_eq!(cached, unfilled);
        let nodes: usize = cached
            .node_stencils
            .0
            .get()
            .unwrap()
            .iter()
            .map(Vec::len)
            .sum();
        assert!(nodes > angles.len() * 24 * 24 / 4, "{nodes}");
    }

    /// Node stencils are cached when the nodes (elevations x resolution^2) number at most the
    /// bound, and not one more.
    #[test]
    fn node_stencils_are_cached_up_to_the_bound() {
        use crate::lookup::{Lookup, WithLookup};
        let dir = tempfile::tempdir().unwrap();
        let path = store(dir.path());
        let grid = AngularGrid::new(8, 8, 16).unwrap();
        let (angles, resolution) = ([0.0, 35.0, 70.0], 12);
        let n_nodes = angles.len() * resolution * resolution;
        let m = crate::store::StoreMaterial::open(&path, "glossy").unwrap();
        let log = WithLookup::new(&m, Lookup::LogMultilinear).unwrap();
        for (bound, caches) in [(n_nodes, true), (n_nodes - 1, false)] {
            let albedo = GridAlbedo::new(&grid, &angles, resolution).unwrap();
            albedo.table_by_nodes(&log, bound).unwrap();
            let cached = albedo.node_stencils.0.get().is_some();
            assert_eq!(cached, caches, "bound {bound}");
        }
    }

    /// A stream fed a stored material's values in blocks of any size (splitting cells or
    /// not) gives the table of its cells up to the sums' order; a block out of order, of the
    /// wrong length or past the end, and a stream finished early, are errors.
    #[test]
    fn streamed_values_give_the_table_of_their_cells() {
        let dir = tempfile::tempdir().unwrap();
        let path = store(dir.path());
        let angles = [0.0, 35.0, 70.0, 86.0];
        let m = crate::store::StoreMaterial::open(&path, "glossy").unwrap();
        let (grid, nc) = (m.grid().unwrap(), m.channels().len());
        let albedo = GridAlbedo::new(&grid, &angles, 24).unwrap();
        let want = albedo.table(&m).unwrap();
        assert!(want.values.iter().all(|&v| v > 0.1), "{:?}", want.values);
        let mut all = Vec::with_capacity(grid.len() * nc);
        let mut f = vec![0.0; nc];
        for a in 0..grid.len() {
            m.eval_cell(a, &mut f).unwrap();
            all.extend(f.iter().map(|&v| v as f32));
        }
        for block in [1, 2, nc, 7 * nc + 2, all.len()] {
            let mut stream = albedo.stream(m.channels());
            for (i, values) in all.chunks(block).enumerate() {
                let start = i * block;
                stream.push(start..start + values.len(), values).unwrap();
            }
            let got = stream.finish().unwrap();
            assert_eq!(
                (&got.angles_deg, &got.channels),
                (&want.angles_deg, &want.channels)
            );
            for (g, w) in got.values.iter().zip(&want.values) {
                assert!((g - w).abs() <= 1e-13 * w, "block {block}: {g} vs {w}");
            }
        }
        let message = |r: Result<()>| r.unwrap_err().to_string();
        let mut stream = albedo.stream(m.channels());
        stream.push(0..5, &all[..5]).unwrap();
        let e = message(stream.push(6..8, &all[6..8]));
        assert!(e.contains("block 6..8 of 2 values after 5 of"), "{e}");
        let e = message(stream.push(5..8, &all[5..7]));
        assert!(e.contains("block 5..8 of 2 values"), "{e}");
        let end = all.len();
        let e = message(stream.push(5..end + 1, &vec![0.0; end - 4]));
        assert!(e.contains(&format!("after 5 of {end}")), "{e}");
        let e = stream.finish().unwrap_err().to_string();
        assert!(e.contains(&format!("ended after 5 of {end} values")), "{e}");
    }

    /// The peak is the first of equal largest values, in elevation then channel order.
    #[test]
    fn the_peak_is_the_first_largest_value() {
        let table = AlbedoTable {
            angles_deg: vec![0.0, 45.0, 80.0],
            channels: Channels::Rgb,
            values: vec![0.5, 0.9, 0.1, 0.9, 0.2, 0.9, 0.3, 0.4, 0.9],
        };
        let peak = table.peak().unwrap();
        assert_eq!((peak.value, peak.angle_deg, peak.channel), (0.9, 0.0, 1));
    }

    /// Energy gain starts strictly above 1 + ENERGY_MARGIN.
    #[test]
    fn energy_gain_starts_above_the_margin() {
        for quiet in [0.5, 0.999, 1.0, 1.0 + ENERGY_MARGIN] {
            assert!(!gains_energy(quiet), "{quiet}");
        }
        for gain in [1.0 + 1.1 * ENERGY_MARGIN, 1.5, f64::INFINITY] {
            assert!(gains_energy(gain), "{gain}");
        }
    }

    #[test]
    fn elevations_and_resolution_are_checked() {
        let src = Lambert(vec![1.0]);
        for bad in [90.0, -0.5, f64::NAN] {
            let e = directional_albedo(&src, &[0.0, bad], 8)
                .unwrap_err()
                .to_string();
            assert!(e.contains("[0, 90) degrees"), "{e}");
        }
        let e = directional_albedo(&src, &[0.0], 0).unwrap_err().to_string();
        assert!(e.contains("resolution of 0"), "{e}");
        let grid = AngularGrid::new(4, 4, 4).unwrap();
        assert!(GridAlbedo::new(&grid, &[95.0], 8).is_err());
        assert!(directional_albedo(&src, &[], 8).unwrap().peak().is_none());
    }
}
