//! Pixels of ROS 2 image messages to stride's images and back.
//!
//! Colour: `sensor_msgs/Image` in `rgb8`, `bgr8`, `rgba8`, `bgra8` or `mono8`, or a
//! `sensor_msgs/CompressedImage` in PNG or JPEG. Depth: `16UC1` (or `mono16`) in raw units
//! (`units_per_m` of them per metre: 1000 by REP 118), `32FC1` in metres (NaN or infinity:
//! no return), or a compressed 16-bit PNG (plain, or after the 12-byte header of
//! `compressedDepth`). Rows are read `step` bytes apart, as the message says.

use super::ros2::{CompressedImageMsg, ImageMsg};
use crate::png_io::{decode_depth_raw, decode_rgb, depth_from_raw};
use std::path::Path;
use stride_core::image::{DepthImage, Image, RgbImage};

/// An image message's payload, raw or compressed.
#[derive(Debug, Clone, PartialEq)]
pub enum ImagePayload<'a> {
    /// `sensor_msgs/Image`.
    Raw(ImageMsg<'a>),
    /// `sensor_msgs/CompressedImage`.
    Compressed(CompressedImageMsg<'a>),
}

/// Rows of `bytes_per_px`-byte pixels from a raw image, checked against its size and step
/// (before anything of the image's size is allocated).
fn rows<'a>(m: &ImageMsg<'a>, bytes_per_px: usize) -> Result<Vec<&'a [u8]>, String> {
    let (w, h, step) = (m.width as usize, m.height as usize, m.step as usize);
    if w == 0 || h == 0 {
        return Err(format!("an empty {w}x{h} image"));
    }
    let row_bytes = w * bytes_per_px;
    if step < row_bytes {
        return Err(format!(
            "step {step} is shorter than a row of {w} {} pixels ({row_bytes} bytes)",
            m.encoding
        ));
    }
    let need = step * (h - 1) + row_bytes;
    if m.data.len() < need {
        return Err(format!(
            "{} bytes of pixels, a {w}x{h} {} image with step {step} needs {need}",
            m.data.len(),
            m.encoding
        ));
    }
    Ok((0..h)
        .filter_map(|r| m.data.get(r * step..r * step + row_bytes))
        .collect())
}

/// The colour image of a message.
pub fn rgb_image(payload: &ImagePayload) -> Result<RgbImage, String> {
    match payload {
        ImagePayload::Compressed(c) => decode_rgb(c.data, Path::new(""))
            .map_err(|e| format!("{} image: {}", c.format, e.detail())),
        ImagePayload::Raw(m) => {
            let (bpp, order): (usize, [usize; 3]) = match m.encoding.as_str() {
                "rgb8" => (3, [0, 1, 2]),
                "bgr8" => (3, [2, 1, 0]),
                "rgba8" => (4, [0, 1, 2]),
                "bgra8" => (4, [2, 1, 0]),
                "mono8" | "8UC1" => (1, [0, 0, 0]),
                other => {
                    return Err(format!(
                        "colour encoding '{other}' is not supported (rgb8, bgr8, rgba8, \
                         bgra8, mono8)"
                    ))
                }
            };
            let rows = rows(m, bpp)?;
            let mut px = Vec::with_capacity(m.width as usize * m.height as usize);
            for row in rows {
                px.extend(
                    row.chunks_exact(bpp)
                        .map(|p| [p[order[0]], p[order[1]], p[order[2]]]),
                );
            }
            Image::from_vec(m.width, m.height, px).map_err(|e| e.to_string())
        }
    }
}

/// The raw 16-bit depth units of a message, when it holds them (`16UC1`, `mono16`, PNG).
fn depth_raw_u16(payload: &ImagePayload) -> Result<Option<Image<u16>>, String> {
    match payload {
        ImagePayload::Compressed(c) => {
            let png = if c.format.contains("compressedDepth") {
                c.data.get(12..).unwrap_or(&[])
            } else {
                c.data
            };
            decode_depth_raw(png, Path::new(""))
                .map(Some)
                .map_err(|e| format!("{} depth image: {}", c.format, e.detail()))
        }
        ImagePayload::Raw(m) if matches!(m.encoding.as_str(), "16UC1" | "mono16") => {
            let rows = rows(m, 2)?;
            let mut px = Vec::with_capacity(m.width as usize * m.height as usize);
            for row in rows {
                px.extend(row.chunks_exact(2).map(|b| {
                    if m.is_bigendian != 0 {
                        u16::from_be_bytes([b[0], b[1]])
                    } else {
                        u16::from_le_bytes([b[0], b[1]])
                    }
                }));
            }
            Image::from_vec(m.width, m.height, px)
                .map(Some)
                .map_err(|e| e.to_string())
        }
        ImagePayload::Raw(_) => Ok(None),
    }
}

