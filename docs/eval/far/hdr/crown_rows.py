"""Crown colour error of `conifer eval` pictures by bands of rows, to tell the
crown from the bare trunk below it.

python3 crown_rows.py REF.png OURS.png [OURS2.png ...] [--rows 15]

For each band of ROWS rows (from the reference crown's top): the pixels the
reference covers by at least 26/255 (the pixels `crown_color_error` reads)
and each picture's mean absolute RGB difference (0-255) from the reference
over them.
"""
import sys

import numpy as np
from PIL import Image

args = [a for a in sys.argv[1:] if not a.startswith("--")]
rows = 15
if "--rows" in sys.argv:
    rows = int(sys.argv[sys.argv.index("--rows") + 1])
    args = [a for a in args if a != str(rows)]
ref = np.array(Image.open(args[0])).astype(float)
others = [np.array(Image.open(p)).astype(float) for p in args[1:]]
crown = ref[..., 3] >= 26
errors = [np.abs(ref[..., :3] - o[..., :3]).mean(axis=2) for o in others]
ys = np.nonzero(crown)[0]
print("rows      pixels  " + "  ".join(p.split("/")[-1] for p in args[1:]))
for y0 in range(ys.min(), ys.max() + 1, rows):
    band = crown.copy()
    band[:y0] = False
    band[y0 + rows:] = False
    if band.sum() == 0:
        continue
    print(f"{y0:3d}-{y0 + rows - 1:3d}  {band.sum():6d}  " + "  ".join(f"{e[band].mean():6.2f}" for e in errors))
print(f"all       {crown.sum():6d}  " + "  ".join(f"{e[crown].mean():6.2f}" for e in errors))
