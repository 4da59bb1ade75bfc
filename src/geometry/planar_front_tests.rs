//! Tests of [`super::front_layer`]: a front layer in front of an object's main one.

use super::tests::jitter;
use super::*;

/// Points on x = 0 at the given depths (y), `n` of each, spread over a 2 m strip.
fn layers(counts: &[(f64, usize)]) -> Vec<Point3<f64>> {
    let mut out = Vec::new();
    for &(y, n) in counts {
        for i in 0..n {
            out.push(Point3::new(0.0, y + 0.003 * jitter(i, 7), 0.001 * i as f64));
        }
    }
    out
}

#[test]
fn a_front_layer_must_stand_out_of_the_noise_before_it() {
    // Histograms seen on dev scenes (points per 1 cm). A window's close-up: the glass and,
    // 6 cm before it, its frame's face, 3 % of the points, far above the readings between.
    let window = layers(&[
        (0.01, 1550),
        (0.02, 9679),
        (0.03, 150),
        (0.04, 62),
        (0.05, 69),
        (0.06, 64),
        (0.07, 78),
        (0.08, 358),
        (0.09, 1),
    ]);
    let front = front_layer(&window, 1, 1.0, 0.02, 0.02, 0.15);
    assert!((front - 0.08).abs() < 0.006, "{front}");
    // A picture 6 m away, past the sensor's range: most of its points were put on the wall,
    // and the few measured ones scatter over the 10 cm before it. Their largest bump holds
    // 4 % of the points but is no surface: the readings around it are as many.
    let picture = layers(&[
        (6.87, 1),
        (6.88, 1),
        (6.89, 3),
        (6.90, 8),
        (6.91, 3),
        (6.92, 2),
        (6.93, 4),
        (6.94, 3),
        (6.95, 6),
        (6.97, 2),
        (6.98, 301),
    ]);
    let front = front_layer(&picture, 1, -1.0, 6.98, 0.02, 0.15);
    assert!((front - 6.98).abs() < 0.006, "{front}");
}

#[test]
fn a_frame_seen_over_its_inner_faces_is_still_the_front() {
    // A window's close-up from the side (props dev 0543, object 2, per 1 cm): the glass
    // 1 cm before the wall, the frame's inner faces spread evenly over the 6 cm before
    // it, then the frame's face. The readings between never fall to half the face's.
    let inner = [
        (0.005, 4965),
        (0.015, 257),
        (0.025, 248),
        (0.035, 261),
        (0.045, 251),
        (0.055, 259),
    ];
    let window = layers(&[&inner[..], &[(0.065, 508), (0.075, 115)]].concat());
    let front = front_layer(&window, 1, 1.0, 0.005, 0.02, 0.15);
    assert!((front - 0.065).abs() < 0.006, "{front}");
    // Without the face, the inner faces alone are no layer: the front is the glass.
    let faces = layers(&inner);
    let front = front_layer(&faces, 1, 1.0, 0.005, 0.02, 0.15);
    assert!((front - 0.005).abs() < 0.006, "{front}");
}
