//! Robustness of the file readers (RGL tensor files, dataset stores, MERL, `.npy`, Neural-BRDF):
//! random bytes and corruptions of real files must give errors naming the file, never panics,
//! hangs or allocations beyond the file's size. (The cargo-fuzz target in `fuzz/` explores the
//! tensor-file reader further.)

use std::path::{Path, PathBuf};

use brdf_io::Channels;
use brdf_io::rgl::RglBsdf;
use brdf_io::tensor::{Field, TensorFile};
use proptest::prelude::*;

fn real_file() -> Option<(PathBuf, Vec<u8>)> {
    let p = shared_data::path("rgl-rgb/paper_white_rgb.bsdf")?;
    let b = std::fs::read(&p).unwrap();
    Some((p, b))
}

/// Parses bytes as a tensor file and, when that works, as an RGL BSDF, evaluating a few pairs.
/// Returns whether the BSDF could be built.
fn exercise(bytes: &[u8]) -> bool {
    let Ok(tf) = TensorFile::from_bytes(bytes, "fuzz.bsdf") else {
        return false;
    };
    for f in tf.fields() {
        let _ = f.to_f64(Path::new("fuzz.bsdf"));
    }
    let Ok(bsdf) = RglBsdf::from_tensor_file(&tf) else {
        return false;
    };
    let mut out = vec![0.0; bsdf.channels().len()];
    for (wi, wo) in [
        ([0.0, 0.0, 1.0], [0.0, 0.0, 1.0]),
        ([0.3, 0.1, 0.9], [-0.5, 0.2, 0.4]),
        ([0.999, 0.0, 0.01], [-0.999, 0.0, 0.01]),
    ] {
        bsdf.eval(wi, wo, &mut out).unwrap();
    }
    true
}

#[test]
fn truncations_of_a_real_file_are_errors() {
    let Some((_, bytes)) = real_file() else {
        return;
    };
    assert!(exercise(&bytes), "the intact file must load");
    let mut cut = 0;
    while cut < bytes.len() {
        assert!(
            TensorFile::from_bytes(&bytes[..cut], "t.bsdf").is_err(),
            "truncation at {cut} accepted"
        );
        cut += 1024;
    }
    // Every cut inside the header too.
    for cut in 0..420 {
        assert!(TensorFile::from_bytes(&bytes[..cut], "t.bsdf").is_err());
    }
}

#[test]
fn header_byte_flips_never_panic() {
    let Some((_, bytes)) = real_file() else {
        return;
    };
    // The field table ends before the first array (offset 416 in this file).
    let mut loaded = 0;
    let mut copy = bytes.clone();
    for pos in 0..416 {
        for v in [0u8, 0xff, bytes[pos] ^ 0x01, bytes[pos].wrapping_add(8)] {
            if v == bytes[pos] {
                continue;
            }
            copy[pos] = v;
            loaded += usize::from(exercise(&copy));
            copy[pos] = bytes[pos];
        }
    }
    // Some flips (e.g. in the description text) keep the file loadable.
    assert!(loaded > 0);
}

