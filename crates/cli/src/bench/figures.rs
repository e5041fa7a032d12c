//! The report's figures as small hand-written SVGs: trajectories over the satellite map, and
//! line charts over time. Every figure carries the machine and build line.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::Context;
use image::GrayImage;

/// A polyline (world x, y in metres) with a legend label and a colour.
#[derive(Debug)]
pub struct Track<'a> {
    pub label: &'a str,
    pub colour: &'a str,
    pub xy: &'a [(f64, f64)],
}

/// Absolute fixes drawn as dots coloured by confidence (red 0 → green 1).
#[derive(Debug)]
pub struct Fixes<'a> {
    pub xyw: &'a [(f64, f64, f64)],
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

fn confidence_colour(w: f64) -> String {
    let w = w.clamp(0.0, 1.0);
    format!(
        "rgb({},{},40)",
        (230.0 * (1.0 - w)) as u8,
        (200.0 * w) as u8
    )
}

/// Trajectories over the satellite map crop around them. `map` is the satellite image with
/// ground sampling `gsd` (world x = u·gsd, y = −v·gsd); the crop is written as a PNG beside
/// the SVG.
pub fn trajectories_over_map(
    svg: &Path,
    map: &GrayImage,
    gsd: f64,
    tracks: &[Track<'_>],
    fixes: Option<&Fixes<'_>>,
    title: &str,
    machine: &str,
) -> anyhow::Result<()> {
    let all = tracks.iter().flat_map(|t| t.xy.iter());
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, y) in all {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if x0 > x1 {
        anyhow::bail!("no trajectory to draw for {}", svg.display());
    }
    let margin = 5.0;
    // Crop in map pixels (v = −y / gsd).
    let u0 = (((x0 - margin) / gsd).floor().max(0.0)) as u32;
    let u1 = (((x1 + margin) / gsd).ceil() as u32).min(map.width());
    let v0 = ((-(y1 + margin) / gsd).floor().max(0.0)) as u32;
    let v1 = ((-(y0 - margin) / gsd).ceil() as u32).min(map.height());
    let png_name = svg.with_extension("map.png");
    let mut href = String::new();
    if u1 > u0 && v1 > v0 {
        let crop = image::imageops::crop_imm(map, u0, v0, u1 - u0, v1 - v0).to_image();
        let scale = (1000.0 / crop.width().max(crop.height()) as f64).min(1.0);
        let small = image::imageops::resize(
            &crop,
            ((crop.width() as f64 * scale) as u32).max(1),
            ((crop.height() as f64 * scale) as u32).max(1),
            image::imageops::FilterType::Triangle,
        );
        small
            .save(&png_name)
            .with_context(|| format!("writing {}", png_name.display()))?;
        href = png_name
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
    }
    // SVG user units: metres, X = x, Y = −y.
    let (vx, vy) = (x0 - margin, -(y1 + margin));
    let (vw, vh) = (x1 - x0 + 2.0 * margin, y1 - y0 + 2.0 * margin);
    let px_per_m = 900.0 / vw.max(vh);
    let (w_px, h_px) = (vw * px_per_m, vh * px_per_m + 60.0);
    let stroke = 1.5 / px_per_m;
    let mut s = String::new();
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w_px:.0}" height="{h_px:.0}" viewBox="{vx:.3} {:.3} {vw:.3} {:.3}">"#,
        vy - 40.0 / px_per_m,
        vh + 60.0 / px_per_m
    );
    let _ = writeln!(
        s,
        r#"<rect x="{vx}" y="{}" width="{vw}" height="{}" fill="white"/>"#,
        vy - 40.0 / px_per_m,
        vh + 60.0 / px_per_m
    );
    if !href.is_empty() {
        let _ = writeln!(
            s,
            r#"<image href="{href}" x="{:.3}" y="{:.3}" width="{:.3}" height="{:.3}" preserveAspectRatio="none" opacity="0.8"/>"#,
            u0 as f64 * gsd,
            v0 as f64 * gsd,
            (u1 - u0) as f64 * gsd,
            (v1 - v0) as f64 * gsd
        );
    }
    if let Some(f) = fixes {
        for &(x, y, w) in f.xyw {
            let _ = writeln!(
                s,
                r#"<circle cx="{x:.3}" cy="{:.3}" r="{:.3}" fill="{}" />"#,
                -y,
                2.5 / px_per_m,
                confidence_colour(w)
            );
        }
    }
    for t in tracks {
        let pts: Vec<String> =
            t.xy.iter()
                .map(|&(x, y)| format!("{x:.3},{:.3}", -y))
                .collect();
        let _ = writeln!(
            s,
            r#"<polyline points="{}" fill="none" stroke="{}" stroke-width="{stroke:.4}"/>"#,
            pts.join(" "),
            t.colour
        );
    }
    let font = 13.0 / px_per_m;
    let _ = writeln!(
        s,
        r#"<text x="{:.3}" y="{:.3}" font-size="{font:.3}" font-family="sans-serif">{}</text>"#,
        vx + 5.0 / px_per_m,
        vy - 22.0 / px_per_m,
        escape(title)
    );
    let mut legend_x = vx + 5.0 / px_per_m;
    for t in tracks {
        let _ = writeln!(
            s,
            r#"<text x="{legend_x:.3}" y="{:.3}" font-size="{font:.3}" font-family="sans-serif" fill="{}">— {}</text>"#,
            vy - 6.0 / px_per_m,
            t.colour,
            escape(t.label)
        );
        legend_x += (t.label.len() as f64 * 7.5 + 40.0) / px_per_m;
    }
    if fixes.is_some() {
        let _ = writeln!(
            s,
            r#"<text x="{legend_x:.3}" y="{:.3}" font-size="{font:.3}" font-family="sans-serif">● fixes, red w=0 → green w=1</text>"#,
            vy - 6.0 / px_per_m
        );
    }
    let _ = writeln!(
        s,
        r##"<text x="{:.3}" y="{:.3}" font-size="{:.3}" font-family="sans-serif" fill="#444">{}</text>"##,
        vx + 5.0 / px_per_m,
        vy + vh + 14.0 / px_per_m,
        font * 0.85,
        escape(machine)
    );
    // 10 m scale bar in the lower right corner.
    let (bx, by) = (vx + vw - 5.0 / px_per_m - 10.0, vy + vh - 8.0 / px_per_m);
    let _ = writeln!(
        s,
        r#"<line x1="{bx:.3}" y1="{by:.3}" x2="{:.3}" y2="{by:.3}" stroke="black" stroke-width="{:.3}"/><text x="{:.3}" y="{:.3}" font-size="{font:.3}" font-family="sans-serif" text-anchor="middle">10 m</text>"#,
        bx + 10.0,
        3.0 / px_per_m,
        bx + 5.0,
        by - 5.0 / px_per_m
    );
    s.push_str("</svg>\n");
    std::fs::write(svg, s).with_context(|| format!("writing {}", svg.display()))
}

