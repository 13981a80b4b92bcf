#!/usr/bin/env python3
"""Checks filmback's OpenEXR output with the reference OpenEXR library (Python `OpenEXR`).

    python3 tests/openexr_check.py [--bin target/debug/filmback] [FILE.exr ...]

Without files it makes its own: two small PNG frames of a ramp through the sRGB curve,
two stops apart (pure Python, no imaging package), merged by `filmback merge --srgb` as
half/PIZ and float/ZIP with `--confidence`, as half/PIZ without it, and as an ACES
container (AP0, half, uncompressed). Each file must open in the reference reader with R,
G, B (and confidence.Y where written) of the right type, finite values, and filmback's
header attributes; only the ACES container carries `acesImageContainerFlag = 1`, with
the AP0 primaries and no compression. Exits 0 with a "skipped" note when the `OpenEXR`
package is not installed, 1 on any failure.
"""
from __future__ import annotations

import argparse
import math
import os
import struct
import subprocess
import sys
import tempfile
import zlib

try:
    import OpenEXR
    import numpy as np
except ImportError as e:  # the reference reader is optional on developer machines
    print(f"openexr_check: skipped ({e.name} is not installed)")
    sys.exit(0)

REQUIRED = [
    "chromaticities",
    "software",
    "comments",
    "filmbackExposureRatio",
    "filmbackFrame0",
    "filmbackFrame1",
    "filmbackResponse",
    "filmbackWeighting",
    "filmbackScale",
    "filmbackRadianceScale",
]


def png(path: str, width: int, height: int, rgb: bytes) -> None:
    def chunk(kind: bytes, data: bytes) -> bytes:
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))

    rows = b"".join(b"\0" + rgb[y * width * 3:(y + 1) * width * 3] for y in range(height))
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n")
        f.write(chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)))
        f.write(chunk(b"IDAT", zlib.compress(rows)))
        f.write(chunk(b"IEND", b""))


def srgb(x: float) -> int:
    x = min(max(x, 0.0), 1.0)
    b = 12.92 * x if x <= 0.0031308 else 1.055 * x ** (1 / 2.4) - 0.055
    return round(b * 255)


def make_bracket(folder: str) -> list[str]:
    width, height = 96, 64
    paths = []
    for name, exposure in (("dark", 0.25), ("bright", 1.0)):
        data = bytearray()
        for y in range(height):
            for x in range(width):
                radiance = 2.0 ** (-8 + 12 * x / (width - 1))  # 12 stops across
                tint = (1.0, 0.8 + 0.2 * y / height, 0.6)
                data += bytes(srgb(exposure * radiance * t) for t in tint)
        path = os.path.join(folder, f"{name}.png")
        png(path, width, height, bytes(data))
        paths.append(path)
    return paths


def check_aces(path: str, header: dict, aces: bool) -> list[str]:
    """The ACES container's flag where it qualifies (SMPTE ST 2065-4), and only there."""
    flag = header.get("acesImageContainerFlag")
    if not aces:
        return [f"{path}: acesImageContainerFlag {flag} on a file that is not one"] if flag else []
    problems = [] if flag == 1 else [f"{path}: acesImageContainerFlag is {flag}, expected 1"]
    red = np.asarray(header.get("chromaticities", [0])).ravel()[:2]
    if not np.allclose(red, [0.7347, 0.2653], atol=1e-4):
        problems.append(f"{path}: chromaticities red {red}, expected AP0's")
    if "NO_COMPRESSION" not in str(header.get("compression")):
        problems.append(f"{path}: compression {header.get('compression')}, expected none")
    return problems


def check(path: str, dtype: str, confidence: bool, aces: bool = False) -> list[str]:
    problems = []
    with OpenEXR.File(path) as f:
        header = f.header()
        channels = f.channels()
        problems += check_aces(path, header, aces)
        for key in REQUIRED:
            if key not in header:
                problems.append(f"{path}: header lacks {key}")
        if "RGB" not in channels:
            problems.append(f"{path}: no R, G, B channels (found {sorted(channels)})")
            return problems
        rgb = channels["RGB"].pixels
        if str(rgb.dtype) != dtype:
            problems.append(f"{path}: RGB is {rgb.dtype}, expected {dtype}")
        if not np.isfinite(rgb).all():
            problems.append(f"{path}: non-finite radiance values")
        if rgb.min() < 0:
            problems.append(f"{path}: negative radiance")
        if confidence:
            conf = channels.get("confidence.Y") or channels.get("confidence")
            if conf is None:
                problems.append(f"{path}: no confidence channel (found {sorted(channels)})")
        ratio = float(np.asarray(header.get("filmbackExposureRatio", [0])).ravel()[0])
        if not math.isclose(ratio, 4.0, rel_tol=1e-6) and "generated" in path:
            problems.append(f"{path}: filmbackExposureRatio {ratio}, expected 4")
    return problems


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", default=os.environ.get("FILMBACK_BIN", "target/debug/filmback"))
    ap.add_argument("files", nargs="*")
    a = ap.parse_args()
    problems: list[str] = []
    checked = 0
    for path in a.files:
        problems += check(path, "float16", confidence=False)
        checked += 1
    if not a.files:
        if not os.path.exists(a.bin):
            subprocess.run(["cargo", "build", "-q", "--bin", "filmback"], check=True)
        with tempfile.TemporaryDirectory() as tmp:
            frames = make_bracket(tmp)
            # With --confidence the merge is buffered; without, an 8-bit pair is merged
            # while the file is encoded: check both paths.
            for sample, compression, dtype, confidence, aces in (
                ("half", "piz", "float16", True, False),
                ("float", "zip", "float32", True, False),
                ("half", "piz", "float16", False, False),
                ("half", "none", "float16", False, True),
            ):
                out = os.path.join(tmp, f"generated-{sample}-{compression}-{confidence}")
                run = subprocess.run(
                    [a.bin, "merge", *frames, "-o", out, "--srgb",
                     "--times", "1/400,1/100", "--exr", sample, "--compression", compression]
                    + (["--confidence"] if confidence else [])
                    + (["--primaries", "ap0"] if aces else []),
                    capture_output=True, text=True)
                if run.returncode != 0:
                    problems.append(f"filmback merge failed: {run.stderr.strip()}")
                    continue
                problems += check(os.path.join(out, "dark.exr"), dtype, confidence, aces)
                checked += 1
    for p in problems:
        print(f"openexr_check: FAIL {p}")
    if not problems:
        print(f"openexr_check: ok ({checked} file(s) opened by OpenEXR {OpenEXR.__version__})")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
