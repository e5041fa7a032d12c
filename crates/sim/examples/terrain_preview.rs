//! Top-down shaded previews of the three terrains, and timing of synthesis + shading.
//!
//! ```text
//! cargo run --release -p jointloc-sim --example terrain_preview -- [--size-m 25] [--seed 1]
//!     [--out /tmp] [--sun-az 135] [--sun-el 30] [--cell 0.025] [--timing]
//! ```
//! Writes `<out>/terrain_<kind>.png` (grey, as a camera sees radiance) and
//! `<out>/terrain_<kind>_color.png` (tinted for a human eye). `--timing` instead generates and
//! shades a 4800 × 3200-cell area (120 m × 80 m at 2.5 cm; `--width`, `--height` change it)
//! per kind (`--kind crater` picks one) and prints the times.

use std::time::Instant;

use jointloc_sim::{
    ShadingConfig, Sun, TerrainConfig, TerrainExtent, TerrainKind, generate_terrain, shade,
};

fn arg<T: std::str::FromStr>(args: &[String], name: &str, default: T) -> T {
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let size_m: f64 = arg(&args, "--size-m", 25.0);
    let seed: u64 = arg(&args, "--seed", 1);
    let out: String = arg(&args, "--out", "/tmp".to_string());
    let sun = Sun {
        azimuth_deg: arg(&args, "--sun-az", 135.0),
        elevation_deg: arg(&args, "--sun-el", 30.0),
    };
    let timing = args.iter().any(|a| a == "--timing");
    let only: Option<String> = args
        .iter()
        .position(|a| a == "--kind")
        .and_then(|i| args.get(i + 1).cloned());
    let cfg = TerrainConfig {
        cell_m: arg(&args, "--cell", 0.025),
        ..Default::default()
    };
    let shading = ShadingConfig::default();
    let kinds = [
        TerrainKind::Crater,
        TerrainKind::Gravel,
        TerrainKind::Mountain,
    ];
    for kind in kinds {
        if only
            .as_deref()
            .is_some_and(|k| !format!("{kind:?}").eq_ignore_ascii_case(k))
        {
            continue;
        }
        let (w, h) = if timing {
            (
                arg(&args, "--width", 4800usize),
                arg(&args, "--height", 3200usize),
            )
        } else {
            let n = (size_m / cfg.cell_m).round() as usize;
            (n, n)
        };
        let extent = TerrainExtent {
            origin_x: 0.0,
            origin_y: h as f64 * cfg.cell_m,
            width_cells: w,
            height_cells: h,
        };
        let (t0, c0) = (Instant::now(), cpu_seconds());
        let terrain = generate_terrain(kind, &extent, &cfg, seed)?;
        let (t1, c1) = (Instant::now(), cpu_seconds());
        let rad = shade(&terrain, &sun, &shading);
        let (t2, c2) = (Instant::now(), cpu_seconds());
        let hmin = terrain.height.data.iter().cloned().fold(f32::MAX, f32::min);
        let hmax = terrain.height.data.iter().cloned().fold(f32::MIN, f32::max);
        println!(
            "{kind:?}: {w}×{h} cells, generate {:.2} s (cpu {:.2} s), shade {:.2} s (cpu {:.2} s), \
             height [{hmin:.2}, {hmax:.2}] m, max relief in 10 m windows {:.2} m",
            (t1 - t0).as_secs_f64(),
            c1 - c0,
            (t2 - t1).as_secs_f64(),
            c2 - c1,
            max_window_relief(&terrain.height, (10.0 / cfg.cell_m) as usize),
        );
        if timing {
            continue;
        }
        // Exposure: the 99.5th percentile of radiance maps to 0.95, then sRGB-like gamma.
        let mut sorted = rad.data.clone();
        sorted.sort_by(f32::total_cmp);
        let p = sorted[(sorted.len() as f64 * 0.995) as usize].max(1e-6);
        let gain = 0.95 / p;
        let name = format!("{kind:?}").to_lowercase();
        let grey: Vec<u8> = rad
            .data
            .iter()
            .map(|&v| ((v * gain).clamp(0.0, 1.0).powf(1.0 / 2.2) * 255.0).round() as u8)
            .collect();
        image::GrayImage::from_raw(w as u32, h as u32, grey)
            .ok_or("image size")?
            .save(format!("{out}/terrain_{name}.png"))?;
        let tint = [1.0f32, 0.72, 0.52];
        let mut rgb = Vec::with_capacity(w * h * 3);
        for &v in &rad.data {
            for t in tint {
                rgb.push(((v * gain * t).clamp(0.0, 1.0).powf(1.0 / 2.2) * 255.0).round() as u8);
            }
        }
        image::RgbImage::from_raw(w as u32, h as u32, rgb)
            .ok_or("image size")?
            .save(format!("{out}/terrain_{name}_color.png"))?;
    }
    Ok(())
}

/// User + system CPU time of this process (all threads) from /proc, 0 where unavailable.
fn cpu_seconds() -> f64 {
    std::fs::read_to_string("/proc/self/stat")
        .ok()
        .and_then(|s| {
            let rest = &s[s.rfind(')')? + 2..];
            let f: Vec<&str> = rest.split_whitespace().collect();
            Some((f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?) / 100.0)
        })
        .unwrap_or(0.0)
}

/// Largest max − min of the height over square windows of `win` cells (stride win / 2).
fn max_window_relief(g: &jointloc_sim::Grid<f32>, win: usize) -> f32 {
    let win = win.min(g.width).min(g.height).max(1);
    let step = (win / 2).max(1);
    let mut best = 0.0f32;
    let mut r0 = 0;
    while r0 + win <= g.height {
        let mut c0 = 0;
        while c0 + win <= g.width {
            let (mut lo, mut hi) = (f32::MAX, f32::MIN);
            for r in (r0..r0 + win).step_by(4) {
                for c in (c0..c0 + win).step_by(4) {
                    let z = g.at(c, r);
                    lo = lo.min(z);
                    hi = hi.max(z);
                }
            }
            best = best.max(hi - lo);
            c0 += step;
        }
        r0 += step;
    }
    best
}
