//! Mask post-processing of the paper: one square erosion, then keep the largest
//! 8-connected components.

use image::{GrayImage, Luma};
use imageproc::distance_transform::Norm;
use imageproc::region_labelling::{connected_components, Connectivity};

use super::Mask;

fn to_gray(mask: &Mask) -> GrayImage {
    let data = mask
        .data
        .iter()
        .map(|&b| if b { 255u8 } else { 0 })
        .collect();
    // Size always matches: Mask keeps width * height entries.
    GrayImage::from_raw(mask.width, mask.height, data)
        .unwrap_or_else(|| GrayImage::new(mask.width, mask.height))
}

/// Erode with a `kernel` x `kernel` all-ones square. Pixels outside the image count as
/// foreground (so a mask touching the border is not eaten from that side, as in OpenCV).
/// Even kernels are rounded up to the next odd size; 0 and 1 return the mask unchanged.
pub fn erode_square(mask: &Mask, kernel: u32) -> Mask {
    square_op(mask, kernel, imageproc::morphology::erode)
}

/// Apply a square (L-infinity) morphological operator of side `kernel` (0/1: unchanged).
fn square_op(mask: &Mask, kernel: u32, op: fn(&GrayImage, Norm, u8) -> GrayImage) -> Mask {
    if kernel <= 1 || mask.count() == 0 {
        return mask.clone();
    }
    let radius = (kernel / 2).min(254) as u8;
    // Only the mask's bounding box grown by the radius can change; with one more pixel of
    // background around it, working on that crop gives the whole image's result.
    let Some(b) = bounds(mask, u32::from(radius) + 1) else {
        return mask.clone();
    };
    let out = op(&to_gray(&crop(mask, b)), Norm::LInf, radius);
    let part = Mask {
        width: out.width(),
        height: out.height(),
        data: out.pixels().map(|p| p[0] > 0).collect(),
    };
    paste(mask.width, mask.height, &part, b)
}

/// A `width` x `height` mask holding `part` at the top-left corner of `b`, empty elsewhere.
fn paste(width: u32, height: u32, part: &Mask, b: [u32; 4]) -> Mask {
    let mut out = Mask::new(width, height);
    for y in b[1]..b[3] {
        let dst = (y * width + b[0]) as usize;
        let src = ((y - b[1]) * part.width) as usize;
        out.data[dst..dst + part.width as usize]
            .copy_from_slice(&part.data[src..src + part.width as usize]);
    }
    out
}

/// Dilate with a `kernel` x `kernel` all-ones square (odd sizes; 0 and 1 return the mask).
pub fn dilate_square(mask: &Mask, kernel: u32) -> Mask {
    square_op(mask, kernel, imageproc::morphology::dilate)
}

/// [`dilate_square`] of `mask`, only over the pixels `r` = [x0, y0, x1, y1) (clamped to the
/// mask), as an `r`-sized mask. A pixel's dilation reads the mask within the square's
/// radius of it, so the crop of `r` grown by the radius and one more pixel (clamped to the
/// image, outside of which nothing is set in either case) gives the same values in `r`,
/// without reading, or writing, the rest of the frame.
pub(crate) fn dilate_square_within(mask: &Mask, kernel: u32, r: [u32; 4]) -> Mask {
    let x1 = r[2].min(mask.width);
    let y1 = r[3].min(mask.height);
    let (x0, y0) = (r[0].min(x1), r[1].min(y1));
    // The radius `square_op` uses, and one more pixel of margin.
    let m = if kernel <= 1 {
        1
    } else {
        (kernel / 2).min(254) + 1
    };
    let outer = [
        x0.saturating_sub(m),
        y0.saturating_sub(m),
        x1.saturating_add(m).min(mask.width),
        y1.saturating_add(m).min(mask.height),
    ];
    let part = dilate_square(&crop(mask, outer), kernel);
    crop(
        &part,
        [x0 - outer[0], y0 - outer[1], x1 - outer[0], y1 - outer[1]],
    )
}

/// Keep the `keep` largest 8-connected components (ties: lower label first); 0 keeps all.
pub fn keep_largest_components(mask: &Mask, keep: usize) -> Mask {
    if keep == 0 || mask.count() == 0 {
        return mask.clone();
    }
    let labels = connected_components(&to_gray(mask), Connectivity::Eight, Luma([0u8]));
    let mut sizes: Vec<usize> = Vec::new();
    for p in labels.pixels() {
        let l = p[0] as usize;
        if l > 0 {
            if sizes.len() < l {
                sizes.resize(l, 0);
            }
            sizes[l - 1] += 1;
        }
    }
    let mut order: Vec<usize> = (0..sizes.len()).collect();
    order.sort_by(|&a, &b| sizes[b].cmp(&sizes[a]).then(a.cmp(&b)));
    let mut keep_label = vec![false; sizes.len() + 1];
    for &i in order.iter().take(keep) {
        keep_label[i + 1] = true;
    }
    Mask {
        width: mask.width,
        height: mask.height,
        data: labels.pixels().map(|p| keep_label[p[0] as usize]).collect(),
    }
}

