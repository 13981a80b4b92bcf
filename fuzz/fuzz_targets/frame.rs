//! `frame::decode` on arbitrary bytes with a small pixel limit: an error or a frame of
//! the declared shape, never a panic and never a large allocation.
#![no_main]

use std::path::Path;

use filmback::frame::{self, Limits};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|bytes: &[u8]| {
    let limits = Limits {
        max_pixels: 1 << 16,
    };
    if let Ok(loaded) = frame::decode(Path::new("fuzz.jpg"), bytes, limits) {
        let f = &loaded.frame;
        assert!(u64::from(f.width()) * u64::from(f.height()) <= limits.max_pixels);
        assert!(f.channels() == 1 || f.channels() == 3);
    }
});
