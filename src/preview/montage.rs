//! One pair as a PNG montage: source depth, condition (unknown pixels grey), known mask, inpainted
//! target — colour-mapped with one depth scale shared by the montage — and both clouds rendered into
//! the target camera with the stored pose (source red, target green, yellow where both cover a pixel with
//! depths less than 5 cm apart).

use super::canvas::{text_height, Canvas, Rgb};
use super::colormap::{shade, turbo, BACKGROUND, BOTH, INVALID, SOURCE, TARGET, TEXT, UNKNOWN};
use crate::error::{Error, Result};
use crate::export::row_pose;
use crate::geometry::{transform_points, Point};
use crate::shards::row::PairRow;
use crate::sources::depth_png::decode_depth_png;
use std::path::Path;

/// Gap between panels and around the montage, pixels.
pub const PAD: u32 = 8;
/// Panels per montage.
pub const PANELS: u32 = 5;
const TITLE_H: u32 = 30;
const LABEL_H: u32 = 16;
const BAR_H: u32 = 34;
/// Splat footprint: the official voxel size, metres (a point covers about one voxel).
const SPLAT_METRES: f64 = 0.025;
/// Pixels both clouds cover within this depth difference are drawn as "both".
const BOTH_METRES: f32 = 0.05;

/// The montage size for panels of `w` × `h` pixels.
pub fn montage_size(w: u32, h: u32) -> (u32, u32) {
    (PANELS * w + (PANELS + 1) * PAD, PAD + TITLE_H + h + LABEL_H + BAR_H + PAD)
}

/// A decoded 16-bit depth image (millimetres) or 8-bit mask.
struct Image {
    width: u32,
    height: u32,
    data: Vec<u16>,
}

fn decode_depth(bytes: &[u8], what: &str) -> Result<Option<Image>> {
    if bytes.is_empty() {
        return Ok(None);
    }
    let d = decode_depth_png(bytes, Path::new(what))?;
    Ok(Some(Image { width: d.width, height: d.height, data: d.data }))
}

fn decode_mask(bytes: &[u8]) -> Result<Option<Image>> {
    if bytes.is_empty() {
        return Ok(None);
    }
    let bad = |e: String| Error::input("known_mask_png", e);
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes)).read_info().map_err(|e| bad(e.to_string()))?;
    let (w, h) = (reader.info().width, reader.info().height);
    if reader.info().color_type != png::ColorType::Grayscale || reader.info().bit_depth != png::BitDepth::Eight {
        return Err(bad("expected an 8-bit grayscale PNG".into()));
    }
    let mut buf = vec![0u8; reader.output_buffer_size().ok_or_else(|| bad("too large".into()))?];
    reader.next_frame(&mut buf).map_err(|e| bad(e.to_string()))?;
    buf.truncate(w as usize * h as usize);
    Ok(Some(Image { width: w, height: h, data: buf.into_iter().map(u16::from).collect() }))
}

