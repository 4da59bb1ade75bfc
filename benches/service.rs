//! Service benchmarks (run: `cargo bench --bench service`):
//! - polling throughput of `GET /v1/jobs/{id}` with 32 concurrent keep-alive clients
//!   (the clients share the machine's cores with the server, so this is a lower bound);
//! - scene ingest speed for ScanNet-size frames (1296x968 JPEG + 640x480 16-bit depth).

use grounder::config::Config;
use grounder::startup::Application;
use std::io::Write;
use std::time::{Duration, Instant};

fn scannet_size_scene(frames: usize) -> Vec<u8> {
    let mut b = tar::Builder::new(Vec::new());
    let mut add = |path: String, bytes: &[u8]| {
        let mut h = tar::Header::new_gnu();
        h.set_size(bytes.len() as u64);
        h.set_mode(0o644);
        h.set_cksum();
        b.append_data(&mut h, path, bytes).expect("tar");
    };
    for i in 0..frames {
        let img = image::RgbImage::from_fn(1296, 968, |x, y| {
            let n = (x.wrapping_mul(2654435761) ^ y.wrapping_mul(40503) ^ i as u32) % 32;
            image::Rgb([
                ((x / 5) as u8).wrapping_add(n as u8),
                ((y / 4) as u8).wrapping_add(n as u8),
                (i * 7) as u8,
            ])
        });
        let mut jpg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpg, 90)
            .encode_image(&img)
            .expect("jpeg");
        add(format!("color/{}.jpg", i * 20), &jpg);
        let depth = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(640, 480, |x, y| {
            image::Luma([800 + ((x * 7 + y * 3) % 3000) as u16])
        });
        let mut png = Vec::new();
        depth
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .expect("png");
        add(format!("depth/{}.png", i * 20), &png);
        add(
            format!("pose/{}.txt", i * 20),
            format!("1 0 0 {i}\n0 1 0 0\n0 0 1 0\n0 0 0 1\n").as_bytes(),
        );
    }
    add(
        "intrinsic/intrinsic_color.txt".into(),
        b"1170 0 648 0\n0 1170 484 0\n0 0 1 0\n0 0 0 1\n",
    );
    add(
        "intrinsic/intrinsic_depth.txt".into(),
        b"577 0 320 0\n0 577 240 0\n0 0 1 0\n0 0 0 1\n",
    );
    b.into_inner().expect("tar")
}

fn main() {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .expect("runtime");
    rt.block_on(async {
        let dir = tempfile::tempdir().expect("tempdir");
        let cfg = Config { addr: "127.0.0.1:0".into(), data_dir: dir.path().into(), pipeline: "test:delay_ms=1".into(), detector: "none".into(), ..Config::default() };
        let app = Application::build(cfg).await.expect("app");
        let base = format!("http://{}", app.local_addr().expect("addr"));
        tokio::spawn(app.run_until(std::future::pending()));
        let c = reqwest::Client::new();

        let frames = 60;
        let body = scannet_size_scene(frames);
        let mut best = f64::MAX;
        let mut sid = String::new();
        for _ in 0..3 {
            let t = Instant::now();
            let r = c.post(format!("{base}/v1/scenes")).header("content-type", "application/x-tar").body(body.clone()).send().await.expect("upload");
            let secs = t.elapsed().as_secs_f64();
            assert_eq!(r.status().as_u16(), 201);
            sid = r.json::<serde_json::Value>().await.expect("json")["id"].as_str().unwrap_or_default().to_string();
            best = best.min(secs);
        }
        println!("ingest: {frames} ScanNet-size frames ({:.0} MB tar) in {:.2} s = {:.0} frames/s (best of 3)", body.len() as f64 / 1e6, best, frames as f64 / best);

        let job: serde_json::Value = c.post(format!("{base}/v1/jobs")).json(&serde_json::json!({"scene_id": sid, "query": "the chair"})).send().await.expect("job").json().await.expect("json");
        let url = format!("{base}/v1/jobs/{}", job["id"].as_str().unwrap_or_default());
        tokio::time::sleep(Duration::from_millis(500)).await;
        let dur = Duration::from_secs(5);
        let start = Instant::now();
        let mut tasks = Vec::new();
        for _ in 0..32 {
            let (c, url) = (c.clone(), url.clone());
            tasks.push(tokio::spawn(async move {
                let mut n = 0u64;
                while start.elapsed() < dur {
                    let r = c.get(&url).send().await.expect("get");
                    let _ = r.bytes().await;
                    n += 1;
                }
                n
            }));
        }
        let mut total = 0;
        for t in tasks {
            total += t.await.unwrap_or(0);
        }
        println!("polling: {} GET /v1/jobs/{{id}} in {:.1} s = {:.0} req/s (32 clients in-process)", total, start.elapsed().as_secs_f64(), total as f64 / start.elapsed().as_secs_f64());
        let _ = std::io::stdout().flush();
    });
}
