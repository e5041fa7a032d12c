//! `jointloc run` on a 133° Kannala–Brandt fisheye flight (issue 26): the same 30 m of ground
//! and path rendered through the fisheye and through the default pinhole, each localised in
//! the world frame with the ORB matcher (the fisheye through its lens model in tracking,
//! triangulation, the BAs, the absolute localisation's warp and the global BA's noise model).
//! The fisheye localises as well as the pinhole: APE within 1.5× online and at the end, each
//! with its defaults (for the fisheye: no terrain correction, its view being wider than
//! `[terrain] max_fov_deg`).

mod common;

use common::{run_orb_on, sim_crater};

#[test]
fn a_fisheye_flight_localises_as_well_as_the_pinhole_one() {
    let tmp = tempfile::tempdir().unwrap();
    let mut ape = Vec::new();
    for (name, lens) in [
        ("fisheye", &["--camera", "fisheye", "--fov-deg", "133"][..]),
        ("pinhole", &[][..]),
    ] {
        let data = tmp.path().join(format!("{name}-data"));
        sim_crater(&data, "33", lens);
        let out = tmp.path().join(format!("{name}-out"));
        let (stdout, summary) = run_orb_on(&data, &out, &["--sequential"]);
        let (frames, world) = (
            summary["frames"].as_u64().unwrap(),
            summary["world_poses"].as_u64().unwrap(),
        );
        // Geo-referenced after the first three fixes, then every frame.
        assert!(
            world + 40 >= frames,
            "{name}: {world} of {frames}\n{stdout}"
        );
        assert!(
            summary["fixes_used"].as_u64().unwrap() >= 10,
            "{name}: {stdout}"
        );
        // The terrain correction is on for the pinhole's 53° and off for the fisheye's
        // 133° (`[terrain] max_fov_deg`, 90° by default).
        let updates = summary["terrain_correction_m"]["updates"].as_u64().unwrap();
        assert_eq!(
            updates > 0,
            name == "pinhole",
            "{name}: {updates} estimates"
        );
        let online = summary["ape_translation"]["rmse"].as_f64().unwrap();
        let end = summary["ape_translation_final"]["rmse"].as_f64().unwrap();
        assert!(online < 0.15 && end < 0.15, "{name}: {stdout}");
        ape.push((online, end));
    }
    let ((fish_online, fish_end), (pin_online, pin_end)) = (ape[0], ape[1]);
    println!("online {fish_online:.4} vs {pin_online:.4} m, end {fish_end:.4} vs {pin_end:.4} m");
    assert!(
        fish_online <= 1.5 * pin_online,
        "online: fisheye {fish_online} m against pinhole {pin_online} m"
    );
    assert!(
        fish_end <= 1.5 * pin_end,
        "at the end: fisheye {fish_end} m against pinhole {pin_end} m"
    );
}
