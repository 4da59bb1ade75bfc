//! Hostile uploads: inputs built to exhaust the process. Each must be answered with a
//! problem+json refusal while the same server keeps answering, and without the process's
//! peak memory jumping by what the input declares.

mod append_crash;
mod backpressure;
mod fuzz;
mod headers;
mod limits;
mod watchdog;

use crate::helpers::{problem, tar_of, test_config, tiny_scene_files, TestApp};

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
pub(super) fn png_claiming(w: u32, h: u32) -> Vec<u8> {
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
pub(super) fn jpeg_claiming(original: &[u8], w: u16, h: u16) -> Vec<u8> {
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
/// Fail when the process's peak memory grew by `kb` or more since `before` (VmHWM, kB).
pub(super) fn assert_peak_growth_under(before: Option<u64>, kb: u64) {
    if let (Some(a), Some(b)) = (before, vm_hwm_kb()) {
        assert!(b.saturating_sub(a) < kb, "peak memory grew by {} kB", b - a);
    }
}

/// Fail unless the server still answers `/healthz` with 200 (after `what`).
pub(super) async fn assert_still_answers(app: &TestApp, what: &str) {
    let health = app.get("/healthz").await;
    assert_eq!(health.status().as_u16(), 200, "{what}");
}

pub(super) fn vm_hwm_kb() -> Option<u64> {
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
        let (status, ct, p) = problem(r).await;
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
        assert_still_answers(&app, what).await;
    }
    // The bombs declare gigabytes to terabytes; refusing them costs next to nothing.
    assert_peak_growth_under(before, 200_000);
    let (_, list) = app.get_json("/v1/scenes").await;
    assert_eq!(list["scenes"].as_array().map(Vec::len), Some(0));
    app.stop().await;
}

/// A panic inside a job's pipeline ends that job `failed` (kind `internal`) and the worker
/// goes on: with one worker, the jobs after two panics still run.
#[tokio::test]
async fn a_panicking_job_fails_alone_and_the_worker_goes_on() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut cfg = test_config(dir.path().to_path_buf());
    cfg.workers = 1;
    cfg.pipeline = "test:delay_ms=10".into();
    let app = TestApp::spawn_with(cfg).await;
    let scene_id = app.upload_tiny_scene(3).await;
    let mut ids = Vec::new();
    for q in ["the chair [panic]", "the table [panic]", "the lamp"] {
        ids.push(app.submit_job(&scene_id, q).await);
    }
    let mut states = Vec::new();
    for id in &ids {
        let j = app.wait_job(id, std::time::Duration::from_secs(20)).await;
        states.push((
            j["status"].as_str().unwrap_or("").to_string(),
            j["error"]["code"].as_str().unwrap_or("").to_string(),
        ));
        let detail = j["error"]["detail"].as_str().unwrap_or("");
        assert!(
            !detail.contains("panicked at"),
            "no panic text leaks: {detail}"
        );
    }
    assert_eq!(
        states,
        vec![
            ("failed".into(), "internal".into()),
            ("failed".into(), "internal".into()),
            ("succeeded".into(), String::new()),
        ]
    );
    let (_, list) = app.get_json("/v1/jobs?status=running").await;
    assert_eq!(list["jobs"].as_array().map(Vec::len), Some(0), "{list}");
    app.stop().await;
}

/// A scene whose indexing fails takes the jobs queued on it down with it, with its reason.
/// The jobs are put in the queue of an indexing scene while no server runs; the scene's
/// frames are removed, so the re-indexing of the server that starts then fails.
#[tokio::test]
async fn jobs_queued_on_a_scene_that_fails_indexing_fail_with_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = test_config(dir.path().to_path_buf());
    let app = TestApp::spawn_with(cfg.clone()).await;
    let scene_id = app.upload_tiny_scene(3).await;
    app.stop().await;

    let db = dir.path().join("grounder.db");
    let url = format!("sqlite://{}", db.display());
    let pool = sqlx::SqlitePool::connect(&url).await.expect("open the db");
    sqlx::query("UPDATE scenes SET status = 'indexing' WHERE id = ?")
        .bind(&scene_id)
        .execute(&pool)
        .await
        .expect("update");
    for i in 0..5 {
        sqlx::query("INSERT INTO jobs (id, scene_id, query, status, created_at) VALUES (?, ?, ?, 'queued', '2026-01-01T00:00:00Z')")
            .bind(format!("queued-{i}"))
            .bind(&scene_id)
            .bind(format!("query {i}"))
            .execute(&pool)
            .await
            .expect("insert");
    }
    pool.close().await;

    // A detector that cannot load now stops start-up (it no longer fails indexing), so
    // indexing is made to fail by the scene's frames vanishing while no server runs.
    let scene_dir = dir.path().join("scenes").join(&scene_id);
    assert!(scene_dir.is_dir(), "{}", scene_dir.display());
    for sub in ["color", "depth"] {
        let _ = std::fs::remove_dir_all(scene_dir.join(sub));
    }
    let mut cfg2 = cfg;
    cfg2.detector = "oracle".into();
    let app = TestApp::spawn_with(cfg2).await;
    for i in 0..5 {
        let j = app
            .wait_job(&format!("queued-{i}"), std::time::Duration::from_secs(10))
            .await;
        assert_eq!(j["status"], "failed", "{j}");
        assert_eq!(j["error"]["code"], "scene_failed", "{j}");
        assert!(
            j["error"]["detail"]
                .as_str()
                .is_some_and(|d| d.contains("index")),
            "the scene's reason: {j}"
        );
    }
    app.stop().await;
}

