import sys
from PIL import Image; import numpy as np
for f in sys.argv[1:]:
  a=np.asarray(Image.open(f).convert('RGB')).astype(float)
  sky=np.array([140,168,204])
  print(f)
  for r0 in range(100,450,40):
    b=a[r0:r0+40]; d=np.abs(b-sky).sum(-1); t=b[d>30]
    lin=(t/255)**2.2
    print(f"  rows {r0}-{r0+40}: mean {t.mean(0).round(0)}  std {t.std(0).mean():.1f}  n={len(t)}")
