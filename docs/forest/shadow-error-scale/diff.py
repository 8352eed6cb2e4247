# Compares two pictures: mean |dRGB|, the 99th percentile of each pixel's
# largest channel difference, the share of pixels off by more than 8, and
# the mean luminance (0-255). Usage: diff.py REFERENCE.png OTHER.png
import sys
from PIL import Image
import numpy as np
a=np.asarray(Image.open(sys.argv[1]).convert('RGB')).astype(int)
b=np.asarray(Image.open(sys.argv[2]).convert('RGB')).astype(int)
d=np.abs(a-b)
lum=lambda x:(0.2126*x[...,0]+0.7152*x[...,1]+0.0722*x[...,2])
print(f"{sys.argv[2]} vs {sys.argv[1]}: mean |dRGB| {d.mean():.3f}, p99 {np.percentile(d.max(axis=2),99):.1f}, pixels >8: {(d.max(axis=2)>8).mean()*100:.2f} %, mean luminance {lum(a).mean():.2f} -> {lum(b).mean():.2f}")
