#!/usr/bin/env python3
"""Reads a merged DNG written by `filmback merge --dng` with LibRaw (the copy that
rawpy's wheel from PyPI carries) and compares it with the merge filmback made.

    python3 tests/dng_check.py MERGED.dng EXPECTED.f32 EXPECTED.json

EXPECTED.f32 holds the samples the DNG should carry (little-endian 32-bit floats, row
by row, the merged radiance over the bracket's exposure ratio, so 1.0 is the shortest
frame's clipping point); EXPECTED.json its width, height, CFA pattern, as-shot neutral
and XYZ -> camera colour matrix.

LibRaw converts floating-point DNG samples to 16-bit integers when it loads them,
scaled so that the larger of the white level and the largest sample becomes 16383, and
clamps negative samples to 0. So the samples are compared as
`(raw - black)/(white - black)` against `max(expected, 0)` over the brightest expected
sample, and must agree within one step of that scale, 1/16383 (a step of rounding or
truncation, and float rounding of the scale). The CFA pattern, the white balance
(LibRaw's multipliers, the reciprocal of the as-shot neutral, to 1e-4 relative), the
camera -> sRGB matrix LibRaw derives from the colour matrix (to 2e-3: LibRaw 0.22's
derivation differs from the one restated here by 6e-4; a missing or wrong matrix is off
by about 1) and that LibRaw develops the file to finite, non-black RGB are checked too. Prints the measured differences; exits 0 with a "skipped" note when rawpy
or numpy is missing, 1 on any failure.
"""
from __future__ import annotations

import json
import sys

try:
    import numpy as np
    import rawpy
except ImportError as e:  # the reference reader is optional on developer machines
    print(f"dng_check: skipped ({e.name} is not installed)")
    sys.exit(0)

LIBRAW_TARGET = 16383.0
# dcraw's and LibRaw's linear sRGB -> XYZ (D65), the columns of its xyz_rgb.
XYZ_RGB = np.array(
    [
        [0.412453, 0.357580, 0.180423],
        [0.212671, 0.715160, 0.072169],
        [0.019334, 0.119193, 0.950227],
    ]
)


def main(dng: str, expected_path: str, tags_path: str) -> int:
    tags = json.load(open(tags_path))
    width, height = tags["width"], tags["height"]
    expected = np.fromfile(expected_path, dtype="<f4").reshape(height, width)
    failures = []
    with rawpy.imread(dng) as raw:
        samples = raw.raw_image_visible.astype(np.float64)
        if samples.shape != (height, width):
            print(f"dng_check: {dng}: {samples.shape} samples, not {(height, width)}")
            return 1
        black = np.array(raw.black_level_per_channel, dtype=np.float64)
        colours = raw.raw_colors_visible
        white = float(raw.white_level)
        signal = (samples - black[colours]) / (white - black[colours])
        brightest = max(float(expected.max()), 1.0)
        want = np.maximum(expected.astype(np.float64), 0.0) / brightest
        difference = np.abs(signal - want)
        step = 1.0 / LIBRAW_TARGET
        print(
            f"dng_check: LibRaw {rawpy.libraw_version}: samples within "
            f"{difference.max():.3e} of full scale (mean {difference.mean():.2e}; "
            f"one 16383rd is {step:.3e}); white level {white:.0f}, black {black[0]:.0f}"
        )
        if difference.max() > step * 1.001:
            worst = np.unravel_index(np.argmax(difference), difference.shape)
            failures.append(
                f"sample {worst}: LibRaw {signal[worst]:.6f}, expected {want[worst]:.6f}"
            )
        letters = "".join(raw.color_desc.decode()[c] for c in raw.raw_pattern.flatten())
        if letters != tags["cfa"]:
            failures.append(f"CFA {letters}, expected {tags['cfa']}")
        multipliers = np.array(raw.camera_whitebalance[:3], dtype=np.float64)
        neutral = multipliers[1] / multipliers
        want_neutral = np.array(tags["neutral"], dtype=np.float64)
        neutral_error = np.abs(neutral / want_neutral - 1.0).max()
        print(f"dng_check: as-shot neutral {neutral.round(5).tolist()} ({neutral_error:.1e} off)")
        if neutral_error > 1e-4:
            failures.append(f"neutral {neutral.tolist()}, expected {want_neutral.tolist()}")
        # LibRaw keeps a DNG's colour matrix only through the camera -> sRGB matrix it
        # derives from it (rgb_xyz_matrix is filled for cameras in its own table):
        # dcraw's cam_xyz_coeff, rows of M . XYZ->sRGB normalised to sum 1, inverted.
        cam_rgb = np.array(tags["colour_matrix"], dtype=np.float64) @ XYZ_RGB
        cam_rgb /= cam_rgb.sum(axis=1, keepdims=True)
        want_matrix = np.linalg.inv(cam_rgb)
        matrix = np.array(raw.color_matrix, dtype=np.float64)[:, :3]
        matrix_error = np.abs(matrix - want_matrix).max()
        print(f"dng_check: camera -> sRGB matrix from the colour matrix within {matrix_error:.1e}")
        if matrix_error > 2e-3:
            failures.append(f"camera -> sRGB {matrix.tolist()}, expected {want_matrix.tolist()}")
        options = dict(use_camera_wb=True, no_auto_bright=True, gamma=(1, 1), output_bps=16)
        if raw.raw_pattern.shape == (6, 6):
            # LibRaw 0.22's default X-Trans interpolation fails with an I/O error on these
            # small synthetic X-Trans DNGs, the integer frames rawler wrote as well as the
            # merge: develop with its linear interpolation.
            options["demosaic_algorithm"] = rawpy.DemosaicAlgorithm.LINEAR
        rgb = raw.postprocess(**options)
        if rgb.shape[:2] != (height, width) or not np.isfinite(rgb).all() or rgb.max() == 0:
            failures.append(f"LibRaw developed {rgb.shape}, max {rgb.max()}")
    for f in failures:
        print(f"dng_check: {dng}: {f}")
    if failures:
        return 1
    print("dng_check: ok")
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 4:
        print(__doc__)
        sys.exit(2)
    sys.exit(main(*sys.argv[1:]))
