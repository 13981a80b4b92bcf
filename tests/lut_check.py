#!/usr/bin/env python3
"""Applies filmback's .cube LUTs with OpenColorIO (the reference implementation, PyPI
`opencolorio`) and compares them with filmback's own rendering of the same inputs.

    python3 tests/lut_check.py DIR NAME:OUTPUT ...

For each NAME, DIR holds NAME.cube, NAME.in.f32 (input code values, RGB float32
little-endian) and NAME.want.f32 (filmback's rendering of those inputs in the display
encoding OUTPUT: srgb, rec709 or p3). The LUT is applied by OpenColorIO's FileTransform
(its default interpolation); both results are decoded to display light and compared as
CIEDE2000 in CIELAB (D65). Limits: p95 <= 1.0 and max <= 3.0. `tests/lut.rs` writes
the files and runs this script. Exits 0 with a "skipped" note when OpenColorIO or numpy
is not installed, 1 on any failure.
"""
from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
try:
    import numpy as np
    import PyOpenColorIO as ocio
except ImportError as e:  # the reference implementation is optional on developer machines
    print(f"lut_check: skipped ({e.name} is not installed)")
    sys.exit(0)

from cielab import ciede2000, decode, lab  # noqa: E402

P95_LIMIT = 1.0
MAX_LIMIT = 3.0

def check(folder: str, name: str, output: str) -> bool:
    read = lambda suffix: np.fromfile(os.path.join(folder, name + suffix), "<f4").reshape(-1, 3)
    codes = np.ascontiguousarray(read(".in.f32"), dtype=np.float32)
    want = read(".want.f32").astype(np.float64)
    transform = ocio.FileTransform(src=os.path.join(folder, name + ".cube"))
    processor = ocio.GetCurrentConfig().getProcessor(transform)
    got = codes.copy()
    processor.getDefaultCPUProcessor().applyRGB(got)
    de = ciede2000(lab(decode(got.astype(np.float64), output)), lab(decode(want, output)))
    p95, worst = float(np.percentile(de, 95)), float(de.max())
    ok = p95 <= P95_LIMIT and worst <= MAX_LIMIT
    print(
        f"lut_check: {name} (OpenColorIO {ocio.__version__}, {len(de)} pixels): "
        f"CIEDE2000 p95 {p95:.3f} max {worst:.3f} {'ok' if ok else 'FAILED'}"
    )
    return ok


def main() -> int:
    if len(sys.argv) < 3:
        print(__doc__, file=sys.stderr)
        return 2
    folder = sys.argv[1]
    results = [check(folder, *case.rsplit(":", 1)) for case in sys.argv[2:]]
    return 0 if all(results) else 1


if __name__ == "__main__":
    sys.exit(main())