/// Renders the montage of `row` (rows without stored depth maps get "not stored" panels).
pub fn render_pair(row: &PairRow) -> Result<Canvas> {
    let source = decode_depth(&row.source_depth_png, "source_depth_png")?;
    let condition = decode_depth(&row.condition_depth_png, "condition_depth_png")?;
    let target = decode_depth(&row.target_depth_png, "target_depth_png")?;
    let mask = decode_mask(&row.known_mask_png)?;
    let (pw, ph) = [&source, &condition, &target, &mask]
        .iter()
        .find_map(|i| i.as_ref().map(|i| (i.width, i.height)))
        .unwrap_or(if row.width > 0 && row.height > 0 { (row.width, row.height) } else { (256, 256) });

    // One depth scale: every valid pixel of the three depth maps (known ones for the condition).
    let mut range = (u16::MAX, 0u16);
    let known = |i: usize| mask.as_ref().map_or(true, |m| m.data.get(i).is_some_and(|&v| v > 0));
    for (img, use_mask) in [(&source, false), (&condition, true), (&target, false)] {
        for (i, &v) in img.iter().flat_map(|im| im.data.iter().enumerate()) {
            if v > 0 && v < u16::MAX && (!use_mask || known(i)) {
                range = (range.0.min(v), range.1.max(v));
            }
        }
    }
    if range.0 > range.1 {
        range = (500, 5000);
    }
    let (lo, hi) = (range.0 as f32 / 1000.0, (range.1.max(range.0 + 1)) as f32 / 1000.0);
    let norm = |mm: u16| (mm as f32 / 1000.0 - lo) / (hi - lo);
    let depth_colour = |v: u16| if v == 0 || v == u16::MAX { INVALID } else { turbo(norm(v)) };

    let (w, h) = montage_size(pw, ph);
    let mut c = Canvas::new(w, h, BACKGROUND);
    let title = format!("{}   STATUS {}   UNIT {}", row.pair_key, row.status.as_str(), row.unit_index);
    c.text(PAD as i64, PAD as i64, &title, TEXT, 1);
    let sub = format!(
        "OVERLAP SOURCE {:.3}  TARGET {:.3}   POINTS {} / {}   POSE DRAWS {}",
        row.overlap_source,
        row.overlap_target,
        row.source_points.len(),
        row.target_points.len(),
        row.pose_draws
    );
    c.text(PAD as i64, PAD as i64 + 12, &sub, TEXT, 1);

    let top = (PAD + TITLE_H) as i64;
    let x_of = |k: u32| (PAD + k * (pw + PAD)) as i64;
    let panels: [(&Option<Image>, &str); 4] = [
        (&source, "SOURCE DEPTH"),
        (&condition, "CONDITION (GREY = UNKNOWN)"),
        (&mask, "KNOWN MASK (WHITE = KNOWN)"),
        (&target, "TARGET (INPAINTED)"),
    ];
    for (k, (img, label)) in panels.iter().enumerate() {
        let x = x_of(k as u32);
        match img {
            Some(im) => {
                for (i, &v) in im.data.iter().enumerate() {
                    let colour = match k {
                        1 if !known(i) => UNKNOWN,
                        2 => if v > 0 { [255, 255, 255] } else { [0, 0, 0] },
                        _ => depth_colour(v),
                    };
                    c.set(x + (i as u32 % im.width) as i64, top + (i as u32 / im.width) as i64, colour);
                }
            }
            None => not_stored(&mut c, x, top, pw, ph),
        }
        c.text(x, top + ph as i64 + 5, label, TEXT, 1);
    }
    let clouds = render_clouds(row, pw, ph, lo, hi)?;
    c.blit(x_of(4), top, &clouds);
    c.text(x_of(4), top + ph as i64 + 5, "CLOUDS: RED SRC, GREEN TGT, YELLOW BOTH", TEXT, 1);

    // The shared depth scale.
    let bar_y = top + (ph + LABEL_H) as i64 + 4;
    let bar_w = (3 * pw) as i64;
    for i in 0..bar_w {
        c.fill_rect(PAD as i64 + i, bar_y, 1, 10, turbo(i as f32 / (bar_w - 1) as f32));
    }
    let ly = bar_y + 14;
    c.text(PAD as i64, ly, &format!("{lo:.2} M"), TEXT, 1);
    let hi_label = format!("{hi:.2} M");
    c.text(PAD as i64 + bar_w - super::canvas::text_width(&hi_label, 1), ly, &hi_label, TEXT, 1);
    c.text_centered(PAD as i64 + bar_w / 2, ly, "DEPTH, SHARED SCALE (BLACK = NO DEPTH)", TEXT, 1);
    Ok(c)
}

fn not_stored(c: &mut Canvas, x: i64, y: i64, w: u32, h: u32) {
    c.fill_rect(x, y, w as i64, h as i64, INVALID);
    if w < 80 {
        return;
    }
    c.text_centered(x + w as i64 / 2, y + h as i64 / 2 - text_height(1) / 2, "NOT STORED", UNKNOWN, 1);
}

