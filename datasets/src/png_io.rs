//! Image decoding and encoding: colour images (PNG or JPEG) and 16-bit PNG depth images.

use crate::error::DatasetError;
use png::{BitDepth, ColorType, Transformations};
use std::io::Cursor;
use std::path::Path;
use stride_core::image::{DepthImage, GrayImage, Image, RgbImage};

fn image_err(path: &Path, message: impl Into<String>) -> DatasetError {
    DatasetError::Image {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// Decoded pixel bytes with their layout.
struct Raw {
    width: u32,
    height: u32,
    color: ColorType,
    depth: BitDepth,
    bytes: Vec<u8>,
}

fn decode_raw(
    bytes: &[u8],
    path: &Path,
    transformations: Transformations,
) -> Result<Raw, DatasetError> {
    let mut decoder = png::Decoder::new(Cursor::new(bytes));
    decoder.set_transformations(transformations);
    let mut reader = decoder
        .read_info()
        .map_err(|e| image_err(path, format!("not a readable PNG: {e}")))?;
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| image_err(path, "PNG too large to decode"))?;
    let mut buf = vec![0u8; size];
    let info = reader
        .next_frame(&mut buf)
        .map_err(|e| image_err(path, format!("corrupt PNG data: {e}")))?;
    buf.truncate(info.buffer_size());
    Ok(Raw {
        width: info.width,
        height: info.height,
        color: info.color_type,
        depth: info.bit_depth,
        bytes: buf,
    })
}

fn read_file(path: &Path) -> Result<Vec<u8>, DatasetError> {
    std::fs::read(path).map_err(|e| DatasetError::io(path, e))
}

const PNG_MAGIC: &[u8] = b"\x89PNG";
const JPEG_MAGIC: &[u8] = &[0xFF, 0xD8, 0xFF];

/// Decodes a colour image to 8-bit RGB, by its content (not its name): a PNG (8 or 16 bit;
/// grey, grey+alpha, RGB, RGBA or palette; alpha is dropped, 16-bit channels keep their high
/// byte) or a JPEG (colour or grey). Anything else is an error naming the file.
pub fn decode_rgb(bytes: &[u8], path: &Path) -> Result<RgbImage, DatasetError> {
    if bytes.starts_with(JPEG_MAGIC) {
        return decode_jpeg(bytes, path);
    }
    if !bytes.starts_with(PNG_MAGIC) {
        return Err(image_err(
            path,
            "not a PNG or JPEG image (colour images must be one of the two)",
        ));
    }
    let raw = decode_raw(
        bytes,
        path,
        Transformations::EXPAND | Transformations::STRIP_16,
    )?;
    let px: Vec<[u8; 3]> = match raw.color {
        ColorType::Rgb => raw
            .bytes
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect(),
        ColorType::Rgba => raw
            .bytes
            .chunks_exact(4)
            .map(|c| [c[0], c[1], c[2]])
            .collect(),
        ColorType::Grayscale => raw.bytes.iter().map(|&g| [g, g, g]).collect(),
        ColorType::GrayscaleAlpha => raw
            .bytes
            .chunks_exact(2)
            .map(|c| [c[0], c[0], c[0]])
            .collect(),
        ColorType::Indexed => return Err(image_err(path, "palette PNG was not expanded")),
    };
    Image::from_vec(raw.width, raw.height, px).map_err(|e| image_err(path, e.to_string()))
}

/// Decodes a JPEG (baseline or progressive; colour or grey) to 8-bit RGB.
fn decode_jpeg(bytes: &[u8], path: &Path) -> Result<RgbImage, DatasetError> {
    use zune_core::colorspace::ColorSpace;
    use zune_core::options::DecoderOptions;
    let options = DecoderOptions::default().jpeg_set_out_colorspace(ColorSpace::RGB);
    let mut decoder = zune_jpeg::JpegDecoder::new_with_options(Cursor::new(bytes), options);
    let pixels = decoder
        .decode()
        .map_err(|e| image_err(path, format!("corrupt or unsupported JPEG: {e:?}")))?;
    let info = decoder
        .info()
        .ok_or_else(|| image_err(path, "JPEG without a frame header"))?;
    let px: Vec<[u8; 3]> = match decoder.output_colorspace() {
        Some(ColorSpace::RGB) => pixels.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        Some(ColorSpace::Luma) => pixels.iter().map(|&g| [g, g, g]).collect(),
        other => {
            return Err(image_err(
                path,
                format!("JPEG decoded to an unsupported colour space {other:?}"),
            ))
        }
    };
    Image::from_vec(u32::from(info.width), u32::from(info.height), px)
        .map_err(|e| image_err(path, e.to_string()))
}

/// Reads and decodes a colour image file (PNG or JPEG); see [`decode_rgb`].
pub fn read_rgb(path: &Path) -> Result<RgbImage, DatasetError> {
    decode_rgb(&read_file(path)?, path)
}

/// Decodes a 16-bit single-channel depth PNG to metres: `raw / depth_scale`, 0 stays 0
/// (no measurement). Any other PNG format is an error naming the file.
pub fn decode_depth(
    bytes: &[u8],
    path: &Path,
    depth_scale: f64,
) -> Result<DepthImage, DatasetError> {
    Ok(depth_from_raw(&decode_depth_raw(bytes, path)?, depth_scale))
}

/// Decodes a 16-bit single-channel depth PNG to its raw units (as stored, 0 = no
/// measurement). Any other PNG format is an error naming the file.
pub fn decode_depth_raw(bytes: &[u8], path: &Path) -> Result<Image<u16>, DatasetError> {
    if !bytes.starts_with(PNG_MAGIC) {
        return Err(image_err(
            path,
            "a depth image must be a 16-bit single-channel PNG; this file is not a PNG \
             (a lossy format such as JPEG cannot hold depth)",
        ));
    }
    let raw = decode_raw(bytes, path, Transformations::IDENTITY)?;
    if raw.color != ColorType::Grayscale || raw.depth != BitDepth::Sixteen {
        return Err(image_err(
            path,
            format!(
                "a depth image must be a 16-bit single-channel PNG, this one is {:?} with {:?} bits",
                raw.color, raw.depth
            ),
        ));
    }
    let px: Vec<u16> = raw
        .bytes
        .chunks_exact(2)
        .map(|c| u16::from_be_bytes([c[0], c[1]]))
        .collect();
    Image::from_vec(raw.width, raw.height, px).map_err(|e| image_err(path, e.to_string()))
}

/// Raw depth units to metres: `raw / units_per_m`, 0 stays 0.
pub fn depth_from_raw(raw: &Image<u16>, units_per_m: f64) -> DepthImage {
    let inv = 1.0 / units_per_m;
    raw.map(|v| (f64::from(v) * inv) as f32)
}

/// Reads and decodes a depth PNG file; see [`decode_depth`].
pub fn read_depth(path: &Path, depth_scale: f64) -> Result<DepthImage, DatasetError> {
    decode_depth(&read_file(path)?, path, depth_scale)
}

fn encode(
    width: u32,
    height: u32,
    color: ColorType,
    depth: BitDepth,
    data: &[u8],
) -> Result<Vec<u8>, png::EncodingError> {
    let mut out = Vec::with_capacity(data.len() / 2 + 1024);
    {
        let mut enc = png::Encoder::new(&mut out, width, height);
        enc.set_color(color);
        enc.set_depth(depth);
        enc.set_compression(png::Compression::Fast);
        let mut writer = enc.write_header()?;
        writer.write_image_data(data)?;
        writer.finish()?;
    }
    Ok(out)
}

/// Encodes an 8-bit RGB image as PNG bytes.
pub fn encode_rgb(img: &RgbImage) -> Result<Vec<u8>, String> {
    let data: Vec<u8> = img.as_slice().iter().flatten().copied().collect();
    encode(
        img.width(),
        img.height(),
        ColorType::Rgb,
        BitDepth::Eight,
        &data,
    )
    .map_err(|e| e.to_string())
}

/// Encodes an 8-bit grey image as PNG bytes.
pub fn encode_gray(img: &GrayImage) -> Result<Vec<u8>, String> {
    encode(
        img.width(),
        img.height(),
        ColorType::Grayscale,
        BitDepth::Eight,
        img.as_slice(),
    )
    .map_err(|e| e.to_string())
}

/// Encodes raw 16-bit depth units as a single-channel PNG (big-endian, as PNG requires).
pub fn encode_depth_u16(img: &Image<u16>) -> Result<Vec<u8>, String> {
    let data: Vec<u8> = img
        .as_slice()
        .iter()
        .flat_map(|v| v.to_be_bytes())
        .collect();
    encode(
        img.width(),
        img.height(),
        ColorType::Grayscale,
        BitDepth::Sixteen,
        &data,
    )
    .map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_round_trip_in_metres() {
        let raw = Image::from_vec(2, 2, vec![0u16, 5000, 10000, 65535]).unwrap();
        let png = encode_depth_u16(&raw).unwrap();
        let d = decode_depth(&png, Path::new("d.png"), 5000.0).unwrap();
        assert_eq!(d.as_slice(), &[0.0, 1.0, 2.0, 13.107]);
    }

    #[test]
    fn rgb_round_trip_and_gray_expansion() {
        let img = Image::from_vec(2, 1, vec![[1u8, 2, 3], [250, 251, 252]]).unwrap();
        let png = encode_rgb(&img).unwrap();
        assert_eq!(decode_rgb(&png, Path::new("c.png")).unwrap(), img);
        let g = Image::from_vec(2, 1, vec![7u8, 9]).unwrap();
        let png = encode_gray(&g).unwrap();
        let rgb = decode_rgb(&png, Path::new("g.png")).unwrap();
        assert_eq!(rgb.as_slice(), &[[7, 7, 7], [9, 9, 9]]);
    }

    fn testdata(name: &str) -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("testdata")
            .join(name)
    }

    /// The fixtures (made with Pillow, quality 95): red = 10 x, green = 15 y, blue = 128.
    #[test]
    fn jpeg_colour_grey_and_progressive_decode_to_rgb() {
        for name in ["gradient_24x16.jpg", "gradient_24x16_progressive.jpg"] {
            let bytes = std::fs::read(testdata(name)).unwrap();
            let img = decode_rgb(&bytes, Path::new(name)).unwrap();
            assert_eq!((img.width(), img.height()), (24, 16));
            for (x, y) in [(0u32, 0u32), (12, 8), (23, 15)] {
                let [r, g, b] = img.as_slice()[(y * 24 + x) as usize];
                let near = |a: u8, e: u32| (i64::from(a) - i64::from(e)).abs() <= 12;
                assert!(
                    near(r, 10 * x) && near(g, 15 * y) && near(b, 128),
                    "{name} ({x}, {y}): {r} {g} {b}"
                );
            }
        }
        let bytes = std::fs::read(testdata("grey_24x16.jpg")).unwrap();
        let img = decode_rgb(&bytes, Path::new("grey")).unwrap();
        let [r, g, b] = img.as_slice()[23];
        assert!(r == g && g == b && (218..=242).contains(&r), "{r} {g} {b}");
    }

    #[test]
    fn wrong_formats_and_garbage_are_named() {
        let g = Image::from_vec(1, 1, vec![7u8]).unwrap();
        let png = encode_gray(&g).unwrap();
        let e = decode_depth(&png, Path::new("depth/x.png"), 5000.0)
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("depth/x.png: a depth image must be a 16-bit"),
            "{e}"
        );
        let e = decode_rgb(b"not a png", Path::new("rgb/y.png"))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("rgb/y.png: not a PNG or JPEG image"), "{e}");
        let e = decode_rgb(b"\x89PNG garbage", Path::new("rgb/z.png"))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("rgb/z.png: not a readable PNG"), "{e}");
        let jpeg = std::fs::read(testdata("gradient_24x16.jpg")).unwrap();
        let e = decode_depth(&jpeg, Path::new("depth/j.png"), 5000.0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("this file is not a PNG"), "{e}");
        let e = decode_rgb(&jpeg[..jpeg.len() / 3], Path::new("rgb/t.jpg"))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("rgb/t.jpg: corrupt or unsupported JPEG"),
            "{e}"
        );
        let mut truncated = encode_rgb(&Image::filled(64, 64, [9u8, 9, 9])).unwrap();
        truncated.truncate(truncated.len() / 2);
        assert!(decode_rgb(&truncated, Path::new("t.png")).is_err());
    }
}
