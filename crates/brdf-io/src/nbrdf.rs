//! Neural-BRDF networks (Sztrajman et al. 2021, asztr/Neural-BRDF): 6-21-21-3 MLPs that
//! approximate measured RGB BRDFs, stored one network per row of an `(N, 675)` f32 `.npy` file
//! with a names file (one name per line, same order).
//!
//! Row layout: W1 (6 x 21, input-major: `W1[i * 21 + j]`), b1 (21), W2 (21 x 21), b2 (21),
//! W3 (21 x 3), b3 (3). Forward pass (the authors' `nn.h`): `a1 = relu(x W1 + b1)`,
//! `a2 = relu(a1 W2 + b2)`, `rgb = max(exp(a2 W3 + b3) - 1, 0)`, in 1/sr (no cosine factor).
//!
//! Input convention (the authors' `coords.py` `io_to_hd` and `nbrdf_npy.cpp`): with the half
//! vector h = normalize(wi + wo) at polar angles (theta_h, phi_h), the input is
//! `x = (sin theta_h, 0, cos theta_h, d)` where `d` is the difference vector of **wo**: wo rotated
//! by -phi_h about z, then by -theta_h about y (phi_d unfolded in (-pi, pi]). `(wi, wo)` follow
//! Mitsuba's argument order like every [`BrdfSource`]; the authors' plugin passes Mitsuba's `wo`
//! (the light side, MERL's "incident" direction) as the first argument of `io_to_hd`. Checked on
//! the real data: against the RGL files, taking d from wo halves the error of taking it from wi
//! (e.g. paper_white: median 0.5 % vs 1.6 %).
//!
//! The networks extrapolate wildly where they saw no training data (grazing angles): values far
//! above any measured BRDF appear. Resampling counts values above an outlier threshold
//! ([`DEFAULT_OUTLIER_THRESHOLD`] unless set otherwise) and can clamp them to it.

use std::path::{Path, PathBuf};

use crate::error::{Error, Result};
use crate::grid::{AngularGrid, Channels, Vec3, unit};
use crate::source::{
    BrdfSource, ImportReport, PairWeights, ResampleOptions, resample_cells,
    resample_cells_indexed_into,
};

/// Number of weights per network (6*21 + 21 + 21*21 + 21 + 21*3 + 3).
pub const WEIGHTS_PER_NETWORK: usize = 675;

/// Default outlier threshold in 1/sr (see [`crate::source::DEFAULT_OUTLIER_THRESHOLD`]).
pub const DEFAULT_OUTLIER_THRESHOLD: f64 = crate::source::DEFAULT_OUTLIER_THRESHOLD;

/// How [`Nbrdf::resample_with`] treats network outputs (the shared [`ResampleOptions`]).
pub type NbrdfOptions = ResampleOptions;

/// A set of Neural-BRDF networks: weights and names.
#[derive(Debug, Clone)]
pub struct NbrdfSet {
    path: PathBuf,
    names: Vec<String>,
    weights: Vec<f32>,
}