#[test]
fn corrupted_offsets_and_data_are_errors() {
    let Some((path, bytes)) = real_file() else {
        return;
    };
    let tf = TensorFile::open(&path).unwrap();
    // Locate each field's offset slot in the header and point it past the end of the file.
    let mut pos = 18;
    for f in tf.fields() {
        let offset_at = pos + 2 + f.name().len() + 2 + 1;
        let mut copy = bytes.clone();
        copy[offset_at..offset_at + 8].copy_from_slice(&(bytes.len() as u64).to_le_bytes());
        let e = match TensorFile::from_bytes(&copy, "o.bsdf") {
            Ok(_) => panic!("offset of {:?} past the end accepted", f.name()),
            Err(e) => e.to_string(),
        };
        assert!(e.contains("past the end") && e.contains(f.name()), "{e}");
        copy[offset_at..offset_at + 8].copy_from_slice(&u64::MAX.to_le_bytes());
        assert!(TensorFile::from_bytes(&copy, "o.bsdf").is_err());
        pos = offset_at + 8 + 8 * f.shape().len();
    }
    // A NaN inside the rgb table: the BSDF refuses to load and names the field.
    let rgb_at = 559_592 + 4 * 1000;
    let mut copy = bytes.clone();
    copy[rgb_at..rgb_at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    let tf = TensorFile::from_bytes(&copy, "nan.bsdf").unwrap();
    let e = RglBsdf::from_tensor_file(&tf).unwrap_err().to_string();
    assert!(
        e.contains("nan.bsdf") && e.contains("\"rgb\"") && e.contains("non-finite"),
        "{e}"
    );
}

/// The BSDF divides by sigma and multiplies by the NDF: a zero sigma (which gave infinite
/// values) or a negative NDF is an error naming the file and the field.
#[test]
fn zero_sigma_and_negative_ndf_are_errors() {
    if real_file().is_none() {
        return;
    }
    for (name, bad, rule) in [("sigma", 0.0f32, "> 0"), ("ndf", -1.0, ">= 0")] {
        let tf = with_field(name, "bad.bsdf", |v| v[7] = bad).unwrap();
        let e = RglBsdf::from_tensor_file(&tf).unwrap_err().to_string();
        assert!(
            e.contains("bad.bsdf") && e.contains(&format!("\"{name}\"")) && e.contains(rule),
            "{e}"
        );
        assert!(e.contains("value 7 of"), "{e}");
    }
    // The rgb table renamed: a spectral table without its wavelengths is named as such (not
    // "missing field rgb"); with neither table, the RGB one is missing.
    for (name, reason) in [
        ("spectra", "without its field \"wavelengths\""),
        ("table", "missing field \"rgb\""),
    ] {
        let tf = with_replaced("rgb", "spec.bsdf", |f, path| {
            Field::from_f32(name, f.shape().to_vec(), &f.to_f32(path).unwrap()).unwrap()
        })
        .unwrap();
        let e = RglBsdf::from_tensor_file(&tf).unwrap_err().to_string();
        assert!(e.contains("spec.bsdf") && e.contains(reason), "{name}: {e}");
    }
}

/// A stray "spectra" field in an RGB file (no wavelengths) is ignored: the file is the RGB
/// file it was, value for value.
#[test]
fn an_rgb_file_with_a_stray_spectra_field_is_read_as_rgb() {
    let Some((path, _)) = real_file() else {
        return;
    };
    let tf = TensorFile::open(&path).unwrap();
    let mut fields = tf.fields().to_vec();
    fields.push(Field::from_f32("spectra", vec![2], &[1.0, 2.0]).unwrap());
    let bytes = TensorFile::to_bytes(&fields).unwrap();
    let stray = TensorFile::from_bytes(&bytes, "stray.bsdf").unwrap();
    let (a, b) = (
        RglBsdf::from_tensor_file(&tf).unwrap(),
        RglBsdf::from_tensor_file(&stray).unwrap(),
    );
    assert_eq!(b.channels(), Channels::Rgb);
    let (mut fa, mut fb) = ([0.0; 3], [0.0; 3]);
    for (wi, wo) in [
        ([0.0, 0.0, 1.0], [0.0, 0.0, 1.0]),
        ([0.3, 0.1, 0.9], [-0.5, 0.2, 0.4]),
    ] {
        a.eval(wi, wo, &mut fa).unwrap();
        b.eval(wi, wo, &mut fb).unwrap();
        assert_eq!(fa, fb);
        assert!(fa[0] > 0.1, "{fa:?}");
    }
}

/// The value, VNDF and luminance tables must agree in shape: a square luminance table of
/// another size than the value table, and empty incident axes (every table then empty along
/// them), are refused with the reason.
#[test]
fn table_shapes_must_agree_and_incident_axes_be_non_empty() {
    // Luminance at half the value table's size (square, finite, >= 0; evaluation never reads it).
    let Some(tf) = with_replaced("luminance", "lum.bsdf", |f, _| {
        let s = f.shape();
        let shape = vec![s[0], s[1], s[2] / 2, s[3] / 2];
        Field::from_f32(
            "luminance",
            shape.clone(),
            &vec![0.5; shape.iter().product()],
        )
        .unwrap()
    }) else {
        return;
    };
    let e = RglBsdf::from_tensor_file(&tf).unwrap_err().to_string();
    assert!(
        e.contains("lum.bsdf") && e.contains("need equal square tables"),
        "{e}"
    );
    // Empty phi_i (axis 0 of the tables) or theta_i (axis 1), consistently everywhere.
    for axis in [0, 1] {
        let name = ["phi_i", "theta_i"][axis];
        let tf = rebuilt("empty.bsdf", |f, _| {
            let mut shape = f.shape().to_vec();
            match f.name() {
                n if n == name => shape[0] = 0,
                "vndf" | "luminance" | "rgb" => shape[axis] = 0,
                _ => return None,
            }
            Some(Field::from_f32(f.name(), shape, &[]).unwrap())
        })
        .unwrap();
        let e = RglBsdf::from_tensor_file(&tf).unwrap_err().to_string();
        assert!(
            e.contains("empty.bsdf") && e.contains("empty phi_i or theta_i"),
            "{name}: {e}"
        );
    }
}

/// The real file with field `name` replaced by `edit` of its values (as f32), parsed as if read
/// from `file_name`.
fn with_field(name: &str, file_name: &str, edit: impl Fn(&mut Vec<f32>)) -> Option<TensorFile> {
    with_replaced(name, file_name, |f, path| {
        let mut v = f.to_f32(path).unwrap();
        edit(&mut v);
        Field::from_f32(name, f.shape().to_vec(), &v).unwrap()
    })
}

/// The real file with field `name` replaced by `field(old, real file's path)`, parsed as if read
/// from `file_name`.
fn with_replaced(
    name: &str,
    file_name: &str,
    field: impl Fn(&Field, &Path) -> Field,
) -> Option<TensorFile> {
    rebuilt(file_name, |f, path| {
        (f.name() == name).then(|| field(f, path))
    })
}

/// The real file with every field `f` for which `replace(f, real file's path)` gives one
/// replaced by it, parsed as if read from `file_name`.
fn rebuilt(
    file_name: &str,
    replace: impl Fn(&Field, &Path) -> Option<Field>,
) -> Option<TensorFile> {
    let (path, _) = real_file()?;
    let tf = TensorFile::open(&path).unwrap();
    let fields: Vec<Field> = tf
        .fields()
        .iter()
        .map(|f| replace(f, &path).unwrap_or_else(|| f.clone()))
        .collect();
    let bytes = TensorFile::to_bytes(&fields).unwrap();
    Some(TensorFile::from_bytes(&bytes, file_name).unwrap())
}

/// The error of building the BSDF from the real file with field `name` edited; it must name the
/// file, the field (in quotes) and contain every one of `words`.
fn assert_refused(name: &str, edit: impl Fn(&mut Vec<f32>), words: &[&str]) {
    assert_file_refused(with_field(name, "damaged.bsdf", edit), name, words);
}

/// Building the BSDF from `tf` (`None`: no shared data, nothing to check) fails with an error
/// naming the file, the field `name` (in quotes) and containing every one of `words`.
fn assert_file_refused(tf: Option<TensorFile>, name: &str, words: &[&str]) {
    let Some(tf) = tf else {
        return;
    };
    let e = RglBsdf::from_tensor_file(&tf).unwrap_err().to_string();
    assert!(
        e.contains(&tf.path().display().to_string()) && e.contains(&format!("\"{name}\"")),
        "{e}"
    );
    for w in words {
        assert!(e.contains(w), "{w:?} missing from: {e}");
    }
}

/// Incident angles outside the format's range made evaluation NaN or silently wrong (an audit:
/// a moved `theta_i` offset gave NaN in 10 % of random pairs, a negative first `theta_i` 0.2395
/// instead of 0.2783 at normal incidence, a last one of 10 rad was accepted).
#[test]
fn out_of_range_incident_angles_are_errors() {
    let Some((_, bytes)) = real_file() else {
        return;
    };
    // The audit's file: byte 117 is in the offset of theta_i (stored at 456), which then reads
    // 8 increasing vndf values, 1.1e-4 to 1.37e-4.
    let mut copy = bytes.clone();
    copy[117] ^= 0xff;
    let tf = TensorFile::from_bytes(&copy, "flip117.bsdf").unwrap();
    let t = tf.field_f64("theta_i").unwrap();
    assert!(t[0] > 1.1e-4 && t[7] < 1.37e-4, "{t:?}");
    let e = RglBsdf::from_tensor_file(&tf).unwrap_err().to_string();
    assert!(
        e.contains("flip117.bsdf")
            && e.contains("\"theta_i\"")
            && e.contains("must run from 0 to pi/2")
            && e.contains("0.0063 to 0.0078 degrees"),
        "{e}"
    );
    // The audit's other file: theta_i[0] = -1 written over the bytes.
    let mut copy = bytes.clone();
    copy[456..460].copy_from_slice(&(-1.0f32).to_le_bytes());
    let tf = TensorFile::from_bytes(&copy, "neg.bsdf").unwrap();
    let e = RglBsdf::from_tensor_file(&tf).unwrap_err().to_string();
    assert!(
        e.contains("neg.bsdf")
            && e.contains("\"theta_i\"")
            && e.contains("within [0, pi/2]")
            && e.contains("value 0 of 8 is -1"),
        "{e}"
    );
    let range = "within [0, pi/2]";
    assert_refused("theta_i", |v| v[7] = 10.0, &[range, "value 7 of 8 is 10"]);
    // Just past pi/2 + 1e-6 (the slack for f32 rounding).
    assert_refused("theta_i", |v| v[7] = 1.570_799, &[range, "value 7 of 8"]);
    assert_refused("theta_i", |v| v[0] = -1e-5, &[range, "value 0 of 8"]);
    // In range but stopping short of 90 degrees or starting late: the incidences beyond would
    // silently take the nearest slice.
    let span = "must run from 0 to pi/2";
    assert_refused("theta_i", |v| v[7] = 1.45, &[span, "to 83.0"]);
    assert_refused("theta_i", |v| v[0] = 0.1, &[span, "from 0.1"]);
    assert_refused(
        "theta_i",
        |v| v[3] = v[2],
        &["strictly increasing", "value 3 of 8"],
    );
    let phi = "within [-pi, pi]";
    assert_refused("phi_i", |v| v[0] = 4.0, &[phi, "value 0 of 1 is 4"]);
    assert_refused("phi_i", |v| v[0] = -3.2, &[phi, "value 0 of 1 is -3.2"]);
    // f32 roundings of the ends are accepted: pi/2 rounded up (as cg files would hold it), and a
    // little below (as paper_white holds it); -pi and pi rounded for phi_i.
    for (name, k, x) in [
        ("theta_i", 7, std::f32::consts::FRAC_PI_2),
        ("theta_i", 7, 1.570_796_2),
        ("theta_i", 0, -1e-7),
        ("phi_i", 0, std::f32::consts::PI),
        ("phi_i", 0, -std::f32::consts::PI),
    ] {
        let tf = with_field(name, "ok.bsdf", |v| v[k] = x).unwrap();
        let b = RglBsdf::from_tensor_file(&tf).unwrap();
        let mut out = [0.0; 3];
        b.eval([0.0, 0.0, 1.0], [0.0, 0.0, 1.0], &mut out).unwrap();
        assert!(out.iter().all(|v| v.is_finite() && *v > 0.2), "{out:?}");
    }
}

/// Densities the evaluator divides by or inverts: negative `vndf` values, negative or
/// non-finite `luminance` values and an NDF that is 0 everywhere are errors.
#[test]
fn negative_densities_and_an_empty_ndf_are_errors() {
    let rule = "finite and >= 0";
    assert_refused("vndf", |v| v[5] = -1e-4, &[rule, "value 5 of 131072"]);
    assert_refused("luminance", |v| v[9] = -0.5, &[rule, "value 9 of 8192"]);
    assert_refused("luminance", |v| v[9] = f32::INFINITY, &["non-finite"]);
    assert_refused(
        "ndf",
        |v| v.iter_mut().for_each(|x| *x = 0.0),
        &["0 everywhere"],
    );
    // A vndf slice with no density at all.
    assert_refused(
        "vndf",
        |v| v[..128 * 128].iter_mut().for_each(|x| *x = 0.0),
        &["slice 0 integrates to 0"],
    );
}

/// A field of the wrong dtype with the right rank, or of the right dtype with the wrong rank,
/// is refused, naming the file, the field, what it holds and what was expected.
#[test]
fn fields_of_the_wrong_dtype_or_rank_are_errors() {
    // theta_i in f64: same values, same rank.
    let theta_f64 = with_replaced("theta_i", "retyped.bsdf", |f, p| {
        Field::from_f64("theta_i", f.shape().to_vec(), &f.to_f64(p).unwrap()).unwrap()
    });
    let words = ["\"theta_i\" is F64", "expected F32 of rank 1"];
    assert_file_refused(theta_f64, "theta_i", &words);
    // ndf in f32 with a leading axis of 1: same values, rank 3.
    let ndf_rank_3 = with_replaced("ndf", "retyped.bsdf", |f, p| {
        let shape = [&[1][..], f.shape()].concat();
        Field::from_f32("ndf", shape, &f.to_f32(p).unwrap()).unwrap()
    });
    let words = ["\"ndf\" is F32 with shape [1, ", "expected F32 of rank 2"];
    assert_file_refused(ndf_rank_3, "ndf", &words);
}

/// A vndf slice whose rows are partly empty (as the 90-degree slice of every RGL file is, on
/// the half facing away from wi) inverted 0/0 = NaN wherever a half vector fell in the empty
/// rows and the incidence used that slice alone. Here the empty rows are in the slice of normal
/// incidence, where every half-vector azimuth is reached: values stay finite, and the other half
/// of the rows gives the same values as long as the slice's normalisation is accounted for.
#[test]
fn empty_vndf_rows_evaluate_finite() {
    // Rows are the half-vector azimuth (128 of them); empty the first 64 of slice 0.
    let Some(tf) = with_field("vndf", "rows.bsdf", |v| {
        v[..64 * 128].iter_mut().for_each(|x| *x = 0.0)
    }) else {
        return;
    };
    let b = RglBsdf::from_tensor_file(&tf).unwrap();
    let mut out = [0.0; 3];
    let mut n = 0;
    for i in 1..90 {
        for j in 0..72 {
            let (t, p) = (f64::from(i).to_radians(), f64::from(j * 5).to_radians());
            let wo = [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()];
            b.eval([0.0, 0.0, 1.0], wo, &mut out).unwrap();
            // paper_white's rgb table is >= 0.
            assert!(
                out.iter().all(|v| v.is_finite() && *v >= 0.0),
                "{wo:?}: {out:?}"
            );
            n += 1;
        }
    }
    assert_eq!(n, 89 * 72);
}

/// The seven RGL files open, hold theta_i from 0 to pi/2 within f32 rounding and phi_i = [0],
/// and evaluate finite, also with wo a hair above the horizon (wo.z = 1e-320: 1 / wo.z
/// overflows, and a zero value times it was NaN at 16-62 of 3240 incidences per file).
#[test]
fn real_files_open_and_never_evaluate_to_nan() {
    let Some(dir) = shared_data::path("rgl-rgb") else {
        return;
    };
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "bsdf"))
        .collect();
    files.sort();
    assert_eq!(files.len(), 7);
    for file in &files {
        let b = RglBsdf::open(file).unwrap();
        let t = b.theta_i();
        assert_eq!(t.len(), 8);
        assert_eq!(t[0], 0.0);
        assert!((t[7] - std::f64::consts::FRAC_PI_2).abs() < 1e-7, "{t:?}");
        let tf = TensorFile::open(file).unwrap();
        assert_eq!(tf.field_f64("phi_i").unwrap(), vec![0.0]);
        let mut out = [0.0; 3];
        let (mut zeros, mut seed) = (0, 7u64);
        let mut rnd = move || {
            seed = seed
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..20_000 {
            let mut dir = || {
                let (z, p) = (rnd(), std::f64::consts::TAU * rnd());
                let r = (1.0 - z * z).sqrt();
                [r * p.cos(), r * p.sin(), z]
            };
            let (wi, wo) = (dir(), dir());
            b.eval(wi, wo, &mut out).unwrap();
            assert!(out.iter().all(|v| v.is_finite()), "{wi:?} {wo:?}: {out:?}");
        }
        for i in 0..90 {
            for j in 0..36 {
                let (t, p) = (f64::from(i).to_radians(), f64::from(j * 10).to_radians());
                let wi = [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()];
                b.eval(wi, [1.0, 0.0, 1e-320], &mut out).unwrap();
                assert!(
                    out.iter().all(|v| !v.is_nan()),
                    "{}: {wi:?}",
                    file.display()
                );
                zeros += usize::from(out.iter().all(|&v| v == 0.0));
            }
        }
        assert!(zeros > 0, "{}: no zero value exercised", file.display());
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..2048)) {
        let _ = exercise(&bytes);
        let _ = brdf_io::merl::parse_merl(&bytes, "r.binary");
        let _ = brdf_io::npy::parse(&bytes, "r.npy");
    }

    #[test]
    fn random_headers_with_valid_magic_never_panic(
        tail in proptest::collection::vec(any::<u8>(), 0..512),
        n_fields in 0u32..6,
    ) {
        let mut bytes = b"tensor_file\0\x01\x00".to_vec();
        bytes.extend_from_slice(&n_fields.to_le_bytes());
        bytes.extend_from_slice(&tail);
        let _ = exercise(&bytes);
        let mut npy = b"\x93NUMPY\x01\x00".to_vec();
        npy.extend_from_slice(&tail);
        let _ = brdf_io::npy::parse(&npy, "r.npy");
    }

    #[test]
    fn random_data_flips_never_panic(
        flips in proptest::collection::vec((416usize..658_928, any::<u8>()), 1..8),
    ) {
        let Some((_, bytes)) = real_file() else { return Ok(()) };
        let mut copy = bytes;
        for (pos, v) in flips {
            copy[pos] = v;
        }
        let _ = exercise(&copy);
    }
}

