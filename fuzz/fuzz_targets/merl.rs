//! Fuzz target: arbitrary bytes through the MERL `.binary` reader, its dataset-order export
//! (marker filling) and its resampling onto a small grid. Any panic is a bug.
#![no_main]

use brdf_io::grid::AngularGrid;
use brdf_io::merl::{Resampling, parse_merl};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(brdf) = parse_merl(data, "fuzz.binary") else {
        return;
    };
    // The fuzzer keeps inputs small, so the grids it reaches are small: bound the work anyway.
    if brdf.grid().len() > 1 << 16 {
        return;
    }
    let (values, _) = brdf.to_dataset_order();
    assert_eq!(values.len(), 3 * brdf.grid().len());
    let target = AngularGrid::new(2, 3, 4).expect("a valid grid");
    for method in [Resampling::Nearest, Resampling::default()] {
        let (values, _) = brdf.resample(&target, method);
        assert_eq!(values.len(), 3 * target.len());
    }
});
