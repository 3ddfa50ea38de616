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
        let fields: Vec<Field> = tf
            .fields()
            .iter()
            .map(|f| {
                if f.name() != name {
                    return f.clone();
                }
                let mut v = f.to_f64(&path).unwrap();
                v[7] = f64::from(bad);
                let v: Vec<f32> = v.iter().map(|&x| x as f32).collect();
                Field::from_f32(name, f.shape().to_vec(), &v).unwrap()
            })
            .collect();
        let bytes = TensorFile::to_bytes(&fields).unwrap();
        let tf = TensorFile::from_bytes(&bytes, "bad.bsdf").unwrap();
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