/// A tar header of `kind` declaring `size` bytes, followed by `body`.
pub(super) fn tar_header(kind: u8, name: &str, size: u64, body: &[u8]) -> Vec<u8> {
    let mut h = [0u8; 512];
    h[..name.len()].copy_from_slice(name.as_bytes());
    h[100..107].copy_from_slice(b"0000644");
    h[124..135].copy_from_slice(format!("{size:011o}").as_bytes());
    h[136..147].copy_from_slice(b"00000000000");
    h[156] = kind;
    h[257..263].copy_from_slice(b"ustar ");
    h[263..265].copy_from_slice(b" \0");
    h[148..156].copy_from_slice(b"        ");
    let sum: u32 = h.iter().map(|&b| u32::from(b)).sum();
    h[148..155].copy_from_slice(format!("{sum:06o}\0").as_bytes());
    let mut out = h.to_vec();
    out.extend_from_slice(body);
    out
}

/// Archive metadata that a reader would hold whole in memory (GNU long names, PAX headers
/// claiming gigabytes) and a zip whose directory claims more entries than allowed are
/// refused from their headers.
#[tokio::test]
async fn archive_metadata_bombs_are_refused_from_their_headers() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut cfg = test_config(dir.path().to_path_buf());
    cfg.max_archive_files = 100;
    let app = TestApp::spawn_with(cfg).await;
    let before = vm_hwm_kb();
    let filler = vec![b'a'; 64 * 1024];
    let gnu = crate::helpers::gzip(&tar_header(b'L', "././@LongLink", 2 << 30, &filler));
    let pax = crate::helpers::gzip(&tar_header(b'x', "pax", 2 << 30, &filler));
    let plain_pax = tar_header(b'x', "pax", (2 << 30) - 1, &filler);
    let mut zip = b"PK\x03\x04".to_vec();
    zip.extend_from_slice(&[0u8; 26]);
    let mut eocd = vec![0x50, 0x4b, 0x05, 0x06, 0, 0, 0, 0];
    eocd.extend_from_slice(&60_000u16.to_le_bytes());
    eocd.extend_from_slice(&60_000u16.to_le_bytes());
    eocd.extend_from_slice(&3_000_000u32.to_le_bytes());
    eocd.extend_from_slice(&0u32.to_le_bytes());
    eocd.extend_from_slice(&0u16.to_le_bytes());
    zip.extend_from_slice(&eocd);
    let cases = [
        (
            "GNU long name of 2 GiB in tar.gz",
            gnu,
            "application/gzip",
            "GNU long name",
        ),
        (
            "PAX header of 2 GiB in tar.gz",
            pax,
            "application/gzip",
            "PAX header",
        ),
        (
            "PAX header of 2 GiB in tar",
            plain_pax,
            "application/x-tar",
            "PAX header",
        ),
        (
            "zip claiming 60000 entries",
            zip,
            "application/zip",
            "60000 entries",
        ),
    ];
    for (what, body, ct, needle) in cases {
        let r = app.upload(body, ct).await;
        let status = r.status().as_u16();
        let p: serde_json::Value = r.json().await.unwrap_or_default();
        assert_eq!(
            (status, p["code"].as_str().unwrap_or("")),
            (413, "archive_too_large"),
            "{what}: {p}"
        );
        let detail = p["detail"].as_str().unwrap_or("");
        assert!(detail.contains(needle), "{what}: {detail}");
        assert_still_answers(&app, what).await;
    }
    assert_peak_growth_under(before, 200_000);
    let leftovers: Vec<_> = std::fs::read_dir(dir.path().join("tmp"))
        .map(|d| d.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    assert!(leftovers.is_empty(), "{leftovers:?}");
    app.stop().await;
}
