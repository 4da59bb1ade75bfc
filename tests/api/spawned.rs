//! The real binary as a child process: `grounder serve` started on a free port, signalled,
//! and waited for, every wait bounded so that a server that hangs fails its test (with the
//! end of its log) instead of stalling the run.

use std::time::{Duration, Instant};

/// A `grounder serve` child process (the real binary) and its base URL; SIGKILLed when
/// dropped while still running, so a failing test leaves no server behind. The last lines
/// of its log are kept, for the message of a test that gives up on it.
pub struct Server {
    pub child: std::process::Child,
    pub base: String,
    log: std::sync::Arc<std::sync::Mutex<std::collections::VecDeque<String>>>,
    /// Ends (disconnects) when the log reader has read the log to its end.
    log_read: std::sync::mpsc::Receiver<()>,
}

impl Drop for Server {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

impl Server {
    /// The last lines the server logged (up to [`LOG_TAIL`]).
    pub fn log_tail(&self) -> String {
        self.log
            .lock()
            .map(|l| l.iter().cloned().collect::<Vec<_>>().join("\n"))
            .unwrap_or_default()
    }

    /// Send `sig` (e.g. "-KILL", "-TERM") and go on at once.
    pub fn send(&self, sig: &str) {
        let pid = self.child.id().to_string();
        std::process::Command::new("kill")
            .args([sig, &pid])
            .status()
            .expect("kill");
    }

    /// Send `sig` (e.g. "-KILL", "-TERM") and wait for the process to exit (its status is
    /// returned); a server still running [`EXIT_PATIENCE`] later fails the test with its log
    /// tail, and is killed when dropped (a shutdown that hangs must fail the test, not stall
    /// the whole run).
    pub fn signal(&mut self, sig: &str) -> std::process::ExitStatus {
        self.send(sig);
        let t = Instant::now();
        loop {
            match self.child.try_wait() {
                Ok(Some(status)) => {
                    // The log reader catches up with what the process wrote before it ended.
                    let _ = self.log_read.recv_timeout(Duration::from_secs(10));
                    return status;
                }
                Ok(None) if t.elapsed() < EXIT_PATIENCE => {
                    std::thread::sleep(Duration::from_millis(10))
                }
                _ => {
                    panic!(
                        "the server at {} did not exit within {EXIT_PATIENCE:?} of kill {sig}; its log ends:\n{}",
                        self.base,
                        self.log_tail()
                    );
                }
            }
        }
    }
}

/// How many of a spawned server's log lines [`Server`] keeps.
const LOG_TAIL: usize = 60;
/// How long a spawned server may take to print its address, or to exit once signalled.
const EXIT_PATIENCE: Duration = Duration::from_secs(60);

/// Start `grounder serve` on a free port and `data_dir`: the test pipeline (200 ms a job),
/// no detector, one worker; `env` adds or overrides settings. Returns once it listens; a
/// server that has not printed its address within [`EXIT_PATIENCE`] fails the test with its
/// log (and is killed when dropped).
pub fn start_server(data_dir: &std::path::Path, env: &[(&str, &str)]) -> Server {
    use std::io::BufRead;
    let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_grounder"));
    cmd.args(["serve", "--addr", "127.0.0.1:0", "--data-dir"])
        .arg(data_dir)
        .env("GROUNDER_PIPELINE", "test:delay_ms=200")
        .env("GROUNDER_DETECTOR", "none")
        .env("GROUNDER_WORKERS", "1")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped());
    for (k, v) in env {
        cmd.env(k, v);
    }
    let mut child = cmd.spawn().expect("spawn grounder");
    let log = std::sync::Arc::new(std::sync::Mutex::new(std::collections::VecDeque::new()));
    let (read_tx, log_read) = std::sync::mpsc::channel::<()>();
    if let Some(stderr) = child.stderr.take() {
        let keep = log.clone();
        std::thread::spawn(move || {
            let _read = read_tx;
            for line in std::io::BufReader::new(stderr).lines() {
                let Ok(line) = line else { break };
                if let Ok(mut l) = keep.lock() {
                    if l.len() == LOG_TAIL {
                        l.pop_front();
                    }
                    l.push_back(line);
                }
            }
        });
    }
    let stdout = child.stdout.take().expect("stdout");
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut line = String::new();
        let read = std::io::BufReader::new(stdout).read_line(&mut line);
        let _ = tx.send(read.map(|_| line));
    });
    let mut server = Server {
        child,
        base: String::new(),
        log,
        log_read,
    };
    let line = match rx.recv_timeout(EXIT_PATIENCE) {
        Ok(Ok(line)) => line,
        other => {
            panic!(
                "the server did not print its address ({other:?}); its log ends:\n{}",
                server.log_tail()
            );
        }
    };
    server.base = line
        .trim()
        .strip_prefix("listening on ")
        .unwrap_or_else(|| panic!("no listening line: {line:?}; log:\n{}", server.log_tail()))
        .to_string();
    server
}
