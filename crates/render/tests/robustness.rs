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
                            let err = error_of(r, &what);
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
    let err = error_of(
        render_sphere(
            &Faulty::new(Channels::Rgb, 1e308, 0),
            &SphereOptions {
                size: 10,
                exposure: 10.0,
                ..SphereOptions::default()
            },
        ),
        "1e308",
    );
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

type Points = Vec<(String, [f64; 2])>;

/// The error of a render that must fail (a picture in the panic message would be megabytes).
fn error_of(r: render::Result<render::Image>, what: &str) -> Error {
    match r {
        Ok(img) => panic!("{what}: rendered a {}x{} picture", img.width, img.height),
        Err(e) => e,
    }
}

fn map_opts() -> render::MapOptions {
    render::MapOptions {
        size: 64,
        variance_samples: 4,
        ..render::MapOptions::default()
    }
}

/// Red dot cores on a map (the training materials' colour, [0.8, 0.05, 0.02]).
fn red_pixels(img: &render::Image) -> usize {
    img.rgb
        .iter()
        .filter(|p| p[0] > 0.6 && p[1] < 0.15 && p[2] < 0.15)
        .count()
}

/// A NaN or infinite predictive variance is an error naming the latent point, whether the
/// background's samples or a thumbnail's far-from-every-material test meets it. A NaN drew
/// white (no uncertainty) and an infinite variance turned the whole map white with a colour
/// bar labelled `inf`, silently. Negative variances (rounding below zero) are clamped.
#[test]
fn non_finite_map_variances_are_errors_naming_the_point() {
    let points: Points = vec![("A".into(), [0.0, 0.0]), ("B".into(), [1.0, 1.0])];
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        let variance = |p: [f64; 2]| Ok(if p[0] > 0.5 { bad } else { 1.0 });
        let err = error_of(
            render::latent_map(&points, &variance, None, &map_opts()),
            &format!("{bad}"),
        );
        let msg = err.to_string();
        assert!(
            msg.contains("predictive variance at latent point (")
                && msg.contains(&format!("is {bad}")),
            "{msg}"
        );
    }
    // Only at the one thumbnail's point (the box's centre, no background sample): met by the
    // far-from-every-material test.
    let variance = |p: [f64; 2]| Ok(if p == [0.5, 0.5] { f64::NAN } else { 1.0 });
    let source = |_: [f64; 2]| -> render::Result<Box<dyn BrdfSource>> {
        Ok(Box::new(Faulty::new(Channels::Rgb, 0.2, 0)))
    };
    let thumbs = render::MapOptions {
        thumbnails: 1,
        sphere: SphereOptions {
            size: 8,
            ..SphereOptions::default()
        },
        far_variance: Some(0.5),
        ..map_opts()
    };
    let err = error_of(
        render::latent_map(&points, &variance, Some(&source), &thumbs),
        "NaN at the thumbnail",
    );
    assert!(err.to_string().contains("(0.5, 0.5) is NaN"), "{err}");
    // Without the far test the thumbnail's variance is not read.
    let no_far = render::MapOptions {
        far_variance: None,
        ..thumbs
    };
    assert!(render::latent_map(&points, &variance, Some(&source), &no_far).is_ok());
    // Negative and zero variances draw (clamped to 0: white).
    let variance = |p: [f64; 2]| Ok(-p[0]);
    let img = render::latent_map(&points, &variance, None, &map_opts()).unwrap();
    assert!(red_pixels(&img) > 0);
}