impl NbrdfSet {
    /// Reads the `(N, 675)` f32/f64 weights file and the names file (N non-empty lines).
    pub fn open(weights_npy: impl AsRef<Path>, names_txt: impl AsRef<Path>) -> Result<Self> {
        let path = weights_npy.as_ref();
        let names_path = names_txt.as_ref();
        let arr = crate::npy::read(path)?;
        if arr.shape.len() != 2 || arr.shape[1] != WEIGHTS_PER_NETWORK {
            return Err(Error::Format {
                path: path.to_path_buf(),
                reason: format!(
                    "Neural-BRDF weights must have shape (N, {WEIGHTS_PER_NETWORK}), got {:?}",
                    arr.shape
                ),
            });
        }
        // Checked before the conversion to f32: an f64 weight beyond the f32 range is finite in
        // the file (it used to be reported as a non-finite weight).
        let wide = arr.to_f64();
        if let Some(i) = wide
            .iter()
            .position(|w| !w.is_finite() || w.abs() > f64::from(f32::MAX))
        {
            let what = if wide[i].is_finite() {
                format!("weight {:e} beyond the f32 range of the networks", wide[i])
            } else {
                format!("non-finite weight {}", wide[i])
            };
            return Err(Error::Format {
                path: path.to_path_buf(),
                reason: format!(
                    "{what} in network {} (element {})",
                    i / WEIGHTS_PER_NETWORK,
                    i % WEIGHTS_PER_NETWORK
                ),
            });
        }
        // In range: the f32 weights are the checked values rounded (as `to_f32` rounds them).
        let weights: Vec<f32> = wide.into_iter().map(|w| w as f32).collect();
        let bytes = std::fs::read(names_path).map_err(|e| Error::io(names_path, e))?;
        let text = String::from_utf8(bytes).map_err(|e| {
            let at = e.utf8_error().valid_up_to();
            let bytes = e.as_bytes();
            Error::Format {
                path: names_path.to_path_buf(),
                reason: format!(
                    "not a UTF-8 text file of names (byte 0x{:02x} at offset {at}, line {})",
                    bytes[at],
                    1 + bytes[..at].iter().filter(|&&b| b == b'\n').count()
                ),
            }
        })?;
        // A byte-order mark (editors on Windows write one) is not part of the first name.
        let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
        let names: Vec<String> = text
            .lines()
            .map(str::trim)
            .filter(|l| !l.is_empty())
            .map(String::from)
            .collect();
        if names.len() != arr.shape[0] {
            return Err(Error::Format {
                path: names_path.to_path_buf(),
                reason: format!(
                    "{} names for {} networks in {}{}",
                    names.len(),
                    arr.shape[0],
                    path.display(),
                    match text.lines().filter(|l| l.trim().is_empty()).count() {
                        0 => String::new(),
                        blank => format!(" ({blank} blank lines not counted)"),
                    }
                ),
            });
        }
        Ok(Self {
            path: path.to_path_buf(),
            names,
            weights,
        })
    }

    /// Number of networks.
    pub fn len(&self) -> usize {
        self.names.len()
    }

    /// Whether the set is empty.
    pub fn is_empty(&self) -> bool {
        self.names.is_empty()
    }

    /// Material names in file order.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// Index of the material called `name`.
    pub fn find(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }

    /// The network of material `i`.
    pub fn material(&self, i: usize) -> Result<Nbrdf> {
        if i >= self.len() {
            return Err(Error::InvalidArgument {
                reason: format!(
                    "{}: material index {i} out of range ({} networks)",
                    self.path.display(),
                    self.len()
                ),
            });
        }
        let row = &self.weights[i * WEIGHTS_PER_NETWORK..(i + 1) * WEIGHTS_PER_NETWORK];
        Nbrdf::from_weights(self.names[i].clone(), row)
    }
}

/// One Neural-BRDF network (weights widened to f64).
#[derive(Debug, Clone)]
pub struct Nbrdf {
    name: String,
    w: Vec<f64>,
}

// Offsets of the blocks in a weight row.
const W1: usize = 0;
const B1: usize = W1 + 6 * 21;
const W2: usize = B1 + 21;
const B2: usize = W2 + 21 * 21;
const W3: usize = B2 + 21;
const B3: usize = W3 + 21 * 3;

impl Nbrdf {
    /// A network from one 675-weight row (layout in the module documentation).
    pub fn from_weights(name: String, row: &[f32]) -> Result<Self> {
        if row.len() != WEIGHTS_PER_NETWORK {
            return Err(Error::InvalidArgument {
                reason: format!(
                    "a Neural-BRDF network has {WEIGHTS_PER_NETWORK} weights, got {}",
                    row.len()
                ),
            });
        }
        Ok(Self {
            name,
            w: row.iter().map(|&x| f64::from(x)).collect(),
        })
    }

