//! Bad inputs reach a clear error or a documented clamp, never a panic or a silently black or
//! NaN picture: sources that return NaN, infinite, negative or huge values, degenerate image
//! sizes and light directions, degenerate latent maps, labels that do not fit.

use brdf_io::{AngularGrid, BrdfSource, Channels, Vec3};
use render::sphere::{PlaneOptions, SphereOptions};
use render::{Error, render_plane, render_sphere};

/// A constant BRDF `value` above the horizon in every channel, except that `bad` replaces it
/// in channel `channel` where the view's cosine is below `below` (1.1: everywhere).
struct Faulty {
    channels: Channels,
    value: f64,
    bad: f64,
    channel: usize,
    below: f64,
    /// Whether it is a grid source (8 x 8 x 16 cells, the bad value in every cell with
    /// theta_h >= 30 degrees when `below` < 1.1).
    grid: Option<AngularGrid>,
}

impl Faulty {
    fn new(channels: Channels, bad: f64, channel: usize) -> Self {
        Self {
            channels,
            value: 0.2,
            bad,
            channel,
            below: 1.1,
            grid: None,
        }
    }
}

impl BrdfSource for Faulty {
    fn channels(&self) -> Channels {
        self.channels.clone()
    }
    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> brdf_io::Result<()> {
        out.fill(0.0);
        if wi[2] > 0.0 && wo[2] > 0.0 {
            out.fill(self.value);
            // `wi` is the first direction: the view (see the sphere module's docs).
            if wi[2] < self.below {
                out[self.channel] = self.bad;
            }
        }
        Ok(())
    }
    fn grid(&self) -> Option<AngularGrid> {
        self.grid
    }
    fn eval_cell(&self, a: usize, out: &mut [f64]) -> brdf_io::Result<()> {
        let grid = self.grid.expect("a grid source");
        out.fill(self.value);
        if self.below > 1.0 || grid.bin_centre_flat(a).theta_h >= 30f64.to_radians() {
            out[self.channel] = self.bad;
        }
        Ok(())
    }
}

const MODES: [&str; 4] = ["table", "fast", "per-pixel", "studio"];

fn opts(size: usize, mode: &str) -> SphereOptions {
    SphereOptions {
        size,
        env_mode: mode.parse().unwrap(),
        ..SphereOptions::default()
    }
}

/// A NaN or infinite BRDF value in a channel the colour needs is an error naming the value,
/// the channel and where it was looked up, for every environment, sphere and plane, grid and
/// other sources, RGB and spectral. It used to render silently: NaN counted as 0 (a black
/// sphere), infinity made NaN pixels (black in the PNG).
#[test]
fn non_finite_brdf_values_are_errors_naming_the_channel() {
    let spectral = Channels::parse_wavelengths("400:700:50").unwrap();
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        for (channels, channel, name) in [
            (Channels::Rgb, 1, "channel G"),
            (spectral.clone(), 2, "channel 500 nm"),
        ] {
            for grid in [None, Some(AngularGrid::new(8, 8, 16).unwrap())] {
                for below in [1.1, 0.5] {
                    let src = Faulty {
                        below,
                        grid,
                        ..Faulty::new(channels.clone(), bad, channel)
                    };
                    for mode in MODES {
                        for plane in [false, true] {
                            let o = opts(12, mode);
                            let r = if plane {
                                render_plane(&src, &o, &PlaneOptions::default())
                            } else {
                                render_sphere(&src, &o)
                            };
                            let what =
                                format!("{bad} {channels:?} {grid:?} {below} {mode} {plane}");
                            let err = r.expect_err(&what);
                            assert!(matches!(err, Error::NonFiniteValue { .. }), "{what}: {err}");
                            let msg = err.to_string();
                            assert!(msg.contains(name), "{what}: {msg}");
                            assert!(msg.contains(&format!("returned {bad} ")), "{what}: {msg}");
                            let at = if grid.is_some() {
                                "grid cell"
                            } else {
                                "view ("
                            };
                            assert!(msg.contains(at), "{what}: {msg}");
                        }
                    }
                }
            }
        }
    }
}

