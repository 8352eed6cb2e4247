#!/usr/bin/env python3
"""Mean sRGB and linear-light spread of two bands of a forest picture.

The README's hillside before and after crowns shaded themselves past the
shadow maps (needs Pillow and NumPy):

    git show d35b376:assets/readme/forest.png > /tmp/before.png
    python3 docs/forest/crown-shade/canopy_bands.py /tmp/before.png assets/readme/forest.png

Rows 130-300 of the 800x450 picture are the crowns between the shadows'
80 m and the haze; rows 300-450 the near crowns, inside the shadows.
Prints one JSON line a picture and band.
"""
import json
import sys

import numpy as np
from PIL import Image

BANDS = {"past the shadows, rows 130-300": (130, 300), "near, rows 300-450": (300, 450)}

for path in sys.argv[1:]:
    srgb = np.asarray(Image.open(path).convert("RGB")).astype(float)
    linear = ((srgb / 255 + 0.055) / 1.055) ** 2.4
    for name, (top, bottom) in BANDS.items():
        light = linear[top:bottom].mean(axis=2)
        print(json.dumps({
            "picture": path,
            "band": name,
            "mean_srgb": srgb[top:bottom].reshape(-1, 3).mean(axis=0).round(1).tolist(),
            "linear_p10": round(float(np.percentile(light, 10)), 4),
            "linear_p90": round(float(np.percentile(light, 90)), 4),
            "linear_std": round(float(light.std()), 4),
        }))
