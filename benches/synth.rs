//! Speed of `synth::generate`: the target is 60 ScanNet-sized frames
//! (colour 1296x968, depth 640x480) in under 30 s on 2 cores in release mode.

use criterion::{criterion_group, criterion_main, Criterion};
use grounder::synth::{generate, Noise, SynthParams};
use std::time::Duration;

fn bench(c: &mut Criterion) {
    let tmp = tempfile::tempdir().expect("temporary directory");
    let mut g = c.benchmark_group("synth");
    g.sample_size(10)
        .warm_up_time(Duration::from_millis(100))
        .measurement_time(Duration::from_secs(1));
    g.bench_function("small_8_frames_320x240", |b| {
        b.iter(|| generate(&SynthParams::small(7), tmp.path()).expect("generate"))
    });
    g.bench_function("scannet_60_frames_1296x968_realistic", |b| {
        b.iter(|| {
            generate(
                &SynthParams {
                    noise: Noise::Realistic,
                    ..SynthParams::new(7)
                },
                tmp.path(),
            )
            .expect("generate")
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