#[test]
fn fuzz_seed_is_a_valid_minimal_bsdf() {
    // The cargo-fuzz seed (fuzz/seeds/tensor_file) must load, so fuzzing starts past the checks.
    let p =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz/seeds/tensor_file/minimal_rgb.bsdf");
    let bytes = std::fs::read(&p).unwrap();
    assert!(exercise(&bytes), "{} does not load", p.display());
    let bsdf = RglBsdf::open(&p).unwrap();
    let mut out = [0.0; 3];
    bsdf.eval([0.0, 0.0, 1.0], [0.0, 0.0, 1.0], &mut out)
        .unwrap();
    assert!(out.iter().all(|v| v.is_finite() && *v >= 0.0), "{out:?}");
}

// ------------------------------------------------------------ dataset stores (.sbrdf)

mod store {
    use std::path::{Path, PathBuf};
    use std::sync::Arc;

    use brdf_io::store::{Compression, Dtype, OpenOptions, Paging, ReadMode, StoreMaterial};
    use brdf_io::{AngularGrid, Channels, Error, Store, StoreInfo, StoreOptions, StoreWriter};
    use proptest::prelude::*;

    pub(super) const COMPRESSIONS: [Compression; 3] = [
        Compression::None,
        Compression::Zstd { level: 1 },
        Compression::ZstdShuffle { level: 1 },
    ];

