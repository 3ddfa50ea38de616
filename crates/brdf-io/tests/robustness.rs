//! Robustness of the file readers: random bytes and corruptions of real files must give errors,
//! never panics. (The cargo-fuzz target in `fuzz/` explores the tensor-file reader further.)

use std::path::{Path, PathBuf};

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
    let Some((path, _)) = real_file() else {
        return;
    };
    let tf = TensorFile::open(&path).unwrap();
    for (name, bad, rule) in [("sigma", 0.0f32, "> 0"), ("ndf", -1.0, ">= 0")] {
        let tf = with_field(name, "bad.bsdf", |v| v[7] = bad).unwrap();
        let e = RglBsdf::from_tensor_file(&tf).unwrap_err().to_string();
        assert!(
            e.contains("bad.bsdf") && e.contains(&format!("\"{name}\"")) && e.contains(rule),
            "{e}"
        );
        assert!(e.contains("value 7 of"), "{e}");
    }
    // A spectral table without its wavelengths is named as such (not "missing field rgb").
    let renamed: Vec<Field> = tf
        .fields()
        .iter()
        .map(|f| {
            if f.name() != "rgb" {
                return f.clone();
            }
            let v: Vec<f32> = f.to_f64(&path).unwrap().iter().map(|&x| x as f32).collect();
            Field::from_f32("spectra", f.shape().to_vec(), &v).unwrap()
        })
        .collect();
    let bytes = TensorFile::to_bytes(&renamed).unwrap();
    let tf = TensorFile::from_bytes(&bytes, "spec.bsdf").unwrap();
    let e = RglBsdf::from_tensor_file(&tf).unwrap_err().to_string();
    assert!(
        e.contains("spec.bsdf") && e.contains("without its field \"wavelengths\""),
        "{e}"
    );
}

/// The real file with field `name` replaced by `edit` of its values (as f32), parsed as if read
/// from `file_name`.
fn with_field(name: &str, file_name: &str, edit: impl Fn(&mut Vec<f32>)) -> Option<TensorFile> {
    let (path, _) = real_file()?;
    let tf = TensorFile::open(&path).unwrap();
    let fields: Vec<Field> = tf
        .fields()
        .iter()
        .map(|f| {
            if f.name() != name {
                return f.clone();
            }
            let mut v = f.to_f32(&path).unwrap();
            edit(&mut v);
            Field::from_f32(name, f.shape().to_vec(), &v).unwrap()
        })
        .collect();
    let bytes = TensorFile::to_bytes(&fields).unwrap();
    Some(TensorFile::from_bytes(&bytes, file_name).unwrap())
}

/// The error of building the BSDF from the real file with field `name` edited; it must name the
/// file, the field (in quotes) and contain every one of `words`.
fn assert_refused(name: &str, edit: impl Fn(&mut Vec<f32>), words: &[&str]) {
    let Some(tf) = with_field(name, "damaged.bsdf", edit) else {
        return;
    };
    let e = RglBsdf::from_tensor_file(&tf).unwrap_err().to_string();
    assert!(
        e.contains("damaged.bsdf") && e.contains(&format!("\"{name}\"")),
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
