//! Binary masks at image resolution.

use serde::{Deserialize, Serialize};

/// A row-major binary mask.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Mask {
    pub width: u32,
    pub height: u32,
    pub data: Vec<bool>,
}

impl Mask {
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            data: vec![false; width as usize * height as usize],
        }
    }

    #[inline]
    pub fn get(&self, x: u32, y: u32) -> bool {
        x < self.width
            && y < self.height
            && self.data[y as usize * self.width as usize + x as usize]
    }

    #[inline]
    pub fn set(&mut self, x: u32, y: u32, v: bool) {
        if x < self.width && y < self.height {
            self.data[y as usize * self.width as usize + x as usize] = v;
        }
    }

    pub fn count(&self) -> usize {
        self.data.iter().filter(|&&b| b).count()
    }

    /// Mask filled inside the pixel box [x1, x2) x [y1, y2) (clamped).
    pub fn from_box(width: u32, height: u32, b: [f32; 4]) -> Self {
        let mut m = Self::new(width, height);
        let [x1, y1, x2, y2] = pixel_box(width, height, b);
        for y in y1..y2 {
            for x in x1..x2 {
                m.set(x, y, true);
            }
        }
        m
    }

    /// Intersection over union of two masks of the same size (0 when both empty).
    pub fn iou(&self, other: &Mask) -> f64 {
        let (mut i, mut u) = (0usize, 0usize);
        for (a, b) in self.data.iter().zip(&other.data) {
            i += (*a && *b) as usize;
            u += (*a || *b) as usize;
        }
        if u == 0 {
            0.0
        } else {
            i as f64 / u as f64
        }
    }
}

/// The pixels [x1, x2) x [y1, y2) that [`Mask::from_box`] fills for box `b` in an image of
/// `width` x `height`, as [x1, y1, x2, y2]: x2 and y2 clamped to the image; empty when
/// x1 >= x2 or y1 >= y2 (then x1 or y1 may lie beyond the image).
pub(crate) fn pixel_box(width: u32, height: u32, b: [f32; 4]) -> [u32; 4] {
    [
        b[0].max(0.0).floor() as u32,
        b[1].max(0.0).floor() as u32,
        (b[2].ceil().max(0.0) as u32).min(width),
        (b[3].ceil().max(0.0) as u32).min(height),
    ]
}
