//! Property/fuzz test of the GeoTIFF reader (`jointloc map import`): a valid GeoTIFF written
//! here with the `tiff` encoder reads back exactly; its mutations (bit flips, truncation,
//! hostile values written over tag counts, offsets and sizes) give `Ok` or an error naming the
//! file, never a panic or an allocation sized by a field of the file.
//!
//! Cases: `JOINTLOC_FUZZ_CASES` (default 500), seed `JOINTLOC_FUZZ_SEED` (docs/testing.md).

mod common;

use std::path::Path;

use jointloc_formats::geotiff::read_geotiff;
use proptest::prelude::*;
use proptest::sample::Index;
use tiff::encoder::{TiffEncoder, colortype};
use tiff::tags::Tag;

use common::{fuzz, runner};

/// A 24 × 16 8-bit GeoTIFF: tie point + pixel scale, UTM 33N GeoKeys, a citation, nodata.
fn valid_geotiff() -> Vec<u8> {
    let mut bytes = std::io::Cursor::new(Vec::new());
    let mut enc = TiffEncoder::new(&mut bytes).unwrap();
    let mut img = enc.new_image::<colortype::Gray8>(24, 16).unwrap();
    let d = img.encoder();
    d.write_tag(Tag::ModelPixelScaleTag, &[0.5f64, 0.5, 0.0][..])
        .unwrap();
    d.write_tag(
        Tag::ModelTiepointTag,
        &[0.0f64, 0.0, 0.0, 500_000.0, 4_000_000.0, 0.0][..],
    )
    .unwrap();
    let keys: [u16; 20] = [
        1, 1, 0, 4, //
        1024, 0, 1, 1, // projected
        1025, 0, 1, 1, // PixelIsArea
        3072, 0, 1, 32633, // EPSG:32633
        3073, 34737, 5, 0, // citation "UTM33"
    ];
    d.write_tag(Tag::GeoKeyDirectoryTag, &keys[..]).unwrap();
    d.write_tag(Tag::GeoAsciiParamsTag, "UTM33|").unwrap();
    d.write_tag(Tag::GdalNodata, "0").unwrap();
    let pixels: Vec<u8> = (0..24 * 16).map(|i| (i % 251) as u8).collect();
    img.write_data(&pixels).unwrap();
    bytes.into_inner()
}

fn read(dir: &Path, bytes: &[u8]) -> Result<(), String> {
    let path = dir.join("map.tif");
    std::fs::write(&path, bytes).unwrap();
    match read_geotiff(&path) {
        Ok(r) => {
            let n = r.samples.len();
            if n != r.width * r.height {
                return Err(format!("{} samples for {} × {}", n, r.width, r.height));
            }
            if !(r.transform.pixel_m > 0.0 && r.transform.easting_m.is_finite()) {
                return Err(format!("accepted a bad transform {:?}", r.transform));
            }
            Ok(())
        }
        Err(e) if e.to_string().contains("map.tif") => Ok(()),
        Err(e) => Err(format!("error without the file name: {e}")),
    }
}

#[test]
fn the_valid_geotiff_reads_back() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("map.tif");
    std::fs::write(&path, valid_geotiff()).unwrap();
    let r = read_geotiff(&path).unwrap();
    assert_eq!((r.width, r.height), (24, 16));
    assert_eq!(r.transform.pixel_m, 0.5);
    assert_eq!(
        (r.transform.easting_m, r.transform.northing_m),
        (500_000.25, 3_999_999.75)
    );
    assert_eq!(r.crs.epsg, Some(32633));
    assert_eq!(r.crs.citation.as_deref(), Some("UTM33"));
    assert_eq!(r.nodata, Some(0.0));
    assert_eq!(r.samples.get(30), 30.0);
}

#[test]
fn fuzz_geotiff_mutations_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let valid = valid_geotiff();
    let hostile = prop_oneof![
        Just(0u32),
        Just(u32::MAX),
        Just(0x7fff_ffff),
        Just(0x0001_0000),
        any::<u32>()
    ];
    let mutation = (
        prop::collection::vec((any::<Index>(), any::<u8>()), 0..6),
        prop::collection::vec((any::<Index>(), hostile), 0..3),
        any::<Index>(),
        any::<bool>(),
    );
    runner()
        .run(&mutation, |(flips, words, cut, truncate)| {
            let mut b = valid.clone();
            for (i, v) in flips {
                let k = i.index(b.len());
                b[k] ^= v;
            }
            for (i, w) in words {
                let k = i.index(b.len() - 4);
                b[k..k + 4].copy_from_slice(&w.to_le_bytes());
            }
            if truncate {
                b.truncate(cut.index(b.len()));
            }
            read(dir.path(), &b).map_err(TestCaseError::fail)
        })
        .unwrap_or_else(|e| panic!("{e}"));
    fuzz(prop::collection::vec(any::<u8>(), 0..512), |b| {
        read(dir.path(), b)
    });
}
