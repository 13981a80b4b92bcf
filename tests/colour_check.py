#!/usr/bin/env python3
"""Converts filmback's wide-gamut renderings back to sRGB with Little CMS 2 (the copy
that Pillow's wheel from PyPI carries, called in floating point) and compares them
with filmback's sRGB rendering of the same look.

    python3 tests/colour_check.py REFERENCE.png WIDE_FILE ...

REFERENCE is the 16-bit sRGB PNG rendering; each WIDE_FILE is the same look encoded for
Display P3 or Rec. 2020 with its ICC profile embedded (JPEG, PNG 8/16 or TIFF 16). The
profile is read by Pillow, the samples at the file's own depth (pypng, tifffile, Pillow
for JPEG), converted with Little CMS from the embedded profile to its built-in sRGB
profile (relative colorimetric, 32-bit float), decoded to linear light and compared with the
reference in CIELAB (D65) as CIEDE2000. Limits: a 16-bit file p95 <= 0.1 and max <= 1.0;
an 8-bit file p95 <= 2.0 and max <= 5.0 (its own quantisation, coarse in the dark tones
of Rec. 2020's transfer function, and a JPEG's compression are in that figure). Exits 0 with a "skipped" note when a package is missing, 1 on any failure.
"""
from __future__ import annotations

import ctypes
import glob
import io
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
try:
    import numpy as np
    import png
    import tifffile
    import PIL
    from PIL import Image
except ImportError as e:  # the reference reader is optional on developer machines
    print(f"colour_check: skipped ({e.name} is not installed)")
    sys.exit(0)

from cielab import ciede2000, decode, lab  # noqa: E402

LIMITS = {16: (0.1, 1.0), 8: (2.0, 5.0)}
# lcms2.h: FLOAT_SH(1) | COLORSPACE_SH(PT_RGB) | CHANNELS_SH(3) | BYTES_SH(4)
TYPE_RGB_FLT = (1 << 22) | (4 << 16) | (3 << 3) | 4
INTENT_RELATIVE_COLORIMETRIC = 1


def little_cms() -> ctypes.CDLL:
    """Pillow's own Little CMS 2 (the library its ImageCms module calls)."""
    libs = os.path.join(os.path.dirname(PIL.__file__), os.pardir, "pillow.libs")
    found = sorted(glob.glob(os.path.join(libs, "liblcms2*.so*")))
    lib = ctypes.CDLL(found[0] if found else "liblcms2.so.2")
    lib.cmsOpenProfileFromMem.restype = ctypes.c_void_p
    lib.cmsOpenProfileFromMem.argtypes = [ctypes.c_char_p, ctypes.c_uint32]
    lib.cmsCreate_sRGBProfile.restype = ctypes.c_void_p
    lib.cmsCreateTransform.restype = ctypes.c_void_p
    lib.cmsCreateTransform.argtypes = [ctypes.c_void_p, ctypes.c_uint32] * 2 + [
        ctypes.c_uint32,
        ctypes.c_uint32,
    ]
    lib.cmsDoTransform.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint32]
    lib.cmsGetEncodedCMMversion.restype = ctypes.c_int
    return lib


def samples(path: str) -> tuple[np.ndarray, int]:
    """The file's RGB samples at 16 bits (8-bit files scaled by 257) and its depth."""
    if path.lower().endswith((".tif", ".tiff")):
        data = tifffile.imread(path)
    elif path.lower().endswith(".png"):
        width, height, rows, info = png.Reader(filename=path).asDirect()
        data = np.vstack([np.asarray(r) for r in rows]).reshape(height, width, 3)
        data = data.astype(np.uint16 if info["bitdepth"] == 16 else np.uint8)
    else:
        data = np.asarray(Image.open(path).convert("RGB"))
    depth = 16 if data.dtype == np.uint16 else 8
    wide = data.astype(np.uint16) * (1 if depth == 16 else 257)
    return np.ascontiguousarray(wide.reshape(-1, 3)), depth


def to_srgb(lib: ctypes.CDLL, path: str) -> tuple[np.ndarray, int]:
    """The file's pixels as sRGB code values 0..1, through its embedded profile."""
    icc = Image.open(path).info.get("icc_profile")
    if not icc:
        raise ValueError(f"{path}: no embedded ICC profile")
    source = lib.cmsOpenProfileFromMem(icc, len(icc))
    target = lib.cmsCreate_sRGBProfile()
    transform = lib.cmsCreateTransform(
        source, TYPE_RGB_FLT, target, TYPE_RGB_FLT, INTENT_RELATIVE_COLORIMETRIC, 0
    )
    if not (source and transform):
        raise ValueError(f"{path}: Little CMS cannot use the embedded profile")
    pixels, depth = samples(path)
    pixels = np.ascontiguousarray(pixels / 65535.0, dtype=np.float32)
    out = np.empty_like(pixels)
    lib.cmsDoTransform(transform, pixels.ctypes.data, out.ctypes.data, len(pixels))
    return out.astype(np.float64), depth


def main() -> int:
    if len(sys.argv) < 3:
        print(__doc__)
        return 2
    lib = little_cms()
    version = lib.cmsGetEncodedCMMversion()
    reference, _ = samples(sys.argv[1])
    want = lab(decode(reference / 65535.0, "srgb"))
    ok = True
    for path in sys.argv[2:]:
        got, depth = to_srgb(lib, path)
        de = ciede2000(lab(decode(got, "srgb")), want)
        p95, worst = float(np.percentile(de, 95)), float(de.max())
        passed = p95 <= LIMITS[depth][0] and worst <= LIMITS[depth][1]
        ok &= passed
        print(
            f"colour_check: {os.path.basename(os.path.dirname(path))}/{os.path.basename(path)} "
            f"({depth}-bit, Little CMS {version}, {len(de)} pixels): CIEDE2000 p95 {p95:.3f} "
            f"max {worst:.3f} {'ok' if passed else 'FAILED'}"
        )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
