//! The renderer's output: per pixel the camera-RGB signal rate.

/// A linear image of camera-RGB signal rates: for each photosite position and colour channel,
/// photo-electrons per second that a photosite of that channel would collect (before noise,
/// dark level and quantisation, which the sensor model adds). Row-major, row 0 at the top.
#[derive(Debug, Clone, PartialEq)]
pub struct RadianceImage {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// `width * height` RGB triples, row-major.
    pub data: Vec<[f32; 3]>,
}

impl RadianceImage {
    /// An all-zero (black) image.
    pub fn black(width: usize, height: usize) -> Self {
        RadianceImage { width, height, data: vec![[0.0; 3]; width * height] }
    }

    /// An image with the same rate everywhere.
    pub fn filled(width: usize, height: usize, rate: [f32; 3]) -> Self {
        RadianceImage { width, height, data: vec![rate; width * height] }
    }

    /// The pixel at column `x`, row `y`.
    pub fn at(&self, x: usize, y: usize) -> [f32; 3] {
        self.data[y * self.width + x]
    }

    /// Largest channel value in the image.
    pub fn max_value(&self) -> f32 {
        self.data.iter().flat_map(|p| p.iter().copied()).fold(0.0, f32::max)
    }
}
