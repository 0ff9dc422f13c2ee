# Multi-stage build of the `retex` binary; the runtime image runs `retex serve` as a non-root
# user with its data directory on a volume.
#   docker build -t retex:0.1.0 .
#   docker run -p 8080:8080 -v retex-data:/var/lib/retex retex:0.1.0
# Any Rust >= 1.89 (Cargo.toml's rust-version); Cargo.lock pins the crates (--locked).
FROM rust:1-bookworm AS build
WORKDIR /src
COPY Cargo.toml Cargo.lock ./
COPY src ./src
# The constraints schema is compiled in (src/engine/methods/schema.rs: include_str!).
COPY api ./api
RUN cargo build --release --locked --bin retex

FROM debian:bookworm-slim
RUN apt-get update \
    && apt-get install -y --no-install-recommends ca-certificates curl \
    && rm -rf /var/lib/apt/lists/* \
    && groupadd --system --gid 10001 retex \
    && useradd --system --uid 10001 --gid retex --home-dir /var/lib/retex retex \
    && mkdir -p /var/lib/retex && chown retex:retex /var/lib/retex
COPY --from=build /src/target/release/retex /usr/local/bin/retex
USER retex
WORKDIR /var/lib/retex
ENV RETEX_ADDR=0.0.0.0:8080 \
    RETEX_DATA_DIR=/var/lib/retex
VOLUME ["/var/lib/retex"]
EXPOSE 8080
HEALTHCHECK --interval=15s --timeout=3s --start-period=10s --retries=3 \
    CMD curl -fsS http://127.0.0.1:8080/healthz || exit 1
# SIGTERM drains connections and lets running jobs finish or re-enqueue (RETEX_SHUTDOWN_SECS).
STOPSIGNAL SIGTERM
ENTRYPOINT ["/usr/local/bin/retex"]
CMD ["serve"]
