//! The `grounder` binary: everything lives in the library; this only hands over.

// mimalloc returns freed memory to the system soon after a burst of jobs, where the system
// allocator's per-thread arenas kept it resident (docs/memory.md has the figures).
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn main() -> std::process::ExitCode {
    grounder::cli::main()
}
