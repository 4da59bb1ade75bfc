//! The grid of sample cells the depth segmenter grows over, and its neighbourhoods.

/// A grid of sample cells (stride `s` colour pixels, at least one depth pixel) over the box
/// plus a margin.
pub(super) struct Grid {
    pub(super) x0: u32,
    pub(super) y0: u32,
    pub(super) s: u32,
    pub(super) w: usize,
    pub(super) h: usize,
    /// depth in metres (0 = none)
    pub(super) z: Vec<f64>,
    /// height along the output frame's z axis
    pub(super) height: Vec<f64>,
    /// horizontal distance from the camera's centre in the output frame
    pub(super) reach: Vec<f64>,
    pub(super) rgb: Vec<[u8; 3]>,
    /// cell centre inside the query box
    pub(super) inb: Vec<bool>,
    /// grid rectangle of the box: gx0..gx1, gy0..gy1
    pub(super) b: [usize; 4],
    /// Cells on a depth edge (see [`super::DepthSegmenter::mark_edges`]): never grown into.
    pub(super) edge: Vec<bool>,
}

impl Grid {
    pub(super) fn neighbours(&self, i: usize) -> [Option<usize>; 4] {
        crate::vision::common::grid_neighbours(i, self.w, self.h)
    }

    /// The 4-connected components of the cells for which `member` holds, each as its
    /// cells, in the order of their first cell in the grid.
    pub(super) fn components(&self, member: impl Fn(usize) -> bool) -> Vec<Vec<usize>> {
        self.joined(member, |_, _| true)
    }

    /// [`Self::components`] where neighbours `i`, `j` join only when `join(i, j)` holds.
    pub(super) fn joined(
        &self,
        member: impl Fn(usize) -> bool,
        join: impl Fn(usize, usize) -> bool,
    ) -> Vec<Vec<usize>> {
        let mut seen = vec![false; self.z.len()];
        let mut out = Vec::new();
        for start in 0..self.z.len() {
            if seen[start] || !member(start) {
                continue;
            }
            seen[start] = true;
            let mut piece = vec![start];
            let mut k = 0;
            while k < piece.len() {
                let i = piece[k];
                for j in self.neighbours(i).into_iter().flatten() {
                    if !seen[j] && member(j) && join(i, j) {
                        seen[j] = true;
                        piece.push(j);
                    }
                }
                k += 1;
            }
            out.push(piece);
        }
        out
    }

    /// Which edges of the frame (`size`: the image's) cell `i` lies on: left, top, right,
    /// bottom.
    pub(super) fn frame_edges(&self, i: usize, size: (u32, u32)) -> [bool; 4] {
        let s = self.s as usize;
        let (x, y) = (
            self.x0 as usize + (i % self.w) * s,
            self.y0 as usize + (i / self.w) * s,
        );
        [
            x == 0,
            y == 0,
            x + s >= size.0 as usize,
            y + s >= size.1 as usize,
        ]
    }

    /// Share of the region's cells that lie outside the box (1 for an empty region).
    pub(super) fn outside_share(&self, region: &[bool]) -> f64 {
        let total = region.iter().filter(|&&b| b).count();
        let outside = (0..region.len())
            .filter(|&i| region[i] && !self.inb[i])
            .count();
        if total == 0 {
            1.0
        } else {
            outside as f64 / total as f64
        }
    }
}