    /// Writes a store of 3 materials on a 3 x 3 x 4 RGB grid (D = 108) in chunks of 16 indices
    /// (7 chunks, the last one shorter) and returns the values as stored.
    pub(super) fn small_store(
        path: &Path,
        compression: Compression,
        dtype: Dtype,
    ) -> Vec<Vec<f32>> {
        let info = StoreInfo {
            grid: AngularGrid::new(3, 3, 4).unwrap(),
            channels: Channels::Rgb,
        };
        let mask = info.grid.validity_mask();
        let rows: Vec<Vec<f32>> = (0..3)
            .map(|m| {
                (0..info.d())
                    .map(|d| match mask[d / 3] {
                        true => dtype.round(0.25 + (m * 100 + d) as f32 / 64.0),
                        false => 0.0,
                    })
                    .collect()
            })
            .collect();
        let options = StoreOptions {
            chunk_len: Some(16),
            compression,
            dtype,
            ..Default::default()
        };
        let mut w = StoreWriter::create(path, info, options).unwrap();
        for (i, row) in rows.iter().enumerate() {
            w.add_material(&format!("mat{i}"), "test", row).unwrap();
        }
        w.finish().unwrap();
        rows
    }

    /// What reading a store gave: the errors (each checked to name the file) and whether the
    /// values read equal `want` wherever a read succeeded.
    #[derive(Debug, Default)]
    pub(super) struct Outcome {
        pub errors: Vec<String>,
        pub opened: bool,
        pub wrong_values: bool,
    }

    impl Outcome {
        fn note<T>(&mut self, path: &Path, what: &str, r: brdf_io::Result<T>) -> Option<T> {
            match r {
                Ok(v) => Some(v),
                Err(e) => {
                    let msg = e.to_string();
                    assert!(
                        msg.contains(&path.display().to_string()),
                        "{what}: the error does not name {}: {msg}",
                        path.display()
                    );
                    self.errors.push(format!("{what}: {msg}"));
                    None
                }
            }
        }
    }

    /// Opens the store at `path` memory-mapped (paged as the kernel likes, and on demand) and
    /// with positioned reads, and reads it through
    /// every read path: the checksum, each chunk (decoded and borrowed), the sequential and
    /// parallel passes, every index's N values, ranges, every material's row, and lookups of
    /// a stored material (every cell, and one direction pair). No read may panic; every error
    /// must name the file; values read are compared with `want` (the values written).
    pub(super) fn exercise(path: &Path, want: &[Vec<f32>]) -> Outcome {
        let mut out = Outcome::default();
        let reads = [
            (ReadMode::Mmap, Paging::ReadAround),
            (ReadMode::Mmap, Paging::OnDemand),
            (ReadMode::Buffered, Paging::Auto),
        ];
        for (mode, paging) in reads {
            let options = OpenOptions {
                mode,
                cache_chunks: 4,
                paging,
            };
            let Some(store) = out.note(path, "open", Store::open_with(path, options)) else {
                continue;
            };
            out.opened = true;
            let (n, d) = (store.n_materials(), store.d());
            let same_shape = n == want.len() && want.iter().all(|r| r.len() == d);
            let check = |out: &mut Outcome, m: usize, i: usize, v: f32| {
                if !same_shape || want[m][i].to_bits() != v.to_bits() {
                    out.wrong_values = true;
                }
            };
            out.note(path, "verify_checksum", store.verify_checksum());
            let mut buf = Vec::new();
            for c in 0..store.n_chunks() {
                out.note(path, "read_chunk", store.read_chunk(c, &mut buf));
                out.note(path, "chunk", store.chunk(c, &mut buf).map(|_| ()));
            }
            out.note(path, "for_each_chunk", store.for_each_chunk(|_, _| {}));
            if store.grid().len() <= 1 << 16 {
                // (The Gram pass sizes its validity mask by the grid: up to 2^27 cells.)
                out.note(path, "gram", store.gram());
            }
            // Every index of the small store; the ends of a bigger one a header claims.
            let indices = || (0..d.min(128)).chain(d.saturating_sub(8).max(128)..d);
            let mut at = vec![0f32; n];
            for i in indices() {
                if out
                    .note(path, "values_at", store.values_at(i, &mut at))
                    .is_some()
                {
                    for (m, &v) in at.iter().enumerate() {
                        check(&mut out, m, i, v);
                    }
                }
            }
            let head = 0..d.min(128);
            let mut all = vec![0f32; n * head.len()];
            if out
                .note(path, "values_in", store.values_in(head.clone(), &mut all))
                .is_some()
            {
                for (k, &v) in all.iter().enumerate() {
                    check(&mut out, k % n, k / n, v);
                }
            }
            for s in head.clone().step_by(5) {
                let r = s..(s + 7).min(d);
                store.prefetch(r.clone());
                let mut b = Vec::new();
                out.note(
                    path,
                    "values_in_ref",
                    store.values_in_ref(r, &mut b).map(|_| ()),
                );
            }
            let mut row = vec![0f32; head.len()];
            for m in 0..n.min(8) {
                if out
                    .note(
                        path,
                        "material_row",
                        store.material_row(m, head.clone(), &mut row),
                    )
                    .is_some()
                {
                    for (i, &v) in row.iter().enumerate() {
                        check(&mut out, m, i, v);
                    }
                }
                let part = d.min(20)..d.min(41);
                let mut short = vec![0f32; part.len()];
                out.note(
                    path,
                    "material_row",
                    store.material_row(m, part, &mut short),
                );
            }
            let store = Arc::new(store);
            for m in 0..n.min(8) {
                let sm = StoreMaterial::by_index(store.clone(), m).unwrap();
                let mut v = vec![0.0; sm.n_channels()];
                out.note(
                    path,
                    "eval",
                    sm.eval([0.1, 0.2, 0.9], [-0.3, 0.1, 0.8], &mut v),
                );
                for a in 0..store.grid().len().min(64) {
                    out.note(
                        path,
                        "eval_cell",
                        brdf_io::BrdfSource::eval_cell(&sm, a, &mut v),
                    );
                }
            }
        }
        out
    }

    fn dir() -> tempfile::TempDir {
        tempfile::tempdir().unwrap()
    }

    /// Writes `byte` at offset `pos` of the file at `path`.
    fn poke(path: &Path, pos: usize, byte: u8) {
        use std::io::{Seek, SeekFrom, Write};
        let mut f = std::fs::OpenOptions::new().write(true).open(path).unwrap();
        f.seek(SeekFrom::Start(pos as u64)).unwrap();
        f.write_all(&[byte]).unwrap();
    }