    /// The material name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The forward pass on an input vector `(hx, hy, hz, dx, dy, dz)`: RGB in 1/sr.
    ///
    /// Each neuron sums its bias and then its inputs' products in input order (no fused
    /// multiply-adds); the loops run over a layer's neurons innermost, so that they vectorise.
    pub fn forward(&self, x: [f64; 6]) -> [f64; 3] {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above).
            return unsafe { self.forward_avx2(x) };
        }
        self.forward_portable(x)
    }

    /// [`Nbrdf::forward`] compiled for AVX2 (4 neurons per instruction instead of 2; separate
    /// multiplies and adds as in every build, so the same bits).
    ///
    /// # Safety
    /// The CPU must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn forward_avx2(&self, x: [f64; 6]) -> [f64; 3] {
        self.forward_portable(x)
    }

    /// The forward pass every build compiles.
    #[inline(always)]
    fn forward_portable(&self, x: [f64; 6]) -> [f64; 3] {
        let w = &self.w;
        let a1 = layer::<6, 21>(&x, &w[W1..B1], &w[B1..W2]);
        let a2 = layer::<21, 21>(&a1, &w[W2..B2], &w[B2..W3]);
        let mut s = [0.0; 3];
        s.copy_from_slice(&w[B3..B3 + 3]);
        for (i, ai) in a2.iter().enumerate() {
            let row = &w[W3 + i * 3..W3 + i * 3 + 3];
            for (sj, wij) in s.iter_mut().zip(row) {
                *sj += ai * wij;
            }
        }
        s.map(|v| (v.exp() - 1.0).max(0.0))
    }

    /// f(wi, wo) as RGB in 1/sr; 0 when either direction is at or below the horizon or the pair
    /// is degenerate (wi = -wo, zero or non-finite vectors).
    pub fn eval(&self, wi: Vec3, wo: Vec3) -> [f64; 3] {
        match network_input(wi, wo) {
            Some(x) => self.forward(x),
            None => [0.0; 3],
        }
    }

    /// The network at every bin centre of `grid`, in dataset order (`flat * 3 + channel`), with
    /// the default options (outliers above [`DEFAULT_OUTLIER_THRESHOLD`] counted, not clamped).
    pub fn resample(&self, grid: &AngularGrid) -> Result<(Vec<f32>, ImportReport)> {
        self.resample_with(grid, NbrdfOptions::default())
    }

    /// As [`Nbrdf::resample`] with explicit outlier handling.
    pub fn resample_with(
        &self,
        grid: &AngularGrid,
        options: NbrdfOptions,
    ) -> Result<(Vec<f32>, ImportReport)> {
        let (values, report) =
            resample_cells(grid, 3, options, PairWeights::Equal, |wi, wo, out| {
                out.copy_from_slice(&self.eval(wi, wo));
                Ok(())
            })?;
        tracing::info!(material = %self.name, %grid, "resampled Neural-BRDF: {report}");
        Ok((values, report))
    }

    /// As [`Nbrdf::resample_with`] on the grid of `inputs`, whose network inputs (made once for
    /// a whole set: [`GridInputs`]) replace the per-cell trigonometry. The same values, bit for
    /// bit.
    pub fn resample_on(
        &self,
        inputs: &GridInputs,
        options: NbrdfOptions,
    ) -> Result<(Vec<f32>, ImportReport)> {
        let grid = &inputs.grid;
        let mut values = vec![0f32; grid.len() * 3];
        let report = resample_cells_indexed_into(
            grid,
            0,
            &mut values,
            3,
            options,
            PairWeights::Equal,
            |flat| inputs.directions(flat),
            |slot, wi, wo, out| {
                let x = match inputs.table.get(slot.cell) {
                    Some(cell) => cell.inputs[usize::from(slot.swapped)],
                    None => network_input(wi, wo),
                };
                out.copy_from_slice(&x.map_or([0.0; 3], |x| self.forward(x)));
                Ok(())
            },
        )?;
        tracing::info!(material = %self.name, %grid, "resampled Neural-BRDF: {report}");
        Ok((values, report))
    }
}

