"""Pixel-scale texture of a crown in two `conifer eval` pictures.

python3 crown_texture.py REF.png OURS.png

Over the crown (reference coverage >= 26/255, the pixels
`crown_color_error` reads) and its opaque part (>= 240/255), on the grey
of each pixel (mean of R, G, B, sRGB 0-255): the mean absolute difference,
the mean signed one (ours - reference), the mean R, G, B of each, the
standard deviation of each picture and their correlation pixel by pixel,
and, after a k x k box filter of both (k = 3, 5), the mean absolute
difference and each picture's mean local standard deviation: how much of
the difference is detail finer than k pixels.
"""
import sys

import numpy as np
from PIL import Image


def box(x, k):
    pad = k // 2
    padded = np.pad(x, pad, mode="edge")
    total = np.zeros_like(x)
    for i in range(k):
        for j in range(k):
            total += padded[i : i + x.shape[0], j : j + x.shape[1]]
    return total / (k * k)


ref = np.asarray(Image.open(sys.argv[1]).convert("RGBA")).astype(float)
ours = np.asarray(Image.open(sys.argv[2]).convert("RGBA")).astype(float)
crown = ref[..., 3] >= 26
opaque = ref[..., 3] >= 240
r = ref[..., :3].mean(axis=2)
o = ours[..., :3].mean(axis=2)
print(f"crown pixels {crown.sum()}, opaque {opaque.sum()}")
print(f"mean |d|: crown {np.abs(o - r)[crown].mean():.2f}, opaque {np.abs(o - r)[opaque].mean():.2f}")
print(f"mean signed d: crown {(o - r)[crown].mean():+.2f}, opaque {(o - r)[opaque].mean():+.2f}")
print(
    "opaque mean RGB: reference",
    np.round(ref[opaque][:, :3].mean(axis=0), 1),
    "ours",
    np.round(ours[opaque][:, :3].mean(axis=0), 1),
)
print(
    f"opaque sd: reference {r[opaque].std():.2f}, ours {o[opaque].std():.2f}, "
    f"correlation {np.corrcoef(r[opaque], o[opaque])[0, 1]:.3f}"
)
for k in (3, 5):
    rb, ob = box(r, k), box(o, k)
    local_r = np.sqrt(np.maximum(box(r * r, k) - rb * rb, 0.0))
    local_o = np.sqrt(np.maximum(box(o * o, k) - ob * ob, 0.0))
    print(
        f"box {k}x{k}: opaque mean |d| {np.abs(ob - rb)[opaque].mean():.2f}, "
        f"local sd reference {local_r[opaque].mean():.2f}, ours {local_o[opaque].mean():.2f}"
    )
