#!/usr/bin/env python3
"""Real-bracket cross-check (issue 15, item 7): predict one real frame from another.

For every bracket in ../shared/testdata/brackets and every triple (fit set S, source i,
target j), the prediction is B^_j = f(gamma_ij * g(B_i)) with g the inverse response
fitted on S, f = g^-1 and gamma_ij = t_j / t_i; the error is in DN (8-bit codes) over the
samples with 5 < DN < 250 in both frame i and frame j (the same samples for every
method). Methods:

  filmback-2    `filmback calibrate --json --ratio R` on an adjacent pair (S = the pair)
  filmback-all  `filmback calibrate --json --times T,...` on every frame (S = all frames):
                the joint fit of every adjacent pair's equations, the curve `merge` and
                the daemon fit for a bracket (response::calibrate_bracket)
  debevec-2/all, robertson-2/all
                OpenCV CalibrateDebevec / CalibrateRobertson (defaults) on the same frames
                and times
  srgb          the sRGB inverse (no fit)

filmback reads JPEG sources as themselves (at --stride = the decimation), as a user's
frames would reach it: its histograms need no registration, and it keeps a wider margin
below white in a lossy file. Other sources reach it as the registered PNGs.

Triples: S is an adjacent pair (two-frame methods) or every frame (all-frame methods);
(i, j) runs over every ordered pair of frames at most MAX_STOPS apart whose samples in
5..250 number at least MIN_SAMPLES in each channel. Every method sees the same pixels:
frames are decoded once by OpenCV, decimated to at most MAX_PIXELS, registered when
adjacent frames are offset (integer translation minimising the spread of one frame's
codes given the other's, cropped to the common area), and written as PNG; filmback reads
those PNGs (so exposure times are passed explicitly to every method). All pixels are used (errors are accumulated through
256x256 joint histograms of (B_i, B_j)), so no sampling seed is involved.

Every adjacent pair's implied exposure ratio is measured and printed (see
measure_ratios: memorial's darkest frames were said not to follow their listed times).
Pairs off by more than RATIO_TOLERANCE are treated as `--times` says, for every method
alike: `listed` (default) keeps the listed times, `measured` gives the chained measured
ratios, `cut` keeps the longest run of frames whose adjacent ratios are within it.

    cargo build --release
    /tmp/filmback-peer-venv/bin/python benches/accuracy/predict_neighbour.py [--bin PATH] [--quick]
        [--bracket NAME] [--times listed|measured|cut] [--brackets DIR]

(the peer's python from ../shared/peer/setup.sh: cv2, numpy.) Output: markdown
tables for docs/accuracy.md.
"""
import argparse
import csv
import glob
import json
import math
import os
import re
import subprocess
import sys
import tempfile
import time
import warnings

import cv2
import numpy as np


HERE = os.path.dirname(os.path.abspath(__file__))
DN_LO, DN_HI = 5, 250  # samples counted: DN_LO < B < DN_HI in source and target
MAX_STOPS = 4.0  # source and target at most this many stops apart
MIN_SAMPLES = 500  # per channel, for an (i, j) to count
MAX_PIXELS = 1.6e6  # frames are decimated (every n-th pixel of every n-th row) to this
WORSE_DN = 2.0  # a two-frame channel is "really worse" beyond this RMS excess, DN
LOW = 0.5  # confidence below this is "flagged low"
RATIO_TOLERANCE = 0.10  # measured/listed ratio off by more than this: does not follow
REGISTER_RADIUS = 8  # registration searches shifts up to this many pixels (working size)
REGISTER_GAIN = 0.05  # and shifts only when that lowers the spread by more than this share
QUICK = 'frobisher'
ABOVE_TOE = 32  # a diagnostic column counts only source samples at or above this code
BANDS = [(DN_LO + 1, 16), (16, 32), (32, 64), (64, 128), (128, DN_HI)]  # source codes, lo..hi-1
CODES = np.arange(256, dtype=float)


def log(*a):
    print(*a, file=sys.stderr, flush=True)


# ---------------------------------------------------------------- brackets and frames

def find_brackets():
    d = HERE
    for _ in range(6):
        for cand in (os.path.join(d, 'shared', 'testdata', 'brackets'),
                     os.path.join(d, '..', 'shared', 'testdata', 'brackets')):
            if os.path.isdir(cand):
                return os.path.normpath(cand)
        d = os.path.dirname(d)
    return None


def exif_exposures(binary, paths):
    out = subprocess.run([binary, 'inspect', '--json', *paths], check=True,
                         capture_output=True, text=True).stdout
    rows = json.loads(out)
    return [r['exposure']['relative_exposure'] or r['exposure']['time_s'] for r in rows]


