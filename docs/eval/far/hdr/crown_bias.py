"""Signed crown colour of `conifer eval` pictures: how much lighter or darker
a method's crown is than the reference's, by how much the reference covers.

python3 crown_bias.py REF.png OURS.png

Over the pixels the reference covers by at least 26/255 (those
`crown_color_error` reads), in bands of reference coverage: the pixel count,
the mean signed sRGB difference (ours - reference, mean of R, G, B, 0-255),
the mean absolute one, and the mean signed coverage difference (0-255).
"""
import sys

import numpy as np
from PIL import Image

ref = np.asarray(Image.open(sys.argv[1]).convert("RGBA")).astype(float)
ours = np.asarray(Image.open(sys.argv[2]).convert("RGBA")).astype(float)
crown = ref[..., 3] >= 26
signed = (ours[..., :3] - ref[..., :3]).mean(axis=2)
alpha = ours[..., 3] - ref[..., 3]
print("reference coverage  pixels  signed  absolute  coverage")
for lo, hi in [(26, 128), (128, 200), (200, 240), (240, 256), (26, 256)]:
    band = crown & (ref[..., 3] >= lo) & (ref[..., 3] < hi)
    print(
        f"{lo:3d}-{hi - 1:3d}            {band.sum():6d}  {signed[band].mean():+6.2f}  "
        f"{np.abs(signed[band]).mean():8.2f}  {alpha[band].mean():+8.2f}"
    )
