"""Crown colour error of an eval picture split by column around the trunk.

python3 docs/eval/elevation/trunk_columns.py OUT_DIR [DISTANCE] [TRUNK_X]:
OUT_DIR is a `conifer eval --out` folder (its ref_D.png and ours_D.png,
alpha the coverage); TRUNK_X the trunk's pixel column (80: the middle of
the quick eval's 160-pixel pictures). Crown pixels are those the
reference covers by 10 % or more, as `crown_color_error` counts them.
"""
import sys

import numpy as np
from PIL import Image

out = sys.argv[1]
distance = sys.argv[2] if len(sys.argv) > 2 else "12.22"
trunk = int(sys.argv[3]) if len(sys.argv) > 3 else 80
ref = np.asarray(Image.open(f"{out}/ref_{distance}m.png").convert("RGBA")).astype(float)
ours = np.asarray(Image.open(f"{out}/ours_{distance}m.png").convert("RGBA")).astype(float)
err = np.abs(ref[..., :3] - ours[..., :3]).mean(-1)
signed = (ours[..., :3] - ref[..., :3]).mean(-1)
coverage = (ours[..., 3] - ref[..., 3]) / 255
crown = ref[..., 3] >= 25.5
total = err[crown].sum()
print(f"crown pixels {crown.sum()}, colour error {err[crown].mean():.2f}")
for name, columns in [("trunk", [trunk]), ("beside it", [trunk - 1, trunk + 1]), ("next out", [trunk - 2, trunk + 2])]:
    m = np.zeros_like(crown)
    m[:, columns] = True
    m &= crown
    print(f"  {name} (columns {columns}): {m.sum()} pixels, colour error {err[m].mean():.2f} "
          f"({err[m].sum() / total:.0%} of the crown's), signed {signed[m].mean():+.2f}, "
          f"coverage {coverage[m].mean():+.3f}")
rest = crown.copy()
rest[:, trunk - 1:trunk + 2] = False
print(f"  the rest: {rest.sum()} pixels, colour error {err[rest].mean():.2f}; the crown's error without "
      f"the three columns' share {err[rest].sum() / crown.sum():.2f}")
