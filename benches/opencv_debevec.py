#!/usr/bin/env python3
"""OpenCV's CalibrateDebevec (70 samples, lambda 10, the peer's settings) on pairs written
by the benches. Reads a JSON list of {"dark", "bright", "t_dark", "t_bright"} from argv[1];
prints JSON {"curves": [256x3 per pair (code, channel RGB)], "ms": [calibrate time per pair]}."""
import json
import sys
import time

import cv2
import numpy as np

cases = json.load(open(sys.argv[1]))
calibrate = cv2.createCalibrateDebevec(70, 10.0)
curves, ms = [], []
for c in cases:
    imgs = [cv2.imread(c["dark"], cv2.IMREAD_COLOR), cv2.imread(c["bright"], cv2.IMREAD_COLOR)]
    times = np.array([c["t_dark"], c["t_bright"]], dtype=np.float32)
    start = time.perf_counter()
    curve = calibrate.process(imgs, times)  # 256x1x3, BGR
    ms.append((time.perf_counter() - start) * 1e3)
    # Non-finite values (OpenCV failed) become 0: an infinite error, counted as a loss.
    curves.append(np.nan_to_num(curve[:, 0, ::-1].astype(float), nan=0.0, posinf=0.0, neginf=0.0).tolist())
json.dump({"curves": curves, "ms": ms}, sys.stdout)
