#!/usr/bin/env python3
"""Cross-check on real brackets (../shared/testdata/brackets): calibrate a pair of frames,
then predict a third frame from its neighbour, B^ = f(gamma * g(B)), with filmback's curve
and with OpenCV's CalibrateDebevec on the same pair; print the error in DN over samples
unclipped (5 < DN < 250) in both the prediction and the frame.

    cargo build --release
    /tmp/filmback-peer-venv/bin/python benches/predict_neighbour.py

(the peer's python from ../shared/peer/setup.sh: cv2, numpy). frobisher: JPEG, 3-stop steps,
exposures from EXIF. memorial: PNG, 1-stop steps, exposure times from its CSV (`--ratio 2`).
"""
import json
import os
import subprocess
import sys
import tempfile
import tomllib

import cv2
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
FILMBACK = os.path.join(HERE, '..', 'target', 'release', 'filmback')
BRACKETS = os.path.join(HERE, '..', '..', 'shared', 'testdata', 'brackets')

# (bracket, curve pair (darker first), exposure times of the pair, source, target,
# source and target exposure times); pair times None: filmback takes the ratio from EXIF.
CASES = [
    ('frobisher', ('IMG_2600.jpg', 'IMG_2601.jpg'), None, 'IMG_2601.jpg', 'IMG_2602.jpg', 1.0, 8.0),
    ('frobisher', ('IMG_2601.jpg', 'IMG_2602.jpg'), None, 'IMG_2601.jpg', 'IMG_2600.jpg', 1.0, 1 / 8),
    ('memorial', ('memorial0062.png', 'memorial0061.png'), (16.0, 32.0), 'memorial0063.png', 'memorial0062.png', 8.0, 16.0),
    ('memorial', ('memorial0063.png', 'memorial0062.png'), (8.0, 16.0), 'memorial0062.png', 'memorial0061.png', 16.0, 32.0),
]


def read(path):
    image = cv2.imread(path, cv2.IMREAD_COLOR)
    if image is None:
        sys.exit(f'{path}: cannot read')
    return image[:, :, ::-1].astype(float)


def predict(curves, src, gamma):
    out = np.zeros_like(src)
    for c in range(3):
        g = np.asarray(curves[c], float)  # g at codes 0..255, non-decreasing
        e = np.interp(src[:, :, c], np.arange(256), g) * gamma
        out[:, :, c] = np.interp(e, g, np.arange(256))  # f = g^-1, clips at 255
    return out


def ours(paths, ratio, workdir):
    out = os.path.join(workdir, 'response.toml')
    cmd = [FILMBACK, 'calibrate', *paths, '-o', out]
    if ratio is not None:
        cmd += ['--ratio', str(ratio)]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    with open(out, 'rb') as f:
        d = tomllib.load(f)
    curves = [np.interp(np.arange(256) / 255, np.linspace(0, 1, len(ch['g'])), ch['g'])
              for ch in d['channel']]
    confidence = [ch.get('confidence', float('nan')) for ch in d['channel']]
    return curves, confidence


def opencv(paths, times):
    images = [cv2.imread(p) for p in paths]
    crf = cv2.createCalibrateDebevec(70, 10.0).process(images, np.array(times, np.float32))
    return [crf[:, 0, 2 - c] for c in range(3)]


def error(pred, truth):
    m = (truth > 5) & (truth < 250) & (pred < 250) & (pred > 5)
    d = np.abs(pred - truth)[m]
    return np.median(d), np.sqrt(np.mean(d ** 2))


def exif_time(path):
    """Exposure time in seconds from the file's EXIF, as `filmback inspect` reads it."""
    out = subprocess.run([FILMBACK, 'inspect', '--json', path], check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out)[0]['exposure']['time_s']


def main():
    if not os.path.exists(FILMBACK):
        sys.exit(f'{FILMBACK}: not built (cargo build --release)')
    with tempfile.TemporaryDirectory() as workdir:
        for bracket, pair, times, source, target, t_source, t_target in CASES:
            base = os.path.join(BRACKETS, bracket)
            paths = [os.path.join(base, p) for p in pair]
            ratio = None if times is None else times[1] / times[0]
            if times is None:
                times = [exif_time(p) for p in paths]
            src = read(os.path.join(base, source))
            truth = read(os.path.join(base, target))
            gamma = t_target / t_source
            curves, confidence = ours(paths, ratio, workdir)
            a = error(predict(curves, src, gamma), truth)
            b = error(predict(opencv(paths, times), src, gamma), truth)
            conf = ' '.join(f'{c:.2f}' for c in confidence)
            print(f'{bracket}: {target} from {source} (curve of {pair[0]}+{pair[1]}): '
                  f'filmback median {a[0]:.2f} / RMS {a[1]:.2f} DN (confidence {conf}), '
                  f'OpenCV {b[0]:.2f} / {b[1]:.2f} DN')


if __name__ == '__main__':
    main()
