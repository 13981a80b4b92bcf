#!/usr/bin/env python3
"""OpenCV's AlignMTB (default settings: 6 levels, exclusion range 4, cut on) on a bracket
written by `cargo bench --bench align`, as its `process` does it: every frame shifted onto
a pivot frame by `calculateShift` of the grey images and `shiftMat` (`process` takes the
middle frame; the bench passes the frame filmback registers onto, so both align onto the
same frame). Arguments: PIVOT (a frame index), then pairs of paths, INPUT OUTPUT, one per
frame; each aligned frame is written to its OUTPUT (PNG)."""
import sys

import cv2

pivot = int(sys.argv[1])
paths = sys.argv[2:]
inputs, outputs = paths[0::2], paths[1::2]
frames = [cv2.imread(p, cv2.IMREAD_COLOR) for p in inputs]
if any(f is None for f in frames):
    sys.exit("could not read " + ", ".join(p for p, f in zip(inputs, frames) if f is None))
mtb = cv2.createAlignMTB()
grey = [cv2.cvtColor(f, cv2.COLOR_BGR2GRAY) for f in frames]
for frame, g, path in zip(frames, grey, outputs):
    shift = mtb.calculateShift(grey[pivot], g)
    cv2.imwrite(path, mtb.shiftMat(frame, shift))
