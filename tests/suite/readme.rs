//! Every command in the README's shell blocks is checked, so that a README command that no
//! longer works fails CI: `grounder` / `cargo run -- ...` lines are parsed by the binary's
//! own command-line parser (subcommand, flags and values), `curl` and `open` URLs must name
//! a path of openapi.yaml, scripts must exist and be executable, and `cargo test` is the
//! command `.ci/run` itself runs. A line of any other kind fails the test: add a check for
//! it here.

use clap::Parser;
use grounder::cli::Cli;
use std::path::Path;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The commands of the README's ```sh blocks: continuation lines joined, comments and
/// blank lines dropped.
fn readme_commands() -> Vec<String> {
    let text = std::fs::read_to_string(root().join("README.md")).unwrap();
    let mut out = Vec::new();
    let mut in_block = false;
    let mut pending = String::new();
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            in_block = !in_block && line.trim() == "```sh";
            continue;
        }
        if !in_block {
            continue;
        }
        let line = strip_comment(line);
        if let Some(head) = line.trim_end().strip_suffix('\\') {
            pending.push_str(head);
            pending.push(' ');
            continue;
        }
        pending.push_str(&line);
        let cmd = std::mem::take(&mut pending).trim().to_string();
        if !cmd.is_empty() {
            out.push(cmd);
        }
    }
    out
}

/// The line without a trailing `# comment` (a `#` after whitespace, outside quotes).
fn strip_comment(line: &str) -> String {
    let (mut single, mut double) = (false, false);
    let mut prev = ' ';
    for (i, c) in line.char_indices() {
        match c {
            '\'' if !double => single = !single,
            '"' if !single => double = !double,
            '#' if !single && !double && prev.is_whitespace() => return line[..i].to_string(),
            _ => {}
        }
        prev = c;
    }
    line.to_string()
}

/// Shell words with `$VAR` replaced by a placeholder id and leading `NAME=value`
/// assignments dropped.
fn words(cmd: &str) -> Vec<String> {
    let w =
        shlex::split(&cmd.replace('$', "V_")).unwrap_or_else(|| panic!("unbalanced quotes: {cmd}"));
    w.into_iter()
        .skip_while(|w| {
            w.split_once('=').is_some_and(|(k, _)| {
                !k.is_empty() && k.chars().all(|c| c.is_ascii_uppercase() || c == '_')
            })
        })
        .collect()
}

/// Paths of openapi.yaml, as patterns (`{id}` matches one segment).
fn api_paths() -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(root().join("openapi.yaml")).unwrap();
    text.lines()
        .filter_map(|l| l.strip_prefix("  /"))
        .filter_map(|l| l.strip_suffix(':'))
        .map(|p| p.split('/').map(str::to_string).collect())
        .collect()
}

fn path_is_in_api(url: &str, paths: &[Vec<String>]) -> bool {
    let after_host = url.split_once("://").map_or(url, |(_, r)| r);
    let path = after_host.split_once('/').map_or("", |(_, p)| p);
    let path = path.split(['?', '#']).next().unwrap_or("");
    let segs: Vec<&str> = path.split('/').collect();
    paths.iter().any(|p| {
        p.len() == segs.len()
            && p.iter().zip(&segs).all(|(a, b)| {
                a == b
                    || (a.starts_with('{') && !b.is_empty())
                    || (a.contains('{') && a.ends_with(".png") && b.ends_with(".png"))
            })
    })
}

fn check(cmd: &str, paths: &[Vec<String>]) -> Result<(), String> {
    let mut problems = Vec::new();
    for part in cmd.split("&&") {
        let w = words(part.trim());
        let Some(first) = w.first() else { continue };
        let grounder_args: Option<Vec<String>> = match first.as_str() {
            "grounder" => Some(w[1..].to_vec()),
            "cargo" if w.get(1).is_some_and(|s| s == "run") => {
                let at = w
                    .iter()
                    .position(|s| s == "--")
                    .ok_or("cargo run without --")?;
                Some(w[at + 1..].to_vec())
            }
            _ => None,
        };
        if let Some(args) = grounder_args {
            let argv = std::iter::once("grounder".to_string()).chain(args);
            if let Err(e) = Cli::try_parse_from(argv) {
                problems.push(format!("{part}: {}", e.kind()));
            }
            continue;
        }
        match first.as_str() {
            "cargo" if w.get(1).is_some_and(|s| s == "test") => {
                let ci = std::fs::read_to_string(root().join(".ci/run")).unwrap();
                if !ci.contains("cargo test") {
                    problems.push(".ci/run does not run cargo test".into());
                }
            }
            "curl" | "open" => match w
                .iter()
                .find(|a| a.contains("localhost") || a.contains("127.0.0.1"))
            {
                Some(url) if path_is_in_api(url, paths) => {}
                Some(url) => problems.push(format!("{url}: no such path in openapi.yaml")),
                None => problems.push(format!("{part}: no URL")),
            },
            s if s.starts_with("scripts/") => {
                let meta = std::fs::metadata(root().join(s)).map_err(|e| format!("{s}: {e}"))?;
                use std::os::unix::fs::PermissionsExt;
                if meta.permissions().mode() & 0o111 == 0 {
                    problems.push(format!("{s} is not executable"));
                }
            }
            other => problems.push(format!("no check for a `{other}` command: {part}")),
        }
    }
    if problems.is_empty() {
        Ok(())
    } else {
        Err(problems.join("; "))
    }
}

#[test]
fn every_readme_command_parses_and_names_what_exists() {
    let cmds = readme_commands();
    assert!(
        cmds.len() >= 8,
        "the README's shell blocks went missing: {cmds:?}"
    );
    let paths = api_paths();
    let failures: Vec<String> = cmds.iter().filter_map(|c| check(c, &paths).err()).collect();
    assert!(
        failures.is_empty(),
        "README commands that no longer work:\n{}",
        failures.join("\n")
    );
}

#[test]
fn the_checks_catch_what_no_longer_works() {
    let paths = api_paths();
    assert!(check("grounder serve --addr 127.0.0.1:8080", &paths).is_ok());
    assert!(check("grounder serve --no-such-flag", &paths).is_err());
    assert!(check("cargo run --release -- frobnicate", &paths).is_err());
    assert!(check("curl localhost:8080/v1/jobs/$JOB", &paths).is_ok());
    assert!(check("curl localhost:8080/v1/nowhere", &paths).is_err());
    assert!(check("scripts/no-such-script.sh", &paths).is_err());
    assert!(check("rm -rf /", &paths).is_err());
    assert_eq!(
        words("GROUNDER_X=1 OPENAI_API_KEY=sk cargo run -- serve"),
        ["cargo", "run", "--", "serve"]
    );
    assert_eq!(strip_comment("curl x  # a '#' comment"), "curl x  ");
}