    /// Puts the byte back when dropped (after the checks of one damaged byte).
    struct Restore<'a>(&'a Path, usize, u8);

    impl Drop for Restore<'_> {
        fn drop(&mut self) {
            poke(self.0, self.1, self.2);
        }
    }

    /// The offset of the JSON header (prefix field 5).
    fn header_offset(bytes: &[u8]) -> usize {
        u64::from_le_bytes(bytes[40..48].try_into().unwrap()) as usize
    }

    /// Recomputes the prefix's xxh3-64 of the prefix fields and the header, so that an edit of
    /// either is not caught by the hash (a crafted file, or damage the hash happens to miss).
    fn fix_hash(bytes: &mut [u8]) {
        let hoff = header_offset(bytes);
        let hlen = u64::from_le_bytes(bytes[48..56].try_into().unwrap()) as usize;
        let mut v = bytes[..56].to_vec();
        if let Some(json) = bytes.get(hoff..hoff.saturating_add(hlen)) {
            v.extend_from_slice(json);
        }
        let h = xxhash_rust::xxh3::xxh3_64(&v);
        bytes[56..64].copy_from_slice(&h.to_le_bytes());
    }

    /// `bytes` with the JSON header replaced by `edit` of it, lengths and hash fixed up.
    fn with_header(bytes: &[u8], edit: impl FnOnce(&mut serde_json::Value)) -> Vec<u8> {
        let hoff = header_offset(bytes);
        let mut header: serde_json::Value = serde_json::from_slice(&bytes[hoff..]).unwrap();
        edit(&mut header);
        let json = serde_json::to_vec_pretty(&header).unwrap();
        let mut out = bytes[..hoff].to_vec();
        out.extend_from_slice(&json);
        out[48..56].copy_from_slice(&(json.len() as u64).to_le_bytes());
        fix_hash(&mut out);
        out
    }

    /// Every read path of the three layouts (f32 and f16) gives the written values.
    #[test]
    fn intact_stores_read_back_on_every_path() {
        let t = dir();
        for compression in COMPRESSIONS {
            for dtype in [Dtype::F32, Dtype::F16] {
                let p = t.path().join("ok.sbrdf");
                let want = small_store(&p, compression, dtype);
                let o = exercise(&p, &want);
                assert!(o.opened && o.errors.is_empty(), "{:?}", o.errors);
                assert!(!o.wrong_values, "{compression:?} {dtype:?}");
            }
        }
    }

    /// A store cut at any length, or with bytes appended, is refused on open (in both read
    /// modes), naming the file.
    #[test]
    fn truncations_at_every_length_and_extensions_are_refused() {
        let t = dir();
        for compression in COMPRESSIONS {
            let p = t.path().join("whole.sbrdf");
            small_store(&p, compression, Dtype::F32);
            let full = std::fs::metadata(&p).unwrap().len();
            let cut = t.path().join("cut.sbrdf");
            std::fs::copy(&p, &cut).unwrap();
            let file = std::fs::OpenOptions::new().write(true).open(&cut).unwrap();
            // Longer first (zeros appended), then every length down to 0.
            for len in [full + 4096, full + 1].into_iter().chain((0..full).rev()) {
                file.set_len(len).unwrap();
                for mode in [ReadMode::Mmap, ReadMode::Buffered] {
                    let options = OpenOptions {
                        mode,
                        ..OpenOptions::default()
                    };
                    let e = Store::open_with(&cut, options).unwrap_err();
                    assert!(
                        matches!(e, Error::NotAStore { .. } | Error::StoreCorrupt { .. }),
                        "{len}: {e}"
                    );
                    let msg = e.to_string();
                    assert!(msg.contains(&cut.display().to_string()), "{len}: {msg}");
                    if len >= 64 {
                        assert!(msg.contains("truncated or extended"), "{len}: {msg}");
                    }
                }
            }
        }
    }

    /// Each byte of the prefix and header damaged: refused on open (the prefix and header
    /// hash), naming the file. Each byte of the offset table damaged: refused on open (the
    /// table must partition the payload, and uncompressed chunks have known sizes), or else
    /// found by the payload checksum and never read as wrong values (a compressed chunk moved
    /// by a few bytes is no zstd frame, or fails its frame checksum).
    #[test]
    fn damaged_prefix_table_or_header_is_found() {
        let t = dir();
        for compression in COMPRESSIONS {
            let p = t.path().join("whole.sbrdf");
            let want = small_store(&p, compression, Dtype::F32);
            let bytes = std::fs::read(&p).unwrap();
            let table = u64::from_le_bytes(bytes[32..40].try_into().unwrap()) as usize;
            let bad = t.path().join("bad.sbrdf");
            std::fs::write(&bad, &bytes).unwrap();
            for pos in (0..64).chain(table..bytes.len()) {
                let flip = if pos % 2 == 0 { 0x01 } else { 0x80 };
                poke(&bad, pos, bytes[pos] ^ flip);
                let _restore = Restore(&bad, pos, bytes[pos]);
                let in_table = (table..header_offset(&bytes)).contains(&pos);
                if !in_table || compression == Compression::None {
                    let e = Store::open(&bad).unwrap_err().to_string();
                    assert!(e.contains(&bad.display().to_string()), "{pos}: {e}");
                    continue;
                }
                let o = exercise(&bad, &want);
                assert!(!o.wrong_values, "{compression:?} {pos}: wrong values read");
                assert!(
                    !o.opened || o.errors.iter().any(|e| e.contains("checksum mismatch")),
                    "{compression:?} {pos}: {:?}",
                    o.errors
                );
            }
        }
    }

    /// The prefix's fields rewritten with a matching hash (offsets past the end, overlapping,
    /// overflowing): refused on open, naming the file, never a panic or a huge allocation.
    #[test]
    fn prefix_fields_with_a_matching_hash_are_checked() {
        let t = dir();
        let p = t.path().join("whole.sbrdf");
        small_store(&p, Compression::Zstd { level: 1 }, Dtype::F32);
        let bytes = std::fs::read(&p).unwrap();
        let len = bytes.len() as u64;
        let bad = t.path().join("bad.sbrdf");
        for field in 0..5 {
            let at = 16 + 8 * field;
            let old = u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap());
            for v in [
                0,
                1,
                old.wrapping_sub(8),
                old.wrapping_add(8),
                len,
                len + 1,
                1 << 40,
                u64::MAX - 4095,
                u64::MAX,
            ] {
                if v == old {
                    continue;
                }
                let mut b = bytes.clone();
                b[at..at + 8].copy_from_slice(&v.to_le_bytes());
                fix_hash(&mut b);
                std::fs::write(&bad, &b).unwrap();
                let e = Store::open(&bad).unwrap_err();
                assert!(
                    matches!(e, Error::StoreCorrupt { .. }),
                    "field {field} = {v}: {e}"
                );
                assert!(e.to_string().contains(&bad.display().to_string()), "{e}");
            }
        }
    }

    /// Each of the prefix's offset conditions refuses a file on its own (the others holding,
    /// the hash fixed up), and a prefix that is consistent by itself but disagrees with the
    /// header's chunk count is refused by the offset table's size. The header may take up to
    /// 64 MiB: one of exactly that size (padded with JSON whitespace) opens and reads back, one
    /// byte more is refused before anything is allocated for it.
    #[test]
    fn each_prefix_offset_condition_is_checked_on_its_own() {
        let t = dir();
        let p = t.path().join("whole.sbrdf");
        let want = small_store(&p, Compression::None, Dtype::F32);
        let bytes = std::fs::read(&p).unwrap();
        let field =
            |b: &[u8], i: usize| u64::from_le_bytes(b[16 + 8 * i..24 + 8 * i].try_into().unwrap());
        let (payload_offset, payload_len, table_offset, header_offset) = (
            field(&bytes, 0),
            field(&bytes, 1),
            field(&bytes, 2),
            field(&bytes, 3),
        );
        assert_eq!(payload_offset + payload_len, header_offset);
        assert!(payload_offset < table_offset && table_offset < header_offset);
        const INCONSISTENT: &str = "inconsistent offsets in the prefix";
        const TABLE_SIZE: &str = "offset table size does not match the chunk count";
        // (what, edits of (field, value), the reason expected).
        let cases = [
            (
                "payload moved, its end kept",
                vec![(0, payload_offset + 8), (1, payload_len - 8)],
                INCONSISTENT,
            ),
            (
                "payload ending before the header",
                vec![(1, payload_len - 8)],
                INCONSISTENT,
            ),
            (
                "table before the payload",
                vec![(2, payload_offset - 8)],
                INCONSISTENT,
            ),
            (
                "table at the payload's start",
                vec![(2, payload_offset)],
                TABLE_SIZE,
            ),
            ("table at the header", vec![(2, header_offset)], TABLE_SIZE),
            (
                "table after the header",
                vec![(2, header_offset + 8)],
                INCONSISTENT,
            ),
        ];
        let bad = t.path().join("bad.sbrdf");
        for (what, edits, reason) in cases {
            let mut b = bytes.clone();
            for (i, v) in edits {
                b[16 + 8 * i..24 + 8 * i].copy_from_slice(&v.to_le_bytes());
            }
            fix_hash(&mut b);
            std::fs::write(&bad, &b).unwrap();
            let e = Store::open(&bad).unwrap_err().to_string();
            assert!(e.contains(&bad.display().to_string()), "{what}: {e}");
            assert!(e.contains(reason), "{what}: {e}");
        }
        // The header padded to the limit, and one byte past it.
        let limit = 64usize << 20;
        for (len, opens) in [(limit, true), (limit + 1, false)] {
            let mut b = bytes.clone();
            b.resize(header_offset as usize + len, b' ');
            b[48..56].copy_from_slice(&(len as u64).to_le_bytes());
            fix_hash(&mut b);
            std::fs::write(&bad, &b).unwrap();
            match Store::open(&bad) {
                Ok(store) => {
                    assert!(opens, "a header of {len} bytes opened");
                    let mut row = vec![0.0; store.d()];
                    for (m, w) in want.iter().enumerate() {
                        store.material_row(m, 0..store.d(), &mut row).unwrap();
                        assert_eq!(&row, w);
                    }
                }
                Err(e) => {
                    assert!(!opens, "a header of {len} bytes: {e}");
                    assert!(e.to_string().contains(INCONSISTENT), "{len}: {e}");
                }
            }
        }
    }

    /// A flipped bit in the chunks is found by the payload checksum; reads of a compressed
    /// store never return wrong values (zstd frames carry their content checksum; a few bits,
    /// such as the frame header's unused bit, change nothing).
    #[test]
    fn damaged_chunk_bytes_are_found() {
        let t = dir();
        for compression in COMPRESSIONS {
            let p = t.path().join("whole.sbrdf");
            let want = small_store(&p, compression, Dtype::F16);
            let bytes = std::fs::read(&p).unwrap();
            let table = u64::from_le_bytes(bytes[32..40].try_into().unwrap()) as usize;
            let bad = t.path().join("bad.sbrdf");
            std::fs::write(&bad, &bytes).unwrap();
            // Every other chunk byte, each bit in turn.
            for pos in (4096..table).step_by(2) {
                poke(&bad, pos, bytes[pos] ^ (1 << (pos / 2 % 8)));
                let _restore = Restore(&bad, pos, bytes[pos]);
                let o = exercise(&bad, &want);
                assert!(o.opened, "{pos}: {:?}", o.errors);
                assert!(
                    o.errors
                        .iter()
                        .any(|e| e.starts_with("verify_checksum: ")
                            && e.contains("checksum mismatch")),
                    "{compression:?} {pos}: {:?}",
                    o.errors
                );
                if compression != Compression::None {
                    assert!(!o.wrong_values, "{compression:?} {pos}: wrong values read");
                }
            }
        }
    }

    /// A header whose payload size disagrees with the prefix (hash fixed up) is refused on
    /// open, naming the file and both numbers.
    #[test]
    fn header_payload_size_must_match_the_prefix() {
        let t = dir();
        let p = t.path().join("sized.sbrdf");
        small_store(&p, Compression::None, Dtype::F32);
        let bytes = std::fs::read(&p).unwrap();
        let payload_len = u64::from_le_bytes(bytes[24..32].try_into().unwrap());
        let edited = with_header(&bytes, |h| {
            assert_eq!(h["payload_bytes"], serde_json::json!(payload_len));
            h["payload_bytes"] = serde_json::json!(payload_len + 8);
        });
        std::fs::write(&p, &edited).unwrap();
        let e = Store::open(&p).unwrap_err().to_string();
        assert!(e.contains(&p.display().to_string()), "{e}");
        assert!(
            e.contains(&format!("payload_bytes = {}", payload_len + 8))
                && e.contains(&format!("payload length {payload_len}")),
            "{e}"
        );
    }

    /// Type-correct header values that disagree with the payload or with each other.
    fn header_edit() -> impl Strategy<Value = (&'static str, serde_json::Value)> {
        use serde_json::json;
        let count = prop::sample::select(vec![
            0u64,
            1,
            2,
            7,
            8,
            15,
            16,
            17,
            36,
            107,
            108,
            109,
            1 << 20,
            1 << 40,
            u64::MAX / 4,
            u64::MAX,
        ]);
        prop_oneof![
            (
                prop::sample::select(vec!["d", "layout.chunk_len", "layout.n_chunks"]),
                count.prop_map(|v| json!(v))
            ),
            (
                Just("layout.dtype"),
                prop::sample::select(vec!["f16", "f32"]).prop_map(|v| json!(v))
            ),
            (
                Just("layout.compression"),
                prop::sample::select(vec![
                    json!({"kind": "none"}),
                    json!({"kind": "zstd", "level": 3}),
                    json!({"kind": "zstd-shuffle", "level": -7}),
                ])
            ),
            (
                Just("grid"),
                prop::sample::select(vec![
                    json!({"n_theta_h": 1, "n_theta_d": 1, "n_phi_d": 1}),
                    json!({"n_theta_h": 3, "n_theta_d": 3, "n_phi_d": 8}),
                    json!({"n_theta_h": 6, "n_theta_d": 3, "n_phi_d": 2}),
                    json!({"n_theta_h": 4096, "n_theta_d": 4096, "n_phi_d": 8}),
                ])
            ),
            (
                Just("channels"),
                prop::sample::select(vec![
                    json!({"kind": "spectral", "wavelengths_nm": [400.0, 500.0, 600.0]}),
                    json!({"kind": "spectral", "wavelengths_nm": [400.0]}),
                    json!({"kind": "spectral", "wavelengths_nm": [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]}),
                ])
            ),
            (
                Just("materials"),
                (0usize..8).prop_map(|n| json!(
                    (0..n)
                        .map(|i| json!({"name": format!("m{i}"), "source": "", "stats": {
                        "count": 0, "min": 0.0, "max": 0.0, "mean": 0.0, "sum_sq": 0.0,
                        "negatives": 0, "zeroed_below_horizon": 0}}))
                        .collect::<Vec<_>>()
                ))
            ),
        ]
    }

    fn set(h: &mut serde_json::Value, key: &str, v: serde_json::Value) {
        let mut slot = h;
        for k in key.split('.') {
            slot = slot.get_mut(k).unwrap();
        }
        *slot = v;
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(96))]

        /// Headers that agree with their hash but not with the payload or with themselves (a
        /// crafted file, or one rewritten by hand): an error naming the file on open or on
        /// read, never a panic or an allocation beyond the file's size. (Values may be wrong:
        /// a header is trusted for what the bytes mean, e.g. zstd-shuffle relabelled zstd.)
        #[test]
        fn consistent_hash_inconsistent_header(
            edits in proptest::collection::vec(header_edit(), 1..4),
            layout in 0usize..3,
            f16 in any::<bool>(),
            consistent in any::<bool>(),
        ) {
            let t = dir();
            let p = t.path().join("edited.sbrdf");
            let dtype = if f16 { Dtype::F16 } else { Dtype::F32 };
            let want = small_store(&p, COMPRESSIONS[layout], dtype);
            let bytes = std::fs::read(&p).unwrap();
            let edited = with_header(&bytes, |h| {
                for (k, v) in edits {
                    set(h, k, v);
                }
                if consistent {
                    // D from the grid and channels, and 7 chunks as in the offset table, so
                    // that only the payload disagrees.
                    let g = &h["grid"];
                    let cells: u64 = ["n_theta_h", "n_theta_d", "n_phi_d"]
                        .iter()
                        .map(|k| g[k].as_u64().unwrap())
                        .product();
                    let channels = h["channels"]["wavelengths_nm"]
                        .as_array()
                        .map_or(3, |w| w.len() as u64);
                    let d = cells * channels;
                    let chunk_len = d.div_ceil(7);
                    h["d"] = serde_json::json!(d);
                    h["layout"]["chunk_len"] = serde_json::json!(chunk_len);
                    h["layout"]["n_chunks"] = serde_json::json!(d.div_ceil(chunk_len));
                }
            });
            std::fs::write(&p, &edited).unwrap();
            let o = exercise(&p, &want);
            prop_assert!(o.opened || !o.errors.is_empty());
        }

        /// Random bytes after the magic, and random values of the five prefix fields over a
        /// real store with the hash fixed up: errors naming the file.
        #[test]
        fn random_prefixes_are_refused(
            tail in proptest::collection::vec(any::<u8>(), 0..5000),
            fields in proptest::collection::vec(any::<u64>(), 5),
        ) {
            let t = dir();
            let p = t.path().join("random.sbrdf");
            let mut b = brdf_io::store::MAGIC.to_vec();
            b.extend_from_slice(&tail);
            std::fs::write(&p, &b).unwrap();
            let e = Store::open(&p).unwrap_err().to_string();
            prop_assert!(e.contains(&p.display().to_string()), "{}", e);
            small_store(&p, Compression::None, Dtype::F32);
            let mut b = std::fs::read(&p).unwrap();
            for (i, v) in fields.iter().enumerate() {
                b[16 + 8 * i..24 + 8 * i].copy_from_slice(&v.to_le_bytes());
            }
            fix_hash(&mut b);
            std::fs::write(&p, &b).unwrap();
            let e = Store::open(&p).unwrap_err().to_string();
            prop_assert!(e.contains(&p.display().to_string()), "{}", e);
        }
    }

    /// A directory, or a FIFO with no writer, is refused at once, naming it: opening a FIFO
    /// blocked until something wrote to it, and a pipe (length 0) was called an empty file.
    #[test]
    fn directories_and_pipes_are_refused_at_once() {
        let t = dir();
        let p: PathBuf = t.path().join("dir.sbrdf");
        std::fs::create_dir(&p).unwrap();
        let e = Store::open(&p).unwrap_err().to_string();
        assert!(
            e.starts_with(&format!("{}: a directory: ", p.display()))
                && e.contains("must be a regular file"),
            "{e}"
        );
        #[cfg(unix)]
        {
            let fifo = t.path().join("fifo.sbrdf");
            let made = std::process::Command::new("mkfifo").arg(&fifo).status();
            if !made.is_ok_and(|s| s.success()) {
                eprintln!("skipped the FIFO case: mkfifo failed");
                return;
            }
            let (tx, rx) = std::sync::mpsc::channel();
            let f = fifo.clone();
            std::thread::spawn(move || {
                tx.send(Store::open(&f).map(|_| ()).unwrap_err().to_string())
            });
            let e = rx
                .recv_timeout(std::time::Duration::from_secs(20))
                .expect("opening a FIFO blocked");
            assert!(
                e.starts_with(&format!("{}: not a regular file (a pipe", fifo.display())),
                "{e}"
            );
        }
    }
}

