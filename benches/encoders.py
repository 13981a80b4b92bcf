#!/usr/bin/env python3
"""The other side of `cargo bench --bench encoders`: libjpeg-turbo (through Pillow) and
OpenEXR's PIZ (through the `OpenEXR` package) on the pixels the bench wrote.

    python3 benches/encoders.py --dir target/bench-data/encoders --width 6000 --height 4000 \
        [--quality 92] [--runs 3] [--checks]

Reads `velvia50.rgb8` (8-bit interleaved RGB) and `radiance.f16` (half interleaved RGB,
little-endian) from DIR, and filmback's own `ours.jpg` and `ours.exr` for the checks.

* JPEG: quality Q, 4:4:4 (filmback's sampling from quality 90), standard Huffman tables,
  encoded from a Pillow image in memory (the conversion from the array is not timed). On
  one thread as one image; on two as filmback does it: bands of 64 rows, each a JPEG with a
  restart interval of one band, joined by RST markers under the first band's header (the
  result must decode to the one-thread file's pixels). PSNR of both files against the
  8-bit source, both decoded by Pillow.
* EXR: R, G, B half, PIZ, scan lines, written to a file, with OpenEXR's global thread
  pool at 0 (all on the calling thread), 1 and 2. Both files must decode to the source
  halves bit for bit.

Every time is the best wall time of `--runs` calls, beside the least CPU time of the whole
process over the same calls (`time.process_time`): on a shared machine the CPU time
compares the encoders' work even when the wall time does not.

With `--checks` it also compares the files (sizes, PSNR, same pixels); the bench asks for
them in its first round only. Prints readable lines, then one line `RESULT {json}` for the
bench. A missing package skips its part (the JSON says why); exits 0 unless a check
fails.
"""
from __future__ import annotations

import argparse
import io
import json
import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor

BAND_ROWS = 64


def best(runs, f):
    """The best wall time and the least CPU time (every thread of the process) of `runs`
    calls of f, in ms, and f's last result."""
    wall, cpu, out = [], [], None
    for _ in range(max(runs, 1)):
        start, start_cpu = time.perf_counter(), time.process_time()
        out = f()
        wall.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    return (min(wall) * 1e3, min(cpu) * 1e3), out


def psnr(reference, other):
    import numpy as np

    diff = reference.astype(np.float64) - other.astype(np.float64)
    mse = float(np.mean(diff * diff))
    return float("inf") if mse == 0 else 10 * np.log10(255.0**2 / mse)


def scan_of(data: bytes):
    """(start of SOF0, start of the entropy-coded segment, its end) of a baseline JPEG."""
    pos, frame = 2, None
    while True:
        marker, length = data[pos + 1], int.from_bytes(data[pos + 2 : pos + 4], "big")
        if marker == 0xC0:
            frame = pos
        if marker == 0xDA:
            return frame, pos + 2 + length, len(data) - 2
        pos += 2 + length


def jpeg(args, rgb, runs):
    try:
        from PIL import Image, features
    except ImportError:
        return {"skipped": "Pillow is not installed"}
    import numpy as np

    turbo = features.version_feature("libjpeg_turbo")
    library = f"Pillow {Image.__version__}, libjpeg-turbo {turbo or 'absent (libjpeg)'}"
    print(f"JPEG: {library}")
    h, w = rgb.shape[:2]
    options = {"quality": args.quality, "subsampling": 0, "optimize": False}

    image = Image.fromarray(rgb)
    (t_convert, _), _ = best(1, lambda: Image.fromarray(rgb))

    def single():
        out = io.BytesIO()
        image.save(out, "JPEG", **options)
        return out.getvalue()

    t1, one = best(runs, single)

    # Bands of 64 rows (a multiple of the 8-row MCU), each one restart interval.
    interval = (BAND_ROWS // 8) * -(-w // 8)
    bands = [image.crop((0, y, w, min(y + BAND_ROWS, h))) for y in range(0, h, BAND_ROWS)]

    def encode_band(band):
        out = io.BytesIO()
        band.save(out, "JPEG", restart_marker_blocks=interval, **options)
        return out.getvalue()

    def banded(pool):
        parts = list(pool.map(encode_band, bands))
        frame, start, _ = scan_of(parts[0])
        header = bytearray(parts[0][:start])
        header[frame + 5 : frame + 7] = h.to_bytes(2, "big")
        out = [bytes(header)]
        for i, part in enumerate(parts):
            if i > 0:
                out.append(bytes([0xFF, 0xD0 + (i - 1) % 8]))
            _, s, e = scan_of(part)
            out.append(part[s:e])
        out.append(b"\xff\xd9")
        return b"".join(out)

    with ThreadPoolExecutor(2) as pool:
        t2, two = best(runs, lambda: banded(pool))
    result = {
        "library": library,
        "ms": {"1": t1[0], "2": t2[0]},
        "cpu_ms": {"1": t1[1], "2": t2[1]},
        "array_to_image_ms": t_convert,
    }
    print(
        f"  1 thread {t1[0]:.1f} ms (CPU {t1[1]:.1f}), "
        f"2 threads (banded) {t2[0]:.1f} ms (CPU {t2[1]:.1f})"
    )
    if not args.checks:
        return result

    def decode(data):
        return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))

    ours_bytes = open(os.path.join(args.dir, "ours.jpg"), "rb").read()
    decoded_one, decoded_ours = decode(one), decode(ours_bytes)
    banded_same = bool(np.array_equal(decode(two), decoded_one))
    same_tables = (
        Image.open(io.BytesIO(one)).quantization
        == Image.open(io.BytesIO(ours_bytes)).quantization
    )
    with open(os.path.join(args.dir, "turbo.jpg"), "wb") as f:
        f.write(one)
    result.update(
        bytes=len(one),
        banded_bytes=len(two),
        banded_same_pixels=banded_same,
        psnr=psnr(rgb, decoded_one),
        ours_psnr=psnr(rgb, decoded_ours),
        same_tables=same_tables,
    )
    print(
        f"  {len(one) / 1e6:.2f} MB, PSNR {result['psnr']:.2f} dB "
        f"(ours {result['ours_psnr']:.2f} dB); same quantisation tables: {same_tables}; "
        f"banded decodes to the same pixels: {banded_same}; "
        f"array → image {t_convert:.1f} ms (not timed)"
    )
    if not banded_same:
        print("encoders.py: the banded libjpeg-turbo file decodes differently", file=sys.stderr)
        sys.exit(1)
    return result


