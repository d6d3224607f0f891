//! Plain row-major image buffers.

/// Why an image could not be built.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ImageError {
    /// The pixel buffer does not hold `width * height` pixels.
    #[error("a {width}x{height} image needs {expected} pixels, got {found}")]
    SizeMismatch {
        /// Width in pixels.
        width: u32,
        /// Height in pixels.
        height: u32,
        /// `width * height`.
        expected: usize,
        /// Pixels supplied.
        found: usize,
    },
}

/// A row-major image: pixel `(x, y)` (column x, row y, origin top-left) is at
/// `data[y * width + x]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Image<T> {
    width: u32,
    height: u32,
    data: Vec<T>,
}

/// 8-bit grey image.
pub type GrayImage = Image<u8>;
/// 8-bit RGB image, channels in R, G, B order.
pub type RgbImage = Image<[u8; 3]>;
/// Depth image in metres along the optical axis; 0.0 marks "no measurement".
pub type DepthImage = Image<f32>;

impl<T: Copy> Image<T> {
    /// Wraps a buffer of `width * height` pixels.
    pub fn from_vec(width: u32, height: u32, data: Vec<T>) -> Result<Self, ImageError> {
        let expected = width as usize * height as usize;
        if data.len() != expected {
            return Err(ImageError::SizeMismatch {
                width,
                height,
                expected,
                found: data.len(),
            });
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// An image with every pixel set to `value`.
    pub fn filled(width: u32, height: u32, value: T) -> Self {
        Self {
            width,
            height,
            data: vec![value; width as usize * height as usize],
        }
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// The pixel at column `x`, row `y`, or `None` outside the image.
    pub fn get(&self, x: u32, y: u32) -> Option<T> {
        if x >= self.width || y >= self.height {
            return None;
        }
        self.data
            .get(y as usize * self.width as usize + x as usize)
            .copied()
    }

    /// Mutable access to the pixel at `(x, y)`, or `None` outside the image.
    pub fn get_mut(&mut self, x: u32, y: u32) -> Option<&mut T> {
        if x >= self.width || y >= self.height {
            return None;
        }
        self.data
            .get_mut(y as usize * self.width as usize + x as usize)
    }

    /// All pixels, row-major.
    pub fn as_slice(&self) -> &[T] {
        &self.data
    }

    /// All pixels, row-major, mutable.
    pub fn as_mut_slice(&mut self) -> &mut [T] {
        &mut self.data
    }

    /// Row `y` as a slice, or `None` outside the image.
    pub fn row(&self, y: u32) -> Option<&[T]> {
        let w = self.width as usize;
        let start = y as usize * w;
        self.data.get(start..start + w)
    }

    /// Consumes the image and returns its buffer.
    pub fn into_vec(self) -> Vec<T> {
        self.data
    }

    /// Applies `f` to every pixel.
    pub fn map<U: Copy>(&self, f: impl Fn(T) -> U) -> Image<U> {
        Image {
            width: self.width,
            height: self.height,
            data: self.data.iter().map(|&p| f(p)).collect(),
        }
    }
}

impl RgbImage {
    /// Luma with the ITU-R BT.601 weights OpenCV uses for `COLOR_RGB2GRAY`
    /// (0.299 R + 0.587 G + 0.114 B, rounded).
    pub fn to_gray(&self) -> GrayImage {
        self.map(|[r, g, b]| {
            let y = (4899 * u32::from(r) + 9617 * u32::from(g) + 1868 * u32::from(b) + 8192) >> 14;
            y.min(255) as u8
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn indexing_is_row_major_and_bounds_checked() {
        let img = Image::from_vec(3, 2, vec![0u8, 1, 2, 3, 4, 5]).unwrap();
        assert_eq!(img.get(2, 1), Some(5));
        assert_eq!(img.get(0, 1), Some(3));
        assert_eq!(img.get(3, 0), None);
        assert_eq!(img.row(1), Some(&[3u8, 4, 5][..]));
        assert!(Image::from_vec(3, 2, vec![0u8; 5]).is_err());
    }

    #[test]
    fn gray_conversion_matches_bt601() {
        let img = Image::from_vec(3, 1, vec![[255, 0, 0], [0, 255, 0], [255, 255, 255]]).unwrap();
        let g = img.to_gray();
        assert_eq!(g.as_slice(), &[76, 150, 255]);
    }
}
