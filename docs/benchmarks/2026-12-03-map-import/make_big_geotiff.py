import numpy as np, rasterio
from rasterio.transform import from_origin
from rasterio.windows import Window
n = 20000
with rasterio.open('big.tif', 'w', driver='GTiff', width=n, height=n, count=1, dtype='uint8', crs='EPSG:32633',
                   transform=from_origin(500000.0, 4000000.0, 0.25, 0.25), tiled=True, blockxsize=512, blockysize=512, BIGTIFF='YES', compress='deflate') as f:
    rng = np.random.default_rng(3)
    base = rng.integers(0, 256, size=(1000, n), dtype=np.uint8)
    for r in range(0, n, 1000):
        f.write(np.roll(base, r, axis=1), 1, window=Window(0, r, n, 1000))