/// A NaN in a channel the observer does not see (900 nm, whose hat function starts at 780 nm,
/// where the CIE tables end) changes no pixel and is no error: only the channels the colour
/// needs are read.
#[test]
fn non_finite_values_in_unneeded_channels_do_not_matter() {
    let channels = Channels::Spectral(vec![500.0, 600.0, 780.0, 900.0]);
    for grid in [None, Some(AngularGrid::new(8, 8, 16).unwrap())] {
        let nan = Faulty {
            grid,
            ..Faulty::new(channels.clone(), f64::NAN, 3)
        };
        let fine = Faulty {
            grid,
            ..Faulty::new(channels.clone(), 0.2, 3)
        };
        for mode in MODES {
            let o = opts(10, mode);
            let (a, b) = (
                render_sphere(&nan, &o).unwrap(),
                render_sphere(&fine, &o).unwrap(),
            );
            assert_eq!(a, b, "{mode}");
            assert!(a.rgb[55][1] > 0.05, "{mode}: {:?}", a.rgb[55]);
        }
    }
}

/// Huge finite values: 1e300 renders (every covered pixel far above 1, so white in the PNG);
/// 1e308 overflows f64 in the colour sums and the environment table (infinity minus infinity,
/// NaN pixels that encoded as black) and is an overflow error instead.
#[test]
fn huge_brdf_values_render_white_or_are_an_overflow_error() {
    for grid in [None, Some(AngularGrid::new(8, 8, 16).unwrap())] {
        for mode in MODES {
            let o = opts(10, mode);
            let src = |value| Faulty {
                value,
                grid,
                ..Faulty::new(Channels::Rgb, 0.0, 0)
            };
            // (channel 0 is 0 everywhere: `bad` = 0.)
            let img = render_sphere(&src(1e300), &o).unwrap();
            let covered: Vec<_> = (img.rgb.iter().zip(&img.alpha))
                .filter(|(_, a)| **a > 0.0)
                .map(|(p, _)| p)
                .collect();
            assert!(covered.len() > 50);
            for p in covered {
                assert_eq!(p[0], 0.0, "{mode}");
                assert!(p[1] > 1e290 && p[1].is_finite(), "{mode}: {p:?}");
            }
            let overflow = SphereOptions {
                exposure: 64.0,
                ..o.clone()
            };
            match render_sphere(&src(1e308), &overflow) {
                Ok(img) => assert!(
                    img.rgb.iter().flatten().all(|v| !v.is_nan()),
                    "{mode}: NaN pixels"
                ),
                Err(e) => {
                    assert!(matches!(e, Error::Overflow { .. }), "{mode}: {e}");
                    assert!(e.to_string().contains("pixels are NaN"), "{e}");
                }
            }
        }
    }
    // The table's interpolation between two infinite nodes was NaN: an error now.
    let err = render_sphere(
        &Faulty::new(Channels::Rgb, 1e308, 0),
        &SphereOptions {
            size: 10,
            exposure: 10.0,
            ..SphereOptions::default()
        },
    )
    .unwrap_err();
    assert!(matches!(err, Error::Overflow { .. }), "{err}");
}

/// Negative BRDF values count as 0 (documented), in every environment.
#[test]
fn negative_brdf_values_render_as_zero_in_every_mode() {
    for mode in MODES {
        let img = render_sphere(&Faulty::new(Channels::Rgb, -5.0, 2), &opts(10, mode)).unwrap();
        for (p, a) in img.rgb.iter().zip(&img.alpha) {
            if *a > 0.0 {
                assert_eq!(p[2], 0.0, "{mode}");
                assert!(p[0] > 0.0 && p[0] == p[1], "{mode}: {p:?}");
            }
        }
    }
}