def bracket_frames(binary, folder):
    """(paths, exposures, how the exposures were found), darkest first."""
    paths = sorted(p for p in glob.glob(os.path.join(folder, '*'))
                   if p.lower().endswith(('.png', '.jpg', '.jpeg', '.tif', '.tiff')))
    table = os.path.join(folder, 'exposure_times_seconds.csv')
    if os.path.exists(table):
        with open(table) as f:
            times = {r['file']: float(r['exposure_seconds']) for r in csv.DictReader(f)}
        exposures, source = [times[os.path.basename(p)] for p in paths], 'listed times (CSV)'
    elif all(re.fullmatch(r'img_[0-9.]+\.\w+', os.path.basename(p)) for p in paths):
        exposures = [float(re.fullmatch(r'img_([0-9.]+)\.\w+', os.path.basename(p)).group(1))
                     for p in paths]
        source = 'times in the file names'
    else:
        exposures, source = exif_exposures(binary, paths), 'EXIF t*S/N^2'
    order = np.argsort(exposures)
    return [paths[k] for k in order], [float(exposures[k]) for k in order], source


def gray(im):
    return cv2.cvtColor(im, cv2.COLOR_RGB2GRAY)


def spread(a, b):
    """Share of the variance of b (samples 5..250 in both) that a does not explain: the
    within-bin variance of b given a's code over b's total variance (1 - correlation ratio).
    Exposure-independent: aligned frames make b a function of a."""
    m = (a > DN_LO) & (a < DN_HI) & (b > DN_LO) & (b < DN_HI)
    a, b = a[m].astype(np.int64), b[m].astype(float)
    if b.size < MIN_SAMPLES:
        return float('inf')
    n = np.bincount(a, minlength=256)
    s, s2 = np.bincount(a, b, 256), np.bincount(a, b * b, 256)
    k = n > 0
    total = (b * b).sum() - b.sum() ** 2 / b.size
    return float((s2[k] - s[k] ** 2 / n[k]).sum() / max(total, 1e-9))


def shifted(a, b, dx, dy, r):
    h, w = a.shape
    return a[r:h - r, r:w - r], b[r + dy:h - r + dy, r + dx:w - r + dx]


def best_shift(a, b, radius=REGISTER_RADIUS):
    """Integer (dx, dy) with b(x + d) ~ a(x) minimising spread(a, b(. + d)): coarse on every
    second pixel over +-radius, then +-1 at full resolution; with the spread at d and at 0."""
    a2, b2 = a[::2, ::2], b[::2, ::2]
    r2 = radius // 2 + 1
    coarse = min((spread(*shifted(a2, b2, dx, dy, r2)), dx, dy)
                 for dy in range(-r2 + 1, r2) for dx in range(-r2 + 1, r2))
    r = radius + 2
    fine = min((spread(*shifted(a, b, dx, dy, r)), dx, dy)
               for dy in range(2 * coarse[2] - 1, 2 * coarse[2] + 2)
               for dx in range(2 * coarse[1] - 1, 2 * coarse[1] + 2))
    zero = spread(*shifted(a, b, 0, 0, r))
    if fine[0] >= zero * (1 - REGISTER_GAIN):
        return np.zeros(2, int), zero, zero
    return np.array(fine[1:]), fine[0], zero


def load(binary, folder):
    paths, exposures, source = bracket_frames(binary, folder)
    images = []
    for p in paths:
        im = cv2.imread(p, cv2.IMREAD_COLOR)
        if im is None:
            sys.exit(f'{p}: cannot read')
        images.append(np.ascontiguousarray(im[:, :, ::-1]))  # RGB
    n = max(1, math.ceil(math.sqrt(images[0].shape[0] * images[0].shape[1] / MAX_PIXELS)))
    images = [np.ascontiguousarray(im[::n, ::n]) for im in images]
    # Registration at the working size: chained adjacent integer shifts.
    offsets, steps = [np.zeros(2, int)], []
    for a, b in zip(images, images[1:]):
        d, after, before = best_shift(gray(a), gray(b))
        steps.append((d, after, before))
        offsets.append(offsets[-1] + d)
    shifts = np.array(offsets)
    registered = bool(np.abs(shifts).max() > 0)
    if registered:
        h, w = images[0].shape[:2]
        x0, y0 = max(0, -shifts[:, 0].min()), max(0, -shifts[:, 1].min())
        x1, y1 = w - max(0, shifts[:, 0].max()), h - max(0, shifts[:, 1].max())
        images = [np.ascontiguousarray(im[y0 + s[1]:y1 + s[1], x0 + s[0]:x1 + s[0]])
                  for im, s in zip(images, shifts)]
    return {
        'paths': paths, 'names': [os.path.splitext(os.path.basename(p))[0] for p in paths],
        'listed': exposures, 'source': source, 'images': images, 'steps': steps,
        'registered': registered, 'decimate': n,
    }


# ---------------------------------------------------------------- curves

def srgb_curve():
    x = CODES / 255
    g = np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
    return np.stack([g, g, g])


def failure(run):
    """filmback's error, its last line, with folders left out of file names."""
    lines = run.stderr.strip().splitlines()
    if not lines:
        return f'exit {run.returncode}'
    return re.sub(r'/\S*/', '', lines[-1]).replace('filmback: ', '')


