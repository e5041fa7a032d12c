"""GeoTIFFs written by GDAL (rasterio), and checks of what `jointloc map import` made of them.

    python map_import.py write DIR   # ortho.tif (8-bit, stripped, UTM), dtm.tif (float32,
                                     # tiled BigTIFF, nodata, 1 m posts), mars16.tif (16-bit,
                                     # tiled, Mars equirectangular, no EPSG code)
    python map_import.py check DIR   # DIR/utm and DIR/mars: the imported map folders
    python map_import.py togeotiff DATASET DIR E0 N0
                                     # a simulated dataset's map and DEM as GeoTIFFs in the
                                     # Mars equirectangular CRS, world (0, 0) at (E0, N0)
"""

import sys
import tomllib
from pathlib import Path

import numpy as np
import rasterio
from PIL import Image
from rasterio.transform import from_origin

MARS = "+proj=eqc +lat_ts=0 +lat_0=0 +lon_0=0 +x_0=0 +y_0=0 +R=3396190 +units=m +no_defs"


def sources():
    rng = np.random.default_rng(7)
    ortho = rng.integers(0, 256, size=(1000, 1200), dtype=np.uint8)
    yy, xx = np.mgrid[0:250, 0:300]
    dtm = (100.0 + 0.05 * xx - 0.02 * yy + 0.3 * np.sin(xx / 7.0)).astype(np.float32)
    dtm[10, 20] = -9999.0
    mars = rng.integers(0, 1024, size=(600, 700)).astype(np.uint16)
    return ortho, dtm, mars


def write(d):
    ortho, dtm, mars = sources()
    common = dict(driver="GTiff", count=1)
    with rasterio.open(d / "ortho.tif", "w", width=1200, height=1000, dtype="uint8", crs="EPSG:32633",
                       transform=from_origin(500000.0, 4000000.0, 0.25, 0.25), **common) as f:
        f.write(ortho, 1)
    with rasterio.open(d / "dtm.tif", "w", width=300, height=250, dtype="float32", nodata=-9999.0,
                       crs="EPSG:32633", transform=from_origin(499990.0, 4000010.0, 1.0, 1.0),
                       tiled=True, blockxsize=64, blockysize=64, BIGTIFF="YES", compress="deflate",
                       **common) as f:
        f.write(dtm, 1)
    with rasterio.open(d / "mars16.tif", "w", width=700, height=600, dtype="uint16", crs=MARS,
                       transform=from_origin(-1000.0, 2000.0, 0.25, 0.25), tiled=True,
                       blockxsize=256, blockysize=256, compress="lzw", **common) as f:
        f.write(mars, 1)


