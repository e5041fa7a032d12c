//! GeoTIFF rasters (orthoimages and DTMs as USGS/PDS and GDAL write them): the pixels, the
//! georeference and the CRS, read with the pure-Rust `tiff` crate (stripped or tiled, classic
//! or BigTIFF, 8/16-bit integer or 32/64-bit float, one band).
//!
//! Georeference: `ModelTransformationTag`, or `ModelTiepointTag` + `ModelPixelScaleTag`, with
//! `GTRasterTypeGeoKey` telling whether the tie point is a pixel's corner (PixelIsArea, the
//! default) or its centre (PixelIsPoint). Only north-up rasters with square pixels in a
//! projected CRS in metres are accepted (the map frame of jointloc is such a grid); anything
//! else is an error that says to reproject first (e.g. `gdalwarp`). The CRS is kept as its
//! EPSG code when the GeoKeys name one, and as the citation text GDAL writes otherwise.

use std::fs::File;
use std::io::BufReader;
use std::path::Path;

use tiff::decoder::{Decoder, DecodingResult, Limits};
use tiff::tags::Tag;

use crate::error::{FormatError, Result};

/// Largest raster accepted, in pixels (a 40 000 × 40 000 scene).
pub const MAX_PIXELS: u64 = 1_600_000_000;
/// Largest ratio of decoded pixel bytes to file bytes believed (deflate tops out near 1032:1,
/// 12-bit LZW near 2700:1).
const MAX_RATIO: u64 = 4096;

/// GeoKey ids (GeoTIFF 1.1, OGC 19-008r4).
mod key {
    pub const MODEL_TYPE: u16 = 1024;
    pub const RASTER_TYPE: u16 = 1025;
    pub const CITATION: u16 = 1026;
    pub const GEOGRAPHIC_TYPE: u16 = 2048;
    pub const PROJECTED_TYPE: u16 = 3072;
    pub const PROJECTED_CITATION: u16 = 3073;
    pub const LINEAR_UNITS: u16 = 3076;
}
const MODEL_GEOGRAPHIC: u16 = 2;
const GEO_DOUBLE_PARAMS: u16 = 34736;
const RASTER_PIXEL_IS_POINT: u16 = 2;
const USER_DEFINED: u16 = 32767;
const UNIT_METRE: u16 = 9001;

/// The pixel values of one band.
#[derive(Debug, Clone, PartialEq)]
pub enum Samples {
    U8(Vec<u8>),
    U16(Vec<u16>),
    F32(Vec<f32>),
}

impl Samples {
    /// Number of values.
    pub fn len(&self) -> usize {
        match self {
            Samples::U8(v) => v.len(),
            Samples::U16(v) => v.len(),
            Samples::F32(v) => v.len(),
        }
    }

    /// True when there is no value.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Value `i` as f64.
    #[inline]
    pub fn get(&self, i: usize) -> f64 {
        match self {
            Samples::U8(v) => v[i] as f64,
            Samples::U16(v) => v[i] as f64,
            Samples::F32(v) => v[i] as f64,
        }
    }
}

/// A north-up, square-pixel georeference in a projected CRS (metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GeoTransform {
    /// Map easting and northing of the *centre* of pixel (0, 0).
    pub easting_m: f64,
    pub northing_m: f64,
    /// Pixel size, metres (columns run east, rows south).
    pub pixel_m: f64,
}

impl GeoTransform {
    /// Map coordinates of the centre of pixel `(col, row)`.
    pub fn pixel_to_map(&self, col: f64, row: f64) -> (f64, f64) {
        (
            self.easting_m + col * self.pixel_m,
            self.northing_m - row * self.pixel_m,
        )
    }
}

/// The CRS as the file states it.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct GeoCrs {
    /// EPSG code of the projected (or geographic) CRS, when the GeoKeys name one.
    pub epsg: Option<u32>,
    /// The citation GDAL writes (often the CRS's name or its WKT), when present.
    pub citation: Option<String>,
    /// The projection's GeoKeys as `name=value` text (`ProjCoordTransGeoKey=17 …`): with no
    /// EPSG code (a Mars CRS) they are the CRS's definition.
    pub geokeys: Option<String>,
}

/// One band of a GeoTIFF with its georeference.
#[derive(Debug, Clone)]
pub struct GeoRaster {
    pub width: usize,
    pub height: usize,
    pub samples: Samples,
    pub transform: GeoTransform,
    pub crs: GeoCrs,
    /// The `GDAL_NODATA` value, when set.
    pub nodata: Option<f64>,
}