def filmback_calibrate(binary, args):
    """(curves 3x256, confidences, channels' JSON) from `filmback calibrate --json ARGS`, or
    (None, reason)."""
    r = subprocess.run([binary, 'calibrate', '--json', *args], capture_output=True, text=True)
    if r.returncode != 0:
        return None, failure(r)
    d = json.loads(r.stdout)
    curves = np.array([np.nan_to_num(np.asarray(ch['inverse_response'], float))
                       for ch in d['channels']])
    return (curves, [float(ch.get('confidence', float('nan'))) for ch in d['channels']],
            d['channels'])


def filmback_pair(binary, dark, bright, ratio, stride=1):
    """An adjacent pair's curves at their ratio (see filmback_calibrate)."""
    return filmback_calibrate(binary, ['--ratio', repr(ratio), '--stride', str(stride), dark, bright])


def filmback_all(binary, paths, exposures, stride=1):
    """Every frame's joint curves at the given exposure times (see filmback_calibrate)."""
    times = ','.join(repr(e) for e in exposures)
    return filmback_calibrate(binary, ['--times', times, '--stride', str(stride), *paths])


def opencv_curve(kind, images, exposures):
    bgr = [np.ascontiguousarray(im[:, :, ::-1]) for im in images]
    t = np.array(exposures, np.float32)
    cal = cv2.createCalibrateDebevec() if kind == 'debevec' else cv2.createCalibrateRobertson()
    crf = cal.process(bgr, t)
    return np.array([crf[:, 0, 2 - c].astype(float) for c in range(3)])


# ---------------------------------------------------------------- prediction

def predict_table(g, gamma):
    """f(gamma * g(B)) at B = 0..255; f inverts the running maximum of g (OpenCV's curves
    need not be monotone; filmback's are)."""
    g = np.nan_to_num(np.asarray(g, float))
    return np.interp(gamma * g, monotone(g), CODES)