/// A line series over time.
#[derive(Debug)]
pub struct Series<'a> {
    pub label: &'a str,
    pub colour: &'a str,
    pub points: &'a [(f64, f64)],
}

/// Line chart of series against time (seconds), y from 0.
pub fn line_chart(
    svg: &Path,
    title: &str,
    y_label: &str,
    series: &[Series<'_>],
    machine: &str,
) -> anyhow::Result<()> {
    let (w, h) = (900.0, 360.0);
    let (l, r, t, b) = (60.0, 20.0, 50.0, 50.0);
    let pts = series.iter().flat_map(|s| s.points.iter());
    let (mut t0, mut t1, mut y1) = (f64::MAX, f64::MIN, 0.0f64);
    for &(x, y) in pts {
        if y.is_finite() {
            t0 = t0.min(x);
            t1 = t1.max(x);
            y1 = y1.max(y);
        }
    }
    if t0 >= t1 {
        (t0, t1) = (0.0, 1.0);
    }
    if y1 <= 0.0 {
        y1 = 1.0;
    }
    let step = nice_step(y1 / 5.0);
    let y1 = (y1 / step).ceil() * step;
    let sx = |x: f64| l + (x - t0) / (t1 - t0) * (w - l - r);
    let sy = |y: f64| h - b - y / y1 * (h - t - b);
    let mut s = String::new();
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="12"><rect width="{w}" height="{h}" fill="white"/>"#
    );
    let _ = writeln!(
        s,
        r#"<text x="{l}" y="20" font-size="14">{}</text>"#,
        escape(title)
    );
    let mut y = 0.0;
    while y <= y1 + 1e-9 {
        let _ = writeln!(
            s,
            r##"<line x1="{l}" x2="{}" y1="{:.1}" y2="{:.1}" stroke="#ddd"/><text x="{}" y="{:.1}" text-anchor="end">{}</text>"##,
            w - r,
            sy(y),
            sy(y),
            l - 5.0,
            sy(y) + 4.0,
            trim(y)
        );
        y += step;
    }
    let tstep = nice_step((t1 - t0) / 8.0);
    let mut x = (t0 / tstep).ceil() * tstep;
    while x <= t1 + 1e-9 {
        let _ = writeln!(
            s,
            r#"<text x="{:.1}" y="{}" text-anchor="middle">{}</text>"#,
            sx(x),
            h - b + 16.0,
            trim(x)
        );
        x += tstep;
    }
    let _ = writeln!(
        s,
        r#"<text x="{}" y="{}" text-anchor="middle">time (s)</text><text x="14" y="{}" transform="rotate(-90 14 {})" text-anchor="middle">{}</text>"#,
        (l + w - r) / 2.0,
        h - b + 32.0,
        (t + h - b) / 2.0,
        (t + h - b) / 2.0,
        escape(y_label)
    );
    let mut lx = l;
    for se in series {
        let p: Vec<String> = se
            .points
            .iter()
            .filter(|(_, v)| v.is_finite())
            .map(|&(x, v)| format!("{:.1},{:.1}", sx(x), sy(v)))
            .collect();
        let _ = writeln!(
            s,
            r#"<polyline points="{}" fill="none" stroke="{}" stroke-width="1.4"/><text x="{lx}" y="38" fill="{}">— {}</text>"#,
            p.join(" "),
            se.colour,
            se.colour,
            escape(se.label)
        );
        lx += se.label.len() as f64 * 7.0 + 40.0;
    }
    let _ = writeln!(
        s,
        r##"<text x="{l}" y="{}" font-size="10" fill="#444">{}</text></svg>"##,
        h - 6.0,
        escape(machine)
    );
    std::fs::write(svg, s).with_context(|| format!("writing {}", svg.display()))
}

