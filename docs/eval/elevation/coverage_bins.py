"""Crown colour error of an eval picture split by the reference's coverage.

python3 docs/eval/elevation/coverage_bins.py OUT_DIR [DISTANCE]: OUT_DIR is
a `conifer eval --out` folder (its ref_D.png and ours_D.png, alpha the
coverage). Crown pixels are those the reference covers by 10 % or more,
as `crown_color_error` counts them.
"""
import sys

import numpy as np
from PIL import Image

out, distance = sys.argv[1], (sys.argv[2] if len(sys.argv) > 2 else "12.22")
ref = np.asarray(Image.open(f"{out}/ref_{distance}m.png").convert("RGBA")).astype(float)
ours = np.asarray(Image.open(f"{out}/ours_{distance}m.png").convert("RGBA")).astype(float)
ref_a, ours_a = ref[..., 3] / 255, ours[..., 3] / 255
crown = ref_a >= 0.1
err = np.abs(ref[..., :3] - ours[..., :3]).mean(-1)
print(f"crown pixels {crown.sum()}, colour error {err[crown].mean():.2f}, "
      f"coverage summed: reference {ref_a[crown].sum():.1f}, ours {ours_a[crown].sum():.1f}")
for lo, hi in [(0.1, 0.3), (0.3, 0.6), (0.6, 0.8), (0.8, 1.01)]:
    m = crown & (ref_a >= lo) & (ref_a < hi)
    print(f"  reference coverage {lo:.1f}-{min(hi, 1):.1f}: {m.sum():3d} pixels, coverage "
          f"{ref_a[m].mean():.3f} vs ours {ours_a[m].mean():.3f}, mean |difference| "
          f"{np.abs(ref_a[m] - ours_a[m]).mean():.3f}, colour error {err[m].mean():.2f} "
          f"({err[m].sum() / err[crown].sum():.0%} of the crown's)")