def joint_histograms(images, exposures):
    """{(i, j): [(a codes, b codes, counts) per channel]} for frames <= MAX_STOPS apart with
    enough samples, plus the list of ordered pairs left out for too few samples."""
    out, thin = {}, []
    n = len(images)
    for i in range(n):
        for j in range(n):
            if i == j or abs(math.log2(exposures[j] / exposures[i])) > MAX_STOPS + 1e-6:
                continue
            hs = []
            for c in range(3):
                a = images[i][:, :, c].ravel().astype(np.int64)
                b = images[j][:, :, c].ravel().astype(np.int64)
                m = (a > DN_LO) & (a < DN_HI) & (b > DN_LO) & (b < DN_HI)
                h = np.bincount(a[m] * 256 + b[m], minlength=65536)
                nz = np.nonzero(h)[0]
                hs.append((nz // 256, (nz % 256).astype(float), h[nz].astype(float)))
            if min(h[2].sum() for h in hs) < MIN_SAMPLES:
                thin.append((i, j))
            else:
                out[(i, j)] = hs
    return out, thin


def sse(curves, hist, gamma, lowest=0):
    """Per channel (sum of squared errors, samples), over source codes >= lowest."""
    out = []
    for c, (a, b, cnt) in enumerate(hist):
        t = predict_table(curves[c], gamma)
        k = a >= lowest
        out.append((float(np.sum(cnt[k] * (t[a[k]] - b[k]) ** 2)), float(cnt[k].sum())))
    return out


def band_sse(curves, hist, gamma):
    """Per source-code band of BANDS: (sum of squared errors, samples), channels pooled."""
    out = []
    tables = [predict_table(curves[c], gamma) for c in range(3)]
    for lo, hi in BANDS:
        e, n = 0.0, 0.0
        for c, (a, b, cnt) in enumerate(hist):
            k = (a >= lo) & (a < hi)
            e += float(np.sum(cnt[k] * (tables[c][a[k]] - b[k]) ** 2))
            n += float(cnt[k].sum())
        out.append((e, n))
    return out


def rms(per_channel):
    s = sum(x for x, _ in per_channel)
    n = sum(y for _, y in per_channel)
    return math.sqrt(s / n) if n else float('nan')


def transfer(a, b):
    """Brightness transfer: mean b per code of a (samples 5..250 in both, codes with >= 20)."""
    a, b = a.ravel().astype(np.int64), b.ravel().astype(float)
    m = (a > DN_LO) & (a < DN_HI) & (b > DN_LO) & (b < DN_HI)
    n = np.bincount(a[m], minlength=256)
    s = np.bincount(a[m], b[m], 256)
    with np.errstate(invalid='ignore', divide='ignore'):
        return np.where(n >= 20, s / n, np.nan)


def monotone(g):
    g = np.maximum.accumulate(np.maximum(np.nan_to_num(np.asarray(g, float)), 0.0))
    return g + CODES * 1e-12 * max(g[-1], 1e-300)


def measure_ratios(images, exposures, curves):
    """Per adjacent pair: the ratio its samples imply, per curve and channel, and the
    curve-free shift of its transfer in DN.

    With at least three adjacent pairs at one listed ratio (memorial), a pair's transfer
    tau_k(b) is compared with the median transfer tau_ref(b) of those pairs, code by code:
    ratio = listed * median_b g(tau_k(b)) / g(tau_ref(b)), so the curve only converts a
    shift in DN to a ratio and its own errors cancel to first order; the DN shift,
    median_b tau_k(b) - tau_ref(b), needs no curve at all. Otherwise the ratio is the
    median over samples 20..235 in both of g(B_bright) / g(B_dark)."""
    n = len(images)
    listed = [exposures[k + 1] / exposures[k] for k in range(n - 1)]
    taus = [[transfer(images[k][:, :, c], images[k + 1][:, :, c]) for c in range(3)]
            for k in range(n - 1)]
    out = []
    for k in range(n - 1):
        peers = [m for m in range(n - 1) if abs(listed[m] / listed[k] - 1) < 0.01]
        row = {'k': k, 'listed': listed[k], 'per': {}, 'shift_dn': None}
        if len(peers) >= 3:
            with warnings.catch_warnings():  # codes no pair holds stay NaN
                warnings.simplefilter('ignore', RuntimeWarning)
                refs = [np.nanmedian(np.array([taus[m][c] for m in peers]), axis=0)
                        for c in range(3)]
            row['shift_dn'] = []
            for c in range(3):
                ok = np.isfinite(taus[k][c]) & np.isfinite(refs[c])
                row['shift_dn'].append(float(np.median(taus[k][c][ok] - refs[c][ok]))
                                       if ok.any() else float('nan'))
            for name, g in curves.items():
                vals = []
                for c in range(3):
                    ok = np.isfinite(taus[k][c]) & np.isfinite(refs[c])
                    gm = monotone(g[c])
                    with np.errstate(invalid='ignore', divide='ignore'):
                        r = np.interp(taus[k][c][ok], CODES, gm) / np.interp(refs[c][ok], CODES, gm)
                    r = r[np.isfinite(r)]
                    vals.append(listed[k] * float(np.median(r)) if r.size else float('nan'))
                row['per'][name] = vals
        else:
            for name, g in curves.items():
                vals = []
                for c in range(3):
                    a = images[k][:, :, c].ravel().astype(np.int64)
                    b = images[k + 1][:, :, c].ravel().astype(np.int64)
                    m = (a > 20) & (a < 235) & (b > 20) & (b < 235)
                    gm = monotone(g[c])
                    with np.errstate(invalid='ignore', divide='ignore'):
                        r = gm[b[m]] / gm[a[m]]
                    r = r[np.isfinite(r)]
                    vals.append(float(np.median(r)) if r.size else float('nan'))
                row['per'][name] = vals
        row['measured'] = float(np.nanmedian([v for vals in row['per'].values() for v in vals]))
        row['off'] = abs(row['measured'] / listed[k] - 1) > RATIO_TOLERANCE
        out.append(row)
    return out


# ---------------------------------------------------------------- one bracket

def all_frame_fits(binary, b, paths, exposures):
    fits, notes = {}, []
    t = time.time()
    res = filmback_all(binary, paths, exposures, b['fit_stride'])
    if res[0] is None:
        notes.append(f"filmback-all failed: {res[1]}")
        fits['filmback-all'] = None
    else:
        fits['filmback-all'] = res[0]
        b['all_confidence'] = res[1]
    fits['debevec-all'] = opencv_curve('debevec', b['images'], exposures)
    fits['robertson-all'] = opencv_curve('robertson', b['images'], exposures)
    log(f"  all-frame fits {time.time() - t:.1f} s")
    return fits, notes


def run_bracket(binary, name, folder, workdir, times_mode):
    log(f'{name}: loading')
    b = load(binary, folder)
    b['name'] = name
    n = len(b['images'])
    # filmback fits its histograms from the files a user would give it: a JPEG source as
    # itself (a JPEG's top codes ring, and filmback keeps a wider margin below white in a
    # lossy file), read at the decimation the other methods see (--stride); its fit needs
    # no registration. Other sources: the registered, decimated frames as PNG.
    jpeg = all(p.lower().endswith(('.jpg', '.jpeg')) for p in b['paths'])
    b['fit_stride'] = b['decimate'] if jpeg else 1
    b['fit_source'] = 'source JPEGs' if jpeg else 'registered PNGs'
    paths = []
    for k, im in enumerate(b['images']):
        if jpeg:
            paths.append(b['paths'][k])
            continue
        p = os.path.join(workdir, f'{name}_{k:02d}_{b["names"][k]}.png')
        cv2.imwrite(p, np.ascontiguousarray(im[:, :, ::-1]))
        paths.append(p)
    exposures = list(b['listed'])
    fits, notes = all_frame_fits(binary, b, paths, exposures)
    # Each adjacent pair's implied ratio under each all-frame curve, against the listed one.
    ratios = measure_ratios(b['images'], exposures, {m: g for m, g in fits.items() if g is not None})
    b['ratios'] = ratios
    b['treatment'] = 'listed times'
    if times_mode == 'measured' and any(r['off'] for r in ratios):
        exposures = [exposures[0]]
        for r in ratios:
            exposures.append(exposures[-1] * r['measured'])
        b['treatment'] = 'measured ratios (chained), every method'
        fits, notes = all_frame_fits(binary, b, paths, exposures)
    elif times_mode == 'cut' and any(r['off'] for r in ratios):
        # Keep the longest run of adjacent pairs that follow their listed ratio.
        best, start = (0, 0), 0
        for k in range(n):
            if k == n - 1 or ratios[k]['off']:
                if k - start > best[1] - best[0]:
                    best = (start, k)
                start = k + 1
        lo, hi = best
        dropped = [b['names'][k] for k in range(n) if not lo <= k <= hi]
        b['treatment'] = f"cut to {b['names'][lo]}..{b['names'][hi]}; dropped {', '.join(dropped)} " \
                         f"(an adjacent ratio off by > {RATIO_TOLERANCE:.0%})"
        keep = list(range(lo, hi + 1))
        b['images'] = [b['images'][k] for k in keep]
        b['names'] = [b['names'][k] for k in keep]
        paths = [paths[k] for k in keep]
        exposures = [exposures[k] for k in keep]
        n = len(keep)
        fits, notes = all_frame_fits(binary, b, paths, exposures)
    b['exposures'] = exposures
    b['notes'] = notes
    fits['srgb'] = srgb_curve()
    t = time.time()
    pair_fits = []
    for k in range(n - 1):
        ratio = exposures[k + 1] / exposures[k]
        fb = filmback_pair(binary, paths[k], paths[k + 1], ratio, b['fit_stride'])
        pair = {'k': k, 'ratio': ratio,
                'filmback-2': fb[0], 'confidence': fb[1] if fb[0] is not None else None,
                'channels': fb[2] if fb[0] is not None else None,
                'failure': None if fb[0] is not None else fb[1],
                'debevec-2': opencv_curve('debevec', b['images'][k:k + 2], exposures[k:k + 2]),
                'robertson-2': opencv_curve('robertson', b['images'][k:k + 2], exposures[k:k + 2])}
        pair_fits.append(pair)
    log(f"  {n - 1} pair fits {time.time() - t:.1f} s")
    t = time.time()
    hists, thin = joint_histograms(b['images'], exposures)
    b['thin'] = thin
    triples_all, triples_two = [], []
    for (i, j), h in hists.items():
        gamma = exposures[j] / exposures[i]
        row = {'i': i, 'j': j}
        for m, curves in fits.items():
            row[m] = None if curves is None else sse(curves, h, gamma)
            row[m + '/toe'] = None if curves is None else sse(curves, h, gamma, ABOVE_TOE)
            if m.endswith('-all'):
                row[m + '/bands'] = None if curves is None else band_sse(curves, h, gamma)
        triples_all.append(row)
        for p in pair_fits:
            row2 = {'pair': p['k'], 'i': i, 'j': j, 'srgb': row['srgb'],
                    'filmback-all': row['filmback-all']}
            for m in ('filmback-2', 'debevec-2', 'robertson-2'):
                row2[m] = None if p[m] is None else sse(p[m], h, gamma)
            triples_two.append(row2)
    log(f"  {len(triples_all)} (i, j), {len(triples_two)} two-frame triples {time.time() - t:.1f} s")
    b['pairs'], b['all'], b['two'] = pair_fits, triples_all, triples_two
    return b


# ---------------------------------------------------------------- tables

def share(rows, a, b):
    """(wins of a over b on RMS, triples); a failed fit (None) loses."""
    wins = 0
    for r in rows:
        if r[a] is not None and (r[b] is None or rms(r[a]) < rms(r[b])):
            wins += 1
    return wins, len(rows)


def pct(w_n):
    w, n = w_n
    return f'{100 * w / n:.0f} % ({w}/{n})' if n else '–'


def median_rms(rows, m):
    v = [rms(r[m]) for r in rows if r[m] is not None]
    return f'{np.median(v):.2f}' if v else '–'


def spearman(rows):
    """Rank correlation of confidence with the excess RMS over the all-frame curve (an
    honest confidence correlates negatively); NaN for fewer than three channels."""
    if len(rows) < 3:
        return float('nan')
    rank = lambda v: np.argsort(np.argsort(v)).astype(float)
    a = rank(np.array([r['confidence'] for r in rows]))
    b = rank(np.array([r['rms2'] - r['rmsall'] for r in rows]))
    return float(np.corrcoef(a, b)[0, 1])


def confidence_rows(b):
    """Per pair and channel: (confidence, RMS two-frame, RMS all-frame)."""
    out = []
    for p in b['pairs']:
        if p['filmback-2'] is None:
            continue
        rows = [r for r in b['two'] if r['pair'] == p['k']]
        for c in range(3):
            s2 = sum(r['filmback-2'][c][0] for r in rows)
            sa = sum(r['filmback-all'][c][0] for r in rows) if all(
                r['filmback-all'] is not None for r in rows) else float('nan')
            n = sum(r['filmback-2'][c][1] for r in rows)
            if n == 0:
                continue
            out.append({'pair': p['k'], 'ratio': p['ratio'], 'channel': 'RGB'[c],
                        'confidence': p['confidence'][c], 'fit': p['channels'][c],
                        'rms2': math.sqrt(s2 / n), 'rmsall': math.sqrt(sa / n)})
    return out


CHANNEL_FIELDS = ['confidence', 'misfit', 'top_span_stops', 'predicted_error_stops',
                  'predicted_shape_error_stops', 'coverage', 'residual_rms',
                  'effective_parameters', 'equations']


def write_channels(brackets, path):
    """One row per two-frame fit channel: bracket, pair, ratio, channel, the fit's own
    figures (`CHANNEL_FIELDS`), its RMS over the pair's triples and the all-frame curve's."""
    with open(path, 'w', newline='') as f:
        w = csv.writer(f)
        w.writerow(['bracket', 'pair', 'ratio', 'channel', *CHANNEL_FIELDS, 'rms2', 'rmsall'])
        for b in brackets:
            for r in confidence_rows(b):
                w.writerow([b['name'], r['pair'], f"{r['ratio']:.4f}", r['channel'],
                            *(r['fit'].get(k) for k in CHANNEL_FIELDS),
                            f"{r['rms2']:.4f}", f"{r['rmsall']:.4f}"])


def report(brackets, args):
    stamp = time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())
    print(f'<!-- predict_neighbour.py {" ".join(sys.argv[1:])}; {stamp}; '
          f'load {os.getloadavg()[0]:.2f} -->\n')
    print('Brackets (frames darkest first). Registration: per adjacent pair the integer shift '
          f'(up to {REGISTER_RADIUS} px at the size used) that minimises the spread of B_bright given '
          'B_dark (within-code variance over total), kept when it lowers the spread by more than '
          f'{REGISTER_GAIN:.0%}; shown as dx,dy (spread at 0 → at the shift):\n')
    print('| bracket | frames | exposures from | size used | adjacent shifts | registered | times '
          '| filmback fits from |')
    print('|---|---|---|---|---|---|---|---|')
    for b in brackets:
        offs = ', '.join(f'{d[0]},{d[1]} ({before:.3f} → {after:.3f})' if d.any() else '0,0'
                         for d, after, before in b['steps'])
        h, w = b['images'][0].shape[:2]
        print(f"| {b['name']} | {len(b['paths'])} | {b['source']} | {w}x{h} (every {b['decimate']}) "
              f"| {offs} | {'yes' if b['registered'] else 'no'} | {b['treatment']} "
              f"| {b['fit_source']}, stride {b['fit_stride']} |")
    print()
    print('Adjacent pairs: the ratio their samples imply, per channel R G B, under each '
          'all-frame curve fitted at the listed times (memorial, 15 pairs at one listed ratio: '
          "each pair's transfer B_bright(B_dark) against the median transfer of all pairs, "
          'code by code, converted to a ratio through the curve; the transfer shift in DN needs '
          'no curve. Otherwise: median of g(B_bright)/g(B_dark) over samples 20..235); '
          f'"off" when the median over curves and channels is more than {RATIO_TOLERANCE:.0%} '
          'from the listed ratio:\n')
    print('| bracket | pair | listed | transfer shift DN (R G B) | filmback-all | debevec-all '
          '| robertson-all | measured |')
    print('|---|---|---|---|---|---|---|---|')
    shown = 0
    for b in brackets:
        names = [os.path.splitext(os.path.basename(p))[0] for p in b['paths']]
        for r in b['ratios']:
            shown += 1
            cell = lambda m: ' '.join(f'{x:.2f}' for x in r['per'][m]) if m in r['per'] else '–'
            dn = ' '.join(f'{x:+.1f}' for x in r['shift_dn']) if r['shift_dn'] else '–'
            print(f"| {b['name']} | {names[r['k']]}→{names[r['k'] + 1]} | {r['listed']:.3g} | {dn} "
                  f"| {cell('filmback-all')} | {cell('debevec-all')} | {cell('robertson-all')} "
                  f"| {r['measured']:.3g}{' off' if r['off'] else ''} |")
    if not shown:
        print('| (none) | | | | | | | |')
    print()
    groups = [(b['name'], [b]) for b in brackets]
    if len(brackets) > 1:
        groups.append(('all', brackets))
    print('Wins on RMS (share of triples; a failed fit loses). Targets: filmback-all over '
          'debevec-all >= 60 %, filmback-2 over debevec-2 >= 85 %.\n')
    print('| bracket | (i, j) | triples (2-frame) | fb-all > deb-all | fb-all > rob-all | fb-all > sRGB '
          f'| fb-all > deb-all, source ≥ {ABOVE_TOE} DN '
          '| fb-2 > deb-2 | fb-2 > deb-2, fitted pairs | fb-2 > rob-2 | fb-2 > sRGB | fb-2 failed fits |')
    print('|---|---|---|---|---|---|---|---|---|---|---|---|')
    for name, bs in groups:
        A = [r for b in bs for r in b['all']]
        T = [r for b in bs for r in b['two']]
        failed = sum(p['filmback-2'] is None for b in bs for p in b['pairs'])
        above_toe = [r for r in A if not math.isnan(rms(r['debevec-all/toe']))]
        npairs = sum(len(b['pairs']) for b in bs)
        print(f"| {name} | {len(A)} | {len(T)} | {pct(share(A, 'filmback-all', 'debevec-all'))} "
              f"| {pct(share(A, 'filmback-all', 'robertson-all'))} | {pct(share(A, 'filmback-all', 'srgb'))} "
              f"| {pct(share(above_toe, 'filmback-all/toe', 'debevec-all/toe'))} "
              f"| {pct(share(T, 'filmback-2', 'debevec-2'))} "
              f"| {pct(share([r for r in T if r['filmback-2'] is not None], 'filmback-2', 'debevec-2'))} "
              f"| {pct(share(T, 'filmback-2', 'robertson-2'))} "
              f"| {pct(share(T, 'filmback-2', 'srgb'))} | {failed} of {npairs} |")
    print()
    print('Median RMS over triples, DN (two-frame methods over the two-frame triples, the others '
          'over the (i, j)):\n')
    methods2 = ['filmback-2', 'debevec-2', 'robertson-2']
    methodsa = ['filmback-all', 'debevec-all', 'robertson-all', 'srgb']
    print('| bracket | ' + ' | '.join(methods2 + methodsa) + ' |')
    print('|---|' + '---|' * (len(methods2) + len(methodsa)))
    for name, bs in groups:
        A = [r for b in bs for r in b['all']]
        T = [r for b in bs for r in b['two']]
        print(f'| {name} | ' + ' | '.join([median_rms(T, m) for m in methods2] +
                                         [median_rms(A, m) for m in methodsa]) + ' |')
    print()
    print('All-frame curves by the code of the source sample (RMS DN over every (i, j), '
          'channels pooled); the last row gives each band\'s share of the samples:\n')
    print('| bracket | method | ' + ' | '.join(f'{lo}–{hi - 1}' for lo, hi in BANDS) + ' |')
    print('|---|---|' + '---|' * len(BANDS))
    for name, bs in groups:
        A = [r for b in bs for r in b['all']]
        for m in methodsa:
            rows = [r[m + '/bands'] for r in A if r.get(m + '/bands') is not None]
            if not rows:
                continue
            cells = [math.sqrt(sum(r[k][0] for r in rows) / max(1.0, sum(r[k][1] for r in rows)))
                     for k in range(len(BANDS))]
            print(f'| {name} | {m} | ' + ' | '.join(f'{v:.2f}' for v in cells) + ' |')
        rows = [r['debevec-all/bands'] for r in A if r.get('debevec-all/bands') is not None]
        total = sum(r[k][1] for r in rows for k in range(len(BANDS)))
        if total:
            print(f'| {name} | samples | ' + ' | '.join(
                f'{100 * sum(r[k][1] for r in rows) / total:.0f} %' for k in range(len(BANDS))) + ' |')
    print()
    print(f'Confidence of two-frame fits against the all-frame curve (per channel of each pair fit: '
          f'"really worse" = its RMS over that pair\'s triples exceeds filmback-all\'s on the same '
          f'samples by > {WORSE_DN:g} DN). Targets: flagged low (< {LOW}) really worse >= 60 %, '
          'not flagged really worse <= 10 %.\n')
    print('| bracket | channels | flagged low | of which really worse | not flagged '
          '| of which really worse | rank corr. confidence vs excess |')
    print('|---|---|---|---|---|---|---|')
    for name, bs in groups:
        rows = [r for b in bs for r in confidence_rows(b)]
        low = [r for r in rows if r['confidence'] < LOW]
        high = [r for r in rows if not r['confidence'] < LOW]
        worse = lambda rs: sum(r['rms2'] - r['rmsall'] > WORSE_DN for r in rs)
        print(f"| {name} | {len(rows)} | {len(low)} | {pct((worse(low), len(low)))} | {len(high)} "
              f"| {pct((worse(high), len(high)))} | {spearman(rows):+.2f} |")
    print()
    print('Two-frame fits, per channel R G B (confidence; RMS DN of filmback-2 / filmback-all over the '
          "pair's triples):\n")
    print('| bracket | pair | ratio | confidence | filmback-2 RMS | filmback-all RMS | debevec-2 RMS |')
    print('|---|---|---|---|---|---|---|')
    for b in brackets:
        cr = confidence_rows(b)
        for p in b['pairs']:
            pair = f"{b['names'][p['k']]}+{b['names'][p['k'] + 1]}"
            rows = [r for r in b['two'] if r['pair'] == p['k']]
            deb = ' '.join(
                f"{math.sqrt(sum(r['debevec-2'][c][0] for r in rows) / max(1, sum(r['debevec-2'][c][1] for r in rows))):.1f}"
                for c in range(3))
            if p['filmback-2'] is None:
                print(f"| {b['name']} | {pair} | {p['ratio']:.3g} | failed: {p['failure']} | – | – | {deb} |")
                continue
            mine = [r for r in cr if r['pair'] == p['k']]
            print(f"| {b['name']} | {pair} | {p['ratio']:.3g} | "
                  + ' '.join(f"{c:.2f}" for c in p['confidence']) + ' | '
                  + ' '.join(f"{r['rms2']:.1f}" for r in mine) + ' | '
                  + ' '.join(f"{r['rmsall']:.1f}" for r in mine) + f' | {deb} |')
    print()
    print('All-frame filmback fits (confidence R G B from `calibrate --json` on every frame):\n')
    print('| bracket | confidence |')
    print('|---|---|')
    for b in brackets:
        conf = ' '.join(f'{c:.2f}' for c in b.get('all_confidence', [])) or '–'
        print(f"| {b['name']} | {conf} |")
        for note in b['notes']:
            print(f"|  | {note} |")
    print()
    for kind, fb, db in (('all', 'filmback-all', 'debevec-all'), ('2', 'filmback-2', 'debevec-2')):
        worst, seen = [], set()
        for b in brackets:
            for r in (b['all'] if kind == 'all' else b['two']):
                if r[fb] is not None:
                    worst.append((rms(r[fb]) - rms(r[db]), b, r))
        worst.sort(key=lambda x: -x[0])
        if kind == 'all':
            print('Worst (i, j) for filmback-all (RMS minus debevec-all\'s, DN):\n')
        else:
            print('\nWorst two-frame triples for filmback-2 (RMS minus debevec-2\'s on the same '
                  'pair, DN; one per pair):\n')
        print('| bracket | fit | target from source | filmback RMS (R G B) | Debevec RMS | sRGB RMS | excess |')
        print('|---|---|---|---|---|---|---|')
        shown = 0
        for d, b, r in worst:
            nm = b['names']
            fit = 'all' if kind == 'all' else f"{nm[r['pair']]}+{nm[r['pair'] + 1]}"
            if kind == '2' and fit in seen:
                continue
            seen.add(fit)
            per = ' '.join(f'{math.sqrt(x / y):.0f}' if y else '–' for x, y in r[fb])
            print(f"| {b['name']} | {fit} | {nm[r['j']]} from {nm[r['i']]} | {rms(r[fb]):.2f} ({per}) "
                  f"| {rms(r[db]):.2f} | {rms(r['srgb']):.2f} | {d:+.2f} |")
            shown += 1
            if shown == args.worst:
                break
    thin = sum(len(b['thin']) for b in brackets)
    if thin:
        print(f'\n(i, j) left out for fewer than {MIN_SAMPLES} samples in a channel: ' + '; '.join(
            f"{b['name']}: " + ', '.join(f"{b['names'][j]}←{b['names'][i]}" for i, j in b['thin'])
            for b in brackets if b['thin']))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--bin', default=os.path.join(HERE, '..', '..', 'target', 'release', 'filmback'),
                    help='filmback binary (default: target/release/filmback)')
    ap.add_argument('--brackets', default=find_brackets(), help='folder of bracket folders')
    ap.add_argument('--quick', action='store_true', help=f'one bracket ({QUICK}), a smoke run')
    ap.add_argument('--bracket', action='append', help='only this bracket (repeatable)')
    ap.add_argument('--times', choices=['listed', 'measured', 'cut'], default='listed',
                    help='exposure times of frames that contradict them (see the docstring)')
    ap.add_argument('--worst', type=int, default=8, help='worst triples to list')
    ap.add_argument('--channels-csv', help='write each two-frame fit channel (what its '
                    '`calibrate --json` says of itself, its RMS and the all-frame RMS) to this CSV')
    args = ap.parse_args()
    binary = os.path.abspath(args.bin)
    if not os.access(binary, os.X_OK):
        sys.exit(f'{binary}: not an executable (cargo build --release, or give --bin)')
    if not args.brackets or not os.path.isdir(args.brackets):
        sys.exit('no brackets folder (../shared/testdata/brackets); give --brackets')
    names = sorted(d for d in os.listdir(args.brackets)
                   if os.path.isdir(os.path.join(args.brackets, d)))
    if args.quick:
        names = [QUICK]
    if args.bracket:
        names = [n for n in names if n in args.bracket]
    cv2.setRNGSeed(0)
    t0 = time.time()
    with tempfile.TemporaryDirectory() as workdir:
        brackets = [run_bracket(binary, n, os.path.join(args.brackets, n), workdir, args.times)
                    for n in names]
    report(brackets, args)
    if args.channels_csv:
        write_channels(brackets, args.channels_csv)
    print(f'\n({time.time() - t0:.0f} s, load {os.getloadavg()[0]:.2f})')


if __name__ == '__main__':
    main()