/// Reads the first band of the GeoTIFF at `path`.
pub fn read_geotiff(path: &Path) -> Result<GeoRaster> {
    let bad = |message: String| FormatError::invalid(path, message);
    let tiff_err = |e: tiff::TiffError| bad(format!("not a readable TIFF: {e}"));
    let file = File::open(path).map_err(|e| FormatError::io(path, e))?;
    let mut decoder = Decoder::new(BufReader::new(file)).map_err(tiff_err)?;
    let (w, h) = decoder.dimensions().map_err(tiff_err)?;
    if (w as u64) * (h as u64) > MAX_PIXELS {
        return Err(bad(format!(
            "{w} × {h} pixels is more than the {MAX_PIXELS} accepted: crop the scene first"
        )));
    }
    let keys = geo_keys(&mut decoder);
    let ascii = decoder
        .get_tag_ascii_string(Tag::GeoAsciiParamsTag)
        .unwrap_or_default();
    let transform = transform(&mut decoder, &keys).map_err(bad)?;
    let doubles = decoder
        .get_tag_f64_vec(Tag::Unknown(GEO_DOUBLE_PARAMS))
        .unwrap_or_default();
    let crs = crs(&keys, &ascii, &doubles).map_err(bad)?;
    let nodata = decoder
        .get_tag_ascii_string(Tag::GdalNodata)
        .ok()
        .and_then(|s| s.trim_matches(char::from(0)).trim().parse::<f64>().ok());
    let mut limits = Limits::default();
    limits.decoding_buffer_size = (MAX_PIXELS * 8) as usize;
    limits.intermediate_buffer_size = (MAX_PIXELS * 8) as usize;
    let mut decoder = decoder.with_limits(limits);
    let colour = decoder.colortype().map_err(tiff_err)?;
    let tiff::ColorType::Gray(bits @ (8 | 16 | 32 | 64)) = colour else {
        return Err(bad(format!(
            "{colour:?}: only single-band (grey) rasters of 8, 16, 32 or 64 bits are read; \
             extract one band first"
        )));
    };
    // No compression TIFF uses packs more than ~4000:1, so a header claiming more pixels than
    // that is corrupt: refuse it before allocating what it claims.
    let claimed = w as u64 * h as u64 * (bits as u64 / 8);
    let file_len = std::fs::metadata(path).map_or(0, |m| m.len());
    if claimed > MAX_RATIO * file_len + 65_536 {
        return Err(bad(format!(
            "{w} × {h} pixels of {bits} bits cannot be held in a file of {file_len} bytes: \
             the file is truncated or corrupt"
        )));
    }
    let samples = match decoder.read_image().map_err(tiff_err)? {
        DecodingResult::U8(v) => Samples::U8(v),
        DecodingResult::U16(v) => Samples::U16(v),
        DecodingResult::I16(v) => Samples::F32(v.into_iter().map(f32::from).collect()),
        DecodingResult::F32(v) => Samples::F32(v),
        DecodingResult::F64(v) => Samples::F32(v.into_iter().map(|x| x as f32).collect()),
        _ => return Err(bad("unsupported sample type: use 8/16-bit or float".into())),
    };
    let n = samples.len();
    if n != w as usize * h as usize {
        return Err(bad(format!("decoded {n} samples for {w} × {h} pixels")));
    }
    Ok(GeoRaster {
        width: w as usize,
        height: h as usize,
        samples,
        transform,
        crs,
        nodata,
    })
}

/// GeoKeys as `(id, location, count, value)`.
fn geo_keys<R: std::io::Read + std::io::Seek>(d: &mut Decoder<R>) -> Vec<[u16; 4]> {
    let Ok(dir) = d.get_tag_u16_vec(Tag::GeoKeyDirectoryTag) else {
        return Vec::new();
    };
    let n = dir.get(3).copied().unwrap_or(0) as usize;
    dir.get(4..)
        .unwrap_or(&[])
        .chunks_exact(4)
        .take(n)
        .map(|k| [k[0], k[1], k[2], k[3]])
        .collect()
}

/// A short key's value (stored in the directory itself).
fn key_value(keys: &[[u16; 4]], id: u16) -> Option<u16> {
    keys.iter().find(|k| k[0] == id && k[1] == 0).map(|k| k[3])
}

/// An ASCII key's text (in `GeoAsciiParamsTag`, '|'-terminated).
fn key_text(keys: &[[u16; 4]], id: u16, ascii: &str) -> Option<String> {
    let k = keys
        .iter()
        .find(|k| k[0] == id && k[1] == Tag::GeoAsciiParamsTag.to_u16())?;
    let (start, len) = (k[3] as usize, k[2] as usize);
    let text = ascii.get(start..start + len)?;
    let text = text.trim_end_matches('|').trim();
    (!text.is_empty()).then(|| text.to_string())
}