/// The networks' inputs at every bin centre of a grid, in both direction orders, with the
/// cells' directions. They are the same for every network, so an import of a set makes them
/// once and passes them to [`Nbrdf::resample_on`]: their trigonometry (the directions, then two
/// `atan2` and three `sin_cos` per order) cost as much as the networks themselves. Grids whose
/// table would exceed [`GridInputs::MAX_BYTES`] keep no table; their inputs are computed per
/// cell, as [`Nbrdf::resample_with`] does.
#[derive(Debug, Clone)]
pub struct GridInputs {
    grid: AngularGrid,
    /// One entry per cell; empty when the grid is beyond the size limit.
    table: Vec<CellInputs>,
}

/// One cell of [`GridInputs`].
#[derive(Debug, Clone, Copy)]
struct CellInputs {
    /// The bin-centre directions `(wi, wo)`.
    dirs: (Vec3, Vec3),
    /// The inputs of `(wi, wo)` and of `(wo, wi)` (`None` where [`network_input`] gives none).
    inputs: [Option<[f64; 6]>; 2],
}

impl GridInputs {
    /// The largest table kept, in bytes (MERL's own 90 x 90 x 180 grid needs ~230 MB).
    pub const MAX_BYTES: usize = 512 << 20;

    /// The inputs of every cell of `grid` (in parallel), or none beyond [`Self::MAX_BYTES`].
    pub fn new(grid: &AngularGrid) -> Self {
        use rayon::prelude::*;
        let entry = std::mem::size_of::<CellInputs>();
        let table = if grid.len().saturating_mul(entry) > Self::MAX_BYTES {
            Vec::new()
        } else {
            (0..grid.len())
                .into_par_iter()
                .map(|cell| {
                    let (wi, wo) = grid.bin_centre_flat(cell).to_dirs();
                    CellInputs {
                        dirs: (wi, wo),
                        inputs: [network_input(wi, wo), network_input(wo, wi)],
                    }
                })
                .collect()
        };
        Self { grid: *grid, table }
    }

    /// The grid.
    pub fn grid(&self) -> &AngularGrid {
        &self.grid
    }

    /// Whether the inputs are tabulated (false beyond [`Self::MAX_BYTES`]).
    pub fn is_tabulated(&self) -> bool {
        self.table.len() == self.grid.len()
    }

    /// The bin-centre directions of cell `flat`.
    fn directions(&self, flat: usize) -> (Vec3, Vec3) {
        match self.table.get(flat) {
            Some(cell) => cell.dirs,
            None => self.grid.bin_centre_flat(flat).to_dirs(),
        }
    }
}

impl BrdfSource for Nbrdf {
    fn channels(&self) -> Channels {
        Channels::Rgb
    }

    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> Result<()> {
        crate::source::check_output_len(out, 3)?;
        out.copy_from_slice(&Nbrdf::eval(self, wi, wo));
        Ok(())
    }
}

/// One dense layer with ReLU: `relu(x W + b)` for `W` stored input-major (`W[i * OUT + j]`).
/// Neuron `j` sums `b[j]`, then `x[0] W[0][j]`, `x[1] W[1][j]`, ... in that order.
#[inline(always)]
fn layer<const IN: usize, const OUT: usize>(x: &[f64; IN], w: &[f64], b: &[f64]) -> [f64; OUT] {
    let mut s = [0.0; OUT];
    s.copy_from_slice(&b[..OUT]);
    for (i, xi) in x.iter().enumerate() {
        let row = &w[i * OUT..(i + 1) * OUT];
        for (sj, wij) in s.iter_mut().zip(row) {
            *sj += xi * wij;
        }
    }
    s.map(|v| v.max(0.0))
}