// ------------------------------------------------------------ MERL, .npy and Neural-BRDF files

/// A MERL file of resolution `dims` holding 0.5, 1.5, ... (stored numbers).
fn merl_bytes(dims: [i32; 3]) -> Vec<u8> {
    let mut b: Vec<u8> = dims.iter().flat_map(|d| d.to_le_bytes()).collect();
    let n = 3 * dims.iter().map(|&d| d as usize).product::<usize>();
    b.extend((0..n).flat_map(|i| (0.5 + i as f64).to_le_bytes()));
    b
}

/// The error of parsing `bytes` as a MERL file named `name`; it must name the file.
fn merl_err(bytes: &[u8], name: &str) -> String {
    let e = brdf_io::merl::parse_merl(bytes, name)
        .err()
        .unwrap_or_else(|| panic!("{name}: accepted"))
        .to_string();
    assert!(e.starts_with(&format!("{name}: ")), "{e}");
    e
}

#[test]
fn merl_truncations_and_extensions_are_errors() {
    let bytes = merl_bytes([2, 2, 4]);
    let m = brdf_io::merl::parse_merl(&bytes, "ok.binary").unwrap();
    assert_eq!(m.values().len(), 48);
    for len in 0..bytes.len() {
        let e = merl_err(&bytes[..len], "cut.binary");
        let want = if len < 12 {
            "truncated MERL file".to_owned()
        } else {
            format!("must have 396 bytes, it has {len}")
        };
        assert!(e.contains(&want), "{len}: {e}");
    }
    let mut longer = bytes.clone();
    longer.extend_from_slice(&[0; 8]);
    assert!(merl_err(&longer, "long.binary").contains("must have 396 bytes, it has 404"));
}

