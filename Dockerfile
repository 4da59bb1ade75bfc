# Multi-stage build of the grounder service.
FROM rust:1-bookworm AS build
WORKDIR /src
COPY Cargo.toml Cargo.lock ./
COPY .cargo .cargo
COPY src src
COPY migrations migrations
COPY prompts prompts
COPY assets assets
COPY models models
# Cargo.toml declares [[bench]] targets: their sources must exist for the manifest to load.
COPY benches benches
RUN cargo build --release --locked --bin grounder

# The ONNX Runtime library comes from the onnxruntime Python wheel (one file is kept).
FROM python:3.11-slim-bookworm AS ort
RUN pip download --no-deps --only-binary=:all: onnxruntime==1.31.1 -d /tmp/ort \
 && python -c "import zipfile,glob; z=zipfile.ZipFile(glob.glob('/tmp/ort/*.whl')[0]); open('/libonnxruntime.so.1.31.1','wb').write(z.read('onnxruntime/capi/libonnxruntime.so.1.31.1'))"

FROM debian:bookworm-slim
RUN apt-get update && apt-get install -y --no-install-recommends ca-certificates libstdc++6 \
 && rm -rf /var/lib/apt/lists/* \
 && useradd --system --uid 10001 --create-home grounder \
 && mkdir -p /data /opt/grounder && chown grounder /data
COPY --from=build /src/target/release/grounder /usr/local/bin/grounder
COPY --from=build /src/models /opt/grounder/models
COPY --from=ort /libonnxruntime.so.1.31.1 /opt/grounder/lib/libonnxruntime.so.1.31.1
ENV ORT_DYLIB_PATH=/opt/grounder/lib/libonnxruntime.so.1.31.1 \
    GROUNDER_ADDR=0.0.0.0:8080 \
    GROUNDER_DATA_DIR=/data \
    GROUNDER_MODEL_DIR=/opt/grounder/models
USER grounder
WORKDIR /opt/grounder
VOLUME ["/data"]
EXPOSE 8080
# Liveness from inside the container, with what the slim image has (bash, no curl):
# GET /healthz on the port GROUNDER_ADDR names.
HEALTHCHECK --interval=30s --timeout=5s --start-period=20s --retries=3 \
  CMD ["bash", "-c", "exec 3<>/dev/tcp/127.0.0.1/${GROUNDER_ADDR##*:} && printf 'GET /healthz HTTP/1.0\\r\\nHost: localhost\\r\\n\\r\\n' >&3 && head -n1 <&3 | grep -q ' 200 '"]
ENTRYPOINT ["grounder"]
CMD ["serve"]