/// The network input `(sin theta_h, 0, cos theta_h, d)` of a direction pair, or `None` when the
/// pair is not above the horizon or degenerate.
fn network_input(wi: Vec3, wo: Vec3) -> Option<[f64; 6]> {
    let wi = unit(wi)?;
    let wo = unit(wo)?;
    if !(wi[2] > 0.0 && wo[2] > 0.0) {
        return None;
    }
    let h = unit([wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]])?;
    let theta_h = (h[0] * h[0] + h[1] * h[1]).sqrt().atan2(h[2]);
    let phi_h = h[1].atan2(h[0]);
    // d = R_y(-theta_h) R_z(-phi_h) wo.
    let (s, c) = (-phi_h).sin_cos();
    let t = [wo[0] * c - wo[1] * s, wo[0] * s + wo[1] * c, wo[2]];
    let (s, c) = (-theta_h).sin_cos();
    let d = [t[0] * c + t[2] * s, t[1], t[2] * c - t[0] * s];
    Some([theta_h.sin(), 0.0, theta_h.cos(), d[0], d[1], d[2]])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::HalfDiff;

    /// A names file with a different count says so, and says when blank lines (skipped) made
    /// the difference.
    #[test]
    fn name_count_mismatch_mentions_skipped_blank_lines() {
        let dir = tempfile::tempdir().unwrap();
        let weights = dir.path().join("w.npy");
        let mut w = crate::npy::NpyWriter::create(
            &weights,
            crate::npy::NpyDtype::F32,
            &[2, WEIGHTS_PER_NETWORK],
        )
        .unwrap();
        w.write_f32(&vec![0.0; 2 * WEIGHTS_PER_NETWORK]).unwrap();
        w.finish().unwrap();
        let names = dir.path().join("n.txt");
        for (text, blank) in [("a\n\n", true), ("a\n", false)] {
            std::fs::write(&names, text).unwrap();
            let e = NbrdfSet::open(&weights, &names).unwrap_err().to_string();
            assert!(
                e.contains("n.txt") && e.contains("1 names for 2 networks"),
                "{e}"
            );
            assert_eq!(e.contains("(1 blank lines not counted)"), blank, "{e}");
        }
        std::fs::write(&names, "a\n\nb\n").unwrap();
        assert_eq!(
            NbrdfSet::open(&weights, &names).unwrap().names(),
            ["a", "b"]
        );
        // A UTF-8 byte-order mark and CRLF line ends are not part of the names (the mark
        // used to stay at the start of the first name, which `--only a` then did not find).
        std::fs::write(&names, "\u{feff}a\r\nb\r\n").unwrap();
        let set = NbrdfSet::open(&weights, &names).unwrap();
        assert_eq!(set.names(), ["a", "b"]);
        assert_eq!(set.find("a"), Some(0));
    }

    /// A set knows its size and hands out each network under its own name; an empty weights
    /// file with an empty names file is an empty set, not an error.
    #[test]
    fn sets_report_their_size_and_name_their_networks() {
        let dir = tempfile::tempdir().unwrap();
        let (weights, names) = (dir.path().join("w.npy"), dir.path().join("n.txt"));
        crate::npy::write_f64(
            &weights,
            &[2, WEIGHTS_PER_NETWORK],
            &vec![0.25; 2 * WEIGHTS_PER_NETWORK],
        )
        .unwrap();
        std::fs::write(&names, "first\nsecond\n").unwrap();
        let set = NbrdfSet::open(&weights, &names).unwrap();
        assert_eq!((set.len(), set.is_empty()), (2, false));
        assert_eq!(set.material(1).unwrap().name(), "second");
        assert_eq!(set.material(0).unwrap().name(), "first");
        let e = set.material(2).unwrap_err().to_string();
        assert!(
            e.contains("w.npy: material index 2 out of range (2 networks)"),
            "{e}"
        );
        crate::npy::write_f64(&weights, &[0, WEIGHTS_PER_NETWORK], &[]).unwrap();
        std::fs::write(&names, "").unwrap();
        let empty = NbrdfSet::open(&weights, &names).unwrap();
        assert_eq!((empty.len(), empty.is_empty()), (0, true));
    }

    /// Through the [`BrdfSource`] trait a network gives its forward pass, refuses an output
    /// buffer of the wrong length, and gives 0 when a direction lies exactly on the horizon
    /// (z = 0 is not above it, even though the half vector is then well defined).
    #[test]
    fn source_eval_is_the_forward_pass_and_zero_on_the_horizon() {
        let net = seeded_network(5);
        let (wi, wo) = ([0.3, -0.2, 0.8], [-0.1, 0.4, 0.6]);
        let want = net.forward(network_input(wi, wo).unwrap());
        assert!(want.iter().any(|&v| v > 0.0), "{want:?}");
        let mut out = [f64::NAN; 3];
        BrdfSource::eval(&net, wi, wo, &mut out).unwrap();
        assert_eq!(out.map(f64::to_bits), want.map(f64::to_bits));
        let e = BrdfSource::eval(&net, wi, wo, &mut [0.0; 2]).unwrap_err();
        assert!(e.to_string().contains("2 slots for 3 channels"), "{e}");
        let (up, flat) = ([0.0, 0.0, 1.0], [1.0, 0.0, 0.0]);
        assert_eq!(network_input(flat, up), None);
        assert_eq!(network_input(up, flat), None);
        assert_eq!(net.eval(flat, up), [0.0; 3]);
        assert_eq!(net.eval(up, flat), [0.0; 3]);
        // Just above the horizon there is an input.
        assert!(network_input([1.0, 0.0, 1e-9], up).is_some());
    }

    /// Weights that the networks cannot hold are refused naming the file, the network, the
    /// element and the problem: an f64 weight beyond the f32 range is not called non-finite.
    #[test]
    fn weights_beyond_f32_or_not_finite_are_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let names = dir.path().join("n.txt");
        std::fs::write(&names, "a\nb\n").unwrap();
        let weights = dir.path().join("w.npy");
        for (bad, want) in [
            (
                1e300,
                "w.npy: weight 1e300 beyond the f32 range of the networks in network 1 (element 7)",
            ),
            (
                f64::NAN,
                "w.npy: non-finite weight NaN in network 1 (element 7)",
            ),
            (
                -f64::INFINITY,
                "w.npy: non-finite weight -inf in network 1 (element 7)",
            ),
        ] {
            let mut row = vec![0.5f64; 2 * WEIGHTS_PER_NETWORK];
            row[WEIGHTS_PER_NETWORK + 7] = bad;
            crate::npy::write_f64(&weights, &[2, WEIGHTS_PER_NETWORK], &row).unwrap();
            let e = NbrdfSet::open(&weights, &names).unwrap_err();
            assert!(matches!(e, Error::Format { .. }), "{e}");
            assert!(e.to_string().ends_with(want), "{e}");
        }
        // The largest f32 passes.
        let mut row = vec![0.5f64; 2 * WEIGHTS_PER_NETWORK];
        row[3] = f64::from(f32::MAX);
        crate::npy::write_f64(&weights, &[2, WEIGHTS_PER_NETWORK], &row).unwrap();
        let set = NbrdfSet::open(&weights, &names).unwrap();
        assert_eq!(set.material(0).unwrap().w[3], f64::from(f32::MAX));
    }

    #[test]
    fn input_matches_rusinkiewicz_angles() {
        let hd = HalfDiff {
            theta_h: 0.4,
            theta_d: 0.7,
            phi_d: 1.2,
        };
        let (wi, wo) = hd.to_dirs();
        // Rotating the pair about the normal must not change the input.
        let rot = |v: Vec3| {
            let (s, c) = 2.0f64.sin_cos();
            [v[0] * c - v[1] * s, v[0] * s + v[1] * c, v[2]]
        };
        for (a, b) in [(wo, wi), (rot(wo), rot(wi))] {
            // d is taken from the second argument.
            let x = network_input(a, b).unwrap();
            let want = [
                0.4f64.sin(),
                0.0,
                0.4f64.cos(),
                0.7f64.sin() * 1.2f64.cos(),
                0.7f64.sin() * 1.2f64.sin(),
                0.7f64.cos(),
            ];
            for k in 0..6 {
                assert!((x[k] - want[k]).abs() < 1e-12, "{x:?} vs {want:?}");
            }
        }
        assert!(network_input([0.0, 0.0, 1.0], [1.0, 0.0, -0.1]).is_none());
        // Directions of any finite length: a norm whose square underflows or overflows
        // (below ~1e-154, above ~1e154) used to give no input (a value of 0).
        let x = network_input(wi, wo).unwrap();
        for s in [1e-170, 1e170] {
            let y = network_input(wi.map(|v| v * s), wo).unwrap();
            assert!(
                x.iter().zip(&y).all(|(a, b)| (a - b).abs() < 1e-12),
                "{s:e}: {y:?}"
            );
        }
        assert!(network_input([0.0; 3], wo).is_none());
    }

    /// A negative, zero, NaN or infinite outlier threshold is refused before resampling (with
    /// `-1` and clamping every value used to be stored as -1).
    #[test]
    fn bad_outlier_thresholds_are_refused() {
        let net = Nbrdf::from_weights("t".into(), &vec![0f32; WEIGHTS_PER_NETWORK]).unwrap();
        let grid = AngularGrid::new(2, 2, 4).unwrap();
        for t in [-1.0, 0.0, f64::NAN, f64::INFINITY] {
            let options = NbrdfOptions {
                outlier_threshold: t,
                clamp_outliers: true,
                ..NbrdfOptions::default()
            };
            let e = net.resample_with(&grid, options).unwrap_err();
            assert!(matches!(e, Error::InvalidArgument { .. }), "{e}");
            assert!(
                e.to_string().contains(&format!(
                    "outlier threshold {t} must be a finite number > 0"
                )),
                "{e}"
            );
        }
        let options = NbrdfOptions {
            outlier_threshold: 0.5,
            clamp_outliers: true,
            ..NbrdfOptions::default()
        };
        let (values, report) = net.resample_with(&grid, options).unwrap();
        assert_eq!(values.len(), 3 * grid.len());
        assert_eq!(report.outliers_clamped, 0);
        assert!(values.iter().all(|&v| v == 0.0), "{values:?}");
    }

    #[test]
    fn forward_pass_of_a_hand_built_network() {
        // Only hidden unit 0 of each layer is active: a1_0 = relu(hz), a2_0 = relu(2 a1_0),
        // rgb_c = exp((c + 1) * a2_0 + 0.1) - 1.
        let mut row = vec![0f32; WEIGHTS_PER_NETWORK];
        row[W1 + 2 * 21] = 1.0;
        row[W2] = 2.0;
        for c in 0..3 {
            row[W3 + c] = (c + 1) as f32;
            row[B3 + c] = 0.1;
        }
        let net = Nbrdf::from_weights("t".into(), &row).unwrap();
        let y = net.forward([0.0, 0.0, 0.5, 0.3, 0.2, 0.9]);
        for (c, v) in y.iter().enumerate() {
            let want = ((c as f64 + 1.0) * 1.0 + 0.1f64).exp() - 1.0;
            assert!((v - want).abs() < 1e-6, "{y:?}");
        }
        // Negative pre-activations clamp: hz < 0 gives exp(0.1) - 1 on every channel.
        let z = net.forward([0.0, 0.0, -1.0, 0.0, 0.0, 1.0]);
        assert!((z[0] - (0.1f64.exp() - 1.0)).abs() < 1e-6);
    }

    /// A network of seeded weights in [-0.6, 0.6) (splitmix64).
    fn seeded_network(seed: u64) -> Nbrdf {
        let mut state = seed;
        let row: Vec<f32> = (0..WEIGHTS_PER_NETWORK)
            .map(|_| {
                state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
                let mut z = state;
                z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
                z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
                z ^= z >> 31;
                ((z >> 11) as f64 / (1u64 << 53) as f64 * 1.2 - 0.6) as f32
            })
            .collect();
        Nbrdf::from_weights(format!("net{seed}"), &row).unwrap()
    }

    /// The forward pass neuron by neuron, as the authors' `nn.h` writes it: the reference the
    /// vectorised layers must reproduce bit for bit.
    fn forward_by_neurons(net: &Nbrdf, x: [f64; 6]) -> [f64; 3] {
        let w = &net.w;
        let dense = |input: &[f64], weights: usize, bias: usize, outputs: usize| -> Vec<f64> {
            (0..outputs)
                .map(|j| {
                    let mut s = w[bias + j];
                    for (i, xi) in input.iter().enumerate() {
                        s += xi * w[weights + i * outputs + j];
                    }
                    s
                })
                .collect()
        };
        let a1: Vec<f64> = dense(&x, W1, B1, 21).iter().map(|v| v.max(0.0)).collect();
        let a2: Vec<f64> = dense(&a1, W2, B2, 21).iter().map(|v| v.max(0.0)).collect();
        let o = dense(&a2, W3, B3, 3);
        [0, 1, 2].map(|c| (o[c].exp() - 1.0).max(0.0))
    }

    #[test]
    fn vectorised_layers_give_the_neuron_by_neuron_bits() {
        let grid = AngularGrid::new(6, 6, 12).unwrap();
        for seed in 0..8 {
            let net = seeded_network(seed);
            for cell in 0..grid.len() {
                let (wi, wo) = grid.bin_centre_flat(cell).to_dirs();
                for x in [network_input(wi, wo), network_input(wo, wi)]
                    .into_iter()
                    .flatten()
                {
                    let (got, want) = (net.forward(x), forward_by_neurons(&net, x));
                    assert_eq!(got.map(f64::to_bits), want.map(f64::to_bits), "{x:?}");
                }
            }
        }
    }

    /// Resampling on shared inputs gives `resample_with`'s values and report exactly, in both
    /// reciprocity modes, with the table and without one (the fallback of grids beyond
    /// `GridInputs::MAX_BYTES`).
    #[test]
    fn shared_inputs_resample_the_same_bits() {
        let grid = AngularGrid::new(8, 8, 16).unwrap();
        let tabulated = GridInputs::new(&grid);
        assert!(tabulated.is_tabulated());
        let untabulated = GridInputs {
            grid,
            table: Vec::new(),
        };
        assert!(!untabulated.is_tabulated());
        for seed in [3, 11] {
            let net = seeded_network(seed);
            for reciprocal in [true, false] {
                let options = NbrdfOptions {
                    reciprocal,
                    ..NbrdfOptions::default()
                };
                let (want, want_report) = net.resample_with(&grid, options).unwrap();
                assert!(want.iter().any(|&v| v > 0.0));
                for inputs in [&tabulated, &untabulated] {
                    let (got, report) = net.resample_on(inputs, options).unwrap();
                    assert_eq!(
                        got.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                        want.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
                    );
                    // The cosine-weighted sums depend on how rayon split the cells; the
                    // rest of the report does not.
                    let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 * b.abs();
                    assert!(close(report.reciprocal_sq, want_report.reciprocal_sq));
                    assert!(close(
                        report.non_reciprocal_sq,
                        want_report.non_reciprocal_sq
                    ));
                    let sums_aside = ImportReport {
                        reciprocal_sq: want_report.reciprocal_sq,
                        non_reciprocal_sq: want_report.non_reciprocal_sq,
                        ..report
                    };
                    assert_eq!(sums_aside, want_report);
                }
            }
        }
    }
}
