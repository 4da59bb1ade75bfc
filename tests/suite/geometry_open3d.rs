//! Our statistical outlier removal must keep exactly the points Open3D keeps.
//! Fixture: tests/fixtures/geometry/sor_open3d.json (made by make_sor_fixture.py there).

use grounder::geometry::{neighbour_mean_distances, statistical_outlier_indices};
use nalgebra::Point3;
use serde::Deserialize;

#[derive(Deserialize)]
struct Case {
    name: String,
    nb_neighbors: usize,
    std_ratio: f64,
    points: Vec<[f64; 3]>,
    kept: Vec<usize>,
    mean_distances: Vec<f64>,
}

#[derive(Deserialize)]
struct Fixture {
    open3d_version: String,
    cases: Vec<Case>,
}

#[test]
fn sor_matches_open3d_kept_indices() -> anyhow::Result<()> {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fixtures/geometry/sor_open3d.json"
    );
    let fx: Fixture = serde_json::from_str(&std::fs::read_to_string(path)?)?;
    assert!(fx.cases.len() >= 3, "fixture has {} cases", fx.cases.len());
    for c in &fx.cases {
        let pts: Vec<Point3<f64>> = c
            .points
            .iter()
            .map(|p| Point3::new(p[0], p[1], p[2]))
            .collect();
        let means = neighbour_mean_distances(&pts, c.nb_neighbors);
        assert_eq!(means.len(), c.mean_distances.len());
        let worst = means
            .iter()
            .zip(&c.mean_distances)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(
            worst <= 1e-6,
            "{}: mean neighbour distance differs by {worst}",
            c.name
        );
        let ours = statistical_outlier_indices(&pts, c.nb_neighbors, c.std_ratio);
        assert!(
            c.kept.len() < pts.len(),
            "{}: case removes nothing, not a useful check",
            c.name
        );
        assert_eq!(
            ours, c.kept,
            "case {} (Open3D {})",
            c.name, fx.open3d_version
        );
        println!(
            "{}: {} of {} kept, identical to Open3D {}; max |mean distance diff| = {worst:e}",
            c.name,
            ours.len(),
            pts.len(),
            fx.open3d_version
        );
    }
    Ok(())
}