/// Both clouds seen from the target camera: the source moved by `T_target_from_source`, each point a
/// square splat about one voxel wide, nearest point per pixel and cloud, shaded darker with depth.
fn render_clouds(row: &PairRow, w: u32, h: u32, lo: f32, hi: f32) -> Result<Canvas> {
    let moved = transform_points(&row.source_points, &row_pose(row)?);
    let [fx, fy, cx, cy] = row.target_intrinsics;
    let n = w as usize * h as usize;
    let splat = |pts: &[Point]| -> Vec<f32> {
        let mut z = vec![f32::INFINITY; n];
        for p in pts.iter().filter(|p| p.z > 1e-3) {
            let u = (fx * p.x as f64 / p.z as f64 + cx).round() as i64;
            let v = (fy * p.y as f64 / p.z as f64 + cy).round() as i64;
            let r = ((fx * SPLAT_METRES / p.z as f64).round() as i64).clamp(1, 5);
            for yy in (v - r / 2)..(v - r / 2 + r) {
                for xx in (u - r / 2)..(u - r / 2 + r) {
                    if xx >= 0 && yy >= 0 && xx < w as i64 && yy < h as i64 {
                        let i = yy as usize * w as usize + xx as usize;
                        z[i] = z[i].min(p.z);
                    }
                }
            }
        }
        z
    };
    let (zs, zt) = (splat(&moved), splat(&row.target_points));
    let mut c = Canvas::new(w, h, INVALID);
    let light = |z: f32| 1.0 - 0.6 * ((z - lo) / (hi - lo)).clamp(0.0, 1.0);
    for i in 0..n {
        let (s, t) = (zs[i], zt[i]);
        let colour: Option<Rgb> = match (s.is_finite(), t.is_finite()) {
            (true, true) if (s - t).abs() < BOTH_METRES => Some(shade(BOTH, light(s.min(t)))),
            (true, true) if s < t => Some(shade(SOURCE, light(s))),
            (_, true) => Some(shade(TARGET, light(t))),
            (true, false) => Some(shade(SOURCE, light(s))),
            (false, false) => None,
        };
        if let Some(col) = colour {
            c.set((i % w as usize) as i64, (i / w as usize) as i64, col);
        }
    }
    Ok(c)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::tests_support::empty_row;
    use crate::sources::depth_png::encode_depth_png;

    #[test]
    fn montage_has_the_documented_size_and_colours_known_and_unknown_pixels() {
        let mut row = empty_row();
        let d: Vec<u16> = (0..16).map(|i| if i == 0 { 0 } else { 1000 + 100 * i }).collect();
        row.source_depth_png = encode_depth_png(4, 4, &d).unwrap();
        row.condition_depth_png = row.source_depth_png.clone();
        let mask: Vec<bool> = (0..16).map(|i| i % 2 == 0).collect();
        row.known_mask_png = crate::stages::pack::encode_mask_png(&mask, 4, 4).unwrap();
        row.source_points = vec![Point::new(0.0, 0.0, 1.0)];
        row.target_points = vec![Point::new(0.0, 0.0, 1.0)];
        let c = render_pair(&row).unwrap();
        assert_eq!((c.width, c.height), montage_size(4, 4));
        let top = PAD + TITLE_H;
        assert_eq!(c.get(PAD, top), INVALID); // source pixel 0: no depth
        assert_eq!(c.get(PAD + 1, top), turbo(0.0)); // the nearest valid depth starts the scale
        assert_eq!(c.get(PAD + 4 + PAD + 1, top), UNKNOWN); // condition pixel 1 is unknown
        assert_eq!(c.get(PAD + 2 * (4 + PAD), top), [255, 255, 255]); // mask: pixel 0 known
        assert_eq!(c.get(PAD + 2 * (4 + PAD) + 1, top), [0, 0, 0]);
        assert_eq!(c.get(PAD + 3 * (4 + PAD), top + 1), INVALID); // target not stored
        // Both clouds hit pixel (2, 2) of the last panel at the same depth.
        assert_eq!(c.get(PAD + 4 * (4 + PAD) + 2, top + 2), shade(BOTH, 1.0));
    }
}