/// Degenerate latent maps draw their dots: one or two materials, all at one point, a tiny
/// range, coordinates up to 1e300, non-ASCII and overlong names, one latent axis with
/// thumbnails. Coordinates whose plot extent overflows f64 (1e308 apart, f64::MAX) are an
/// error saying so: the map drew no dot at all (every position NaN), silently.
#[test]
fn degenerate_latent_maps_draw_or_are_refused_clearly() {
    let variance = |_: [f64; 2]| Ok(1.0);
    let source = |_: [f64; 2]| -> render::Result<Box<dyn BrdfSource>> {
        Ok(Box::new(Faulty::new(Channels::Rgb, 0.2, 0)))
    };
    let cases: Vec<Points> = vec![
        vec![("A".into(), [0.0, 0.0])],
        vec![("A".into(), [0.3, -2.0]), ("B".into(), [0.3, -2.0])],
        vec![("A".into(), [1e-300, 0.0]), ("B".into(), [-1e-300, 0.0])],
        vec![("A".into(), [1e300, -1e300]), ("B".into(), [-1e300, 1e300])],
        vec![("A".into(), [7e307, 0.0]), ("B".into(), [7e307, 1.0])],
        vec![
            ("ÄÖÜ größe ★".into(), [0.0, 0.0]),
            ("日本語".into(), [0.1, 0.0]),
            ("X".repeat(400), [0.2, 0.0]),
        ],
    ];
    for points in &cases {
        for one_axis in [false, true] {
            for (thumbnails, src) in [(0, None), (2, Some(&source))] {
                let opts = render::MapOptions {
                    thumbnails,
                    one_axis,
                    sphere: SphereOptions {
                        size: 8,
                        ..SphereOptions::default()
                    },
                    ..map_opts()
                };
                let src = src.map(|s| s as &render::map::SourceAt<'_>);
                let img = render::latent_map(points, &variance, src, &opts)
                    .unwrap_or_else(|e| panic!("{points:?}: {e}"));
                assert!(red_pixels(&img) >= 1, "{points:?}: no dot drawn");
                assert!(img.rgb.iter().flatten().all(|v| v.is_finite()));
            }
        }
    }
    for points in [
        vec![
            ("A".to_owned(), [1e308, 1e308]),
            ("B".to_owned(), [-1e308, -1e308]),
        ],
        vec![("A".to_owned(), [f64::MAX, 0.0])],
        vec![
            ("A".to_owned(), [0.0, -f64::MAX]),
            ("B".to_owned(), [0.0, 0.0]),
        ],
    ] {
        let err = error_of(
            render::latent_map(&points, &variance, None, &map_opts()),
            &format!("{points:?}"),
        );
        assert!(
            err.to_string().contains("too large to plot"),
            "{points:?}: {err}"
        );
    }
    // Non-finite coordinates and variance sample counts out of range are refused up front
    // (a count of 10^6 per axis allocated 10^12 samples and aborted).
    let points: Points = vec![("A".into(), [f64::NAN, 0.0])];
    error_of(
        render::latent_map(&points, &variance, None, &map_opts()),
        "NaN",
    );
    let points: Points = vec![("A".into(), [0.0, 0.0])];
    for samples in [0, 1, render::map::MAX_VARIANCE_SAMPLES + 1, 1 << 40] {
        let opts = render::MapOptions {
            variance_samples: samples,
            ..map_opts()
        };
        let err = error_of(
            render::latent_map(&points, &variance, None, &opts),
            &format!("{samples} samples"),
        );
        assert!(
            err.to_string().contains("variance samples"),
            "{samples}: {err}"
        );
    }
}

/// Ticks over a range wider than the largest f64 (-1e308..1e308) are none, not one at NaN.
#[test]
fn ticks_of_an_overflowing_range_are_empty() {
    assert!(render::map::nice_ticks(-1e308, 1e308, 5).is_empty());
    let t = render::map::nice_ticks(-1e307, 1e307, 5);
    assert!(
        !t.is_empty() && t.iter().all(|(v, _)| v.is_finite()),
        "{t:?}"
    );
}

/// A heat map of values that do not make whole rows is an error (it indexed past the image and
/// panicked); whole rows draw.
#[test]
fn heat_maps_of_partial_rows_are_refused() {
    let map = vec![Some(1.0), None, Some(3.0), Some(0.5), None];
    for width in [0, 2, 3, 4] {
        let err = render::sheet::heat_map(&map, width, 5.0)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("5 values is not made of rows"),
            "{width}: {err}"
        );
    }
    let img = render::sheet::heat_map(&map, 5, 5.0).unwrap();
    assert_eq!((img.width, img.height), (5, 1));
    assert_eq!(img.alpha, [1.0, 0.0, 1.0, 1.0, 0.0]);
    let empty = render::sheet::heat_map(&[], 0, 5.0).unwrap();
    assert_eq!((empty.width, empty.height), (0, 0));
}