/// Resolutions that are no grid are refused from the 12 header bytes, before anything is
/// allocated for them (2^31 - 1 per axis would be 2^96 values).
#[test]
fn merl_bad_resolutions_are_errors() {
    for (dims, want) in [
        ([0, 90, 180], "bad MERL resolution [0, 90, 180]"),
        ([90, -90, 180], "bad MERL resolution [90, -90, 180]"),
        ([i32::MIN, 1, 1], "bad MERL resolution"),
        ([i32::MAX; 3], "longer than 4096 bins"),
        ([4097, 1, 1], "longer than 4096 bins"),
        ([4096, 4096, 4096], "more than the supported 134217728"),
    ] {
        let mut b: Vec<u8> = dims.iter().flat_map(|d| d.to_le_bytes()).collect();
        b.extend_from_slice(&[0; 64]);
        let e = merl_err(&b, "dims.binary");
        assert!(e.contains(want), "{dims:?}: {e}");
    }
}

/// NaN and infinities anywhere are refused with their place; huge finite values load (the
/// resampling reports values beyond the f32 range of a store).
#[test]
fn merl_non_finite_values_are_errors_naming_their_place() {
    let bytes = merl_bytes([2, 2, 4]);
    for (i, v) in [(0, f64::NAN), (47, f64::INFINITY), (20, f64::NEG_INFINITY)] {
        let mut b = bytes.clone();
        b[12 + 8 * i..20 + 8 * i].copy_from_slice(&v.to_le_bytes());
        let e = merl_err(&b, "nan.binary");
        assert!(
            e.contains(&format!(
                "non-finite value {v} at value index {i} (byte offset {}",
                12 + 8 * i
            )),
            "{e}"
        );
    }
    let mut b = bytes.clone();
    b[12..20].copy_from_slice(&f64::MAX.to_le_bytes());
    let m = brdf_io::merl::parse_merl(&b, "big.binary").unwrap();
    let (_, report) = m.resample(m.grid(), brdf_io::merl::Resampling::Average);
    let e = report.ensure_finite("big.binary").unwrap_err().to_string();
    assert!(e.starts_with("big.binary: "), "{e}");
}