def check(d):
    ortho, dtm, mars = sources()
    utm = d / "utm"
    meta = tomllib.loads((utm / "map.toml").read_text())
    assert meta["gsd_m"] == 0.25 and (meta["width_px"], meta["height_px"]) == (1200, 1000), meta
    crs = meta["crs"]
    assert crs["epsg"] == 32633, crs
    # World (0, 0) is the centre of pixel (0, 0): a quarter-metre pixel's centre.
    assert abs(crs["easting_m"] - 500000.125) < 1e-9 and abs(crs["northing_m"] - 3999999.875) < 1e-9, crs
    # The pixels, unchanged; a tile is its window of the map.
    png = np.asarray(Image.open(utm / "satellite.png"))
    assert (png == ortho).all(), "satellite.png differs from the GeoTIFF's pixels"
    tile = np.asarray(Image.open(utm / "satellite" / "1_250_0.png"))
    assert (tile == ortho[0:500, 250:750]).all(), "tile 1 is not the map's window"
    # The DTM: post (i, j) at world (origin + i·gsd, origin − j·gsd), heights to 1 mm.
    e = meta["elevation"]
    assert e["gsd_m"] == 1.0 and (e["width_px"], e["height_px"]) == (300, 250), e
    with rasterio.open(d / "dtm.tif") as f:
        t = f.transform
    ex, ny = t * (0.5, 0.5)  # centre of post (0, 0) in map coordinates
    assert abs(e["origin_x_m"] - (ex - crs["easting_m"])) < 1e-9, e
    assert abs(e["origin_y_m"] - (ny - crs["northing_m"])) < 1e-9, e
    posts = np.asarray(Image.open(utm / "elevation.png")).astype(np.float64)
    heights = e["offset_m"] + posts * e["scale_m"]
    valid = dtm != -9999.0
    err = np.abs(heights - dtm)[valid].max()
    assert err <= 0.0005 + 1e-9, f"DEM off by {err} m"
    # The nodata post takes a neighbour's height.
    assert abs(heights[10, 20] - dtm[10, 21]) < 0.001 or abs(heights[10, 20] - dtm[10, 19]) < 0.001
    # Mars: no EPSG code; the projection's GeoKeys are kept; 16 bits stretched monotonically.
    m = tomllib.loads((d / "mars" / "map.toml").read_text())
    keys = m["crs"]["geokeys"]
    assert "ProjCoordTransGeoKey=17" in keys and "GeogSemiMajorAxisGeoKey=3396190" in keys, keys
    assert "epsg" not in m["crs"], m["crs"]
    png = np.asarray(Image.open(d / "mars" / "satellite.png")).astype(np.int64)
    order = np.argsort(mars.ravel(), kind="stable")
    assert (np.diff(png.ravel()[order]) >= 0).all(), "the stretch is not monotonic"
    assert png.min() == 0 and png.max() == 255
    print("ok")


def togeotiff(dataset, d, e0, n0):
    meta = tomllib.loads((dataset / "map.toml").read_text())
    gsd = meta["gsd_m"]
    sat = np.asarray(Image.open(dataset / meta["image"]))
    # Pixel (0, 0) is centred on world (0, 0), i.e. on map (e0, n0): its corner is half a pixel off.
    with rasterio.open(d / "satellite.tif", "w", driver="GTiff", count=1, width=sat.shape[1],
                       height=sat.shape[0], dtype="uint8", crs=MARS, tiled=True,
                       transform=from_origin(e0 - gsd / 2, n0 + gsd / 2, gsd, gsd)) as f:
        f.write(sat, 1)
    e = meta["elevation"]
    posts = np.asarray(Image.open(dataset / e["image"])).astype(np.float64)
    heights = (e["offset_m"] + posts * e["scale_m"]).astype(np.float32)
    g = e["gsd_m"]
    with rasterio.open(d / "elevation.tif", "w", driver="GTiff", count=1, width=heights.shape[1],
                       height=heights.shape[0], dtype="float32", crs=MARS,
                       transform=from_origin(e0 + e["origin_x_m"] - g / 2, n0 + e["origin_y_m"] + g / 2, g, g)) as f:
        f.write(heights, 1)


def checkmars(d):
    """The simulator's GeoTIFFs, as GDAL reads them: Mars equirectangular, Jezero."""
    for name in ["satellite.tif", "elevation.tif"]:
        with rasterio.open(d / name) as f:
            proj = f.crs.to_proj4()
            assert "+proj=eqc" in proj and ("+R=3396190" in proj or "+a=3396190" in proj), proj
            assert f.transform.a > 0 and f.transform.e < 0 and f.transform.b == 0, f.transform
            assert 4_590_000 < f.transform.c < 4_600_000, f.transform
    print("ok")


if __name__ == "__main__":
    if sys.argv[1] == "checkmars":
        checkmars(Path(sys.argv[2]))
    elif sys.argv[1] == "togeotiff":
        togeotiff(Path(sys.argv[2]), Path(sys.argv[3]), float(sys.argv[4]), float(sys.argv[5]))
    else:
        {"write": write, "check": check}[sys.argv[1]](Path(sys.argv[2]))