/// The colour bar and its top label of a comparison sheet stay on the image, the label over
/// the bar however long the number: with small spheres the 60 px bar ran off the image's
/// right edge, taking the label with it, and a scale of 1e300 was written as 301 digits from
/// far left of the image, over the bar's "0" and its name.
#[test]
fn sheet_scale_labels_fit_over_their_bar() {
    let src = Faulty::new(Channels::Rgb, 0.2, 0);
    let rows = vec![("R".to_owned(), vec![&src as &dyn BrdfSource, &src])];
    for de_max in [10.0, 2.5, 1e300, 123456789.0, 1e-7] {
        let sheet = render::comparison_sheet(&["A", "B"], &rows, &opts(16, "table"), de_max)
            .unwrap_or_else(|e| panic!("{de_max}: {e}"));
        let img = &sheet.image;
        // Label column 40 + 8 px, cells of 16 + 8 px: the bar starts at x0 = 56 + 2 x 24 and
        // is 60 px wide; its labels sit 13 px below its top (y = 19 + 35 + 8 + 13).
        let (x0, y) = (104usize, 75usize);
        assert_eq!(img.width, x0 + 60 + 8, "{de_max}");
        assert!(
            img.get(x0 + 59, y - 5) != img.get(x0 + 59, 0),
            "no bar at its end"
        );
        let ink: Vec<usize> = (y..y + 7)
            .flat_map(|y| (0..img.width).filter(move |&x| img.get(x, y)[0] > 0.5))
            .collect();
        assert!(ink.iter().any(|&x| x >= x0), "{de_max}: no top label");
        for x in ink {
            let on_zero = (x0 - 12..x0 - 12 + 5).contains(&x);
            assert!(
                on_zero || (x0..x0 + 60).contains(&x),
                "{de_max}: ink at x = {x}"
            );
        }
        assert_eq!(sheet.mean_delta_e, [[0.0]]);
    }
}

/// A thumbnail that fails names its latent point, with the cause.
#[test]
fn failed_thumbnails_name_their_latent_point() {
    let points: Points = vec![("A".into(), [0.0, 0.0]), ("B".into(), [1.0, 1.0])];
    let variance = |_: [f64; 2]| Ok(1.0);
    let source = |p: [f64; 2]| -> render::Result<Box<dyn BrdfSource>> {
        let bad = if p[0] > 0.5 && p[1] > 0.5 {
            f64::NAN
        } else {
            0.2
        };
        Ok(Box::new(Faulty::new(Channels::Rgb, bad, 1)))
    };
    let opts = render::MapOptions {
        thumbnails: 2,
        sphere: SphereOptions {
            size: 8,
            ..SphereOptions::default()
        },
        ..map_opts()
    };
    let err = error_of(
        render::latent_map(&points, &variance, Some(&source), &opts),
        "NaN thumbnail",
    );
    let msg = err.to_string();
    assert!(
        msg.starts_with("the thumbnail at latent point (0.75, 0.75): the BRDF source returned NaN"),
        "{msg}"
    );
    assert!(matches!(
        err,
        Error::Thumbnail { point: [0.75, 0.75], ref cause } if matches!(**cause, Error::NonFiniteValue { .. })
    ));
    // Its cause is in its message only, so a chain printed with `{:#}` says it once.
    assert!(std::error::Error::source(&err).is_none());
}

/// Out-of-range scene numbers are errors that quote them readably: 1e300 as `1e300`, not as
/// three hundred digits.
#[test]
fn bad_scene_numbers_are_quoted_readably() {
    let src = Faulty::new(Channels::Rgb, 0.5, 0);
    let cases = [
        (
            SphereOptions {
                exposure: 1e300,
                ..opts(10, MODES[0])
            },
            "exposure 1e300 must be within +-64 stops",
        ),
        (
            SphereOptions {
                light: (1e300, 0.0),
                ..opts(10, MODES[0])
            },
            "light (1e300, 0.0): theta must be in [0, 180] degrees",
        ),
        (
            SphereOptions {
                env_radiance: -1e-300,
                ..opts(10, MODES[0])
            },
            "environment radiance -1e-300 must be finite and >= 0",
        ),
    ];
    for (options, message) in cases {
        let e = error_of(render_sphere(&src, &options), message);
        assert!(matches!(e, Error::InvalidArgument { .. }), "{e}");
        assert!(e.to_string().contains(message), "{e}");
    }
}
