//! `metadata::read` on arbitrary bytes: must never panic, whatever the container.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|bytes: &[u8]| {
    let meta = filmback::metadata::read(bytes);
    // Whatever was read must respect the documented invariants.
    assert!((1..=8).contains(&meta.orientation));
    if let Some(t) = meta.exposure.time_s {
        assert!(t.is_finite() && t > 0.0);
    }
    if let Some(n) = meta.exposure.f_number {
        assert!(n.is_finite() && n > 0.0);
    }
    if let Some(s) = meta.exposure.iso {
        assert!(s.is_finite() && s > 0.0);
    }
    if let Some(c) = meta.captured_at {
        let _ = c.to_rfc3339();
    }
});
