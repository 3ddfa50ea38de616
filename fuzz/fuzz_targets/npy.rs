//! Fuzz target: arbitrary bytes through the `.npy` reader and its conversions. Any panic is a
//! bug; errors are the expected outcome for garbage input.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(array) = brdf_io::npy::parse(data, "fuzz.npy") else {
        return;
    };
    assert_eq!(array.to_f64().len(), array.len());
    assert_eq!(array.to_f32().len(), array.len());
});