fn transform<R: std::io::Read + std::io::Seek>(
    d: &mut Decoder<R>,
    keys: &[[u16; 4]],
) -> std::result::Result<GeoTransform, String> {
    let point = key_value(keys, key::RASTER_TYPE) == Some(RASTER_PIXEL_IS_POINT);
    // Map coordinates of the point that (col, row) = (0, 0) refers to, and the pixel steps.
    let (e0, n0, sx, sy, rot) = if let Ok(m) = d.get_tag_f64_vec(Tag::ModelTransformationTag) {
        if m.len() < 16 {
            return Err("ModelTransformationTag has fewer than 16 values".into());
        }
        (m[3], m[7], m[0], -m[5], m[1].abs() + m[4].abs())
    } else {
        let scale = d.get_tag_f64_vec(Tag::ModelPixelScaleTag).map_err(
            |_| "no georeference: neither ModelTransformationTag nor ModelPixelScaleTag",
        )?;
        let tie = d
            .get_tag_f64_vec(Tag::ModelTiepointTag)
            .map_err(|_| "no georeference: ModelPixelScaleTag without ModelTiepointTag")?;
        if scale.len() < 2 || tie.len() < 6 {
            return Err("ModelPixelScaleTag or ModelTiepointTag is too short".into());
        }
        let (i, j) = (tie[0], tie[1]);
        (
            tie[3] - i * scale[0],
            tie[4] + j * scale[1],
            scale[0],
            scale[1],
            0.0,
        )
    };
    let finite = [e0, n0, sx, sy].iter().all(|v| v.is_finite());
    if !finite || sx <= 0.0 || sy <= 0.0 {
        return Err(format!(
            "pixel size {sx} × {sy}: the raster must be north-up with positive pixel sizes"
        ));
    }
    if rot > 1e-9 * sx {
        return Err("the raster is rotated: reproject it north-up first (gdalwarp)".into());
    }
    if (sx - sy).abs() > 1e-6 * sx {
        return Err(format!(
            "pixels are {sx} × {sy} m: resample to square pixels first (gdalwarp -tr)"
        ));
    }
    // PixelIsArea: (0, 0) is the corner of pixel (0, 0); its centre is half a pixel inside.
    let half = if point { 0.0 } else { 0.5 * sx };
    Ok(GeoTransform {
        easting_m: e0 + half,
        northing_m: n0 - half,
        pixel_m: sx,
    })
}

/// Names of the GeoKeys that define a projection (GeoTIFF 1.1 §7).
fn key_name(id: u16) -> Option<&'static str> {
    Some(match id {
        2048 => "GeographicTypeGeoKey",
        2050 => "GeogGeodeticDatumGeoKey",
        2056 => "GeogEllipsoidGeoKey",
        2057 => "GeogSemiMajorAxisGeoKey",
        2058 => "GeogSemiMinorAxisGeoKey",
        2059 => "GeogInvFlatteningGeoKey",
        2061 => "GeogPrimeMeridianLongGeoKey",
        3072 => "ProjectedCSTypeGeoKey",
        3074 => "ProjectionGeoKey",
        3075 => "ProjCoordTransGeoKey",
        3076 => "ProjLinearUnitsGeoKey",
        3078 => "ProjStdParallel1GeoKey",
        3079 => "ProjStdParallel2GeoKey",
        3080 => "ProjNatOriginLongGeoKey",
        3081 => "ProjNatOriginLatGeoKey",
        3082 => "ProjFalseEastingGeoKey",
        3083 => "ProjFalseNorthingGeoKey",
        3088 => "ProjCenterLongGeoKey",
        3089 => "ProjCenterLatGeoKey",
        3092 => "ProjScaleAtNatOriginGeoKey",
        3095 => "ProjStraightVertPoleLongGeoKey",
        _ => return None,
    })
}

/// The projection's GeoKeys as text, short values and doubles.
fn geokeys_text(keys: &[[u16; 4]], doubles: &[f64]) -> Option<String> {
    let parts: Vec<String> = keys
        .iter()
        .filter_map(|k| {
            let name = key_name(k[0])?;
            match k[1] {
                0 => Some(format!("{name}={}", k[3])),
                GEO_DOUBLE_PARAMS => doubles.get(k[3] as usize).map(|v| format!("{name}={v}")),
                _ => None,
            }
        })
        .collect();
    (!parts.is_empty()).then(|| parts.join(" "))
}

fn crs(keys: &[[u16; 4]], ascii: &str, doubles: &[f64]) -> std::result::Result<GeoCrs, String> {
    if key_value(keys, key::MODEL_TYPE) == Some(MODEL_GEOGRAPHIC) {
        return Err(
            "the CRS is geographic (degrees): reproject to a projected CRS in metres first".into(),
        );
    }
    if let Some(u) = key_value(keys, key::LINEAR_UNITS)
        && u != UNIT_METRE
    {
        return Err(format!(
            "linear unit {u} is not the metre (9001): reproject to metres first"
        ));
    }
    let code = key_value(keys, key::PROJECTED_TYPE)
        .or_else(|| key_value(keys, key::GEOGRAPHIC_TYPE))
        .filter(|&c| c != USER_DEFINED && c != 0)
        .map(u32::from);
    let citation = key_text(keys, key::PROJECTED_CITATION, ascii)
        .or_else(|| key_text(keys, key::CITATION, ascii));
    Ok(GeoCrs {
        epsg: code,
        citation: citation.filter(|c| c != "unknown"),
        geokeys: geokeys_text(keys, doubles),
    })
}

