"""Mean colour of a forest picture in bands of 40 rows, the sky left out.

python3 docs/forest/haze/bands.py PNG...: for each picture, from row 100
down, the mean sRGB of the pixels farther than 30 (summed over the three
channels) from the sky's 140, 168, 204, their spread, and their count.
"""
import sys

import numpy as np
from PIL import Image

SKY = np.array([140, 168, 204])

for path in sys.argv[1:]:
    picture = np.asarray(Image.open(path).convert("RGB")).astype(float)
    print(path)
    for top in range(100, picture.shape[0], 40):
        band = picture[top:top + 40]
        ground = band[np.abs(band - SKY).sum(-1) > 30]
        if len(ground) == 0:
            continue
        print(f"  rows {top}-{top + 40}: mean {ground.mean(0).round(0)}  "
              f"std {ground.std(0).mean():.1f}  n={len(ground)}")
