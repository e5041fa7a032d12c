//! The flight's sun, which the localiser relights the map to: `--flight-sun AZ,EL`, else the
//! settings' `[absloc.relight] flight_sun`, else what a simulated dataset's `map.toml` records
//! as `[scene.uav_sun]`.

use std::path::Path;

use anyhow::{Context, bail};
use jointloc_formats::MapInfo;
use jointloc_formats::map_toml::SunInfo;

/// `--flight-sun AZ,EL` in degrees: azimuth clockwise from north, elevation above the horizon.
pub fn parse(text: &str) -> anyhow::Result<SunInfo> {
    parse_sun(text).with_context(|| format!("--flight-sun {text}"))
}

/// `AZ,EL` in degrees: azimuth clockwise from north, elevation in (0, 90].
pub fn parse_sun(text: &str) -> anyhow::Result<SunInfo> {
    let parsed = text
        .split_once(',')
        .and_then(|(a, e)| Some((a.trim().parse::<f64>().ok()?, e.trim().parse::<f64>().ok()?)));
    let Some((azimuth_deg, elevation_deg)) = parsed else {
        bail!("`{text}`: expected AZIMUTH,ELEVATION in degrees");
    };
    let sun = SunInfo {
        azimuth_deg,
        elevation_deg,
    };
    if !sun.is_valid() {
        bail!("`{text}`: the azimuth must be finite and the elevation in (0, 90] degrees");
    }
    Ok(sun)
}

/// Sets `configured` from `flag`, or, when both are absent, from the dataset's record.
pub fn resolve(
    flag: Option<&str>,
    configured: &mut Option<SunInfo>,
    dataset: &Path,
) -> anyhow::Result<()> {
    if let Some(text) = flag {
        *configured = Some(parse(text)?);
        return Ok(());
    }
    if configured.is_some() {
        return Ok(());
    }
    let path = dataset.join("map.toml");
    if path.is_file() {
        let map = MapInfo::read(&path).with_context(|| format!("reading {}", path.display()))?;
        if let Some(scene) = map.scene {
            tracing::info!(
                azimuth_deg = scene.uav_sun.azimuth_deg,
                elevation_deg = scene.uav_sun.elevation_deg,
                "flight sun from the simulated dataset's map.toml"
            );
            *configured = Some(scene.uav_sun);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_azimuth_and_elevation_and_refuses_the_rest() {
        let s = parse("258.5, 18.3").unwrap();
        assert_eq!((s.azimuth_deg, s.elevation_deg), (258.5, 18.3));
        for bad in ["258.5", "a,b", "10,0", "10,-5", "10,95", "nan,20"] {
            assert!(parse(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn the_flag_wins_then_the_settings_then_the_dataset() {
        let dir = tempfile::tempdir().unwrap();
        let mut sun = Some(SunInfo {
            azimuth_deg: 1.0,
            elevation_deg: 2.0,
        });
        resolve(Some("10,20"), &mut sun, dir.path()).unwrap();
        assert_eq!(sun.unwrap().azimuth_deg, 10.0);
        resolve(None, &mut sun, dir.path()).unwrap();
        assert_eq!(sun.unwrap().azimuth_deg, 10.0);
        let mut none = None;
        resolve(None, &mut none, dir.path()).unwrap();
        assert!(none.is_none(), "no map.toml, no sun");
    }
}
