//! Axis-aligned 3D boxes and the metrics of FORMATS §3.

use nalgebra::Point3;
use serde::{Deserialize, Serialize};

/// Axis-aligned box in the scene's output frame (metres).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Aabb {
    pub min: [f64; 3],
    pub max: [f64; 3],
}

impl Aabb {
    pub fn new(min: [f64; 3], max: [f64; 3]) -> Self {
        Self { min, max }
    }

    /// Smallest box holding every point; `None` for no points.
    pub fn from_points<'a, I: IntoIterator<Item = &'a Point3<f64>>>(points: I) -> Option<Self> {
        let mut it = points.into_iter();
        let first = it.next()?;
        let mut b = Aabb { min: [first.x, first.y, first.z], max: [first.x, first.y, first.z] };
        for p in it {
            for i in 0..3 {
                b.min[i] = b.min[i].min(p[i]);
                b.max[i] = b.max[i].max(p[i]);
            }
        }
        Some(b)
    }

    pub fn center(&self) -> [f64; 3] {
        [0, 1, 2].map(|i| 0.5 * (self.min[i] + self.max[i]))
    }

    pub fn size(&self) -> [f64; 3] {
        [0, 1, 2].map(|i| (self.max[i] - self.min[i]).max(0.0))
    }

    pub fn volume(&self) -> f64 {
        self.size().iter().product()
    }

    /// Intersection volume / union volume (0 when disjoint or both empty).
    pub fn iou(&self, other: &Aabb) -> f64 {
        let mut inter = 1.0;
        for i in 0..3 {
            let lo = self.min[i].max(other.min[i]);
            let hi = self.max[i].min(other.max[i]);
            if hi <= lo {
                return 0.0;
            }
            inter *= hi - lo;
        }
        let union = self.volume() + other.volume() - inter;
        if union <= 0.0 {
            0.0
        } else {
            inter / union
        }
    }

    /// Euclidean distance between the two centres.
    pub fn center_distance(&self, other: &Aabb) -> f64 {
        let (a, b) = (self.center(), other.center());
        ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
    }

    pub fn contains(&self, p: &Point3<f64>, tolerance: f64) -> bool {
        (0..3).all(|i| p[i] >= self.min[i] - tolerance && p[i] <= self.max[i] + tolerance)
    }
}