/// A file `name` holding `bytes` (in a new temporary directory).
fn temp_file(name: &str, bytes: &[u8]) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join(name);
    std::fs::write(&p, bytes).unwrap();
    (dir, p)
}

/// `.npy` files (f32 2-D, f64 1-D) cut at every length: an error naming the file.
#[test]
fn npy_truncations_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a.npy"), dir.path().join("b.npy"));
    brdf_io::npy::write_f32(&a, &[2, 3], &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]).unwrap();
    brdf_io::npy::write_f64(&b, &[4], &[0.5, -1.0, f64::MAX, 0.0]).unwrap();
    for p in [a, b] {
        let bytes = std::fs::read(&p).unwrap();
        let whole = brdf_io::npy::parse(&bytes, &p).unwrap();
        assert_eq!(whole, brdf_io::npy::read(&p).unwrap());
        let size = if matches!(whole.data, brdf_io::npy::NpyData::F32(_)) {
            4
        } else {
            8
        };
        let data_start = bytes.len() - whole.len() * size;
        for len in 0..bytes.len() {
            let e = brdf_io::npy::parse(&bytes[..len], "cut.npy")
                .unwrap_err()
                .to_string();
            assert!(e.starts_with("cut.npy: "), "{len}: {e}");
            // Cuts in the data are named for the data they miss.
            if len >= data_start {
                assert!(e.contains("data bytes, the file has"), "{len}: {e}");
            }
        }
    }
}

/// Every header byte of an `.npy` file changed: an error naming the file, or (e.g. a changed
/// padding space) an array whose values fill the data exactly.
#[test]
fn npy_header_byte_changes_are_errors_or_harmless() {
    let (_dir, p) = temp_file("h.npy", b"");
    brdf_io::npy::write_f32(&p, &[2, 3], &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]).unwrap();
    let bytes = std::fs::read(&p).unwrap();
    let mut loaded = 0;
    for pos in 0..64 {
        for v in [0u8, b' ', b'(', b')', b',', b'\'', b'9', 0x80, 0xff] {
            let mut b = bytes.clone();
            b[pos] = v;
            match brdf_io::npy::parse(&b, "h.npy") {
                Ok(a) => {
                    assert_eq!(a.len(), a.shape.iter().product::<usize>());
                    loaded += 1;
                }
                Err(e) => assert!(e.to_string().starts_with("h.npy: "), "{e}"),
            }
        }
    }
    assert!(loaded > 0);
}

/// Neural-BRDF weights and names that do not fit: errors naming the file at fault.
#[test]
fn nbrdf_bad_weights_and_names_are_errors_naming_the_file() {
    use brdf_io::nbrdf::{NbrdfSet, WEIGHTS_PER_NETWORK};
    let dir = tempfile::tempdir().unwrap();
    let weights = dir.path().join("w.npy");
    let names = dir.path().join("n.txt");
    std::fs::write(&names, "a\nb\n").unwrap();
    let open_err = |w: &Path, n: &Path| NbrdfSet::open(w, n).unwrap_err().to_string();
    for shape in [
        vec![2, WEIGHTS_PER_NETWORK - 1],
        vec![2 * WEIGHTS_PER_NETWORK],
        vec![1, 2, WEIGHTS_PER_NETWORK],
        vec![],
    ] {
        let count = shape.iter().product::<usize>();
        brdf_io::npy::write_f32(&weights, &shape, &vec![0.5; count]).unwrap();
        let e = open_err(&weights, &names);
        assert!(
            e.starts_with(&format!("{}: ", weights.display()))
                && e.contains(&format!("must have shape (N, 675), got {shape:?}")),
            "{e}"
        );
    }
    brdf_io::npy::write_f32(&weights, &[2, WEIGHTS_PER_NETWORK], &vec![0.5; 1350]).unwrap();
    NbrdfSet::open(&weights, &names).unwrap();
    // Weights cut short, a names file given as the weights, names that are not UTF-8.
    let bytes = std::fs::read(&weights).unwrap();
    let cut = dir.path().join("cut.npy");
    for len in [0, 9, 100, bytes.len() - 1] {
        std::fs::write(&cut, &bytes[..len]).unwrap();
        let e = open_err(&cut, &names);
        assert!(e.starts_with(&format!("{}: ", cut.display())), "{e}");
    }
    let e = open_err(&names, &names);
    assert!(e.contains("not an .npy file"), "{e}");
    std::fs::write(&names, b"a\nb\xff\xfe\n").unwrap();
    let e = open_err(&weights, &names);
    assert!(
        e.starts_with(&format!("{}: ", names.display()))
            && e.contains("not a UTF-8 text file of names (byte 0xff at offset 3, line 2)"),
        "{e}"
    );
    let e = open_err(&weights, dir.path());
    assert!(e.starts_with(&format!("{}: ", dir.path().display())), "{e}");
    let e = open_err(&weights, &dir.path().join("missing.txt"));
    assert!(e.contains("missing.txt"), "{e}");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Any resolution header over data of any length: an error naming the file, or a BRDF
    /// on exactly that grid.
    #[test]
    fn merl_random_headers_never_panic(
        dims in proptest::array::uniform3(prop_oneof![any::<i32>(), 1i32..5]),
        extra in 0usize..600,
    ) {
        let mut b: Vec<u8> = dims.iter().flat_map(|d| d.to_le_bytes()).collect();
        b.extend((0..extra).map(|i| i as u8));
        match brdf_io::merl::parse_merl(&b, "r.binary") {
            Ok(m) => prop_assert_eq!(b.len(), 12 + 24 * m.grid().len()),
            Err(e) => prop_assert!(e.to_string().starts_with("r.binary: ")),
        }
    }

    /// `.npy` headers assembled from plausible and implausible pieces: an error naming the file,
    /// or an array whose shape accounts for every data byte.
    #[test]
    fn npy_random_headers_never_panic(
        descr in prop::sample::select(vec!["'<f4'", "'<f8'", "'>f4'", "'|u1'", "''", "[('a', '<f4')]", "<f4"]),
        fortran in prop::sample::select(vec!["False", "True", "0", ""]),
        shape in proptest::collection::vec(prop::sample::select(vec![
            "(", ")", ",", " ", "0", "1", "2", "3", "-1", "675", "18446744073709551615", "99999999999", "x",
        ]), 0..8),
        version in 1u8..4,
        data_len in 0usize..64,
    ) {
        let dict = format!(
            "{{'descr': {descr}, 'fortran_order': {fortran}, 'shape': {}, }}\n",
            shape.concat()
        );
        let mut b = b"\x93NUMPY".to_vec();
        b.push(version);
        b.push(0);
        if version == 1 {
            b.extend_from_slice(&(dict.len() as u16).to_le_bytes());
        } else {
            b.extend_from_slice(&(dict.len() as u32).to_le_bytes());
        }
        b.extend_from_slice(dict.as_bytes());
        b.extend((0..data_len).map(|i| i as u8));
        match brdf_io::npy::parse(&b, "r.npy") {
            Ok(a) => {
                let size = if matches!(a.data, brdf_io::npy::NpyData::F32(_)) { 4 } else { 8 };
                prop_assert_eq!(a.len() * size, data_len);
                prop_assert_eq!(a.len(), a.shape.iter().product::<usize>());
            }
            Err(e) => prop_assert!(e.to_string().starts_with("r.npy: ")),
        }
    }
}
