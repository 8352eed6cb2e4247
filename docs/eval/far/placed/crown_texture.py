"""Crown colour error of two `conifer eval` pictures, raw and box-filtered,
and the mean and spread of their opaque crown pixels.

python3 crown_texture.py REF.png OURS.png

The crown colour error is `eval::measure::crown_color_error`: the mean
absolute RGB difference (0-255) over the pixels the reference covers by at
least 26/255; here also after a k x k box filter of both pictures (k = 3, 5),
which leaves out what does not line up pixel by pixel. Mean and std (sRGB)
over the reference's opaque pixels (alpha > 0.9).
"""
import sys

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from PIL import Image

ref = np.array(Image.open(sys.argv[1])).astype(float)
ours = np.array(Image.open(sys.argv[2])).astype(float)
crown = ref[..., 3] >= 26
opaque = ref[..., 3] > 0.9 * 255


def box(picture, k):
    if k == 1:
        return picture
    p = k // 2
    padded = np.pad(picture, ((p, p), (p, p), (0, 0)), mode="edge")
    return sliding_window_view(padded, (k, k), axis=(0, 1)).mean(axis=(-1, -2))


for k in (1, 3, 5):
    error = np.abs(box(ref, k)[..., :3] - box(ours, k)[..., :3]).mean(axis=2)[crown].mean()
    print(f"crown colour error, {k}x{k} box: {error:.2f}")
for name, picture in (("reference", ref), ("ours", ours)):
    rgb = picture[opaque][:, :3]
    print(f"{name}: {opaque.sum()} opaque pixels, mean RGB {rgb.mean(0).round(1)}, std {rgb.std(0).round(1)}")