/// The depth image (m, 0 = no return) of a message; `units_per_m` scales 16-bit units.
pub fn depth_image(payload: &ImagePayload, units_per_m: f64) -> Result<DepthImage, String> {
    if let Some(raw) = depth_raw_u16(payload)? {
        return Ok(depth_from_raw(&raw, units_per_m));
    }
    let ImagePayload::Raw(m) = payload else {
        return Err("unreachable: compressed depth is 16-bit".into());
    };
    if m.encoding != "32FC1" {
        return Err(format!(
            "depth encoding '{}' is not supported (16UC1, mono16, 32FC1, or a 16-bit PNG)",
            m.encoding
        ));
    }
    let rows = rows(m, 4)?;
    let mut px = Vec::with_capacity(m.width as usize * m.height as usize);
    for row in rows {
        px.extend(row.chunks_exact(4).map(|b| {
            let b = [b[0], b[1], b[2], b[3]];
            let v = if m.is_bigendian != 0 {
                f32::from_be_bytes(b)
            } else {
                f32::from_le_bytes(b)
            };
            if v.is_finite() && v > 0.0 {
                v
            } else {
                0.0
            }
        }));
    }
    Image::from_vec(m.width, m.height, px).map_err(|e| e.to_string())
}

/// The raw 16-bit units of a depth message, for lossless conversion (a `32FC1` image is
/// refused: it holds metres, not units).
pub fn depth_units(payload: &ImagePayload) -> Result<Image<u16>, String> {
    depth_raw_u16(payload)?.ok_or_else(|| {
        "a 32FC1 depth image holds metres, not 16-bit units: it cannot be written as a \
         TUM depth PNG without rounding"
            .to_owned()
    })
}

/// Colour pixels as a packed `rgb8` buffer (row step `3 * width`).
pub fn rgb8_bytes(img: &RgbImage) -> Vec<u8> {
    img.as_slice().iter().flatten().copied().collect()
}

/// Depth units as a packed little-endian `16UC1` buffer (row step `2 * width`).
pub fn u16_le_bytes(img: &Image<u16>) -> Vec<u8> {
    img.as_slice()
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mcap::ros2::Header;

    fn raw<'a>(encoding: &str, w: u32, h: u32, step: u32, data: &'a [u8]) -> ImagePayload<'a> {
        ImagePayload::Raw(ImageMsg {
            header: Header::default(),
            height: h,
            width: w,
            encoding: encoding.into(),
            is_bigendian: 0,
            step,
            data,
        })
    }

    #[test]
    fn colour_encodings_and_row_padding() {
        // 2x2 bgr8 with 2 bytes of padding per row.
        let data = [1, 2, 3, 4, 5, 6, 0, 0, 7, 8, 9, 10, 11, 12, 0, 0];
        let img = rgb_image(&raw("bgr8", 2, 2, 8, &data)).unwrap();
        assert_eq!(
            img.as_slice(),
            &[[3, 2, 1], [6, 5, 4], [9, 8, 7], [12, 11, 10]]
        );
        let mono = rgb_image(&raw("mono8", 2, 1, 2, &[5, 9])).unwrap();
        assert_eq!(mono.as_slice(), &[[5, 5, 5], [9, 9, 9]]);
        let e = rgb_image(&raw("yuv422", 2, 1, 4, &[0; 4])).unwrap_err();
        assert!(e.contains("'yuv422' is not supported"), "{e}");
        let e = rgb_image(&raw("rgb8", 2, 2, 6, &[0; 11])).unwrap_err();
        assert!(e.contains("11 bytes of pixels"), "{e}");
    }

    #[test]
    fn depth_encodings() {
        let mm = [0xE8, 0x03, 0, 0]; // 1000, 0
        let d = depth_image(&raw("16UC1", 2, 1, 4, &mm), 1000.0).unwrap();
        assert_eq!(d.as_slice(), &[1.0, 0.0]);
        let mut f = Vec::new();
        for v in [1.25f32, f32::NAN] {
            f.extend_from_slice(&v.to_le_bytes());
        }
        let d = depth_image(&raw("32FC1", 2, 1, 8, &f), 1000.0).unwrap();
        assert_eq!(d.as_slice(), &[1.25, 0.0]);
        assert!(depth_units(&raw("32FC1", 2, 1, 8, &f)).is_err());
        let e = depth_image(&raw("rgb8", 1, 1, 3, &[0; 3]), 1000.0).unwrap_err();
        assert!(e.contains("depth encoding 'rgb8'"), "{e}");
    }
}