fn nice_step(raw: f64) -> f64 {
    if raw.is_nan() || raw <= 0.0 {
        return 1.0;
    }
    let p = 10f64.powf(raw.log10().floor());
    let m = raw / p;
    let n = if m <= 1.0 {
        1.0
    } else if m <= 2.0 {
        2.0
    } else if m <= 5.0 {
        5.0
    } else {
        10.0
    };
    n * p
}

fn trim(v: f64) -> String {
    let s = format!("{v:.3}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn figures_are_written_with_their_map_crop() {
        let dir = tempfile::tempdir().unwrap();
        let map = GrayImage::from_fn(400, 400, |u, v| image::Luma([((u + v) % 256) as u8]));
        let xy = [(2.0, -2.0), (10.0, -12.0), (15.0, -15.0)];
        let svg = dir.path().join("traj.svg");
        trajectories_over_map(
            &svg,
            &map,
            0.05,
            &[Track {
                label: "gt",
                colour: "black",
                xy: &xy,
            }],
            Some(&Fixes {
                xyw: &[(10.0, -12.0, 0.7)],
            }),
            "crater <easy>",
            "2 cores",
        )
        .unwrap();
        let text = std::fs::read_to_string(&svg).unwrap();
        assert!(text.contains("<polyline") && text.contains("crater &lt;easy&gt;"));
        assert!(dir.path().join("traj.map.png").exists());
        let chart = dir.path().join("err.svg");
        line_chart(
            &chart,
            "APE",
            "m",
            &[Series {
                label: "a",
                colour: "red",
                points: &[(0.0, 0.1), (1.0, 0.3)],
            }],
            "2 cores",
        )
        .unwrap();
        assert!(
            std::fs::read_to_string(&chart)
                .unwrap()
                .contains("polyline")
        );
        assert_eq!(nice_step(0.13), 0.2);
        assert_eq!(nice_step(7.0), 10.0);
    }
}
