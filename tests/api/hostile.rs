//! Hostile uploads: inputs built to exhaust the process. Each must be answered with a
//! problem+json refusal while the same server keeps answering, and without the process's
//! peak memory jumping by what the input declares.

use crate::helpers::{tar_of, test_config, tiny_scene_files, TestApp};

/// A PNG chunk: length, type, data, CRC over type and data.
fn png_chunk(kind: &[u8; 4], data: &[u8]) -> Vec<u8> {
    let mut out = (data.len() as u32).to_be_bytes().to_vec();
    out.extend_from_slice(kind);
    out.extend_from_slice(data);
    let mut crc = flate2::Crc::new();
    crc.update(kind);
    crc.update(data);
    out.extend_from_slice(&crc.sum().to_be_bytes());
    out
}

/// A tiny PNG whose header claims `w` x `h` 16-bit grey pixels.
fn png_claiming(w: u32, h: u32) -> Vec<u8> {
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = w.to_be_bytes().to_vec();
    ihdr.extend_from_slice(&h.to_be_bytes());
    ihdr.extend_from_slice(&[16, 0, 0, 0, 0]);
    png.extend(png_chunk(b"IHDR", &ihdr));
    let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
    std::io::Write::write_all(&mut z, &[0u8; 64]).expect("zlib");
    png.extend(png_chunk(b"IDAT", &z.finish().expect("zlib")));
    png.extend(png_chunk(b"IEND", &[]));
    png
}

/// A valid JPEG with the size in its frame header rewritten to `w` x `h`.
fn jpeg_claiming(original: &[u8], w: u16, h: u16) -> Vec<u8> {
    let mut out = original.to_vec();
    let sof = (0..out.len() - 1)
        .find(|&i| out[i] == 0xFF && (0xC0..=0xC2).contains(&out[i + 1]))
        .expect("a frame header");
    // FF Cx, length (2), precision (1), height (2), width (2).
    out[sof + 5..sof + 7].copy_from_slice(&h.to_be_bytes());
    out[sof + 7..sof + 9].copy_from_slice(&w.to_be_bytes());
    out
}

/// Peak resident memory of this process in kB (Linux), if it can be read.
fn vm_hwm_kb() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

#[tokio::test]
async fn image_dimension_bombs_are_refused_and_the_server_lives() {
    let dir = tempfile::tempdir().expect("tempdir");
    let app = TestApp::spawn_with(test_config(dir.path().to_path_buf())).await;
    let good = tiny_scene_files(3);
    let replace = |path: &str, bytes: Vec<u8>| -> Vec<(String, Vec<u8>)> {
        good.iter()
            .map(|(p, b)| (p.clone(), if p == path { bytes.clone() } else { b.clone() }))
            .collect()
    };
    let jpg = good
        .iter()
        .find(|(p, _)| p == "color/20.jpg")
        .map(|(_, b)| b.clone())
        .expect("frame 20");
    let before = vm_hwm_kb();
    let cases = [
        // 10^12 pixels of 16 bits: 2 TB if allocated from the header.
        (
            "depth PNG claiming 1,000,000 x 1,000,000",
            replace("depth/20.png", png_claiming(1_000_000, 1_000_000)),
        ),
        (
            "depth PNG claiming 60,000 x 60,000 (under the decoder's side limit)",
            replace("depth/0.png", png_claiming(60_000, 60_000)),
        ),
        (
            "colour JPEG claiming 65,535 x 65,535",
            replace("color/20.jpg", jpeg_claiming(&jpg, 65_535, 65_535)),
        ),
    ];
    for (what, files) in cases {
        let body = tar_of(&files, None);
        assert!(body.len() < 100_000, "{what}: the input itself is small");
        let r = app.upload(body, "application/x-tar").await;
        let status = r.status().as_u16();
        let ct = r
            .headers()
            .get("content-type")
            .and_then(|v| v.to_str().ok())
            .unwrap_or("")
            .to_string();
        let p: serde_json::Value = r.json().await.unwrap_or_default();
        assert_eq!(
            (status, p["code"].as_str().unwrap_or("")),
            (413, "image_too_large"),
            "{what}: {p}"
        );
        assert_eq!(ct, "application/problem+json", "{what}");
        let detail = p["detail"].as_str().unwrap_or("");
        assert!(
            detail.contains("max_image_pixels") && detail.contains("frame"),
            "{what}: the detail names the limit and the entry: {detail}"
        );
        let health = app
            .client
            .get(app.url("/healthz"))
            .send()
            .await
            .expect("the server still answers");
        assert_eq!(health.status().as_u16(), 200, "{what}");
    }
    if let (Some(a), Some(b)) = (before, vm_hwm_kb()) {
        // The bombs declare gigabytes to terabytes; refusing them costs next to nothing.
        assert!(
            b.saturating_sub(a) < 200_000,
            "peak memory grew by {} kB",
            b - a
        );
    }
    let (_, list) = app.get_json("/v1/scenes").await;
    assert_eq!(list["scenes"].as_array().map(Vec::len), Some(0));
    app.stop().await;
}
