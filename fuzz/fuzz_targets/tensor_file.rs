//! Fuzz target: arbitrary bytes through the tensor-file reader, the RGL BSDF builder and its
//! evaluator. Any panic is a bug; errors are the expected outcome for garbage input.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(tf) = brdf_io::tensor::TensorFile::from_bytes(data, "fuzz.bsdf") else {
        return;
    };
    for f in tf.fields() {
        let _ = f.to_f64(std::path::Path::new("fuzz.bsdf"));
    }
    let Ok(bsdf) = brdf_io::rgl::RglBsdf::from_tensor_file(&tf) else {
        return;
    };
    let mut out = vec![0.0; bsdf.channels().len()];
    let _ = bsdf.eval([0.3, 0.1, 0.9], [-0.5, 0.2, 0.4], &mut out);
    let _ = bsdf.eval([0.999, 0.0, 0.01], [-0.999, 0.0, 0.01], &mut out);
});
