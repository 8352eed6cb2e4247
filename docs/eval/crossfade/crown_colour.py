"""Crown colour error and summed coverage of `conifer eval` pictures.

python3 crown_colour.py REF.png OURS.png

The crown colour error is `eval::measure::crown_color_error`: the mean
absolute RGB difference (0-255) over the pixels the reference covers by at
least 26/255. The summed coverage is each picture's alpha summed, in pixels.
"""
import sys

import numpy as np
from PIL import Image

ref = np.array(Image.open(sys.argv[1])).astype(float)
ours = np.array(Image.open(sys.argv[2])).astype(float)
crown = ref[..., 3] >= 26
error = np.abs(ref[..., :3] - ours[..., :3]).mean(axis=2)[crown].mean()
print(f"crown colour error {error:.2f}; summed coverage: reference {ref[..., 3].sum() / 255:.0f}, "
      f"ours {ours[..., 3].sum() / 255:.0f}")