/// Pixel bounds [x0, y0, x1, y1) of the set pixels grown by `margin` (clamped), if any.
pub(crate) fn bounds(mask: &Mask, margin: u32) -> Option<[u32; 4]> {
    let (mut x0, mut y0, mut x1, mut y1) = (u32::MAX, u32::MAX, 0, 0);
    for y in 0..mask.height {
        let row = &mask.data[(y * mask.width) as usize..((y + 1) * mask.width) as usize];
        if let (Some(a), Some(b)) = (row.iter().position(|&v| v), row.iter().rposition(|&v| v)) {
            (x0, x1) = (x0.min(a as u32), x1.max(b as u32 + 1));
            (y0, y1) = (y0.min(y), y + 1);
        }
    }
    (x1 > 0).then(|| {
        [
            x0.saturating_sub(margin),
            y0.saturating_sub(margin),
            (x1 + margin).min(mask.width),
            (y1 + margin).min(mask.height),
        ]
    })
}

fn crop(mask: &Mask, b: [u32; 4]) -> Mask {
    let mut out = Mask::new(b[2] - b[0], b[3] - b[1]);
    for y in b[1]..b[3] {
        let src = (y * mask.width + b[0]) as usize;
        let dst = ((y - b[1]) * out.width) as usize;
        out.data[dst..dst + out.width as usize]
            .copy_from_slice(&mask.data[src..src + out.width as usize]);
    }
    out
}

/// The paper's post-processing: erosion by `kernel`, then the `keep` largest components.
/// Works on the mask's bounding box (plus a background margin, so the result is the same
/// as on the whole image) to keep the cost proportional to the object, not the frame.
pub fn postprocess_mask(mask: &Mask, kernel: u32, keep: usize) -> Mask {
    let Some(b) = bounds(mask, 2) else {
        return mask.clone();
    };
    let part = keep_largest_components(&erode_square(&crop(mask, b), kernel), keep);
    paste(mask.width, mask.height, &part, b)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rect(m: &mut Mask, x0: u32, y0: u32, x1: u32, y1: u32) {
        for y in y0..y1 {
            for x in x0..x1 {
                m.set(x, y, true);
            }
        }
    }

    #[test]
    fn erosion_shrinks_rectangle_by_radius() {
        let mut m = Mask::new(40, 30);
        rect(&mut m, 5, 5, 25, 20); // 20 x 15
        let e = erode_square(&m, 5); // radius 2
        assert_eq!(e.count(), 16 * 11);
        assert!(e.get(7, 7) && !e.get(6, 7) && e.get(22, 17) && !e.get(23, 17));
    }

    #[test]
    fn erosion_does_not_eat_image_border() {
        let mut m = Mask::new(20, 20);
        rect(&mut m, 0, 0, 10, 20); // touches left, top, bottom borders
        let e = erode_square(&m, 3);
        assert_eq!(e.count(), 9 * 20);
        assert!(e.get(0, 0) && e.get(8, 19) && !e.get(9, 5));
    }

    #[test]
    fn full_mask_survives_and_tiny_blobs_vanish() {
        let mut m = Mask::new(10, 10);
        rect(&mut m, 0, 0, 10, 10);
        assert_eq!(erode_square(&m, 15).count(), 100);
        let mut t = Mask::new(30, 30);
        rect(&mut t, 10, 10, 14, 14);
        assert_eq!(erode_square(&t, 5).count(), 0);
    }

    #[test]
    fn cropped_postprocess_equals_full_image() {
        let mut m = Mask::new(60, 40);
        rect(&mut m, 0, 3, 20, 30); // touches the left border
        rect(&mut m, 30, 10, 45, 25);
        rect(&mut m, 50, 0, 58, 6); // touches the top border
        rect(&mut m, 25, 34, 29, 38);
        for (k, keep) in [(3, 2), (5, 2), (3, 0), (7, 1)] {
            let full = keep_largest_components(&erode_square(&m, k), keep);
            assert_eq!(
                postprocess_mask(&m, k, keep),
                full,
                "kernel {k} keep {keep}"
            );
        }
        assert_eq!(postprocess_mask(&Mask::new(5, 5), 3, 2).count(), 0);
    }

    #[test]
    fn cropped_square_ops_equal_the_whole_image_operator() {
        let mut m = Mask::new(60, 40);
        rect(&mut m, 0, 3, 20, 30); // touches the left border
        rect(&mut m, 30, 10, 45, 25);
        rect(&mut m, 52, 0, 60, 6); // touches the top-right corner
        for k in [3, 5, 9, 15] {
            for (name, op) in [
                (
                    "erode",
                    imageproc::morphology::erode as fn(&GrayImage, Norm, u8) -> GrayImage,
                ),
                ("dilate", imageproc::morphology::dilate),
            ] {
                let whole = op(&to_gray(&m), Norm::LInf, (k / 2) as u8);
                let want: Vec<bool> = whole.pixels().map(|p| p[0] > 0).collect();
                assert_eq!(square_op(&m, k, op).data, want, "{name} kernel {k}");
            }
        }
        assert_eq!(dilate_square(&Mask::new(8, 8), 5).count(), 0);
    }

    #[test]
    fn keeps_two_largest_eight_connected() {
        let mut m = Mask::new(30, 30);
        rect(&mut m, 0, 0, 5, 5); // 25
        rect(&mut m, 5, 5, 7, 7); // diagonal touch -> same component as the first: 29
        rect(&mut m, 10, 0, 13, 3); // 9
        rect(&mut m, 20, 20, 24, 24); // 16
        rect(&mut m, 0, 20, 2, 22); // 4
        let k = keep_largest_components(&m, 2);
        assert_eq!(k.count(), 29 + 16);
        assert!(k.get(6, 6) && k.get(21, 21) && !k.get(11, 1) && !k.get(0, 20));
        assert_eq!(keep_largest_components(&m, 0).count(), m.count());
    }
}
