# Multi-stage build of the `retex` binary.
FROM rust:1-bookworm AS build
WORKDIR /src
COPY Cargo.toml ./
COPY src ./src
RUN cargo build --release

FROM debian:bookworm-slim
RUN useradd --system --home /var/lib/retex retex && mkdir -p /var/lib/retex && chown retex /var/lib/retex
COPY --from=build /src/target/release/retex /usr/local/bin/retex
USER retex
WORKDIR /var/lib/retex
ENTRYPOINT ["/usr/local/bin/retex"]
CMD ["--help"]
