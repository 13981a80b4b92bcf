#!/usr/bin/env python3
"""Cross-check on real frames (../shared/testdata/brackets/frobisher, 3-stop steps): predict a
frame from its neighbour, B^ = f(gamma * g(B)), with filmback's curve and with OpenCV's
CalibrateDebevec, and print the error in DN. First run:
    filmback calibrate IMG_2600.jpg IMG_2601.jpg -o /tmp/resp-0001.toml
    filmback calibrate IMG_2601.jpg IMG_2602.jpg -o /tmp/resp-0102.toml
then this script with the peer's python."""
import tomllib

import cv2
import numpy as np

B='/work/shared/testdata/brackets/frobisher/'
ims=[cv2.imread(B+f'IMG_260{i}.jpg')[:,:,::-1].astype(float) for i in range(3)]
times=np.array([1/8,1,8],dtype=np.float32)
def predict(curves, src, gamma):
    out=np.zeros_like(src)
    for c in range(3):
        g=np.asarray(curves[c],float)  # g at codes 0..255, non-decreasing
        e=np.interp(src[:,:,c], np.arange(256), g)*gamma
        out[:,:,c]=np.interp(e, g, np.arange(256))  # f = g^-1, clips at 255
    return out
def ours(path):
    d=tomllib.load(open(path,'rb'))
    return [np.interp(np.arange(256)/255, np.linspace(0,1,len(ch['g'])), ch['g']) for ch in d['channel']]
def opencv(i,j):
    crf=cv2.createCalibrateDebevec(70,10.0).process([cv2.imread(B+f'IMG_260{i}.jpg'),cv2.imread(B+f'IMG_260{j}.jpg')], times[[i,j]])
    return [crf[:,0,2-c] for c in range(3)]
def err(pred, truth):
    m=(truth>5)&(truth<250)&(pred<250)&(pred>5)
    d=np.abs(pred-truth)[m]
    return np.median(d), np.sqrt(np.mean(d**2)), m.mean()
# predict frame 2 from frame 1 with the curve of pair (0,1); frame 0 from frame 1 with the curve of pair (1,2)
for name,cur in [('filmback',(ours('/tmp/resp-0001.toml'),ours('/tmp/resp-0102.toml'))),('OpenCV Debevec',(opencv(0,1),opencv(1,2)))]:
    a=err(predict(cur[0], ims[1], 8.0), ims[2]); b=err(predict(cur[1], ims[1], 1/8), ims[0])
    print(f'{name}: 2602 from 2601 (curve of 2600+2601): median {a[0]:.2f} DN, RMS {a[1]:.2f} DN over {a[2]*100:.0f}% of samples; 2600 from 2601 (curve of 2601+2602): median {b[0]:.2f} DN, RMS {b[1]:.2f} DN over {b[2]*100:.0f}%')