def exr(args, halves, runs):
    try:
        import OpenEXR
    except ImportError:
        return {"skipped": "OpenEXR is not installed"}
    import numpy as np

    library = f"OpenEXR {OpenEXR.OPENEXR_VERSION}"
    print(f"EXR: {library}")
    planes = {c: np.ascontiguousarray(halves[:, :, k]) for k, c in enumerate("RGB")}
    header = {"compression": OpenEXR.PIZ_COMPRESSION, "type": OpenEXR.scanlineimage}
    path = os.path.join(args.dir, "openexr.exr")
    times, cpu = {}, {}
    before = OpenEXR.global_thread_count()
    for threads in (0, 1, 2):
        # The pool's size, and the file's own count of blocks in flight (a File takes the
        # pool's size when it is made). File replaces the values of the dict it is given
        # by its Channel objects, so each gets a copy of the dict.
        OpenEXR.set_global_thread_count(threads)
        with OpenEXR.File(header, dict(planes), num_threads=threads) as image:
            (wall, cpu_ms), _ = best(runs, lambda: image.write(path))
        times[str(threads)], cpu[str(threads)] = wall, cpu_ms
    OpenEXR.set_global_thread_count(before)
    print(
        "  "
        + ", ".join(f"{n} threads {t:.1f} ms (CPU {cpu[n]:.1f})" for n, t in times.items())
    )
    result = {"library": library, "ms": times, "cpu_ms": cpu}
    if not args.checks:
        return result

    def same_halves(file):
        with OpenEXR.File(file, separate_channels=True) as f:
            read = f.channels()
            return all(
                np.array_equal(read[c].pixels.view(np.uint16), planes[c].view(np.uint16))
                for c in "RGB"
            )

    same = same_halves(path) and same_halves(os.path.join(args.dir, "ours.exr"))
    size = os.path.getsize(path)
    print(f"  {size / 1e6:.2f} MB; both files decode to the source halves: {same}")
    if not same:
        print("encoders.py: an EXR does not decode to the source halves", file=sys.stderr)
        sys.exit(1)
    result.update(bytes=size, same_pixels=same)
    return result


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", required=True)
    parser.add_argument("--width", type=int, required=True)
    parser.add_argument("--height", type=int, required=True)
    parser.add_argument("--quality", type=int, default=92)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--checks", action="store_true")
    args = parser.parse_args()
    try:
        import numpy as np
    except ImportError:
        skipped = {"skipped": "numpy is not installed"}
        print("encoders.py: skipped (numpy is not installed)")
        print("RESULT " + json.dumps({"jpeg": skipped, "exr": skipped}))
        return
    h, w = args.height, args.width
    rgb = np.fromfile(os.path.join(args.dir, "velvia50.rgb8"), np.uint8).reshape(h, w, 3)
    halves = np.fromfile(os.path.join(args.dir, "radiance.f16"), "<f2").reshape(h, w, 3)
    result = {"jpeg": jpeg(args, rgb, args.runs), "exr": exr(args, halves, args.runs)}
    for part in ("jpeg", "exr"):
        if "skipped" in result[part]:
            print(f"{part}: skipped ({result[part]['skipped']})")
    print("RESULT " + json.dumps(result))


if __name__ == "__main__":
    main()