/// The Mars 2000 sphere's radius (IAU), metres.
pub const MARS_RADIUS_M: f64 = 3_396_190.0;

/// Writes one band as a GeoTIFF (deflate, strips) in the Mars equirectangular CRS (sphere of
/// [`MARS_RADIUS_M`], standard parallel and central meridian 0), the GeoKeys GDAL writes for
/// `+proj=eqc +R=3396190 +units=m`, so GIS tools place it on Mars.
pub fn write_mars_geotiff(
    path: &Path,
    width: usize,
    height: usize,
    samples: &Samples,
    transform: &GeoTransform,
) -> Result<()> {
    use tiff::encoder::{Compression, TiffEncoder, colortype};
    let err =
        |e: tiff::TiffError| FormatError::invalid(path, format!("cannot write the GeoTIFF: {e}"));
    let file = File::create(path).map_err(|e| FormatError::io(path, e))?;
    let mut enc = TiffEncoder::new(std::io::BufWriter::new(file))
        .map_err(err)?
        .with_compression(Compression::Deflate(Default::default()));
    // PixelIsArea: the tie point is the corner of pixel (0, 0).
    let half = 0.5 * transform.pixel_m;
    let scale = [transform.pixel_m, transform.pixel_m, 0.0];
    let tie = [
        0.0,
        0.0,
        0.0,
        transform.easting_m - half,
        transform.northing_m + half,
        0.0,
    ];
    let citation = "Mars 2000 equirectangular (sphere R = 3396190 m)|";
    let doubles = [MARS_RADIUS_M, MARS_RADIUS_M, 0.0, 0.0, 0.0, 0.0, 0.0];
    #[rustfmt::skip]
    let keys: [u16; 4 * 19] = [
        1, 1, 0, 18,
        1024, 0, 1, 1, // GTModelTypeGeoKey: projected
        1025, 0, 1, 1, // GTRasterTypeGeoKey: PixelIsArea
        1026, 34737, citation.len() as u16, 0, // GTCitationGeoKey
        2048, 0, 1, USER_DEFINED, // GeographicTypeGeoKey
        2050, 0, 1, USER_DEFINED, // GeogGeodeticDatumGeoKey
        2054, 0, 1, 9102, // GeogAngularUnitsGeoKey: degree
        2056, 0, 1, USER_DEFINED, // GeogEllipsoidGeoKey
        2057, 34736, 1, 0, // GeogSemiMajorAxisGeoKey
        2058, 34736, 1, 1, // GeogSemiMinorAxisGeoKey
        3072, 0, 1, USER_DEFINED, // ProjectedCSTypeGeoKey
        3074, 0, 1, USER_DEFINED, // ProjectionGeoKey
        3075, 0, 1, 17, // ProjCoordTransGeoKey: equirectangular
        3076, 0, 1, UNIT_METRE, // ProjLinearUnitsGeoKey
        3078, 34736, 1, 2, // ProjStdParallel1GeoKey
        3082, 34736, 1, 3, // ProjFalseEastingGeoKey
        3083, 34736, 1, 4, // ProjFalseNorthingGeoKey
        3088, 34736, 1, 5, // ProjCenterLongGeoKey
        3089, 34736, 1, 6, // ProjCenterLatGeoKey
    ];
    let (w, h) = (width as u32, height as u32);
    macro_rules! write_band {
        ($colour:ty, $data:expr) => {{
            let mut img = enc.new_image::<$colour>(w, h).map_err(err)?;
            let d = img.encoder();
            d.write_tag(Tag::ModelPixelScaleTag, &scale[..])
                .map_err(err)?;
            d.write_tag(Tag::ModelTiepointTag, &tie[..]).map_err(err)?;
            d.write_tag(Tag::GeoKeyDirectoryTag, &keys[..])
                .map_err(err)?;
            d.write_tag(Tag::GeoDoubleParamsTag, &doubles[..])
                .map_err(err)?;
            d.write_tag(Tag::GeoAsciiParamsTag, citation).map_err(err)?;
            img.write_data($data).map_err(err)?;
        }};
    }
    match samples {
        Samples::U8(v) => write_band!(colortype::Gray8, v),
        Samples::U16(v) => write_band!(colortype::Gray16, v),
        Samples::F32(v) => write_band!(colortype::Gray32Float, v),
    }
    Ok(())
}
